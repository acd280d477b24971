"""The ``bluemarble`` Earth (raytrace._earth): the image's orientation against geography, the lit
disc's mean reflectance, the ocean's, the sun glint where the mirror geometry (found here by
minimising Fermat's optical path with SciPy) puts it, seeded clouds, and the local contrast, ocean
and cloud colours of the main job's frames."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy.optimize import minimize

from raytrace import _earth, shade
from raytrace import environment as env
from raytrace._background import earth_background
from raytrace._context import _background_params
from raytrace.camera import Camera
from raytrace.lighting import EARTH_RADIUS_M, SOLAR_CONSTANT_W_M2, Earth, Lighting

R_E = EARTH_RADIUS_M
GEO_M = 42_164_000.0  # geostationary radius: the whole disc in view


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _enu(lat_deg: float, lon_deg: float):
    """Earth-fixed up, east, north unit vectors at (lat, lon)."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    up = np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    return up, east, np.cross(up, east)


def _above(lat_deg: float, lon_deg: float):
    """R_body_from_earth of a body frame over (lat, lon): body z towards Earth's centre (down),
    x east, y south (a camera with these axes looks at nadir, image up = north)."""
    up, east, north = _enu(lat_deg, lon_deg)
    return np.vstack([east, -north, -up])  # rows: the body axes in Earth-fixed coordinates


def _view(R_be, dist_m, sun_body, W, H, f, R_body_from_cam=np.eye(3), seed=0, clouds=True, albedo=0.3,
          step=shade._BACKGROUND_STEP):
    """Earth behind an empty image: radiance (H, W, 3), Earth mask, and per pixel the unit ray,
    the ground normal (body frame) and the Sun's cosine there (numpy, on its own); ``step`` 1:
    every pixel's state evaluated, none interpolated."""
    earth = Earth((0.0, 0.0, 1.0), dist_m, texture="bluemarble", R_body_from_earth=R_be, cloud_seed=seed,
                  albedo=albedo)
    light = Lighting(sun_dir_body=tuple(_unit(sun_body)), earth=earth)
    p, tex = _background_params(light)
    p[env.P_PIX_RAD] = 1.0 / f
    if not clouds:
        p[env.P_CLOUD_THRESHOLD] = 1e3
    rad = np.zeros((H, W, 3), np.float32)  # the renderer's types: the kernel's compiled signature
    mask = np.zeros((H, W), dtype=bool)
    cam = Camera(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
    earth_background(np.zeros((H, W), dtype=np.uint16), np.zeros(3), np.ascontiguousarray(R_body_from_cam), f, f,
                     cam.cx, cam.cy, *cam.lens_arrays(), p, tex, step, shade._BACKGROUND_TOL,
                     shade._BACKGROUND_CHORD, mask, rad)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    D = np.stack([(u - cam.cx) / f, (v - cam.cy) / f, np.ones((H, W))], -1) @ np.asarray(R_body_from_cam).T
    D /= np.linalg.norm(D, axis=-1, keepdims=True)
    c = np.array([0.0, 0.0, dist_m])
    b = D @ c
    t = b - np.sqrt(np.maximum(R_E ** 2 - (dist_m ** 2 - b * b), 0.0))
    m = (D * t[..., None] - c) / R_E
    return rad, mask, D, m, m @ _unit(sun_body), p, tex


def _reflectance(rad, mu_s):
    """π L / (E_sun μ_s), per channel."""
    return math.pi * rad / (SOLAR_CONSTANT_W_M2 * np.maximum(mu_s, 1e-9)[..., None])


@numba.njit(cache=False)
def _state(p, tex, E, foot_m):
    """Water fraction and cloud density (every octave down to foot_m) at Earth-fixed unit vectors."""
    out = np.empty((E.shape[0], 2))
    for k in range(E.shape[0]):
        st = _earth.coarse_state(p, tex, E[k, 0], E[k, 1], E[k, 2], 0.0)
        cf, _ = _earth.fine_octaves(E[k, 0], E[k, 1], E[k, 2], st[5], st[6], st[7], foot_m, R_E, 1.0, 0.0, 0.0)
        out[k, 0] = st[3]
        out[k, 1] = st[4] + cf
    return out


def _packed(seed=0):
    return Lighting(sun_dir_body=(0.0, 0.0, -1.0),
                    earth=Earth((0.0, 0.0, 1.0), GEO_M, texture="bluemarble", cloud_seed=seed)).packed()


@pytest.mark.parametrize("place, lat, lon, check", [
    ("Sahara", 23.0, 10.0, lambda c: c.mean() > 0.25 and c[0] > c[2]),
    ("central Pacific", 0.0, -150.0, lambda c: c.mean() < 0.03 and c[2] > 2 * c[0]),
    ("Greenland", 75.0, -40.0, lambda c: c.min() > 0.5),
    ("Antarctica", -85.0, 60.0, lambda c: c.min() > 0.5),
    ("Gulf of Guinea, Greenwich meridian", 2.0, 0.0, lambda c: c.mean() < 0.03 and c[2] > 2 * c[0]),
    ("Ghana, Greenwich meridian", 8.0, 0.0, lambda c: 0.03 < c.mean() and c[0] > c[2]),
    ("Arabia (east of Greenwich)", 23.0, 47.0, lambda c: c.mean() > 0.2 and c[0] > c[2]),
    ("Atlantic (west of Greenwich)", 23.0, -47.0, lambda c: c.mean() < 0.03 and c[2] > 2 * c[0]),
])
def test_image_orientation_matches_geography(place, lat, lon, check):
    """The Blue Marble read in Earth-fixed axes (longitude from +x east, latitude from +z) puts
    deserts, oceans and ice where geography has them, on both sides of the Greenwich meridian."""
    p, tex = _packed()
    up, _, _ = _enu(lat, lon)
    c = np.array(_earth.texel(p, tex, *up))
    assert check(c), f"{place}: linear RGB {c}"
    water = _earth.water_fraction(*c)
    assert (water > 0.9) == ("Pacific" in place or "Atlantic" in place or "Guinea" in place), (place, water)


def test_cloud_cover_is_two_thirds_and_seeded():
    """67 % of the globe under cloud (the MODIS mean, King et al. 2013), the same field for the
    same seed, another for another seed."""
    n = 40000
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    ph = k * math.pi * (3.0 - math.sqrt(5.0))
    E = np.column_stack([np.sqrt(1 - z * z) * np.cos(ph), np.sqrt(1 - z * z) * np.sin(ph), z])
    p0, tex = _packed(0)
    s0 = _state(p0, tex, E, 1000.0)
    cover = float((s0[:, 1] > p0[env.P_CLOUD_THRESHOLD]).mean())
    assert abs(cover - 0.67) < 0.02, cover
    np.testing.assert_array_equal(s0, _state(_packed(0)[0], tex, E, 1000.0))
    s1 = _state(_packed(1)[0], tex, E, 1000.0)
    assert np.corrcoef(s0[:, 1], s1[:, 1])[0, 1] < 0.2


@pytest.mark.parametrize("lon", [-150.0, 20.0])
def test_full_disc_reflectance(lon):
    """The lit full disc from geostationary distance with the Sun behind the camera: its mean
    top-of-atmosphere reflectance π L/(E_sun μ_s) over the disc's pixels, channels averaged, is
    Earth's 0.30 ± 0.03 (the Pacific hemisphere and the Africa–Europe one)."""
    W = 160
    f = W / 2 / math.tan(math.asin((R_E + _earth.SHELL_M) / GEO_M))
    rad, mask, D, m, mu_s, p, tex = _view(_above(0.0, lon), GEO_M, (0.0, 0.0, -1.0), W, W, f)
    disc = mask & (mu_s > 0)
    assert abs(_reflectance(rad, mu_s)[disc].mean() - 0.30) < 0.03, _reflectance(rad, mu_s)[disc].mean()


def _specular_point(o, sun, c, radius):
    """The point of the sphere (centre c) where the Sun (direction ``sun``, at infinity) is
    mirrored towards o: Fermat's stationary optical path |x − o| − ŝ·x over the sphere."""
    def point(a):
        th, ph = a
        return c + radius * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])

    def path(a):
        x = point(a)
        return np.linalg.norm(x - o) - sun @ x

    best = min((minimize(path, x0, method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-6, "maxiter": 4000})
                for x0 in ([3.0, 0.1], [2.8, 1.0], [2.9, -1.0])), key=lambda r: r.fun)
    return point(best.x)


def test_sun_glint_at_the_specular_point_only_and_dark_ocean():
    """Over cloud-free ocean (central Pacific, clouds switched off) from 400 km, the Sun 40° from
    the zenith: the glint is where the mirror geometry puts it (the pixel of the specular point
    within 85 % of the brightest pixel's radiance, the brightest within 7° of it: its peak leans a
    few degrees outwards, with 1/μ_v and Fresnel's reflectance), and far from it (the Cox–Munk
    slope density below e^-9 of its peak) the ocean is dark: reflectance 0.04–0.10 (view within
    45° of the zenith), blue above red."""
    d = R_E + 400e3
    sun = _unit([math.sin(math.radians(40.0)), 0.0, -math.cos(math.radians(40.0))])
    tilt = math.radians(20.0)  # camera turned towards +x, the specular point off-centre
    R_bc = np.array([[math.cos(tilt), 0.0, math.sin(tilt)], [0.0, 1.0, 0.0], [-math.sin(tilt), 0.0, math.cos(tilt)]])
    W, H, f = 160, 120, 120.0
    rad, mask, D, m, mu_s, p, tex = _view(_above(0.0, -150.0), d, sun, W, H, f, R_body_from_cam=R_bc, clouds=False)
    x = _specular_point(np.zeros(3), sun, np.array([0.0, 0.0, d]), R_E)
    xc = R_bc.T @ x
    u, v = f * xc[0] / xc[2] + (W - 1) / 2, f * xc[1] / xc[2] + (H - 1) / 2
    assert 10 < u < W - 10 and 10 < v < H - 10
    lum = np.where(mask, rad.mean(-1), -1.0)
    vb, ub = np.unravel_index(np.argmax(lum), lum.shape)
    assert math.degrees(math.acos(min(1.0, D[vb, ub] @ _unit(x)))) < 7.0, ((ub, vb), (u, v))
    assert lum[int(round(v)), int(round(u))] > 0.85 * lum[vb, ub]
    h = sun[None, None, :] - D
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    cb = np.einsum("ijk,ijk->ij", h, m)
    far = mask & ((1 - cb ** 2) / cb ** 2 > 9 * _earth.SIGMA2) & (mu_s > 0.3) & (-np.einsum("ijk,ijk->ij", D, m) > 0.7)
    rho = _reflectance(rad, mu_s)
    assert far.sum() > 200
    assert 0.04 < rho[far].mean(-1).min() and rho[far].mean(-1).max() < 0.10, \
        (rho[far].mean(-1).min(), rho[far].mean(-1).max())
    assert np.all(rho[far][:, 2] > 1.5 * rho[far][:, 0])
    # the peak: Cox–Munk π F p(0) / (4 μ_s μ_v) ≈ 0.30 at 40° before the atmosphere, several times the rest
    assert rho[vb, ub].mean() > 0.2 and rho[vb, ub].mean() > 2.5 * rho[far].mean(-1).max()


def test_limb_glows_blue_beyond_the_ground():
    """Rays that miss the ground by 20–50 km of altitude see the lit atmosphere, blue over red,
    fading with height (lower, the limb is optically thick in every channel); beyond the 100 km
    shell nothing."""
    p, tex = _packed()
    d = R_E + 400e3
    p[env.P_DIST] = d
    p[env.P_SX:env.P_SZ + 1] = (1.0, 0.0, 0.0)  # the Sun to the side: the limb lit
    out = []
    for h in (20e3, 35e3, 50e3, 150e3):
        a = math.asin((R_E + h) / d)
        out.append(env.env_radiance(p, tex, 0.0, 0.0, 0.0, math.sin(a), 0.0, math.cos(a)))
    out = np.array(out)
    assert np.all(out[:3, 2] > 1.5 * out[:3, 0]) and out[0, 2] > out[1, 2] > out[2, 2] > 0
    np.testing.assert_array_equal(out[3], 0.0)


@pytest.fixture(scope="module")
def main_job_frames():
    """The main job's geometry (Cassini, spiral, its 57.8° lens) at 320 × 240, 6 frames: per
    frame with Earth behind the target the camera, pose, light and geometry."""
    import cli
    from raytrace.dataset.scenes import lighting_of, load_model
    from raytrace.scene import Scene
    args = cli.build_parser().parse_args(["--target", "cassini", "--pattern", "spiral", "--frames", "6",
                                          "--width", "320", "--height", "240", "--focal-length-mm", "1.0"])
    cfg, given = cli.resolve_config(args)
    assert cfg["render"]["earth_texture"] == "bluemarble"  # the main job's default
    plan = cli.plan_sequence(cfg, given)
    scene = Scene(load_model(plan["model_spec"]))
    c = plan["camera"]
    cam = Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy)
    out = []
    for i, label in enumerate(plan["result"]["frames"]):
        light = lighting_of(plan["lights"][i], cfg["render"], None, cfg["sequence"]["seed"])
        R = np.asarray(label["R_cam_from_body"], dtype=np.float64).reshape(3, 3)
        t = np.asarray(label["t_cam_m"], dtype=np.float64)
        if shade._earth_may_be_in_view(cam, R, light):
            out.append((cam, R, t, light, scene.render_geometry(cam, R, t)))
    assert len(out) >= 3
    return out


def test_main_job_earth_has_texture_ocean_and_clouds(main_job_frames):
    """Behind the target in the main job's frames: local contrast at a 7-pixel scale (std/mean
    of 7×7 windows wholly on lit Earth, median) ≥ 0.01; at an Earth-fixed point of open,
    cloud-free ocean the colour is dark blue, under thick cloud near-white."""
    contrasts, ocean, cloud = [], [], []
    for cam, R, t, light, geo in main_job_frames:
        R_bc = np.ascontiguousarray(R.T)
        o = -R_bc @ t
        p, tex = _background_params(light)
        p[env.P_PIX_RAD] = 1.0 / cam.fx
        H, W = cam.height, cam.width
        rad = np.zeros((H, W, 3), np.float32)
        mask = np.zeros((H, W), dtype=bool)
        earth_background(geo.instance, o, R_bc, cam.fx, cam.fy, cam.cx, cam.cy, *cam.lens_arrays(), p, tex,
                         shade._BACKGROUND_STEP, shade._BACKGROUND_TOL, shade._BACKGROUND_CHORD, mask, rad)
        lum = rad.mean(-1)
        ok = mask & (geo.instance == 0) & (lum > 0.02 * SOLAR_CONSTANT_W_M2 / math.pi)
        for v in range(0, H - 7, 7):
            for u in range(0, W - 7, 7):
                if ok[v:v + 7, u:u + 7].all():
                    win = lum[v:v + 7, u:u + 7]
                    contrasts.append(win.std() / win.mean())
        # each lit Earth pixel's ground point, Earth-fixed (numpy), and its water and cloud
        vv, uu = np.nonzero(ok)
        Dc = np.column_stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones(len(uu))]) @ R
        Dc /= np.linalg.norm(Dc, axis=1, keepdims=True)
        e = np.asarray(light.earth.earth_dir_body)
        c = light.earth.distance_m * e - o
        b = Dc @ c
        tt = b - np.sqrt(R_E ** 2 - (c @ c - b * b))
        m = (o + Dc * tt[:, None] - light.earth.distance_m * e) / R_E
        mu_s = m @ np.asarray(light.sun_dir_body)
        E = m @ light.earth.R_body_from_earth  # = (R_earth_from_body m) row-wise
        st = _state(p, tex, np.ascontiguousarray(E), 2000.0)
        rho = _reflectance(rad[vv, uu], mu_s)
        thr = p[env.P_CLOUD_THRESHOLD]
        pick = (mu_s > 0.2)
        ocean += list(rho[pick & (st[:, 0] > 0.99) & (st[:, 1] < thr - 0.05)])
        cloud += list(rho[pick & (st[:, 1] > thr + 0.6)])
    assert np.median(contrasts) >= 0.01, np.median(contrasts)
    assert len(ocean) > 10 and len(cloud) > 10, (len(ocean), len(cloud))
    ocean, cloud = np.array(ocean), np.array(cloud)
    # open ocean: dark, blue above green above red
    assert np.median(ocean.mean(1)) < 0.12 and np.all(np.median(ocean, 0)[2] > np.median(ocean, 0)[1:].max() * 0.99)
    assert np.median(ocean[:, 2]) > 1.5 * np.median(ocean[:, 0])
    # thick cloud: bright and near-white (channels within 20 % of their mean)
    cm = np.median(cloud, 0)
    assert cm.mean() > 0.5 and np.all(np.abs(cm / cm.mean() - 1) < 0.2), cm


def test_night_side_is_the_twilight_sky_whatever_the_clouds():
    """Beyond the terminator (μ_s ≤ 0) neither the ground nor the clouds are lit: a pixel there is
    the path radiance of the twilit air column alone, the same bits with clouds or without (the
    background skips the fine octaves there), and per pixel what the exact per-point evaluation
    (:func:`raytrace._earth.point_radiance`, the state not interpolated) gives."""
    W, H, f = 160, 120, 100.0
    args = (_above(20.0, -30.0), R_E + 400e3, (1.0, 0.0, 0.0), W, H, f)  # the terminator through nadir
    rad, mask, D, m, mu_s, p, tex = _view(*args)
    rad_clear, *_ = _view(*args, clouds=False)
    # night: beyond the terminator by more than a background cell (8 pixels, Δμ_s ≈ 0.005 here),
    # whose interpolated glint would carry the day side's into it
    night = mask & (mu_s <= -0.01) & (mu_s > _earth.MU_NIGHT + 0.01)
    day = mask & (mu_s > 0.02)
    assert night.sum() > 2000 and day.sum() > 2000
    assert np.array_equal(rad[night], rad_clear[night])
    assert not np.array_equal(rad[day], rad_clear[day])  # the clouds show on the day side
    dist = R_E + 400e3
    exact = np.array([_earth.point_radiance(p, tex, *m[v, u], *D[v, u],
                                            float(D[v, u] @ np.array([0.0, 0.0, dist])
                                                  - math.sqrt(R_E ** 2 - dist ** 2 + (D[v, u, 2] * dist) ** 2)))
                      for v, u in zip(*np.nonzero(night), strict=True)])
    assert exact.max() > 0.0  # twilight: the air above is lit
    np.testing.assert_allclose(rad[night], exact, rtol=1e-2, atol=1e-3 * exact.max())


@pytest.mark.parametrize("tilt_deg", [0.0, 55.0])
def test_day_side_pixels_are_the_point_by_point_evaluation(tilt_deg):
    """Every pixel's state evaluated (step 1), each lit ground pixel of the background kernel, whose
    fine octaves are summed a row at a time, against :func:`raytrace._earth.point_radiance` called
    point by point (its octaves summed one point at a time): at nadir and on a view tilted along
    the rows towards the horizon, where the footprint, and with it the number of fine octaves and
    the last one's fade, changes along each row. Pixels finer than the coarse octaves' 3 km
    (point_radiance fades those beyond the footprint, the kernel's state keeps them all)."""
    W, H, f = 160, 48, 1000.0
    dist = R_E + 400e3
    a = math.radians(tilt_deg)  # about the camera's y axis: the view's obliquity changes along x, the rows
    R_bc = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    rad, mask, D, m, mu_s, p, tex = _view(_above(-5.0, 140.0), dist, (0.3, -0.2, -1.0), W, H, f,
                                          R_body_from_cam=R_bc, step=1)
    lit = mask & (mu_s > 0.1)
    assert lit.sum() == W * H
    t = D @ np.array([0.0, 0.0, dist]) - np.sqrt(R_E ** 2 - dist ** 2 + (D[..., 2] * dist) ** 2)
    exact = np.array([_earth.point_radiance(p, tex, *m[v, u], *D[v, u], float(t[v, u]))
                      for v, u in zip(*np.nonzero(lit), strict=True)])
    foot = np.maximum(t / f / np.maximum(-np.einsum("ijk,ijk->ij", D, m), 0.05), 100.0)
    assert foot.max() < 3e3
    octaves = np.floor(np.log2(R_E / _earth.F_FINE / foot) - 1.0)  # whole fine octaves, per pixel
    varies = (octaves.min(axis=1) < octaves.max(axis=1)).all()
    assert varies if tilt_deg else not varies
    np.testing.assert_allclose(rad[lit], exact, rtol=1e-5)


def _adding(rc, rho):
    """The clouds over the ground by the adding formula (raytrace._earth's docstring):
    R_c + (1 − R_c)² ρ / (1 − R_c ρ)."""
    return rc + (1.0 - rc) ** 2 * rho / (1.0 - rc * rho)


@pytest.mark.parametrize("cloud_over", [-0.2, 0.05, 0.4])
def test_combine_open_water_and_coast_against_the_adding_formula(cloud_over):
    """combine() against the model written out here: over open water (water fraction 1) the land's
    detail does not matter (its term is left out, the same radiance for any land log-detail, even
    one whose exponential overflows); a coast (fraction 0.9) takes it in, the land's reflectance
    scaled by exp(land)."""
    p = np.zeros(_earth.N_EARTH_PARAMS)
    p[10] = SOLAR_CONSTANT_W_M2
    p[_earth.P_SURF_SCALE] = 1.2
    p[_earth.P_CLOUD_THRESHOLD] = _earth.CLOUD_THRESHOLD
    rgb, t, path, gl = (0.02, 0.04, 0.09), (0.9, 0.85, 0.7), (3.0, 5.0, 12.0), (40.0, 38.0, 30.0)
    mu_s, k = 0.6, p[_earth.P_SURF_SCALE]
    cloud = _earth.CLOUD_THRESHOLD + cloud_over
    x = cloud_over
    rc = min(_earth.CLOUD_R_MAX * (1.0 - math.exp(-(x / _earth.CLOUD_SOFT) ** 2)) * k, 0.98) if x > 0 else 0.0

    def expected(wf, land):
        kl = _earth.LAND_SCALE * k * (1.0 - wf) * math.exp(land) + _earth.WATER_SCALE * k * wf
        return [SOLAR_CONSTANT_W_M2 * mu_s / math.pi * t[c] * _adding(rc, min(rgb[c] * kl, 1.0))
                + wf * (1.0 - rc) * gl[c] + path[c] for c in range(3)]

    for wf, lands in ((1.0, (-0.5, 0.0, 0.7, 800.0)), (0.9, (-0.5, 0.0, 0.7))):
        for land in lands:
            got = _earth.combine(p, *rgb, wf, *t, *path, *gl, cloud, land, mu_s)
            want = expected(wf, 0.0 if wf == 1.0 else land)
            np.testing.assert_allclose(got, want, rtol=1e-12)
    coast = [_earth.combine(p, *rgb, 0.9, *t, *path, *gl, cloud, land, mu_s)[0] for land in (-0.5, 0.7)]
    assert coast[1] > coast[0]  # the land's detail shows on the coast
