"""The final gather and the glossy lobe sampling fused into one kernel each that calls Embree itself (raytrace._paths,
raytrace._embree), against the batched code it replaces, which traces through ``embreex``
level by level (a second implementation of the same estimator, kept as the fallback):

* the direct Embree scene returns the same hits as ``Scene.intersect`` / ``Scene.occluded``,
  bit for bit, on rays that graze, hit edges and vertices, start inside parts and miss;
* the scene built without Embree's robust flag (``Scene.direct_fast``, the rays of shading)
  finds the same hits on all but a few of those rays;
* a ``balanced`` frame with the fused gather and lobe sampling equals the batched one on a scene with a glossy
  part, a crevice (paths several bounces deep), Earth and sky, with the Sun on and eclipsed,
  and with the control variate's weight α ≠ 1 (a branch the presets do not take).
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from raytrace import _embree, _paths, presets, shade
from raytrace.camera import Camera
from raytrace.lighting import Earth, Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene

pytestmark = pytest.mark.skipif(not _embree.available(), reason="no Embree 4 library in the embreex wheel")


def _scene():
    plate = trimesh.creation.box((2.0, 2.0, 0.02))
    plate.apply_translation((0.0, 0.0, -0.01))
    wall = trimesh.creation.box((0.02, 2.0, 2.0))
    wall.apply_translation((1.01, 0.0, 1.0))
    block = trimesh.creation.box((0.3, 0.6, 0.25))  # a crevice between it, the plate and the wall
    block.apply_translation((0.82, 0.2, 0.125 + 0.02))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    ball.apply_translation((-0.3, 0.4, 0.5))
    return Scene(TargetModel("plates", (Component("plate", plate, "gold_mli", "bus", 1.0),
                                        Component("wall", wall, "white_paint", "bus", 1.0),
                                        Component("block", block, "silver_mli", "bus", 1.0),
                                        Component("ball", ball, "solar_cell", "solar_panel", 1.0))))


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_direct_embree_hits_equal_embreex_bit_for_bit(scene, monkeypatch):
    rng = np.random.default_rng(5)
    n = 20000
    V = scene.vertices
    # rays from around the parts towards random points, towards vertices and along edges
    O = rng.normal(0.0, 2.0, (n, 3))
    targets = V[rng.integers(0, len(V), n)]
    half = n // 2
    targets[half:] = targets[half:] + rng.normal(0.0, 0.05, (n - half, 3))
    D = targets - O
    D[::7] = rng.normal(size=(len(D[::7]), 3))  # and some in any direction (many misses)
    O[::11] = V[rng.integers(0, len(V), len(O[::11]))] * 0.5  # some from inside the parts
    through_embreex = []
    run = Scene._run

    def spy(self, *a):
        through_embreex.append(a[3])
        return run(self, *a)

    monkeypatch.setattr(Scene, "_run", spy)
    monkeypatch.setattr(presets, "DIRECT_BATCHES", False)  # Scene.intersect through embreex
    want = scene.intersect(O, D, robust=True)
    assert through_embreex == ["INTERSECT"]
    direct = scene.direct
    g = np.empty(n, np.int64)
    p = np.empty(n, np.int64)
    u = np.empty(n, np.float32)
    v = np.empty(n, np.float32)
    t = np.empty(n, np.float32)
    _embree.intersect_batch(direct.handle, O, D, g, p, u, v, t)
    assert (want["geomID"] >= 0).mean() > 0.3 and (want["geomID"] < 0).mean() > 0.05
    # every ray, misses included (embreex's: primID −1, u = v = 0, tfar its initial 1e37)
    np.testing.assert_array_equal(g, want["geomID"])
    np.testing.assert_array_equal(p, want["primID"])
    np.testing.assert_array_equal(u, want["u"])
    np.testing.assert_array_equal(v, want["v"])
    np.testing.assert_array_equal(t, want["tfar"])
    assert np.all(t[g < 0] == np.float32(1e37))
    occ = np.empty(n, np.bool_)
    _embree.occluded_batch(direct.handle, O, D, occ)
    np.testing.assert_array_equal(occ, scene.occluded(O, D, robust=True))
    # Scene.intersect / occluded through the direct kernels (the default) of the robust scene:
    # the same arrays and dtypes, from float32 rows and from broadcast float64 rows alike
    monkeypatch.setattr(presets, "DIRECT_BATCHES", True)
    for O_, D_ in ((O, D), (O.astype(np.float32), D.astype(np.float32)),
                   (np.broadcast_to(O[0], O.shape), D)):
        monkeypatch.setattr(presets, "DIRECT_BATCHES", False)
        ref = scene.intersect(O_, D_)
        ref_occ = scene.occluded(O_, D_)
        monkeypatch.setattr(presets, "DIRECT_BATCHES", True)
        through_embreex.clear()
        got = scene.intersect(O_, D_, robust=True)
        assert through_embreex == []  # the direct kernels, not embreex
        for k in ("geomID", "primID", "u", "v", "tfar"):
            assert got[k].dtype == ref[k].dtype, k
            np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
        np.testing.assert_array_equal(scene.occluded(O_, D_, robust=True), ref_occ)
    assert scene._direct_rays(O, D, None) is not None  # the direct path was the one taken
    assert scene._direct_rays(O, D, np.ones(n)) is None  # a tfar goes through embreex
    np.testing.assert_array_equal(occ, g >= 0)


def test_the_fast_scene_finds_the_robust_hits_but_on_edges(scene, monkeypatch):
    """``Scene.direct_fast`` (no robust flag; the default of ``Scene.intersect`` / ``occluded``)
    against the robust scene:

    * on rays aimed at vertices (±1 mm) from around the parts, the same hit on all but a few,
      and each of those a tie (the same distance: another triangle at a shared edge or
      vertex) or a ray that one of them let through an edge or vertex (the nearer of the two
      hits has a barycentric coordinate < 10⁻³);
    * on rays leaving surface points as the shading casts them (offset ``ray_eps_m`` along
      the normal, cosine-like directions), the distances agree so well that a hit point
      o + t·d lies within a tenth of that offset of the robust one along the hit's normal (the
      gather's paths continue from o + t·d; measured on the four targets: ≤ 0.005 of it)."""
    monkeypatch.setattr(presets, "FAST_TRAVERSAL", True)
    rng = np.random.default_rng(8)
    n = 200_000
    V = scene.vertices
    O = rng.normal(0.0, 2.0, (n, 3))
    D = V[rng.integers(0, len(V), n)] + rng.normal(0.0, 1e-3, (n, 3)) - O
    fast = scene.direct_fast
    assert fast is not None and fast is not scene.direct
    assert scene._direct_rays(O, D, None, robust=False)[0] is fast
    robust = scene.intersect(O, D, robust=True)
    got = scene.intersect(O, D)
    assert (robust["geomID"] >= 0).mean() > 0.5
    same = (got["geomID"] == robust["geomID"]) & (got["primID"] == robust["primID"])
    assert same.mean() > 0.999
    k = np.flatnonzero(~same)
    t_r, t_f = robust["tfar"][k].astype(np.float64), got["tfar"][k].astype(np.float64)
    tie = (robust["geomID"][k] >= 0) & (got["geomID"][k] >= 0) & (np.abs(t_f - t_r) <= 1e-5 * t_r)
    # otherwise one of them passed through an edge or vertex where the other hit: the nearer
    # hit lies on it
    t_r[robust["geomID"][k] < 0] = np.inf
    t_f[got["geomID"][k] < 0] = np.inf
    nearer = np.where(t_r <= t_f, 0, 1)
    bary = [np.stack([h["u"][k], h["v"][k], 1.0 - h["u"][k] - h["v"][k]], axis=1).min(axis=1) for h in (robust, got)]
    on_edge = np.where(nearer == 0, bary[0], bary[1]) < 1e-3
    assert np.all(tie | on_edge)
    hit = np.flatnonzero(same & (robust["geomID"] >= 0))
    np.testing.assert_allclose(got["tfar"][hit], robust["tfar"][hit], rtol=1e-4)
    assert (scene.occluded(O, D) == (robust["geomID"] >= 0)).mean() > 0.999

    # rays of shading: from random points of random triangles, off the surface by ray_eps_m
    m = 100_000
    f = rng.integers(0, len(scene.faces), m)
    r1, r2 = np.sqrt(rng.random(m)), rng.random(m)
    tri = V[scene.faces[f]].astype(np.float64)
    P = (1 - r1)[:, None] * tri[:, 0] + (r1 * (1 - r2))[:, None] * tri[:, 1] + (r1 * r2)[:, None] * tri[:, 2]
    N = scene.face_normal[f] * np.where(rng.random(m) < 0.5, 1.0, -1.0)[:, None]
    d = N + rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[(d * N).sum(axis=1) <= 0.0] *= -1.0
    O2 = P + scene.ray_eps_m * N
    robust = scene.intersect(O2, d, robust=True)
    got = scene.intersect(O2, d)
    both = np.flatnonzero((robust["geomID"] >= 0) & (got["geomID"] == robust["geomID"])
                          & (got["primID"] == robust["primID"]))
    assert len(both) > 0.2 * m and len(both) > 0.99 * (robust["geomID"] >= 0).sum()
    fh = scene.face_offset[robust["geomID"][both]] + robust["primID"][both]
    along_normal = np.abs(got["tfar"][both].astype(np.float64) - robust["tfar"][both]) * \
        np.abs((d[both] * scene.face_normal[fh]).sum(axis=1))
    assert along_normal.max() < 0.1 * scene.ray_eps_m
    monkeypatch.setattr(presets, "FAST_TRAVERSAL", False)
    assert scene.direct_fast is scene.direct


def _frame(scene, light, monkeypatch, fused: bool, samples: int = 16):
    W, H, f = 80, 60, 90.0
    cam = Camera(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
    eye = np.array([-2.5, -1.5, 2.2])
    R = look_at(eye)
    monkeypatch.setattr(presets, "FUSED_GATHER", fused)
    return shade.render(scene, cam, R, -R @ eye, light, quality="balanced", samples=samples, seed=11).radiance


SUN = np.array([-1.0, 0.4, 0.6]) / np.linalg.norm([-1.0, 0.4, 0.6])
EARTH = Earth(tuple(np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])), 6.8e6, albedo=0.3)


@pytest.mark.parametrize("case", ["sun-earth-sky", "eclipsed", "alpha-half"])
def test_fused_gather_equals_the_batched_gather(scene, monkeypatch, case):
    light = Lighting(sun_dir_body=tuple(SUN), earth=EARTH, ambient_radiance_W_m2_sr=1.0,
                     shadow_fraction=0.0 if case == "eclipsed" else 1.0)
    if case == "alpha-half":
        monkeypatch.setattr(presets, "GATHER_ALPHA", 0.5)
    calls = {"gather_traced": [], "lobe_traced": []}
    alphas = []
    for name in calls:
        real = getattr(_paths, name)

        def spy(*a, _real=real, _name=name):
            calls[_name].append(len(a[1]))
            if _name == "gather_traced":
                alphas.append(a[-4])  # the control variate's weight
            return _real(*a)

        monkeypatch.setattr(_paths, name, spy)
    fused = _frame(scene, light, monkeypatch, True)
    # the fused kernels did the gathering and the lobe sampling (gold and silver foil)
    assert sum(calls["gather_traced"]) > 1000 and sum(calls["lobe_traced"]) > 300
    assert set(alphas) == {0.5 if case == "alpha-half" else 1.0}
    n_calls = {k: len(v) for k, v in calls.items()}
    batched = _frame(scene, light, monkeypatch, False)
    assert {k: len(v) for k, v in calls.items()} == n_calls  # and the batched code did not call them
    assert np.isfinite(fused).all() and fused.max() > 0.0
    # the same rays and the same arithmetic: equal up to the last bits of fast-math shading
    np.testing.assert_allclose(fused, batched, rtol=1e-9, atol=1e-9 * float(batched.max()))
