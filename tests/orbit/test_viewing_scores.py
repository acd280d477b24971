"""The phase search's scores (orbit.viewing._scores: every candidate's frames in one stacked
visibility evaluation) against the definition, one :func:`orbit.viewing.fully_lit_and_in_view`
per candidate."""

import numpy as np

from orbit.reference import ReferenceOrbit
from orbit.sun import sun_position_eci
from orbit.viewing import _scores, fully_lit_and_in_view


def test_stacked_scores_are_the_per_candidate_counts():
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 2800.0, 37)
    # an observer 20-200 m from the target, drifting: frames lit, in shadow, in penumbra, Sun in the lens
    s = np.hstack([rng.uniform(-200.0, 200.0, (t.size, 3)), rng.uniform(-0.1, 0.1, (t.size, 3))])
    for inclination, raan, epoch in ((0.9, 0.0, "2026-06-21T12:00:00Z"), (1.7, 2.0, "2026-03-20T00:00:00Z")):
        def make(u0, inclination=inclination, raan=raan, epoch=epoch):
            return ReferenceOrbit(altitude_m=450e3, inclination_rad=inclination, raan_rad=raan, arg_lat_rad=u0,
                                  epoch_utc=epoch)
        r_sun = sun_position_eci(make(0.0).unix_s(t))
        phases = np.radians(np.arange(0.0, 360.0, 7.0))
        got = _scores(make, phases, s, t, r_sun, 0.05)
        want = [np.count_nonzero(fully_lit_and_in_view(make(u0), s, t, r_sun, sun_margin_rad=0.05)) for u0 in phases]
        assert got.tolist() == want
        assert 0 < min(want) < max(want) <= t.size  # the candidates differ: the comparison can fail
