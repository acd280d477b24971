"""Shading against independent answers: closed forms, numerical integration, a second method.

Oracles:
* Lambertian sphere under the Sun: L = ρ E max(0, n·s)/π with n the analytic sphere normal.
* White furnace: a convex Lambertian object under a uniform sky L has radiance ρ L.
* Two perpendicular plates: the first bounce ρ_B/π · ρ_A E · F(p → A), the point-to-rectangle
  form factor F = ∫_A cosθ_p cosθ_q / (π r²) dA integrated with scipy.
* Earth-lit sphere: E(n) = ∫_cap L_earth(ω) max(0, n·ω) dω summed over a fine grid of Earth's
  surface (a different parametrisation from the renderer's ray casting).
* Every preset against the path-traced reference on the four targets, within documented bounds.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
import trimesh
from scipy import integrate
from scipy.ndimage import binary_erosion

from orbit.pose import look_at
from raytrace import _antialias, _context, presets
from raytrace.camera import Camera
from raytrace.lighting import Earth, Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render

W, H, F = 160, 120, 200.0
CAM = Camera(W, H, F, F, (W - 1) / 2, (H - 1) / 2)


def _sphere_scene(albedo=0.5, material="white_paint"):
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=1.0)
    comp = Component("ball", mesh, material, "bus", 1.0, albedo=None if albedo is None else (albedo,) * 3)
    return Scene(TargetModel("ball", (comp,)))


def _pose(rho):
    R = look_at(np.asarray(rho, dtype=float))
    return R, -R @ np.asarray(rho, dtype=float)


def _sphere_normals(R, t):
    """Analytic unit-sphere hit normal (body frame) per pixel centre, NaN on a miss."""
    o = -R.T @ t
    v, u = np.mgrid[0:H, 0:W]
    d = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u, float)], -1) @ R
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ o
    c = o @ o - 1.0
    disc = b * b - c
    tt = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    return o + tt[..., None] * d


@pytest.fixture(scope="module")
def sphere():
    return _sphere_scene()


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8), ("reference", 16)])
def test_lambertian_sphere_under_the_sun_matches_closed_form(sphere, quality, samples):
    R, t = _pose([1.0, -5.0, 2.0])
    s = np.array([0.6, -0.48, 0.64])
    light = Lighting(sun_dir_body=s, sun_irradiance_W_m2=1000.0)
    frame = render(sphere, CAM, R, t, light, quality=quality, samples=samples)
    n = _sphere_normals(R, t)
    expect = 0.5 * 1000.0 * np.clip(n @ s, 0, None) / math.pi
    inner = binary_erosion(frame.geometry.mask, iterations=2) & np.isfinite(expect)
    inner &= np.abs(n @ s) > 0.05  # the faceted terminator differs from the analytic one
    got = frame.radiance[..., 0]
    # icosphere (40962 vertices) with smooth normals vs the true sphere: < 0.5 % of the peak;
    # the reference averages over the pixel (box filter) and the solar disc (soft terminator)
    tol = 0.012 if quality == "reference" else 0.005
    assert np.max(np.abs(got[inner] - expect[inner])) < tol * 0.5 * 1000 / math.pi
    from scipy.ndimage import binary_dilation
    far = ~binary_dilation(frame.geometry.mask, iterations=2)  # (silhouette pixels are anti-aliased)
    assert np.all(frame.radiance[far] == 0.0)  # black space, no Earth


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8), ("reference", 8)])
def test_white_furnace_convex_object_has_radiance_albedo_times_sky(sphere, quality, samples):
    R, t = _pose([0.0, -5.0, 0.0])
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=0.0, ambient_radiance_W_m2_sr=10.0)
    frame = render(sphere, CAM, R, t, light, quality=quality, samples=samples)
    inner = binary_erosion(frame.geometry.mask, iterations=2)
    np.testing.assert_allclose(frame.radiance[inner], 5.0, rtol=2e-3)  # a missing π would be 3x off


@pytest.mark.parametrize("quality,samples,tol", [("fast", None, 0.01), ("balanced", 16, 0.01), ("reference", 64, 0.01)])
def test_white_furnace_concave_object_has_radiance_of_the_sky(quality, samples, tol):
    """Albedo 1 under a uniform sky: every surface point of any shape, however concave, sends
    back exactly the sky's radiance (what a blocked direction hides, the surface there
    returns). Two plates meeting at a right angle: their inner faces see each other over half
    the hemisphere, so the cache's blocked-sky complement, its bounces and the gather's
    control variate all act."""
    scene = _plates(1.0, 1.0)
    R, t = _pose([3.0, -2.5, 2.5])
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=0.0, ambient_radiance_W_m2_sr=10.0)
    frame = render(scene, CAM, R, t, light, quality=quality, samples=samples)
    inner = binary_erosion(frame.geometry.mask, iterations=2)
    assert inner.sum() > 1500
    L = frame.radiance[inner][:, 0].astype(float)
    if quality == "reference":  # the mean: one path per sample, noisy per pixel
        assert L.mean() == pytest.approx(10.0, rel=tol)
    else:
        np.testing.assert_allclose(L, 10.0, rtol=tol)


def _plates(rho_a, rho_b):
    # plate A: horizontal, x in [0, 2], y in [-1, 1], top face at z = 0; plate B: vertical at
    # x in [-0.02, 0], y in [-1, 1], z in [0, 2], facing +x. Thin closed boxes.
    a = trimesh.creation.box((2.0, 2.0, 0.02))
    a.apply_translation((1.0, 0.0, -0.01))
    b = trimesh.creation.box((0.02, 2.0, 2.0))
    b.apply_translation((-0.01, 0.0, 1.0))
    return Scene(TargetModel("plates", (Component("a", a, "white_paint", "bus", 1.0, albedo=(rho_a,) * 3),
                                        Component("b", b, "white_paint", "bus", 1.0, albedo=(rho_b,) * 3))))


def _form_factor_to_floor(y, z):
    """F from a point (0, y, z) on plate B (normal +x) to plate A (z = 0, x∈[0,2], y∈[-1,1])."""
    def f(yy, xx):
        r2 = xx * xx + (yy - y) ** 2 + z * z
        return (xx / math.sqrt(r2)) * (z / math.sqrt(r2)) / (math.pi * r2)
    val, _ = integrate.dblquad(f, 0.0, 2.0, -1.0, 1.0, epsabs=1e-9, epsrel=1e-6)
    return val


@pytest.mark.parametrize("quality,samples,tol", [("fast", None, 0.10), ("balanced", 32, 0.05),
                                                 ("reference", 1024, 0.03)])
def test_perpendicular_plates_first_bounce_matches_form_factor(quality, samples, tol):
    rho_a, rho_b, e = 1.0, 0.1, 1000.0  # B dark: light bouncing back to A is < 2 % of A's
    scene = _plates(rho_a, rho_b)
    rho = np.array([4.0, -0.3, 1.2])
    R, t = _pose(rho)
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=e)  # B is edge-on to the Sun
    # the expectation is the form factor's: ``balanced``'s gather is averaged over 4 seeds (a
    # 5×5 patch of one 32-ray render is still ±2–3 % noisy where B is far from A)
    seeds = range(4) if quality == "balanced" else range(1)
    frames = [render(scene, CAM, R, t, light, quality=quality, samples=samples, seed=sd) for sd in seeds]
    frame, geo = frames[0], frames[0].geometry
    radiance = np.mean([f.radiance for f in frames], axis=0)
    # 5×5-pixel patches on B's face away from its borders (averaging the path tracer's noise);
    # each pixel's depth back-projected to its point on B
    inner = binary_erosion(geo.instance == 2, iterations=6)
    v, u = np.nonzero(inner)
    for k in np.linspace(0, len(u) - 1, 5).astype(int):
        got, expect = [], []
        for dv in range(-2, 3):
            for du in range(-2, 3):
                vv, uu = v[k] + dv, u[k] + du
                z_c = float(geo.depth_m[vv, uu])
                p_cam = np.array([(uu - CAM.cx) / CAM.fx * z_c, (vv - CAM.cy) / CAM.fy * z_c, z_c])
                p = R.T @ (p_cam - t)
                expect.append(rho_b / math.pi * rho_a * e * _form_factor_to_floor(p[1], p[2]))
                got.append(float(radiance[vv, uu, 0]))
        # B also gets light from A that first bounced off B (second order, < 2 %)
        assert np.mean(got) == pytest.approx(np.mean(expect), rel=tol), (v[k], u[k], np.mean(got), np.mean(expect))


def _earth_irradiance(n, earth_dir, dist, radius, albedo, sun, e_sun, n_grid=800):
    """∫ L_earth max(0, n·ω) dω over Earth's visible surface, as a sum over surface patches:
    dω = cosθ_q dA / r² (θ_q between the patch normal and the direction to the target)."""
    c = dist * np.asarray(earth_dir, float)
    w = -np.asarray(earth_dir, float)  # axis: Earth centre → target
    a = np.cross(w, [0.0, 0.0, 1.0] if abs(w[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(w, a)
    cap = math.acos(radius / dist)  # the visible cap's half-angle, seen from Earth's centre
    th = (np.arange(n_grid) + 0.5) / n_grid * cap
    ph = (np.arange(2 * n_grid) + 0.5) / (2 * n_grid) * 2 * math.pi
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    m = (np.cos(TH)[..., None] * w + (np.sin(TH) * np.cos(PH))[..., None] * a
         + (np.sin(TH) * np.sin(PH))[..., None] * b)
    dA = radius ** 2 * np.sin(TH) * (cap / n_grid) * (2 * math.pi / (2 * n_grid))
    q = c + radius * m
    r = np.linalg.norm(q, axis=-1)
    omega = q / r[..., None]  # direction target → patch
    cos_q = np.clip(-(omega * m).sum(-1), 0, None)
    L = albedo * e_sun * np.clip(m @ sun, 0, None) / math.pi
    w = (L * cos_q * dA / r ** 2).ravel()
    n = np.asarray(n, float)
    n2 = np.atleast_2d(n)
    om = omega.reshape(-1, 3)
    E = np.empty(len(n2))  # one value per normal, in blocks (a (normals × patches) matrix is GBs)
    for i in range(0, len(n2), 64):
        cosines = om @ n2[i:i + 64].T
        np.maximum(cosines, 0.0, out=cosines)
        E[i:i + 64] = w @ cosines
    return float(E[0]) if n.ndim == 1 else E


def test_environment_irradiance_table_matches_integral_over_the_visible_cap():
    """The final gather's control variate (raytrace.environment.irradiance_table): Earth's
    unoccluded irradiance on planes of many orientations, against the surface-patch integral;
    where Earth is wholly below a plane's horizon only the sky's π·L_sky remains."""
    from raytrace import environment as env
    earth_dir = np.array([0.3, -0.2, -0.9])
    earth_dir /= np.linalg.norm(earth_dir)
    dist, radius = 6_778_137.0, 6_378_137.0
    sun = np.array([0.9, 0.3, 0.3])  # the visible cap lit, with the terminator inside it
    sun /= np.linalg.norm(sun)
    light = Lighting(sun_dir_body=sun, sun_irradiance_W_m2=1361.0, earth=Earth(earth_dir, dist, radius, 0.3))
    p, tex = light.packed()
    table = env.irradiance_table(p, tex)
    normals = np.random.default_rng(5).normal(size=(60, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    scale = _earth_irradiance(earth_dir, earth_dir, dist, radius, 0.3, sun, 1361.0, n_grid=300)
    assert scale > 20.0
    for n in normals:
        expect = _earth_irradiance(n, earth_dir, dist, radius, 0.3, sun, 1361.0, n_grid=300)
        got = env.irradiance_lookup(table, *n)
        assert got[0] == got[1] == got[2]
        assert got[0] == pytest.approx(expect, rel=0.015, abs=0.003 * scale), (n, got[0], expect)
    sky = Lighting(sun_dir_body=sun, ambient_radiance_W_m2_sr=2.0, earth=Earth(earth_dir, dist, radius, 0.3))
    p, tex = sky.packed()
    table = env.irradiance_table(p, tex)
    # Earth's disc (half-angle 70.2°) is wholly below the horizon of a plane facing away from it
    assert env.irradiance_lookup(table, *(-earth_dir))[0] == pytest.approx(2.0 * math.pi, rel=1e-9)


@pytest.mark.parametrize("quality,samples,tol", [("fast", None, 0.02), ("balanced", 64, 0.02),
                                                 ("reference", 256, 0.02)])
def test_earth_lit_sphere_matches_integral_over_the_visible_cap(sphere, quality, samples, tol):
    earth_dir = np.array([0.0, 0.0, -1.0])
    dist, radius = 6_778_137.0, 6_378_137.0
    # Sun low over the target's horizon: the visible cap is lit, with the terminator inside it
    # (the Sun here was once (0.8, 0, −0.6), which leaves the whole visible cap on the night
    # side: every expected value was 0 and the test could not fail). ν = 0: Earth light only
    sun = np.array([0.97, 0.0, 0.243])
    sun /= np.linalg.norm(sun)
    light = Lighting(sun_dir_body=sun, sun_irradiance_W_m2=1361.0, shadow_fraction=0.0,
                     earth=Earth(earth_dir, dist, radius, 0.3))
    R, t = _pose([0.0, -5.0, -1.0])
    frame = render(sphere, CAM, R, t, light, quality=quality, samples=samples)
    n = _sphere_normals(R, t)
    inner = binary_erosion(frame.geometry.mask, iterations=3) & np.all(np.isfinite(n), -1)
    expect = 0.5 / math.pi * _earth_irradiance(n[inner], earth_dir, dist, radius, 0.3, sun, 1361.0, n_grid=300)
    got = frame.radiance[inner][:, 0].astype(float)
    assert np.count_nonzero(expect > 0.5) > 0.5 * len(expect)  # most points see the lit cap
    if quality == "reference":
        # 256 paths a pixel still leave ~20 % noise per pixel under a bright disc with a sharp
        # limb and terminator; the mean over the ~4000 pixels is within ~0.3 % of its own
        assert got.mean() == pytest.approx(expect.mean(), rel=tol)
        return
    pick = np.linspace(0, len(got) - 1, 16).astype(int)
    for k in pick:
        assert got[k] == pytest.approx(expect[k], rel=tol, abs=0.01 * 0.5 / math.pi * 0.3 * 1361 * 0.5), \
            (n[inner][k], got[k], expect[k])


def test_same_seed_same_bytes_and_seed_changes_noise(sphere):
    R, t = _pose([1.0, -5.0, 2.0])
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), ambient_radiance_W_m2_sr=2.0,
                     earth=Earth((0, 0, -1), 6.778e6))
    a = render(sphere, CAM, R, t, light, quality="balanced", seed=3).radiance
    b = render(sphere, CAM, R, t, light, quality="balanced", seed=3).radiance
    assert a.tobytes() == b.tobytes()
    c = render(sphere, CAM, R, t, light, quality="reference", samples=4, seed=3).radiance
    d = render(sphere, CAM, R, t, light, quality="reference", samples=4, seed=4).radiance
    assert c.tobytes() != d.tobytes()
    assert a.dtype == np.float32 and a.shape == (H, W, 3)


def test_each_preset_renders_with_its_own_cache_lattice_and_the_scene_keeps_both():
    """``balanced`` from 16 rays asks for a lattice 1/90 of the target's size, ``fast`` and
    ``balanced``-8 for the cache's default (1/60): each frame's cache has that spacing, a scene
    keeps one cache per set of options (no rebuild when the presets alternate), and a caller's
    own spacing wins."""
    from raytrace.presets import preset_cache_options, quality_preset
    scene = _sphere_scene()
    R, t = _pose([1.0, -5.0, 2.0])
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), ambient_radiance_W_m2_sr=1.0)
    assert preset_cache_options(quality_preset("fast"), scene.scale_m) == {}
    assert preset_cache_options(quality_preset("balanced", 8), scene.scale_m) == {}
    fine = preset_cache_options(quality_preset("balanced", 16), scene.scale_m)
    assert fine == {"spacing_m": pytest.approx(scene.scale_m / 90)}
    own = {"spacing_m": 0.3}
    assert preset_cache_options(quality_preset("balanced", 16), scene.scale_m, own) == own
    render(scene, CAM, R, t, light, quality="fast", seed=1)
    coarse = scene.radiance_cache()
    assert coarse.spacing_m == pytest.approx(scene.scale_m / 60)
    render(scene, CAM, R, t, light, quality="balanced", samples=16, seed=1)
    finer = scene.radiance_cache(**fine)
    assert finer is not coarse and finer.spacing_m == pytest.approx(scene.scale_m / 90)
    render(scene, CAM, R, t, light, quality="fast", seed=1)
    render(scene, CAM, R, t, light, quality="balanced", samples=16, seed=1)
    assert scene.radiance_cache() is coarse and scene.radiance_cache(**fine) is finer and len(scene._caches) == 2


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8)])
def test_context_built_on_a_side_thread_gives_the_same_bytes(monkeypatch, quality, samples):
    """The frame's context (cache solve, environment tables) is built on a side thread during
    the geometry pass; the frame must be the one built in line, bit for bit."""
    import threading

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: render builds the context in line")
    scene = _plates(0.8, 0.6)  # inter-reflection: the cache's solve matters
    R, t = _pose([3.0, -4.0, 2.5])
    sun, earth = np.array([0.3, -0.5, 0.81]), np.array([0.2, 0.1, -1.0])
    light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)), ambient_radiance_W_m2_sr=1.0,
                     earth=Earth(tuple(earth / np.linalg.norm(earth)), 6.778e6))
    built_on = []
    init = _context._Context.__init__

    def spy(self, *a, **k):
        built_on.append(threading.current_thread().name)
        init(self, *a, **k)

    monkeypatch.setattr(_context._Context, "__init__", spy)
    monkeypatch.setattr(presets, "CONTEXT_ON_SIDE_THREAD", False)
    a = render(scene, CAM, R, t, light, quality=quality, samples=samples, seed=5)
    monkeypatch.setattr(presets, "CONTEXT_ON_SIDE_THREAD", True)
    b = render(scene, CAM, R, t, light, quality=quality, samples=samples, seed=5)
    assert built_on[0] == threading.current_thread().name and built_on[1].startswith("raytrace-context")
    assert a.radiance.tobytes() == b.radiance.tobytes()
    assert (a.radiance > 0).mean() > 0.05


def test_anti_aliasing_chunks_on_two_threads_give_the_same_bytes(monkeypatch, sphere):
    """Anti-aliasing chunks run two at a time on a side pool; with chunks small enough that a
    frame has several, the frame must be the one computed chunk after chunk, bit for bit."""
    import threading

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: the chunks run one after the other")
    R, t = _pose([1.0, -5.0, 2.0])
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), ambient_radiance_W_m2_sr=2.0,
                     earth=Earth((0, 0, -1), 6.778e6))
    monkeypatch.setattr(presets, "CHUNK_RAYS", 16 * 90)  # 90 edge pixels per chunk (a 4 × 4 grid at 8 rays)
    ran_on = []
    chunk = _antialias._shade_chunk

    def spy(*a, **k):
        ran_on.append(threading.current_thread().name)
        return chunk(*a, **k)

    monkeypatch.setattr(_antialias, "_shade_chunk", spy)
    monkeypatch.setattr(presets, "AA_CHUNKS_ON_TWO_THREADS", False)
    a = render(sphere, CAM, R, t, light, quality="balanced", samples=8, seed=2).radiance
    serial = len(ran_on)
    monkeypatch.setattr(presets, "AA_CHUNKS_ON_TWO_THREADS", True)
    b = render(sphere, CAM, R, t, light, quality="balanced", samples=8, seed=2).radiance
    assert serial > 4 and len(ran_on) == 2 * serial
    assert all(n == threading.current_thread().name for n in ran_on[:serial])
    assert all(n.startswith("raytrace-aa") for n in ran_on[serial:])
    assert a.tobytes() == b.tobytes()


def test_side_threads_run_with_the_callers_numba_thread_count():
    from raytrace import shade
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert shade._submit("context", 1, numba.get_num_threads).result() == 1
        assert shade._submit("aa", 2, numba.get_num_threads).result() == 1
    finally:
        numba.set_num_threads(threads)
    assert shade._submit("aa", 2, numba.get_num_threads).result() == threads


def test_earth_disc_in_the_background_has_day_and_night():
    # looking at Earth (below) past a small sphere: lit limb on the Sun's side, dark night side
    scene = _sphere_scene()
    rho = np.array([0.0, 0.0, 30.0])  # above the target, looking down at it and at Earth
    R = look_at(rho, up_ref_lvlh=(0.0, 1.0, 0.0))
    t = -R @ rho
    light = Lighting(sun_dir_body=(1.0, 0.0, 0.0), earth=Earth((0, 0, -1), 6.778e6, albedo=0.3))
    frame = render(scene, CAM, R, t, light, quality="fast")
    bg = ~frame.geometry.mask
    lum = frame.radiance.mean(-1)
    # the camera looks straight down at the sub-target point, on the terminator: half the
    # view is day, half night (to one column of AA)
    day = bg & (lum > 1.0)
    night = bg & (lum == 0.0)
    assert 0.3 < day.mean() < 0.6 and 0.3 < night.mean() < 0.6
    # day side radiance never exceeds albedo·E/π
    assert lum[bg].max() <= 0.3 * 1361 / math.pi * (1 + 1e-6)


@pytest.mark.parametrize("quality", ["fast", "balanced", "reference"])
def test_camera_touching_a_face_sees_that_face_lit_as_the_formula_says(quality):
    """A camera whose optical centre lies on a face of a box, looking into it, sees that face
    at depth 0 everywhere (no 0·∞ in the filter's footprint): ρ/π·E·cosθ + ρ·L_sky."""
    box = Component("box", trimesh.creation.box((2.0, 2.0, 2.0)), "white_paint", "bus", 1.0, albedo=(0.6,) * 3)
    scene = Scene(TargetModel("box", (box,)))
    s = np.array([0.4, -0.3, -0.866])
    s /= np.linalg.norm(s)
    light = Lighting(sun_dir_body=tuple(s), ambient_radiance_W_m2_sr=1.0)
    frame = render(scene, CAM, np.eye(3), [0.2, 0.1, 1.0], light, quality=quality, samples=4)  # centre on z = −1
    assert frame.geometry.mask.all() and np.all(frame.geometry.depth_m == 0.0)
    expect = 0.6 / math.pi * 1361.0 * -s[2] + 0.6 * 1.0
    assert np.all(np.isfinite(frame.radiance))
    assert np.allclose(frame.radiance, expect, rtol=3e-3)  # reference: the sky sampled, ±0.6 of 225.7


def test_mesh_far_from_its_origin_has_no_shadow_acne():
    """Embree holds vertices in float32: a 2 m sphere 5 km from the body origin (ulp 0.5 mm)
    needs secondary rays offset by more than the size-based 2e-5 (40 µm), else it shadows its
    own lit side in speckles. Same image as at the origin, to float32 geometry, and a warning."""
    sun = Lighting(sun_dir_body=(0.6, -0.48, 0.64))
    R, t = _pose([1.0, -5.0, 2.0])
    ref = render(_sphere_scene(), CAM, R, t, sun, quality="fast")
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=1.0)
    mesh.vertices += [5000.0, 0.0, 0.0]
    with pytest.warns(RuntimeWarning, match="recentre the mesh"):
        far = Scene(TargetModel("ball", (Component("ball", mesh, "white_paint", "bus", 1.0, albedo=(0.5,) * 3),)))
    got = render(far, CAM, R, t - R @ [5000.0, 0.0, 0.0], sun, quality="fast")
    lit = ref.radiance.sum(-1) > 1.0
    assert np.count_nonzero((got.radiance.sum(-1) > 1.0) != lit) <= 5 and lit.sum() > 2000  # ± terminator pixels
    assert got.radiance[lit].mean() == pytest.approx(ref.radiance[lit].mean(), rel=1e-3)


@pytest.mark.parametrize("bad,match", [
    (dict(sun_dir_body=(np.nan, 0, 1)), "sun_dir_body"),
    (dict(sun_dir_body=(0, 0, 2)), "unit vector"),
    (dict(sun_dir_body=(0, 0, 1), shadow_fraction=1.5), "shadow_fraction"),
    (dict(sun_dir_body=(0, 0, 1), ambient_radiance_W_m2_sr=-1), "ambient_radiance"),
])
def test_bad_lighting_is_a_clear_error(bad, match):
    with pytest.raises(ValueError, match=match):
        Lighting(**bad)


def test_bad_quality_and_earth_inside_is_a_clear_error(sphere):
    R, t = _pose([1.0, -5.0, 2.0])
    light = Lighting(sun_dir_body=(0, 0, 1))
    with pytest.raises(ValueError, match="quality must be one of fast, balanced, reference"):
        render(sphere, CAM, R, t, light, quality="ultra")
    with pytest.raises(ValueError, match="samples"):
        render(sphere, CAM, R, t, light, quality="balanced", samples=0)
    with pytest.raises(ValueError, match="distance_m"):
        Earth((0, 0, -1), 6.0e6, radius_m=6.378e6)


def _silhouette_error(sphere, quality, samples, seed):
    """Per silhouette pixel of a sphere in a white furnace (radiance exactly 5 on it, 0 in
    space): radiance / 5 minus the fraction of the pixel the sphere's disc covers, here
    integrated on a 64×64 grid per pixel against the analytic disc (a tangent cone: a circle
    of radius f·tan(asin(1/d)) about the principal point)."""
    d = 5.0
    R, t = _pose([0.0, -d, 0.0])
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=0.0, ambient_radiance_W_m2_sr=10.0)
    frame = render(sphere, CAM, R, t, light, quality=quality, samples=samples, seed=seed)
    r_px = CAM.fx * math.tan(math.asin(1.0 / d))
    v, u = np.mgrid[0:H, 0:W]
    edge = np.abs(np.hypot(u - CAM.cx, v - CAM.cy) - r_px) < 1.0
    sub = (np.arange(64) + 0.5) / 64 - 0.5
    du, dv = np.meshgrid(sub, sub)
    uu = u[edge][:, None] + du.ravel() - CAM.cx
    vv = v[edge][:, None] + dv.ravel() - CAM.cy
    cover = (np.hypot(uu, vv) < r_px).mean(axis=1)
    return frame.radiance[edge][:, 0] / 5.0 - cover


@pytest.mark.parametrize("quality,samples", [("fast", None), ("balanced", 8), ("balanced", 16), ("balanced", 32)])
def test_silhouette_pixels_carry_the_covered_fraction_of_the_pixel(sphere, quality, samples):
    """3×3 shaded sub-samples alone measure the covered fraction (:func:`_silhouette_error`)
    with 6 % RMS error here; with the coverage rays (measured 3 %) it must be within 4 %."""
    err = _silhouette_error(sphere, quality, samples, seed=3)
    assert len(err) > 200
    rms = float(np.sqrt(np.mean(err ** 2)))
    assert rms < 0.04, f"silhouette coverage RMS error {rms:.3f}"
    assert abs(float(np.mean(err))) < 0.01  # and unbiased


def test_edge_sub_samples_gather_the_presets_own_ray_count(sphere, monkeypatch):
    """``Quality.aa_gather_rays`` is the ray count of an edge sub-sample's own final gather:
    ``balanced``-32 anti-aliases with 8×8 sub-samples whose own gathers have 32 / 8 = 4 rays
    (``raytrace.presets._balanced_aa_gather``), a preset with 6 casts 6, and those are the
    counts the sub-samples' gathers are called with; they share their pixel's sequence of
    directions (``share`` = 64: keys pixel · 64 + sub-sample)."""
    import dataclasses

    from raytrace import shade

    q = shade.quality_preset("balanced", 32)
    assert (q.aa_grid, q.aa_gather_rays) == (8, 4)
    assert shade.quality_preset("balanced", 16).aa_gather_rays == 4  # a quarter below 32 rays
    seen = []
    gather = _context._Context.gather_E

    def record(self, s, n_rays, pix, *args, **kwargs):
        centres = "counts" in kwargs or "hits" in kwargs
        seen.append((len(pix), n_rays, centres))  # points (with rows, s holds every sub-sample)
        if not centres:
            assert kwargs["share"] == 64 and pix.min() >= 0 and pix.max() < 64 * CAM.width * CAM.height
        return gather(self, s, n_rays, pix, *args, **kwargs)

    monkeypatch.setattr(_context._Context, "gather_E", record)
    R, t = _pose([0.0, -5.0, 0.0])
    light = Lighting(sun_dir_body=(1.0, 0.0, 0.0), sun_irradiance_W_m2=1000.0, ambient_radiance_W_m2_sr=5.0)
    preset = shade.quality_preset
    for rays in (None, 6):
        seen.clear()
        if rays is not None:
            monkeypatch.setattr(shade, "quality_preset",
                                lambda name, samples=None: dataclasses.replace(preset(name, samples),
                                                                               aa_gather_rays=rays))
        render(sphere, CAM, R, t, light, quality="balanced", samples=32, seed=2)
        # the pixel centres' two-pass gather (raytrace.shade._gather_two_pass) asks for the
        # pilot's hits, then per-point counts; the sub-samples' gathers for neither
        sub = {n for _, n, centres in seen if not centres}
        assert sub == {4 if rays is None else rays}, seen


def test_second_sub_sample_pattern_halves_the_silhouette_noise(sphere, monkeypatch):
    """``Quality.aa_extra``: with a second independent pattern at every anti-aliased pixel
    (aa_extra = 1) each silhouette pixel is the mean of two unbiased estimates, so its error
    against the analytic coverage (:func:`_silhouette_error`) has half the variance: RMS ×
    1/√2 ≈ 0.71 (asserted < 0.85, over three seeds), and the mean stays 0."""
    import dataclasses

    from raytrace import shade

    preset = shade.quality_preset

    def errors(extra):
        monkeypatch.setattr(shade, "quality_preset",
                            lambda name, samples=None: dataclasses.replace(preset(name, samples), aa_extra=extra))
        return np.concatenate([_silhouette_error(sphere, "balanced", 8, seed) for seed in (3, 4, 5)])

    one, two = errors(0.0), errors(1.0)
    rms1, rms2 = (float(np.sqrt(np.mean(e ** 2))) for e in (one, two))
    assert rms2 < 0.85 * rms1, f"RMS {rms1:.4f} with one pattern, {rms2:.4f} with two"
    assert abs(float(np.mean(two))) < 0.005


def test_second_sub_sample_pattern_goes_to_the_highest_contrast_pixels(sphere, monkeypatch):
    """``Quality.aa_extra`` = 0.2 on a sphere lit from the side: the second pattern is drawn
    at exactly the 20 % of the anti-aliased pixels whose sub-samples saw the largest contrast
    (:func:`raytrace._rows.subsample_contrast`), and those lie on the lit limb, none on
    the dark limb (black against black)."""
    import dataclasses

    from raytrace import shade

    preset = shade.quality_preset
    monkeypatch.setattr(shade, "quality_preset",
                        lambda name, samples=None: dataclasses.replace(preset(name, samples), aa_extra=0.2))
    calls = []
    first = _antialias._supersample

    def record(*args, **kwargs):
        out = first(*args, **kwargs)
        contrast = args[16] if len(args) > 16 else kwargs.get("contrast_out")
        calls.append((args[7].copy(), None if contrast is None else contrast.copy()))
        return out

    monkeypatch.setattr(_antialias, "_supersample", record)
    R, t = _pose([0.0, -5.0, 0.0])
    light = Lighting(sun_dir_body=(1.0, 0.0, 0.0), sun_irradiance_W_m2=1000.0)  # lights the +x half
    render(sphere, CAM, R, t, light, quality="balanced", samples=8, seed=2)
    (epix, contrast), (epix2, none) = calls
    assert none is None and len(epix2) == int(0.2 * len(epix))
    top = np.sort(epix[np.argsort(-contrast, kind="stable")[:len(epix2)]])
    np.testing.assert_array_equal(epix2, top)
    # the body frame's +x is the image's +u here (camera on −y looking at the centre)
    u = epix2 % W - CAM.cx
    side = np.sign(R[0, 0]) * u  # > 0 on the lit half of the image
    assert np.all(side > 0), "a second pattern on the dark limb"
    assert np.all(contrast[np.isin(epix, epix2)] > 0)


def test_subsample_contrast_is_the_squared_range_of_each_pixels_sub_samples():
    """raytrace._rows.subsample_contrast against NumPy (the peak-to-peak of R + G + B over
    each pixel's rows); a uniform pixel has none, and a step of height c gives c² whatever
    fraction of the pixel each side covers."""
    from raytrace import _rows

    rng = np.random.default_rng(0)
    for S in (9, 16, 36):
        L = rng.gamma(2.0, 1.5, (5000 * S, 3))
        got = np.empty(5000)
        _rows.subsample_contrast(L, S, got)
        want = np.ptp(L.sum(1).reshape(5000, S), axis=1) ** 2
        np.testing.assert_allclose(got, want, rtol=1e-12)
    S = 36
    L = np.tile(np.array([[0.3, 0.2, 0.1]]), (4 * S, 1))
    for p, k in enumerate((0, 1, 18, 35)):
        L[p * S:p * S + k] = [1.3, 0.2, 0.1]  # k of the 36 sub-samples on the bright side
    got = np.empty(4)
    _rows.subsample_contrast(L, S, got)
    np.testing.assert_allclose(got, [0.0, 1.0, 1.0, 1.0], atol=1e-12)


def _dense_cover(px, py, W, H, n=400):
    """Pixels containing points of the triangle (px, py): an independent, sampled rasterisation."""
    a, b = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = a + b <= 1
    u = px[0] + a[keep] * (px[1] - px[0]) + b[keep] * (px[2] - px[0])
    v = py[0] + a[keep] * (py[1] - py[0]) + b[keep] * (py[2] - py[0])
    out = np.zeros((H, W), dtype=bool)
    iu, iv = np.floor(u + 0.5).astype(int), np.floor(v + 0.5).astype(int)  # pixel k spans [k - ½, k + ½)
    ok = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    out[iv[ok], iu[ok]] = True
    return out


def _quad(c, u, v):
    c, u, v = map(np.asarray, (c, u, v))
    return trimesh.Trimesh(np.array([c - u - v, c + u - v, c + u + v, c - u + v], float), [[0, 1, 2], [0, 2, 3]],
                           process=False)


@pytest.mark.parametrize("samples", [8, 16])
def test_shadow_of_a_ribbon_thinner_than_a_pixel_is_found(samples):
    """A black ribbon 0.3 px wide (1.5 cm, 4 m long, diagonal) 0.5 m above a white plate seen
    from 10 m straight above, the Sun 27° off the zenith across the ribbon: its shadow, 5 px
    beside it, is as thin as the ribbon and pixel centres and corners mostly miss it. The light
    the image lacks, Σ (L₀ − L)/L₀ × (pixel footprint)², must be the plate area the ribbon hides
    from the camera plus the area of its shadow the camera sees, both computed here by casting
    rays at the two rectangles on a 1 mm grid (interreflection: none, the ribbon is black).
    Measured: 0.1251 / 0.1268 m² (8 / 16 rays) against 0.1262; without the thin-shadow search
    0.108 / 0.110 (13 % short)."""
    zc, width, length = 10.0, 0.3 * 10.0 / F, 4.0
    d = np.array([1.0, 0.6, 0.0]) / math.hypot(1.0, 0.6)
    p = np.array([-d[1], d[0], 0.0])
    c = np.array([0.3, 0.2, 0.5])
    plate = Component("plate", _quad((0, 0, 0), (10, 0, 0), (0, 10, 0)), "white_paint", "bus", 1.0,
                      albedo=(0.5,) * 3)
    ribbon = Component("ribbon", _quad(c, d * length / 2, p * width / 2), "black_paint", "bus", 1.0,
                       albedo=(0.0,) * 3)
    scene = Scene(TargetModel("ribbon", (plate, ribbon)))
    R = np.diag([1.0, -1.0, -1.0])
    t = -R @ np.array([0.0, 0.0, zc])
    s = 0.5 * p + np.array([0.0, 0.0, 1.0])
    s /= np.linalg.norm(s)
    light = Lighting(sun_dir_body=s, sun_irradiance_W_m2=1000.0)
    img = render(scene, CAM, R, t, light, quality="balanced", samples=samples, seed=1).radiance[..., 0]
    L0 = 0.5 * 1000.0 * s[2] / math.pi
    foot = zc / F
    lacking = float(((L0 - img.astype(np.float64)) / L0).sum()) * foot * foot

    def through_ribbon(P, D):
        tt = (c[2] - P[..., 2]) / D[..., 2]
        Q = P + tt[..., None] * D - c
        return (tt > 0) & (np.abs(Q @ d) <= length / 2) & (np.abs(Q @ p) <= width / 2)

    h = 0.001
    xs = np.arange(-3.0, 3.0, h)
    hidden = seen_shadow = 0.0
    for y0 in np.arange(-2.0, 2.0, 0.5):
        X, Y = np.meshgrid(xs, np.arange(y0, y0 + 0.5, h))
        P = np.stack([X, Y, np.zeros_like(X)], -1)
        behind = through_ribbon(P, np.array([0.0, 0.0, zc]) - P)
        hidden += behind.sum() * h * h
        seen_shadow += (through_ribbon(P, np.broadcast_to(s, P.shape)) & ~behind).sum() * h * h
    assert seen_shadow > 0.05  # the shadow is in view, beside the ribbon
    assert lacking == pytest.approx(hidden + seen_shadow, rel=0.04)


def test_sliver_pixels_marks_exactly_the_pixels_a_thin_triangle_overlaps():
    """A wire 0.03 px wide and 40 px long, slanted across pixel rows: every pixel square it
    overlaps is marked, no other (against a dense point rasterisation); hidden behind the
    pixels' surface it marks nothing; a wide triangle is no sliver."""
    from raytrace._edges import sliver_pixels
    W = H = 100
    f, c, z = 100.0, 49.5, 10.0
    px = np.array([30.3, 70.1, 70.1])
    py = np.array([40.2, 52.7, 52.73])
    V = np.column_stack([(px - c) * z / f, (py - c) * z / f, np.full(3, z)])
    F = np.array([[0, 1, 2]])
    R, t = np.eye(3), np.zeros(3)
    out = np.zeros((H, W), dtype=bool)
    sliver_pixels(V, F, R, t, f, f, c, c, Camera().lens_arrays()[0], 1e-6, 1.0, np.full((H, W), np.inf, dtype=np.float32), out)
    want = _dense_cover(px, py, W, H, n=2000)
    assert want.sum() > 50
    assert np.array_equal(out, want)
    out[:] = False
    sliver_pixels(V, F, R, t, f, f, c, c, Camera().lens_arrays()[0], 1e-6, 1.0, np.full((H, W), 5.0, dtype=np.float32), out)  # a surface in front
    assert not out.any()
    out[:] = False
    sliver_pixels(V, F, R, t, f, f, c, c, Camera().lens_arrays()[0], 1e-6, 1.0, np.full((H, W), 20.0, dtype=np.float32), out)  # a surface behind it
    assert np.array_equal(out, want)
    wide = np.column_stack([(np.array([30.3, 70.1, 50.0]) - c) * z / f, (np.array([40.2, 52.7, 80.0]) - c) * z / f,
                            np.full(3, z)])
    out[:] = False
    sliver_pixels(wide, F, R, t, f, f, c, c, Camera().lens_arrays()[0], 1e-6, 1.0, np.full((H, W), np.inf, dtype=np.float32), out)
    assert not out.any()


def _sat_cover(px, py, W, H):
    """Pixel squares [k − ½, k + ½]² a triangle (px, py) overlaps, by the separating-axis test
    over its whole bounding box, in NumPy (the rule ``sliver_pixels`` applies row by row)."""
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    inside = (uu >= np.min(px) - 0.5) & (uu <= np.max(px) + 0.5) & (vv >= np.min(py) - 0.5) & (vv <= np.max(py) + 0.5)
    sgn = 1.0 if (px[1] - px[0]) * (py[2] - py[0]) - (px[2] - px[0]) * (py[1] - py[0]) > 0 else -1.0
    for k in range(3):
        j = (k + 1) % 3
        a, b = -(py[j] - py[k]) * sgn, (px[j] - px[k]) * sgn
        inside &= a * (uu - px[k]) + b * (vv - py[k]) + 0.5 * (abs(a) + abs(b)) >= 0.0
    return inside


@pytest.mark.parametrize("angle_deg", [0.0, 0.00001, 3.0, 30.0, 45.0, 60.0, 89.99999, 90.0, 120.0, 177.0])
def test_sliver_pixels_row_spans_mark_what_the_whole_box_test_marks(angle_deg):
    """Wires 0.05 px wide and 10–80 px long at every slant, horizontal and vertical ones
    included (edges less than 10⁻³ px high bound nothing): the pixels marked are those the
    separating-axis test marks over the triangle's whole bounding box."""
    from raytrace._edges import sliver_pixels
    W, H = 120, 90
    f, c, z = 100.0, 49.5, 10.0
    rng = np.random.default_rng(int(angle_deg * 1000))
    out = np.zeros((H, W), dtype=bool)
    want = np.zeros((H, W), dtype=bool)
    for _ in range(6):
        length = rng.uniform(10.0, 80.0)
        d = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
        nrm = np.array([-d[1], d[0]])
        p0 = np.array([rng.uniform(20, 100), rng.uniform(20, 70)])
        pts = np.array([p0, p0 + length * d, p0 + length * d + 0.05 * nrm])
        px, py = pts[:, 0], pts[:, 1]
        V = np.column_stack([(px - c) * z / f, (py - c) * z / f, np.full(3, z)])
        out[:] = False
        sliver_pixels(V, np.array([[0, 1, 2]]), np.eye(3), np.zeros(3), f, f, c, c, Camera().lens_arrays()[0], 1e-6, 1.0,
                      np.full((H, W), np.inf, dtype=np.float32), out)
        P = V[:, :2] * f / z + c  # the projection as the kernel computes it
        want = _sat_cover(P[:, 0], P[:, 1], W, H)
        assert want.sum() >= 10
        assert np.array_equal(out, want)


def test_donor_rows_takes_the_centre_else_the_nearest_neighbour_on_the_same_surface():
    """Edge sub-samples take their pixel centre's correction when they lie on its surface;
    otherwise (with borrowing) the nearest neighbouring centre on their own surface, never one
    of another part, a normal more than 25° away or off their plane by more than a footprint."""
    from raytrace._edges import donor_rows
    W = H = 3
    inst = np.full(W * H, 1, dtype=np.uint16)  # part 0 everywhere ...
    inst[2] = 2  # ... but pixel (0, 2): part 1
    row_of_pixel = np.arange(W * H, dtype=np.int32)
    row_of_pixel[8] = -1  # pixel (2, 2) saw space
    # centres on the plane z = 0, normal +z, 1 m apart; the centre pixel (1, 1) is on a wall
    P_c = np.array([[u - 1.0, v - 1.0, 0.0] for v in range(H) for u in range(W)])
    N_c = np.tile([0.0, 0.0, 1.0], (W * H, 1))
    N_c[4] = [1.0, 0.0, 0.0]
    foot = np.full(W * H, 0.05)
    P_c[3, 2] = 0.2  # pixel (1, 0): off the plane by more than a footprint
    # sub-samples of pixel (1, 1): on the floor nearest (1, 0) [off the plane: (2, 0) is next],
    # nearest (0, 2) [another part: (0, 1) is next]; on the wall [the centre]; of part 1 [(0, 2)]
    P = np.array([[-0.9, 0.05, 0.0], [0.8, -0.9, 0.0], [0.0, 0.0, 0.3], [0.9, -0.9, 0.0]])
    NS = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    comp = np.array([0, 0, 0, 1], dtype=np.int64)
    centre = np.full(4, 4, dtype=np.int64)
    out = np.empty(4, dtype=np.int64)
    donor_rows(centre, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c, foot, True, out)
    # brute force: nearest neighbour of the same part, normal and plane
    want = []
    for m in range(4):
        if inst[4] - 1 == comp[m] and NS[m] @ N_c[4] > 0.9 and abs((P[m] - P_c[4]) @ N_c[4]) <= foot[4]:
            want.append(4)
            continue
        ok = [q for q in range(W * H) if q != 4 and row_of_pixel[q] >= 0 and inst[q] - 1 == comp[m]
              and NS[m] @ N_c[q] > 0.9 and abs((P[m] - P_c[q]) @ N_c[q]) <= foot[q]]
        want.append(min(ok, key=lambda q: np.sum((P[m] - P_c[q]) ** 2)) if ok else -1)
    assert list(out) == want
    assert want == [6, 1, 4, 2]  # the cases meant
    donor_rows(centre, W, H, comp, P, NS, row_of_pixel, inst, P_c, N_c, foot, False, out)
    assert list(out) == [-1, -1, 4, -1]


@pytest.mark.parametrize("quality, samples", [("fast", None), ("balanced", 8)])
def test_one_chunk_traced_before_the_cache_gives_the_chunked_bytes(monkeypatch, sphere, quality, samples):
    """When the pixels to anti-alias are one chunk, :func:`render` traces them (rays, hits,
    the Sun, mirror rays) before it waits for the radiance cache, and shades them after: the
    same bytes as several chunks each traced and shaded in turn, and the trace comes before the
    first look-up in the cache."""
    R, t = _pose([1.0, -5.0, 2.0])
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), ambient_radiance_W_m2_sr=2.0,
                     earth=Earth((0, 0, -1), 6.778e6))
    events = []
    trace, cache_E = _antialias._trace_chunk, _context._Context.cache_E

    def spy_trace(*a, **k):
        events.append("trace")
        return trace(*a, **k)

    def spy_cache(self, s):
        events.append("cache")
        return cache_E(self, s)

    monkeypatch.setattr(_antialias, "_trace_chunk", spy_trace)
    monkeypatch.setattr(_context._Context, "cache_E", spy_cache)
    one = render(sphere, CAM, R, t, light, quality=quality, samples=samples, seed=4).radiance
    assert events[0] == "trace" and events.count("trace") >= 1
    events.clear()
    monkeypatch.setattr(presets, "AA_CHUNKS_ON_TWO_THREADS", False)
    monkeypatch.setattr(presets, "CHUNK_RAYS", 16 * 40)  # 40 to 71 edge pixels per chunk
    several = render(sphere, CAM, R, t, light, quality=quality, samples=samples, seed=4).radiance
    assert events[0] == "cache" and events.count("trace") > 3
    assert one.tobytes() == several.tobytes()
    assert (one > 0).mean() > 0.05


def test_put_rows_nonnegative_is_numpys_clamped_assignment():
    """The kernel that writes the shaded rows into the float32 image is NumPy's
    ``out[idx] = np.maximum(src, 0.0)``, bit for bit: negatives and −0 to +0, rounding to
    float32 the same, other rows untouched."""
    from raytrace import _rows
    rng = np.random.default_rng(3)
    src = rng.standard_normal((500, 3)) * 10.0 ** rng.integers(-40, 40, (500, 1))
    src[:7] = [[-0.0, 0.0, -1e-300], [1e-46, -1e-46, 3.4e38], [0.1, 0.2, 0.3], [-5, 5, -0.0],
               [1e39, 2.0, 1.0], [np.nextafter(1.0, 2.0), 1.0 + 2.0 ** -24, 1.0 + 3 * 2.0 ** -24], [7, -7, 0]]
    idx = np.sort(rng.choice(2000, 500, replace=False)).astype(np.int64)
    a = rng.random((2000, 3)).astype(np.float32)
    b = a.copy()
    with np.errstate(over="ignore"):
        a[idx] = np.maximum(src, 0.0)
    _rows.put_rows_nonnegative(idx, src, b)
    assert a.tobytes() == b.tobytes()
    assert not np.signbit(b[idx]).any() and (b[idx] >= 0).all()


def test_unit_rows_and_take_ray_rows_are_numpys_expressions():
    """The kernels that gather the sub-samples' rays are NumPy's expressions bit for bit:
    ``D[idx] / np.linalg.norm(D[idx], axis=1, keepdims=True)`` (the misses' directions towards
    the environment) and ``O[idx]``, ``D[idx]`` with their float32 roundings (the mirror rays
    for Embree), over magnitudes from 10⁻³⁰ to 10³⁰ and rounding ties of float32."""
    from raytrace import _rows
    rng = np.random.default_rng(5)
    n = 4000
    D = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-30, 30, (n, 1))
    D[:3] = [[1.0, 1.0 + 2.0 ** -24, -(1.0 + 3 * 2.0 ** -24)], [3.0, 4.0, 12.0], [-0.0, 1e-300, 2.0]]
    O = rng.standard_normal((n, 3)) * 1e3
    idx = np.sort(rng.choice(n, 1500, replace=False)).astype(np.int64)
    idx[0] = 0
    got = np.empty((len(idx), 3))
    _rows.unit_rows(D, idx, got)
    assert got.tobytes() == (D[idx] / np.linalg.norm(D[idx], axis=1, keepdims=True)).tobytes()
    oi, di = np.empty((len(idx), 3)), np.empty((len(idx), 3))
    o32, d32 = np.empty((len(idx), 3), np.float32), np.empty((len(idx), 3), np.float32)
    _rows.take_ray_rows(idx, O, D, oi, di, o32, d32)
    assert oi.tobytes() == O[idx].tobytes() and di.tobytes() == D[idx].tobytes()
    with np.errstate(over="ignore"):
        assert o32.tobytes() == O[idx].astype(np.float32).tobytes()
        assert d32.tobytes() == D[idx].astype(np.float32).tobytes()


def _glossy_points(material):
    """A ``fast`` context of a unit sphere of ``material`` under the Sun with Earth filling the
    sky behind the camera, and the surfaces of the sphere's pixels seen from the Earth side (their
    mirror rays all escape towards Earth)."""
    from raytrace._kernels import centre_rays
    from raytrace.presets import preset_cache_options, quality_preset
    scene = _sphere_scene(albedo=None, material=material)
    light = Lighting(sun_dir_body=(0.6, -0.48, 0.64), ambient_radiance_W_m2_sr=1.0,
                     earth=Earth((0, -1, 0), 6.778e6))
    R, t = _pose([0.0, -4.0, 0.5])
    ctx = _context._Context(scene, light, preset_cache_options(quality_preset("fast"), scene.scale_m, None),
                            prefiltered_glossy=True)
    ctx.px_rad = 1.0 / CAM.fx
    geo = scene.render_geometry(CAM, R, t)
    pix = np.flatnonzero(geo.instance.ravel() > 0)
    O, D = np.empty((len(pix), 3)), np.empty((len(pix), 3))
    R_bc = np.ascontiguousarray(R.T)
    centre_rays(pix, W, -R_bc @ t, R_bc, CAM.fx, CAM.fy, CAM.cx, CAM.cy, *CAM.lens_arrays(), O, D)
    s = _context._surfaces(scene, O, D, geo.face_index.ravel()[pix].astype(np.int64), ctx.px_rad)
    return ctx, s


@pytest.mark.parametrize("material, wide", [("aluminium", True), ("solar_cell", False)])
def test_mirror_term_of_a_wide_lobe_takes_nothing_along_its_missed_mirror_ray(material, wide):
    """``fast``'s mirror term (raytrace._surface.add_mirror) blends the radiance along the mirror
    ray with weight 1 − t, t = 1 at α ≥ GLOSSY_A1 where the ray escapes: on aluminium (α 0.35)
    the term is the same bits whatever the environment along the missed rays (Earth there, or
    no Earth: the kernel does not look it up), on solar cells (α 0.08 < GLOSSY_A1) it changes
    with it. The mirror rays :meth:`raytrace._context._Sunlight.mirror_hits` gathers by a kernel
    (raytrace._rows.take_ray_rows) are NumPy's fancy indexing of them, array for array."""
    from raytrace import _surface, environment as env
    from raytrace._surface import GLOSSY_A1
    ctx, s = _glossy_points(material)
    assert (ctx.alpha[s["comp"]] >= GLOSSY_A1).all() == wide
    hits = ctx.mirror_hits(s)
    spec = s["m_f0"].max(axis=1) > 0.0 if "m_f0" in s else ctx.specular[s["comp"]]
    o, d = np.empty((len(spec), 3)), np.empty((len(spec), 3))
    _surface.mirror_rays(s["NS"], s["NG"], s["WO"], s["P"], ctx.eps, spec, o, d)
    idx = np.flatnonzero(spec)
    ref = (idx, o[idx], d[idx], ctx.scene.intersect(o[idx], d[idx]))
    for a, b in zip(hits[:3], ref[:3]):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
    assert all(hits[3][k].tobytes() == ref[3][k].tobytes() for k in hits[3])
    assert len(hits[0]) > 100 and (hits[3]["geomID"] < 0).all()
    E = ctx.cache_E(s)
    L_earth = np.zeros((len(s["P"]), 3))
    ctx.add_mirror(s, E, L_earth, hits)
    p = ctx.p
    try:
        ctx.p = p.copy()
        ctx.p[env.P_HAS_EARTH] = 0.0
        ctx.p[env.P_AMBIENT] = 50.0
        L_none = np.zeros((len(s["P"]), 3))
        ctx.add_mirror(s, E, L_none, hits)
    finally:
        ctx.p = p
    rows = hits[0]
    assert (L_earth[rows] > 0.0).all()
    if wide:
        assert L_earth.tobytes() == L_none.tobytes()
    else:
        assert (np.abs(L_none[rows] - L_earth[rows]) > 1e-6 * L_earth[rows]).mean() > 0.5
