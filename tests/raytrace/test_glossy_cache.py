"""The radiance cache's transfer off glossy parts, against quadrature.

A gold foil plate (2 m × 2 m, GGX α = 0.32) lies in the plane z = 0 under the Sun; a black wall
stands on its edge x = 1 m, facing it. The wall's indirect irradiance is then the plate's
single reflection of the Sun, E(x) = ∫ f(ω_sun → ω_yx)·cosθ_sun·E_sun · cosθ_x cosθ_y / r² dA_y,
which a midpoint rule over the plate gives (the wall's shadow on the plate included). Before the
cache followed the lobe of glossy parts it spread their reflection uniformly, as if diffuse:
0.45× the quadrature where the glint points at the wall, 4.4× where it points away."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import trimesh

from raytrace.brdf import brdf_cos
from raytrace.lighting import Lighting
from raytrace.materials import MATERIAL_PRESETS
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene


def _scene():
    plate = trimesh.creation.box((2.0, 2.0, 0.02))
    plate.apply_translation((0.0, 0.0, -0.01))
    wall = trimesh.creation.box((0.02, 2.0, 2.0))
    wall.apply_translation((1.01, 0.0, 1.0))
    return Scene(TargetModel("plates", (Component("plate", plate, "gold_mli", "bus", 1.0),
                                        Component("wall", wall, "black_paint", "bus", 1.0, albedo=(0.0, 0.0, 0.0)))))


@numba.njit(cache=True)
def _brdf_cos_rows(o, sun, diffuse, f0, alpha):
    """brdf_cos at the plate's normal (+z) for each outgoing direction o[k] (a loop in numba,
    not 160 000 calls from Python)."""
    out = np.empty((len(o), 3))
    for k in range(len(o)):
        r, g, b = brdf_cos(0.0, 0.0, 1.0, o[k, 0], o[k, 1], o[k, 2], sun[0], sun[1], sun[2], diffuse[0], diffuse[1],
                           diffuse[2], f0[0], f0[1], f0[2], alpha)
        out[k, 0], out[k, 1], out[k, 2] = r, g, b
    return out


def _quadrature(x, sun, n=400):
    gold = MATERIAL_PRESETS["gold_mli"]
    s = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    Y = np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
    P = np.column_stack([Y, np.zeros(len(Y))])
    v = x - P
    r = np.linalg.norm(v, axis=1)
    o = v / r[:, None]
    cos_y = o[:, 2]
    cos_x = o[:, 0]  # the wall's face looks along −x: cosθ_x = (y − x)·(−x̂)/r
    f = _brdf_cos_rows(o, np.asarray(sun, float), np.asarray(gold.diffuse, float), np.asarray(gold.f0, float),
                       float(gold.roughness))
    if sun[0] > 0.0:  # the wall (x = 1 m, 2 m high) shades the plate where the Sun comes from its side
        f[(1.0 - P[:, 0]) / sun[0] * sun[2] < 2.0] = 0.0
    dA = (2.0 / n) ** 2
    return (f * (cos_x * cos_y / r ** 2 * dA)[:, None]).sum(axis=0)


# glint_away: the wall shades three quarters of the plate, and the cache resolves that
# shadow's edge only to its lattice spacing (measured +12 %, the old diffuse stand-in 4.4×)
@pytest.mark.parametrize("sun, rtol", [((-0.6, 0.0, 0.8), 0.05), ((0.6, 0.0, 0.8), 0.15)],
                         ids=["glint_on_wall", "glint_away"])
def test_wall_irradiance_from_a_glossy_plate(sun, rtol):
    sc = _scene()
    cache = sc.radiance_cache()
    E_sun = 1000.0
    frame = cache.solve(Lighting(sun_dir_body=sun, sun_irradiance_W_m2=E_sun))
    rows = np.arange(0, cache.n_rows, 2)
    pos, nrm = cache.positions[rows // 2], cache.normals[rows // 2]
    # rows on the wall's face towards the plate, away from its edges
    on = (nrm[:, 0] < -0.99) & (np.abs(pos[:, 1]) < 0.7) & (pos[:, 2] > 0.2) & (pos[:, 2] < 1.6) & cache.valid[rows]
    assert on.sum() > 50
    pts = pos[on]
    pick = pts[np.linspace(0, len(pts) - 1, 24).astype(int)]
    want = np.mean([_quadrature(p, np.asarray(sun)) * E_sun for p in pick], axis=0)
    # 24 rows spread over the face, the same for both estimates
    got24 = frame.indirect_W_m2[rows[on]][np.linspace(0, on.sum() - 1, 24).astype(int)].mean(axis=0)
    np.testing.assert_allclose(got24, want, rtol=rtol)


def _glints_per_record(cache, gl, E_sun_hits, lighting):
    """The glint source term of every row summed record by record in Python (the lattice rows
    around each record's hit from :func:`lattice_weights` and the lattice tables, the Sun's
    specular reflection from :func:`brdf_cos`): a second evaluation of
    :func:`raytrace._cache_kernels._glints`."""
    from raytrace._cache_kernels import _lattice_local, lattice_weights
    sun = np.asarray(lighting.sun_dir_body, float)
    e_sun = lighting.sun_irradiance_at_target_W_m2
    out = np.zeros((len(gl["ptr"]) - 1, 3))
    for r in range(len(out)):
        for k in range(gl["ptr"][r], gl["ptr"][r + 1]):
            f = int(gl["face"][k])
            s = int(cache._c_face_s[f])
            a0, c0, a1, c1, a2, c2, *w = lattice_weights(s, gl["u"][k], gl["v"][k])
            rows = [2 * int(cache._c_lat_ids[cache._c_lat_start[f] + _lattice_local(s, a, c)]) + int(gl["side"][k])
                    for a, c in ((a0, c0), (a1, c1), (a2, c2))]
            w = [wi if cache._c_valid[ri] else 0.0 for wi, ri in zip(w, rows, strict=True)]
            vis = sum(wi for wi, ri in zip(w, rows, strict=True) if E_sun_hits[ri] > 0.0) / max(sum(w), 1e-300)
            if vis <= 0.0:
                continue
            c = cache.scene.component_of_face[f]
            fs = brdf_cos(*gl["n"][k], *gl["wo"][k], *sun, 0.0, 0.0, 0.0, *cache.f0[c], cache.alpha[c])
            out[r] += np.asarray(fs) * vis
    return out * np.pi / cache.G * e_sun


def test_glints_from_lattice_rows_found_once_match_a_per_record_sum():
    """The glints' lattice rows are found on the first solve and kept: under a second Sun the
    term is still the per-record sum (the rows do not depend on the lighting)."""
    from raytrace import environment as env
    from raytrace._cache_kernels import _glints
    scene = _scene()
    cache = scene.radiance_cache()
    gl = cache._c["glint"]
    assert gl is not None and gl["ptr"][-1] > 100  # the plate's reflections reach the wall
    for sun in ((-0.6, 0.0, 0.8), (0.3, 0.5, 0.8)):
        light = Lighting(sun_dir_body=tuple(np.asarray(sun) / np.linalg.norm(sun)))
        cache.solve(light)
        assert "lattice_rows" in gl
        p, tex = light.packed()
        E_sun, _ = cache._sources(cache._c_ray_pos, cache._c_nrm, cache._c_solved, cache._c, light,
                                  env.irradiance_table(p, tex), env.env_cells(p, tex, cache.n_cells, 4), None)
        hits = E_sun[cache._c_alias]
        got = np.zeros((cache.n_coarse_rows, 3))
        _glints(gl["ptr"], gl["face"], gl["lattice_rows"], gl["lattice_w"], gl["n"], gl["wo"],
                scene.component_of_face, cache.f0, cache.alpha, hits, light.sun_record(), np.pi / cache.G, got)
        ref = _glints_per_record(cache, gl, hits, light)
        assert np.abs(ref).max() > 0.0
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
