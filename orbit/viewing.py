"""Where on its orbit a sequence is flown: the phase (and if need be the orbit plane) that keeps
the target lit and in view.

A relative-motion sequence is the same in LVLH whatever the reference orbit's argument of
latitude at the epoch ``u₀`` and its right ascension of the ascending node ``Ω``; these only
decide where the Sun and the Earth are. A LEO target spends a third of each orbit in the
Earth's shadow, so a sequence that starts at an arbitrary ``u₀`` can have a third of its
frames black. :func:`sunlit_geometry` chooses ``u₀`` (and, when no ``u₀`` is enough and ``Ω``
is free, ``Ω``) so that as many frames as possible are fully sunlit, in view (no Earth on the
line of sight) and with the Sun outside the lens's exclusion cone, with the same flags as
:func:`orbit.visibility.visibility`.

The search scores each candidate on at most ``max_frames`` frames spread over the window
(the first and last included) and, among the best, takes the middle of the longest run of
neighbouring best ``u₀`` values, so that the chosen geometry keeps a margin on both sides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._checks import finite_array, finite_scalar
from .reference import ReferenceOrbit
from .sun import sun_position_eci
from .visibility import DEFAULT_SUN_MARGIN_RAD, visibility

__all__ = ["SunlitGeometry", "fully_lit_and_in_view", "sunlit_geometry"]

PHASE_STEP_DEG = 1.0
"""Spacing of the ``u₀`` candidates [deg]."""
PLANE_STEP_DEG = 10.0
"""Spacing of the ``Ω`` candidates, where the orbit plane is searched too [deg]."""
_COARSE_PHASE_STEP_DEG = 5.0  # u₀ spacing while Ω is searched; refined to PHASE_STEP_DEG after


@dataclass(frozen=True, slots=True)
class SunlitGeometry:
    """The orbit geometry :func:`sunlit_geometry` chose.

    Attributes
    ----------
    raan_rad : float
        Right ascension of the ascending node Ω [rad].
    arg_lat_rad : float
        Argument of latitude u₀ of the target at the epoch [rad].
    lit_frames : int
        Frames of the scored set that are fully sunlit and in view with it [-].
    scored_frames : int
        Frames scored (at most ``max_frames`` of the sequence) [-].
    plane_searched : bool
        Whether Ω was searched (no u₀ alone made every scored frame lit and in view).
    """

    raan_rad: float
    arg_lat_rad: float
    lit_frames: int
    scored_frames: int
    plane_searched: bool


def fully_lit_and_in_view(orbit: ReferenceOrbit, s_lvlh, t_s, r_sun_eci=None, *,
                          sun_margin_rad: float = DEFAULT_SUN_MARGIN_RAD) -> np.ndarray:
    """Per frame: line of sight clear, Sun clear of the lens and the target fully sunlit
    (ν = 1), for an observer at the LVLH states ``s_lvlh`` (N, 6) at times ``t_s`` (N,) [s]
    of ``orbit``; ``r_sun_eci`` (N, 3) [m] if already computed. Stricter than
    :attr:`orbit.visibility.Visibility.visible`, which counts a frame in penumbra as lit."""
    t = finite_array("t_s", t_s, ndim=(1,))
    if r_sun_eci is None:
        r_sun_eci = sun_position_eci(orbit.unix_s(t))
    r_obs, _ = orbit.observer_state_eci(s_lvlh, t)
    r_tgt, _ = orbit.target_state_eci(t)
    vis = visibility(r_obs, r_tgt, r_sun_eci, sun_margin_rad=sun_margin_rad)
    return vis.line_of_sight & vis.sun_clear & (vis.illuminated_fraction >= 1.0)


def _scores(make_orbit, phases_rad: np.ndarray, s_lvlh, t_s, r_sun, margin: float) -> np.ndarray:
    """Per candidate phase, the frames :func:`fully_lit_and_in_view` counts, with one
    :func:`orbit.visibility.visibility` of every candidate's frames stacked (its tests are
    elementwise per frame: the same flags as one call per candidate, in a tenth of the time)."""
    t = finite_array("t_s", t_s, ndim=(1,))
    r_obs, r_tgt = [], []
    for u0 in phases_rad:
        orbit = make_orbit(u0)
        r_obs.append(orbit.observer_state_eci(s_lvlh, t)[0])
        r_tgt.append(orbit.target_state_eci(t)[0])
    n = len(phases_rad)
    vis = visibility(np.concatenate(r_obs), np.concatenate(r_tgt), np.tile(np.asarray(r_sun, dtype=np.float64), (n, 1)),
                     sun_margin_rad=margin)
    ok = vis.line_of_sight & vis.sun_clear & (vis.illuminated_fraction >= 1.0)
    return np.count_nonzero(ok.reshape(n, t.size), axis=1)


def _best_run(scores: np.ndarray) -> tuple[int, int]:
    """(index at the middle of the longest circular run of maximal scores, its length)."""
    best = scores == scores.max()
    n = len(scores)
    if best.all():
        return 0, n
    start = int(np.flatnonzero(~best)[0]) + 1  # begin just after a non-best candidate
    run_start, run_len, cur_start, cur_len = 0, 0, 0, 0
    for k in range(n):
        i = (start + k) % n
        if best[i]:
            if cur_len == 0:
                cur_start = i
            cur_len += 1
            if cur_len > run_len:
                run_start, run_len = cur_start, cur_len
        else:
            cur_len = 0
    return (run_start + (run_len - 1) // 2) % n, run_len


def sunlit_geometry(s_lvlh, t_s, *, altitude_m: float, inclination_rad: float, epoch_utc: str,
                    raan_rad: float | None = None, arg_lat_rad: float | None = None,
                    sun_margin_rad: float = DEFAULT_SUN_MARGIN_RAD, max_frames: int = 256) -> SunlitGeometry:
    """Choose the free parts of the orbit geometry so that the target is lit and in view.

    Parameters
    ----------
    s_lvlh : array_like, shape (N, 6)
        Observer states relative to the target in LVLH at ``t_s`` [m, m/s].
    t_s : array_like, shape (N,)
        Times since the epoch [s].
    altitude_m, inclination_rad, epoch_utc
        The fixed parts of the reference orbit (as :class:`orbit.reference.ReferenceOrbit`).
    raan_rad, arg_lat_rad : float or None
        Ω and u₀ [rad]; None: chosen here. Ω is only moved from 0 when no u₀ makes every
        scored frame lit and in view at Ω = 0.
    sun_margin_rad : float
        Stray-light margin of the Sun-in-lens test [rad].
    max_frames : int
        Frames scored per candidate (evenly spread, first and last included) [-].

    Returns
    -------
    SunlitGeometry
        With both angles set; the given ones unchanged.

    Raises
    ------
    ValueError
        On non-finite or mismatched input.
    """
    s = finite_array("s_lvlh", s_lvlh, shape_tail=(6,))
    t = finite_array("t_s", t_s, ndim=(1,))
    if s.shape[0] != t.shape[0] or t.size == 0:
        raise ValueError(f"s_lvlh and t_s must hold the same number (> 0) of frames, got {s.shape[0]} and {t.size}")
    margin = finite_scalar("sun_margin_rad", sun_margin_rad, nonnegative=True)
    pick = np.unique(np.round(np.linspace(0, t.size - 1, min(t.size, int(max_frames)))).astype(np.int64))
    s, t = s[pick], t[pick]

    def orbit(raan: float, u0: float) -> ReferenceOrbit:
        return ReferenceOrbit(altitude_m=altitude_m, inclination_rad=inclination_rad, raan_rad=raan,
                              arg_lat_rad=u0, epoch_utc=epoch_utc)

    r_sun = sun_position_eci(orbit(0.0, 0.0).unix_s(t))
    if arg_lat_rad is not None:
        raan = 0.0 if raan_rad is None else float(raan_rad)
        lit = int(_scores(lambda u0: orbit(raan, u0), np.array([float(arg_lat_rad)]), s, t, r_sun, margin)[0])
        return SunlitGeometry(raan, float(arg_lat_rad), lit, t.size, False)

    phases = np.radians(np.arange(0.0, 360.0, PHASE_STEP_DEG))
    raan = 0.0 if raan_rad is None else float(raan_rad)
    scores = _scores(lambda u0: orbit(raan, u0), phases, s, t, r_sun, margin)
    k, _ = _best_run(scores)
    if scores[k] == t.size or raan_rad is not None:
        return SunlitGeometry(raan, float(phases[k]), int(scores[k]), t.size, False)

    coarse = np.radians(np.arange(0.0, 360.0, _COARSE_PHASE_STEP_DEG))
    best = (int(scores[k]), 0, 0.0)  # (lit frames, run length, Ω): Ω = 0 unless another plane does better
    for raan_deg in np.arange(PLANE_STEP_DEG, 360.0, PLANE_STEP_DEG):
        sc = _scores(lambda u0, r=math.radians(raan_deg): orbit(r, u0), coarse, s, t, r_sun, margin)
        j, run = _best_run(sc)
        if (int(sc[j]), run) > best[:2]:
            best = (int(sc[j]), run, math.radians(raan_deg))
    raan = best[2]
    scores = _scores(lambda u0: orbit(raan, u0), phases, s, t, r_sun, margin)
    k, _ = _best_run(scores)
    return SunlitGeometry(raan, float(phases[k]), int(scores[k]), t.size, True)
