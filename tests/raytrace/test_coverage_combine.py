"""Multisample anti-aliasing's combination of coverage and shading
(raytrace._edges.coverage_unshaded_first, coverage_combine) against a plain per-pixel
evaluation of its definition: each group's share of all S + C rays times the mean radiance of
its shaded rays."""
import numpy as np

from raytrace import _edges


def _definition(g_s, L_s, g_c, shaded_c, L_c):
    out = np.zeros((len(g_s), 3))
    S, C = g_s.shape[1], g_c.shape[1]
    for i in range(len(g_s)):
        for g in set(g_s[i]) | set(g_c[i]):
            count = np.sum(g_s[i] == g) + np.sum(g_c[i] == g)
            rad = list(L_s[i][g_s[i] == g]) + list(L_c[i][(g_c[i] == g) & shaded_c[i]])
            assert rad, "every group seen has a shaded ray"
            out[i] += count / (S + C) * np.mean(rad, axis=0)
    return out


def test_groups_seen_only_by_coverage_rays_get_their_first_ray_shaded_and_the_mix_is_exact():
    rng = np.random.default_rng(5)
    n, S, C = 300, 16, 36
    g_s = rng.integers(0, 3, (n, S))
    g_c = rng.integers(0, 5, (n, C))  # groups 3 and 4: seen by coverage rays only
    g_s[:20] = 1  # pixels whose shaded rays all saw one group
    g_c[:3] = 1  # ... and so did their coverage rays
    first = np.zeros((n, C), dtype=bool)
    _edges.coverage_unshaded_first(g_s, g_c, first)
    for i in range(n):
        unseen = [g for g in dict.fromkeys(g_c[i]) if g not in set(g_s[i])]
        expect = [int(np.flatnonzero(g_c[i] == g)[0]) for g in unseen]
        assert sorted(np.flatnonzero(first[i])) == sorted(expect)
    L_s = rng.uniform(0.0, 100.0, (n, S, 3))
    L_c = np.where(first[:, :, None], rng.uniform(0.0, 100.0, (n, C, 3)), 0.0)
    out = np.empty((n, 3))
    _edges.coverage_combine(g_s, L_s, g_c, first, L_c, out)
    np.testing.assert_allclose(out, _definition(g_s, L_s, g_c, first, L_c), rtol=1e-12)
    # a pixel all of one group is the mean of its shaded rays
    one = np.flatnonzero((g_s == 1).all(axis=1) & (g_c == 1).all(axis=1))
    assert len(one) == 3
    for i in one:
        np.testing.assert_allclose(out[i], L_s[i].mean(axis=0), rtol=1e-12)


def test_ray_groups_are_part_plus_one_and_zero_on_a_miss():
    face_offset = np.array([0, 4, 10], dtype=np.int64)
    component_of_face = np.array([0] * 4 + [1] * 6 + [2] * 3, dtype=np.int64)
    geom = np.array([-1, 0, 1, 2, 1], dtype=np.int32)
    prim = np.array([0, 3, 5, 2, 0], dtype=np.int32)
    out = np.empty(5, dtype=np.int64)
    _edges.ray_groups(geom, prim, face_offset, component_of_face, out)
    assert out.tolist() == [0, 1, 2, 3, 2]
