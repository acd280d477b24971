"""The plan of one sequence: states, poses, light directions, visibility and image motion.

:func:`plan_orbit` turns a scenario configuration into everything a sequence needs but its
pixels: the relative orbit sampled (or set explicitly) and propagated with the
Clohessy–Wiltshire equations, the reference orbit placed so that the target is lit and in
view, the Sun, the visibility flags, the target's attitude, the camera's look-at pose and the
per-frame light directions in the target's body frame, and, for ``motion_blur = "auto"``, the
image motion of the target during an exposure. Maths and conventions: docs/orbit.md and
docs/conventions.md.

The configuration is the scenario configuration of the command line as a dict of tables
(``sequence``, ``orbit``, ``attitude``, ``camera``, ``pattern``, ``degrade``; keys as in its
TOML file, SI units in the names). A key ``amplitude_m`` is the option ``--amplitude-m``;
errors (:class:`PlanError`) carry the key they are about and name options that way.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from . import cw, pose, visibility
from .attitude import TargetAttitude
from .epoch import gmst_rad, to_iso_utc, to_unix_seconds
from .patterns import PATTERNS, classify, parameters, state_from_kappa
from .reference import ReferenceOrbit
from .rotations import rot_z
from .sampling import default_window_s, range_band, sample_pattern
from .sun import VALID_UTC_RANGE_S, sun_position_eci
from .viewing import sunlit_geometry

__all__ = ["PlanError", "plan_orbit", "image_motion", "plan_table", "MOTION_SAMPLES", "MOTION_TOL_PX",
           "MOTION_TOL_REL"]


class PlanError(ValueError):
    """A configuration that cannot make a sequence; ``key`` names the configuration key at fault
    (``amplitude_m``: the option ``--amplitude-m``)."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


_ATTITUDE_KEYS = {"spin_axis_body": "spin_axis", "omega0_body_rad_s": "omega0_deg_s",
                  "inertia_body_kg_m2": "inertia_kg_m2", "R0_lvlh_from_body": "attitude_ypr_deg",
                  "spin_rate_rad_s": "spin_rate_deg_s", "yaw_deg": "attitude_ypr_deg",
                  "pitch_deg": "attitude_ypr_deg", "roll_deg": "attitude_ypr_deg"}


def _attitude_error(message: str) -> PlanError:
    """An error of :class:`orbit.attitude.TargetAttitude` about the configuration key that set the
    field it names."""
    for field, key in _ATTITUDE_KEYS.items():
        if message.startswith(field):
            return PlanError(key, message[len(field):].strip())
    return PlanError("attitude", message)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)



def _explicit_pattern(cfg: dict, given: set, n: float, band, radius_m: float):
    """Initial state from --amplitude-m/--kappa (and optional γ, B, phases) instead of a draw."""
    p, seq = cfg["pattern"], cfg["sequence"]
    if p["amplitude_m"] is None or p["kappa"] is None:
        missing = "amplitude_m" if p["amplitude_m"] is None else "kappa"
        raise PlanError(missing, "explicit pattern parameters need both --amplitude-m and --kappa")
    A, kappa = p["amplitude_m"], p["kappa"]
    z_amp = p["z_amp_m"] or 0.0
    z_phase = math.radians(p["z_phase_deg"] or 0.0)
    tau0 = math.radians(p["tau0_deg"] or 0.0)
    x_l = kappa * A
    beta = 1.5 * n * x_l
    window = seq["window_s"] or default_window_s(_class_of(kappa), n, x_l_m=x_l, scale=band.scale)
    gamma = p["gamma_m"] if p["gamma_m"] is not None else beta * (window / 2.0 + tau0 / n)
    s0 = state_from_kappa(A, kappa, gamma, n, z_amp=z_amp, z_phase=z_phase, tau0=tau0)
    params = parameters(s0, n)
    # the class is that of the kappa given (|kappa| = kappa* is drip-drop, 1 drift: docs/orbit.md, "Patterns and
    # their thresholds"); kappa recomputed from the state can fall an ulp on the other side of a boundary
    # (kappa* gave "spiral")
    pattern = _class_of(kappa)
    if params.pattern != pattern and params.pattern in PATTERNS:
        params = replace(params, pattern=pattern)
    if "pattern" in given and pattern != seq["pattern"]:
        raise PlanError("kappa", f"amplitude {A:g} m and kappa {kappa:g} make the pattern {pattern}, "
                       f"not {seq['pattern']} (spiral: 0 < |kappa| < 0.2896, drip-drop: < 1, drift: >= 1)")
    frames = seq["frames"]
    t_s = np.linspace(0.0, window, frames) if frames > 1 else np.zeros(1)
    r = np.linalg.norm(cw.propagate(s0, n, np.concatenate([t_s, np.linspace(0, window, 1024)]))[:, :3], axis=1)
    if r.min() <= radius_m:
        raise PlanError("amplitude_m", f"with these pattern parameters the camera comes within {r.min():.3g} m "
                       f"of the target centre, inside its bounding radius {radius_m:.3g} m; use a larger amplitude, "
                       "|kappa| or --gamma-m")
    draws = {"A_m": A, "kappa": kappa, "x_l_m": x_l, "beta_m_s": beta, "gamma_m": gamma, "tau0_rad": tau0,
             "z_amp_m": z_amp, "z_phase_rad": z_phase}
    return s0, t_s, window, params, draws, 0, (float(r.min()), float(r.max()))


def _class_of(kappa: float) -> str:
    c = classify(1.0, kappa)
    return c if c in PATTERNS else "elliptical"


def plan_orbit(cfg: dict, given: set = frozenset(), *, target: str, radius_m: float, points_body_m=None,
               intrinsics=None) -> dict:
    """Sample (or set), propagate and evaluate one sequence of ``target`` (bounding radius
    ``radius_m`` [m]): everything but the pixels.

    ``given``: the configuration keys the user set (an explicit ``pattern`` must agree with
    ``kappa``). For ``cfg["degrade"]["motion_blur"] == "auto"``, ``points_body_m`` (the model's
    vertices, (K, 3) [m]) and ``intrinsics`` (fx [px], fy [px], width, height) give the image
    motion (:func:`image_motion`).

    Returns a dict: ``result`` (plain-Python scenario and per-frame labels without image
    quantities: the ``--json`` document) and per-frame ``lights`` (Sun, Earth and ν in the body
    frame, rotations to the Earth-fixed and ECI axes, the motion blur). Raises
    :class:`PlanError`.
    """
    seq, orb, att, cam = cfg["sequence"], cfg["orbit"], cfg["attitude"], cfg["camera"]
    n = ReferenceOrbit(altitude_m=orb["altitude_km"] * 1e3).n_rad_s
    band = range_band(radius_m)
    explicit = cfg["pattern"]["amplitude_m"] is not None or cfg["pattern"]["kappa"] is not None
    if explicit:
        s0, t_s, window_s, params, draws, attempts, range_m = _explicit_pattern(cfg, given, n, band, radius_m)
        pattern = params.pattern
    else:
        sample = sample_pattern(seq["pattern"], n, target_radius_m=radius_m, n_frames=seq["frames"],
                                rng=seq["seed"], window_s=seq["window_s"])
        s0, t_s, window_s, params = sample.s0_lvlh, np.asarray(sample.t_s), sample.window_s, sample.params
        draws, attempts, range_m, pattern = dict(sample.draws), sample.attempts, sample.range_m, seq["pattern"]
    if len(t_s) and to_unix_seconds(orb["epoch"]) + float(np.max(t_s)) > VALID_UTC_RANGE_S[1]:
        raise PlanError("epoch", f"the sequence ends {float(np.max(t_s)):.0f} s after {orb['epoch']}, past "
                        "2051-01-01T00:00:00Z (the validity of the solar formulae); choose an earlier --epoch")
    s_lvlh = cw.propagate(s0, n, t_s)
    ref, chosen = _reference_orbit(orb, s_lvlh, t_s)
    r_obs_eci, _ = ref.observer_state_eci(s_lvlh, t_s)
    r_tgt_eci, _ = ref.target_state_eci(t_s)
    unix_s = ref.unix_s(t_s)
    r_sun_eci = sun_position_eci(unix_s)
    vis = visibility.visibility(r_obs_eci, r_tgt_eci, r_sun_eci, sun_margin_rad=math.radians(orb["sun_margin_deg"]))

    try:
        attitude = TargetAttitude.from_euler_zyx_deg(
            att["attitude"], *att["attitude_ypr_deg"], spin_axis_body=att["spin_axis"],
            spin_rate_rad_s=math.radians(att["spin_rate_deg_s"]), omega0_body_rad_s=np.radians(att["omega0_deg_s"]),
            inertia_body_kg_m2=np.diag(att["inertia_kg_m2"]))
    except ValueError as exc:
        raise _attitude_error(str(exc)) from None
    R_lvlh_from_body = attitude.R_lvlh_from_body(t_s, n)
    R_cam_from_lvlh = pose.look_at(s_lvlh[:, :3], roll_rad=math.radians(cam["roll_deg"]))
    R_cam_from_body, t_cam_m = pose.pose_from_relative(s_lvlh[:, :3], R_lvlh_from_body, R_cam_from_lvlh)
    labels = pose.pose_labels(R_cam_from_body, t_cam_m)
    R_lvlh_from_eci = np.swapaxes(ref.R_eci_from_lvlh(t_s), -1, -2)
    R_cam_from_eci = R_cam_from_lvlh @ R_lvlh_from_eci
    # directions seen from the camera (labels) ...
    sun_dir_cam = _unit_rows((R_cam_from_eci @ (r_sun_eci - r_obs_eci)[:, :, None])[:, :, 0])
    earth_dir_cam = _unit_rows((R_cam_from_eci @ -r_obs_eci[:, :, None])[:, :, 0])
    # ... and from the target, in its body frame (the renderer's light)
    R_body_from_eci = np.swapaxes(R_lvlh_from_body, -1, -2) @ R_lvlh_from_eci
    sun_dir_body = _unit_rows((R_body_from_eci @ (r_sun_eci - r_tgt_eci)[:, :, None])[:, :, 0])
    earth_dir_body = _unit_rows((R_body_from_eci @ -r_tgt_eci[:, :, None])[:, :, 0])
    earth_distance_m = np.linalg.norm(r_tgt_eci, axis=1)
    R_body_from_earth = R_body_from_eci @ rot_z(gmst_rad(unix_s))  # Earth-fixed axes (texture)

    motion = None
    if cfg["degrade"].get("motion_blur") == "auto":
        motion = image_motion(points_body_m, intrinsics, cfg["degrade"]["exposure_us"] * 1e-6, s0, n, t_s, attitude,
                              math.radians(cam["roll_deg"]))
    frames, lights = [], []
    visible = vis.visible  # a property that builds the whole array: once, not per frame (a million frames)
    for i in range(t_s.size):
        frames.append({
            "frame": i,
            "t_s": float(t_s[i]),
            "utc": to_iso_utc(float(unix_s[i])),
            "r_lvlh": [float(v) for v in s_lvlh[i, :3]],
            "v_lvlh": [float(v) for v in s_lvlh[i, 3:]],
            "range_m": float(np.linalg.norm(s_lvlh[i, :3])),
            "q_cam_from_body": [float(v) for v in labels.q_cam_from_body[i]],
            "R_cam_from_body": [float(v) for v in R_cam_from_body[i].ravel()],
            "t_cam_m": [float(v) for v in t_cam_m[i]],
            "R_cam_from_eci": [float(v) for v in R_cam_from_eci[i].ravel()],
            "sun_dir_cam": [float(v) for v in sun_dir_cam[i]],
            "earth_dir_cam": [float(v) for v in earth_dir_cam[i]],
            "sun_dir_body": [float(v) for v in sun_dir_body[i]],
            "earth_dir_body": [float(v) for v in earth_dir_body[i]],
            "line_of_sight": bool(vis.line_of_sight[i]),
            "earth_in_background": bool(vis.earth_in_background[i]),
            "sun_angle_deg": float(np.degrees(vis.sun_angle_rad[i])),
            "sun_clear": bool(vis.sun_clear[i]),
            "shadow": ("sunlit", "penumbra", "umbra")[int(vis.shadow[i])],
            "shadow_fraction": float(vis.illuminated_fraction[i]),
            "visible": bool(visible[i]),
            "not_visible_because": [why for why, bad in (
                ("earth_blocks_line_of_sight", not vis.line_of_sight[i]), ("sun_in_lens", not vis.sun_clear[i]),
                ("earth_shadow", not vis.illuminated_fraction[i] > 0.0)) if bad],
        })
        lights.append({"sun_dir_body": sun_dir_body[i].tolist(), "shadow_fraction": float(vis.illuminated_fraction[i]),
                       "earth_dir_body": earth_dir_body[i].tolist(), "earth_distance_m": float(earth_distance_m[i]),
                       "R_body_from_earth": R_body_from_earth[i].tolist(),
                       "R_body_from_eci": R_body_from_eci[i].tolist()})
        if motion is not None:
            lights[-1]["motion"] = [float(motion["length_px"][i]), float(motion["angle_deg"][i])]
            frames[-1]["motion_blur_px"], frames[-1]["motion_angle_deg"] = lights[-1]["motion"]
            frames[-1]["motion_path_px"] = float(motion["path_px"][i])
            frames[-1]["motion_blur_bounded"] = bool(motion["bounded"][i])
    result = {
        "target": target,
        "target_bounding_radius_m": radius_m,
        "pattern": pattern,
        "seed": seq["seed"],
        "reference_orbit": {"altitude_m": ref.altitude_m, "inclination_rad": ref.inclination_rad,
                            "raan_rad": ref.raan_rad, "arg_lat_rad": ref.arg_lat_rad, "epoch_utc": ref.epoch_utc,
                            "a_m": ref.a_m, "period_s": ref.period_s, "chosen": chosen},
        "n": n,
        "s0_lvlh": [float(v) for v in s0],
        "window_s": float(window_s),
        "range_band_m": [band.r_min_m, band.r_max_m],
        "range_m": [float(v) for v in range_m],
        "pattern_parameters": params.to_dict(),
        "pattern_source": "explicit" if explicit else "sampled",
        "sampled": draws,
        "attempts": attempts,
        "t_s": [float(v) for v in t_s],
        "frames": frames,
    }
    return {"result": result, "lights": lights}


MOTION_SAMPLES = (16, 4096)
"""Instants per exposure at which ``--motion-blur auto`` samples the image path: doubled from the
first until the blur changes by less than :data:`MOTION_TOL_PX` or :data:`MOTION_TOL_REL` of it,
at most the second."""
MOTION_TOL_PX = 1e-3
MOTION_TOL_REL = 1e-5


def _reference_orbit(orb: dict, s_lvlh: np.ndarray, t_s: np.ndarray) -> tuple:
    """(the sequence's :class:`orbit.reference.ReferenceOrbit`, the names of the options chosen
    for it): ``--raan-deg`` and ``--arg-lat-deg`` as given, or where unset the geometry of
    :func:`orbit.viewing.sunlit_geometry` (target fully sunlit and in view in the most frames)."""
    raan = None if orb["raan_deg"] is None else math.radians(orb["raan_deg"])
    u0 = None if orb["arg_lat_deg"] is None else math.radians(orb["arg_lat_deg"])
    chosen = []
    if u0 is None:
        g = sunlit_geometry(s_lvlh, t_s, altitude_m=orb["altitude_km"] * 1e3,
                            inclination_rad=math.radians(orb["inclination_deg"]), epoch_utc=orb["epoch"],
                            raan_rad=raan, sun_margin_rad=math.radians(orb["sun_margin_deg"]))
        chosen = ["arg_lat_deg"] + (["raan_deg"] if raan is None and g.plane_searched else [])
        raan, u0 = g.raan_rad, g.arg_lat_rad
    ref = ReferenceOrbit(altitude_m=orb["altitude_km"] * 1e3, inclination_rad=math.radians(orb["inclination_deg"]),
                         raan_rad=0.0 if raan is None else raan, arg_lat_rad=u0, epoch_utc=orb["epoch"])
    return ref, chosen


def image_motion(points_body_m, intrinsics, exposure_s: float, s0, n: float, t_s, attitude, roll_rad: float = 0.0) -> dict:
    """Per frame, the straight-line blur that the target's own image motion makes during an
    exposure of ``exposure_s`` centred on the frame time (``--motion-blur auto``).

    The convex-hull vertices of ``points_body_m`` ((K, 3) [m], the target's vertices) are
    projected with ``intrinsics`` = (fx [px], fy [px], width, height) at instants spread over the exposure (same
    CW state, attitude law and look-at pointing as the frame; doubled until the blur settles,
    :data:`MOTION_SAMPLES`), so the path each vertex sweeps is followed however it turns; each
    is taken as moving uniformly along straight pieces between instants. A camera integrates
    the image along those paths. The blur applied is a straight segment along the principal
    axis v of the vertices' positions about their own means (the larger eigenvector of their
    mean covariance), as long as the paths' spread along v allows: L = min(√(12 λ), E), with λ
    the mean variance of the positions along v (a uniform segment of length L has L²/12) and E
    the RMS over the vertices of each path's extent along v (a point that slows at the ends of
    its swing would otherwise be given a blur longer than the swing). For a straight path at
    constant speed both are its length; a target that turns a whole revolution in the
    exposure blurs over its ring instead of (comparing the end poses alone) not at all. The
    largest L of any centred part of the exposure is taken, so the blur never shrinks as the
    exposure grows (a path that turns back on itself spreads less over a longer time). L is at
    most the image diagonal (``bounded``).

    Returns
    -------
    dict of ndarray, shape (N,)
        ``length_px`` and ``angle_deg`` (the blur applied; angle counter-clockwise from +column
        as :func:`degrade.psf.motion_from_velocity` reports it), ``path_px`` (RMS over the hull
        vertices of the image path length swept during the exposure), ``bounded`` (bool: L
        capped) and ``samples`` (instants used).
    """
    from scipy.spatial import ConvexHull

    fx, fy, width, height = intrinsics
    pts = np.asarray(points_body_m, dtype=np.float64).reshape(-1, 3)
    try:
        hull = ConvexHull(pts).vertices
    except Exception:  # noqa: BLE001 - flat or tiny point sets: use every vertex
        hull = np.arange(len(pts))
    pts = pts[hull]
    t_s = np.asarray(t_s, dtype=np.float64)
    nf = t_s.size
    out = {"length_px": np.zeros(nf), "angle_deg": np.zeros(nf), "path_px": np.zeros(nf),
           "bounded": np.zeros(nf, dtype=bool), "samples": np.zeros(nf, dtype=np.int64)}
    if not exposure_s > 0 or nf == 0:
        return out
    diagonal = math.hypot(width, height)

    def blur(frames: np.ndarray, m: int) -> tuple:
        """(L, θ, path) of ``frames`` from m + 1 instants (m even) over the exposure."""
        tau = np.linspace(-0.5 * exposure_s, 0.5 * exposure_s, m + 1)
        tt = (t_s[frames, None] + tau[None, :]).ravel()
        s = cw.propagate(s0, n, tt)
        R, t = pose.pose_from_relative(s[:, :3], attitude.R_lvlh_from_body(tt, n),
                                       pose.look_at(s[:, :3], roll_rad=roll_rad))
        p = pts[None] @ np.swapaxes(R, -1, -2) + t[:, None, :]          # (F·(m+1), K, 3)
        z = np.where(p[..., 2] > 1e-9, p[..., 2], np.nan)
        uv = np.stack([fx * p[..., 0] / z, fy * p[..., 1] / z], -1)
        uv = uv.reshape(len(frames), m + 1, len(pts), 2)               # (F, instants, K, 2)
        seen = np.all(np.isfinite(uv), axis=(1, 3))                     # in front all along
        uv = np.where(seen[:, None, :, None], uv, 0.0)
        w = seen / np.maximum(seen.sum(axis=1, keepdims=True), 1)       # (F, K): mean over the seen vertices
        a, b = uv[:, :-1], uv[:, 1:]                                    # the m straight pieces
        path = np.sqrt(np.einsum("fk,fk->f", w, np.linalg.norm(b - a, axis=-1).sum(axis=1) ** 2))
        # the whole exposure's covariance (uniform motion on each piece) gives the axis v
        m1 = 0.5 * (a + b).mean(axis=1)                                 # (F, K, 2)
        m2 = ((a[..., :, None] * a[..., None, :] + b[..., :, None] * b[..., None, :]) / 3.0
              + (a[..., :, None] * b[..., None, :] + b[..., :, None] * a[..., None, :]) / 6.0).mean(axis=1)
        cov = np.einsum("fk,fkij->fij", w, m2 - m1[..., :, None] * m1[..., None, :])
        v = np.linalg.eigh(cov)[1][..., -1]                             # (F, 2)
        q = np.einsum("fikc,fc->fik", uv, v)                            # positions along v
        # centred parts j = 1 .. m/2 of the exposure: the pieces c-j .. c+j-1 about the centre c
        c = m // 2
        qa, qb = q[:, :-1], q[:, 1:]
        e1 = 0.5 * (qa + qb)
        e2 = (qa * qa + qb * qb + qa * qb) / 3.0
        j = np.arange(1, c + 1, dtype=np.float64)[None, :, None]
        s1 = (np.cumsum(e1[:, c - 1::-1] + e1[:, c:], axis=1)) / (2 * j)  # (F, m/2, K)
        s2 = (np.cumsum(e2[:, c - 1::-1] + e2[:, c:], axis=1)) / (2 * j)
        lam = np.einsum("fk,fjk->fj", w, np.maximum(s2 - s1 * s1, 0.0))
        hi = np.maximum(np.maximum.accumulate(q[:, c - 1::-1], axis=1), np.maximum.accumulate(q[:, c + 1:], axis=1))
        lo = np.minimum(np.minimum.accumulate(q[:, c - 1::-1], axis=1), np.minimum.accumulate(q[:, c + 1:], axis=1))
        ext = np.maximum(hi, q[:, c:c + 1]) - np.minimum(lo, q[:, c:c + 1])
        E = np.sqrt(np.einsum("fk,fjk->fj", w, ext * ext))
        L = np.minimum(np.sqrt(12.0 * lam), E).max(axis=1)
        theta = np.degrees(np.arctan2(-v[:, 1], v[:, 0]))             # rows grow downward
        theta = np.where(theta <= -90.0, theta + 180.0, np.where(theta > 90.0, theta - 180.0, theta))
        return L, theta, path

    chunk = max(1, int(4_000_000 // (len(pts) * (MOTION_SAMPLES[1] + 1))))
    for a0 in range(0, nf, chunk):
        frames = np.arange(a0, min(nf, a0 + chunk))
        m = MOTION_SAMPLES[0]
        L, theta, path = blur(frames, m)
        while m < MOTION_SAMPLES[1]:
            L2, theta2, path2 = blur(frames, 2 * m)
            m *= 2
            settled = np.all(np.abs(L2 - L) <= np.maximum(MOTION_TOL_PX, MOTION_TOL_REL * L2))
            L, theta, path = L2, theta2, path2
            if settled:
                break
        out["length_px"][frames] = np.minimum(L, diagonal)
        out["bounded"][frames] = L > diagonal
        out["angle_deg"][frames] = np.where(L > 0, theta, 0.0)
        out["path_px"][frames] = path
        out["samples"][frames] = m + 1
    return out



def _num(value) -> str:
    return "undefined" if value is None else (value if isinstance(value, str) else f"{value:.8g}")


def plan_table(result: dict, out) -> None:
    """Write the ``--dry-run`` table of a plan's ``result`` to the text stream ``out``."""
    pp = result["pattern_parameters"]
    ro = result["reference_orbit"]
    w = out.write
    w(f"# target {result['target']} (bounding radius {result['target_bounding_radius_m']:.2f} m), "
      f"pattern {result['pattern']} {pp['side']}, seed {result['seed']}\n")
    w(f"# reference orbit: altitude {ro['altitude_m'] / 1e3:g} km, i {math.degrees(ro['inclination_rad']):g} deg, "
      f"RAAN {math.degrees(ro['raan_rad']):g} deg, u0 {math.degrees(ro['arg_lat_rad']):g} deg, "
      f"epoch {ro['epoch_utc']}, n {result['n']:.10e} rad/s, T {ro['period_s']:.3f} s\n")
    w(f"# A {pp['A']:.4f} m, x_l {pp['x_l']:.4f} m, beta {pp['beta']:.6e} m/s, gamma {pp['gamma']:.4f} m, "
      f"sigma {_num(pp['sigma'])}, kappa {_num(pp['kappa'])}, t_p {pp['t_p']:.3f} s\n")
    w(f"# s0_lvlh [m, m/s] = {' '.join(f'{v:.9g}' for v in result['s0_lvlh'])}\n")
    w(f"# window {result['window_s']:.3f} s, {len(result['frames'])} frames, range band "
      f"{result['range_band_m'][0]:g}-{result['range_band_m'][1]:g} m\n")
    w(f"{'frame':>5} {'t_s':>10} {'x_m':>10} {'y_m':>10} {'z_m':>10} {'vx_m_s':>10} {'vy_m_s':>10} "
      f"{'vz_m_s':>10} {'range_m':>9} {'los':>3} {'earth_bg':>8} {'sun_deg':>7} {'sun_ok':>6} "
      f"{'shadow':>8} {'nu':>6} {'visible':>7}\n")
    yn = ("no", "yes")
    for f in result["frames"]:
        x, y, z = f["r_lvlh"]
        vx, vy, vz = f["v_lvlh"]
        w(f"{f['frame']:5d} {f['t_s']:10.3f} {x:10.4f} {y:10.4f} {z:10.4f} {vx:10.6f} {vy:10.6f} {vz:10.6f} "
          f"{f['range_m']:9.3f} {yn[f['line_of_sight']]:>3} {yn[f['earth_in_background']]:>8} "
          f"{f['sun_angle_deg']:7.2f} {yn[f['sun_clear']]:>6} {f['shadow']:>8} {f['shadow_fraction']:6.4f} "
          f"{yn[f['visible']]:>7}\n")
    n_vis = sum(f["visible"] for f in result["frames"])
    w(f"# {n_vis} of {len(result['frames'])} frames visible (line of sight, Sun clear of the lens, target lit)\n")

