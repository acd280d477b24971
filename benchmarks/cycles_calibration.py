"""Calibrate benchmarks/cycles_render.py against analytic radiance (benchmark only, not a test).

Builds analytic scenes in a temp dir, renders each with cycles_render.py and prints measured
vs analytic radiance [W/(m^2 sr)] with relative errors:

* plate_sun        Lambert plate, albedo rho, sun at incidence theta:  rho E f cos(theta) / pi
                   (also the OBJ-in-millimetres loader and shadow_fraction f)
* cube_sun         a faceted cube under an oblique sun: each face uniform, rho E (n.s) / pi
* plate_ambient    the plate in the white-furnace world only:          rho L; the sky itself is
                   not drawn (0, as raytrace does) unless --draw-ambient (then L)
* sphere_sun       Lambert sphere (icosphere, 81920 faces, radius r, camera at 2000 r) at phase
                   angle a: centre pixel rho E cos(a) / pi; mean over the disc
                   rho E/pi * 2/3 [sin a + (pi - a) cos a]/pi (orthographic closed form), and the
                   flux vs an exact perspective float64 ray-sphere reference
* projection       white 6-px spheres (ambient only) on black space, generic rotation, centred
                   and off-centre principal point: mask centroid vs u = fx x/z + cx,
                   v = fy y/z + cy (and vs the exact box-filtered coverage of the silhouette cone)
* earth_view       the Earth sphere 6778 km away seen from orbit: every pixel vs a float64
                   ray-sphere reference, rho_E E max(n.s, 0)/pi (interior) and the limb position
* plate_earth      plate facing a full Earth from 407 km, plus ambient: rho/pi (E_earth + L pi cos^2 b)
                   with E_earth by quadrature over the visible cap and sin b = R/d
* plate_sun_behind_earth  the sun behind the Earth with shadow_fraction 1: the Earth must not
                   shadow the sun (eclipse is shadow_fraction's job): rho/pi (E + L pi cos^2 b)
* shadow_with_earth  a plate shadowed by a second mesh still is with the Earth present

Run:  .bpyenv/bin/python benchmarks/cycles_calibration.py [--spp 1024] [--threads 2]
      [--keep DIR] [--only plate sphere projection earth] [--timing [--repeats 3]]
(about 5 min at 1024 spp on 2 cores; BPY_PYTHON names the Blender venv's python if it is
not .bpyenv/bin/python)
--timing also renders a 1280x960 scene (sphere + panel + Earth + ambient) at 1, 16, 64, 256 spp
(--repeats times, interleaved) and prints render_s per run.
Reads EXRs with OpenImageIO if importable, else with bpy. Needs numpy and trimesh.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import tempfile

import numpy as np
import trimesh

HERE = os.path.dirname(os.path.abspath(__file__))
RENDER = os.path.join(HERE, "cycles_render.py")
BPY_PYTHON = os.environ.get(
    "BPY_PYTHON", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".bpyenv", "bin", "python"))
E_SUN = 1361.0
R_EARTH = 6371008.8
D_EARTH = 6778137.0


# ----------------------------------------------------------------------------- helpers
def read_exr(path: str) -> np.ndarray:
    try:
        import OpenImageIO as oiio
        inp = oiio.ImageInput.open(path)
        img = inp.read_image("float")
        inp.close()
        return np.asarray(img, np.float32)[:, :, :3]
    except ImportError:
        import bpy
        img = bpy.data.images.load(path, check_existing=False)
        img.colorspace_settings.is_data = True
        W, H = img.size
        buf = np.empty(W * H * img.channels, np.float32)
        img.pixels.foreach_get(buf)
        out = buf.reshape(H, W, img.channels)[::-1, :, :3].copy()  # bpy rows are bottom-up
        bpy.data.images.remove(img)
        return out


def look_at(C, target, up):
    """OpenCV R_cam_from_body, t_cam_m for a camera at C looking at target (y down)."""
    C, target, up = (np.asarray(a, float) for a in (C, target, up))
    z = target - C
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ C


def K(f, cx, cy):
    return [[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]


def unit(v):
    v = np.asarray(v, float)
    return (v / np.linalg.norm(v)).tolist()


def scene(meshes, W, H, Kmat, R, t, sun_dir=(0, 0, 1), E=E_SUN, frac=1.0, ambient=0.0, earth=None):
    """A SCENE.json dict (directions normalised: raytrace.scenefile wants unit vectors)."""
    if earth is not None:
        earth = dict(earth, earth_dir_body=unit(earth["earth_dir_body"]))
    sc = {"meshes": meshes,
          "camera": {"K": Kmat, "width": W, "height": H, "R_cam_from_body": np.asarray(R).ravel().tolist(),
                     "t_cam_m": np.asarray(t).tolist()},
          "sun": {"sun_dir_body": unit(sun_dir), "sun_irradiance_W_m2": E,
                  "shadow_fraction": frac, "angular_diameter_deg": 0.53},
          "ambient_radiance_W_m2_sr": ambient, "quality": "balanced", "samples": None, "seed": 0}
    if earth is not None:
        sc["earth"] = earth
    return sc


class Runner:
    def __init__(self, tmp, spp, threads):
        self.tmp, self.spp, self.threads = tmp, spp, threads

    def __call__(self, name, sc, spp=None, extra=()):
        js, exr = os.path.join(self.tmp, name + ".json"), os.path.join(self.tmp, name + ".exr")
        with open(js, "w") as fh:
            json.dump(sc, fh, indent=1)
        out = subprocess.run([BPY_PYTHON, RENDER, js, "--spp", str(spp or self.spp), "--out", exr,
                              "--threads", str(self.threads), *extra], check=False, capture_output=True, text=True)
        if out.returncode:
            raise RuntimeError(f"{name}: cycles_render failed\n{out.stderr}")
        lines = out.stdout.strip().splitlines()
        assert len(lines) == 1, f"stdout must be one JSON line, got {out.stdout!r}"
        return read_exr(exr), json.loads(lines[0])


ROWS = []


def row(test, quantity, measured, analytic):
    measured, analytic = np.atleast_1d(measured).astype(float), np.atleast_1d(analytic).astype(float)
    rel = np.where(analytic != 0, (measured - analytic) / np.where(analytic != 0, analytic, 1), measured - analytic)
    fmt = lambda a: "/".join(f"{x:.5g}" for x in a)
    ROWS.append((test, quantity, fmt(measured), fmt(analytic), fmt(rel)))
    print(f"{test:<24} {quantity:<36} {fmt(measured):>32} {fmt(analytic):>32} {fmt(rel):>28}", flush=True)
    return rel


def sphere_ply(path, radius, centre, subdivisions):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation(centre)
    m.export(path)


# ----------------------------------------------------------------------------- tests
def plate_tests(run, tmp):
    # 2 m x 2 m plate in z = 0, normal +z; PLY in metres and OBJ in millimetres
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    trimesh.Trimesh(v, f, process=False).export(os.path.join(tmp, "plate.ply"))
    trimesh.Trimesh(v * 1000, f, process=False).export(os.path.join(tmp, "plate_mm.obj"))
    rho = np.array([0.8, 0.5, 0.2])
    W = H = 64
    R, t = look_at([1.0, -0.5, 3.0], [0, 0, 0], [0, 1, 0])  # oblique view: Lambert is view-independent
    k = K(60.0, (W - 1) / 2, (H - 1) / 2)
    centre = (slice(24, 40), slice(24, 40))
    factors = {}
    for name, path, scale, theta, frac in (("plate_sun 0deg", "plate.ply", 1.0, 0.0, 1.0),
                                           ("plate_sun 60deg", "plate.ply", 1.0, 60.0, 1.0),
                                           ("plate_sun obj mm f=.37", "plate_mm.obj", 1e-3, 30.0, 0.37)):
        th = math.radians(theta)
        sun = [math.sin(th), 0.0, math.cos(th)]
        img, _ = run(name.replace(" ", "_").replace("=", ""),
                     scene([{"path": path, "unit_scale_m": scale, "albedo": rho.tolist()}], W, H, k, R, t,
                           sun_dir=sun, frac=frac))
        meas = img[centre].reshape(-1, 3).mean(0)
        ana = rho * E_SUN * frac * math.cos(th) / math.pi
        factors[name] = float(np.mean(meas / ana))
        row(name, "plate radiance R/G/B", meas, ana)
    L = 5.0
    img, _ = run("plate_ambient", scene([{"path": "plate.ply", "unit_scale_m": 1.0, "albedo": rho.tolist()}],
                                        W, H, k, R, t, E=0.0, ambient=L))
    meas = img[centre].reshape(-1, 3).mean(0)
    factors["plate_ambient"] = float(np.mean(meas / (rho * L)))
    row("plate_ambient", "plate radiance R/G/B", meas, rho * L)
    row("plate_ambient", "sky pixel (0,0): not drawn", img[0, 0], [0.0, 0.0, 0.0])
    img, _ = run("plate_ambient_drawn", scene([{"path": "plate.ply", "unit_scale_m": 1.0, "albedo": rho.tolist()}],
                                              W, H, k, R, t, E=0.0, ambient=L), extra=["--draw-ambient"])
    row("plate_ambient", "sky pixel (0,0), --draw-ambient", img[0, 0], [L, L, L])
    row("plate_ambient", "plate radiance, --draw-ambient", img[centre].reshape(-1, 3).mean(0), rho * L)
    return factors


def cube_test(run, tmp):
    """Flat faces stay flat: a unit cube (crease 30 deg: faceted) under an oblique sun."""
    trimesh.creation.box(extents=[1, 1, 1]).export(os.path.join(tmp, "cube.obj"))
    W, fpx, rho = 128, 90.0, 0.5
    R, t = look_at([2.5, 3.0, 2.0], [0, 0, 0], [0, 0, 1])
    k = K(fpx, (W - 1) / 2, (W - 1) / 2)
    sun = np.array(unit([0.3, 0.5, 0.81]))
    img, _ = run("cube_sun", scene([{"path": "cube.obj", "unit_scale_m": 1.0, "albedo": [rho] * 3}],
                                   W, W, k, R, t, sun_dir=sun))
    g = img.mean(axis=2)
    for n in np.eye(3):  # the +x, +y, +z faces face the camera
        p = R @ (0.5 * n) + t
        u, v = round(fpx * p[0] / p[2] + (W - 1) / 2), round(fpx * p[1] / p[2] + (W - 1) / 2)
        patch = g[v - 3:v + 4, u - 3:u + 4]
        row("cube_sun", f"face {'xyz'[int(np.argmax(n))]}: mean (max-min)/mean {np.ptp(patch) / patch.mean():.1e}",
            patch.mean(), rho * E_SUN * float(n @ sun) / math.pi)


def sphere_tests(run, tmp):
    r, d, W = 1.0, 2000.0, 384
    sphere_ply(os.path.join(tmp, "sphere.ply"), r, [0, 0, 0], 6)
    f = 150.0 * d / r  # disc radius ~150 px
    rho = 0.7
    R, t = look_at([0, 0, d], [0, 0, 0], [0, 1, 0])
    rpx = f * math.tan(math.asin(r / d))
    for a_deg in (0.0, 45.0, 90.0, 135.0):
        a = math.radians(a_deg)
        img, _ = run(f"sphere_sun_{a_deg:.0f}",
                     scene([{"path": "sphere.ply", "unit_scale_m": 1.0, "albedo": [rho] * 3}], W, W,
                           K(f, (W - 1) / 2, (W - 1) / 2), R, t, sun_dir=[math.sin(a), 0, math.cos(a)]))
        g = img.mean(axis=2)
        c = (W - 1) // 2
        centre = g[c - 1:c + 3, c - 1:c + 3].mean()  # 4 px around the centre (exactly symmetric)
        if a_deg < 90:  # (at 90 deg the centre is on the terminator)
            row(f"sphere_sun a={a_deg:.0f}", "centre radiance", centre, rho * E_SUN * math.cos(a) / math.pi)
        phase = (math.sin(a) + (math.pi - a) * math.cos(a)) / math.pi
        row(f"sphere_sun a={a_deg:.0f}", "disc mean radiance", g.sum() / (math.pi * rpx ** 2),
            rho * E_SUN / math.pi * 2 / 3 * phase)
        sun = np.array([math.sin(a), 0, math.cos(a)])
        ref = sphere_reference(W, W, K(f, (W - 1) / 2, (W - 1) / 2), R, t, np.zeros(3), r, sun, rho, E_SUN, 0.0)[0]
        print(f"{'':<24} {'':<36} exact perspective (camera at {d / r:.0f} r, float64 ray-sphere): flux "
              f"Cycles/exact - 1 = {g.sum() / ref.sum() - 1:+.2e}; closed form/exact - 1 = "
              f"{rho * E_SUN / math.pi * 2 / 3 * phase * math.pi * rpx ** 2 / ref.sum() - 1:+.2e}", flush=True)


def coverage(W, H, k, R, t, centre, radius, win, ss=32):
    """Exact box-filtered coverage of a sphere's silhouette cone in a pixel window (float64)."""
    (u0, u1), (v0, v1) = win
    o = (np.arange(ss) + 0.5) / ss - 0.5
    uu = (np.arange(u0, u1)[:, None] + o[None, :]).ravel()
    vv = (np.arange(v0, v1)[:, None] + o[None, :]).ravel()
    U, V = np.meshgrid(uu, vv)
    dcam = np.stack([(U - k[0][2]) / k[0][0], (V - k[1][2]) / k[1][1], np.ones_like(U)], -1)
    dcam /= np.linalg.norm(dcam, axis=-1, keepdims=True)
    c = R @ np.asarray(centre) + t
    hit = dcam @ (c / np.linalg.norm(c)) >= math.cos(math.asin(radius / np.linalg.norm(c)))
    return hit.reshape(v1 - v0, ss, u1 - u0, ss).mean(axis=(1, 3))


def projection_tests(run, tmp):
    W, H = 640, 480
    rng = np.random.default_rng(1)
    A = rng.normal(size=(3, 3))
    R, _ = np.linalg.qr(A)
    R *= np.sign(np.linalg.det(R))
    t = np.array([0.3, -0.2, 10.0])
    for label, k in (("centred c", K(900.0, (W - 1) / 2, (H - 1) / 2)), ("off-centre c", K(900.0, 290.3, 262.8))):
        targets = [(320.0, 240.0, 9.0), (101.3, 57.6, 7.5), (561.7, 430.2, 12.0)]  # u, v, depth
        spheres, meshes = [], []
        for i, (u, v, z) in enumerate(targets):
            p_cam = np.array([(u - k[0][2]) / k[0][0] * z, (v - k[1][2]) / k[1][1] * z, z])
            p_body = R.T @ (p_cam - t)
            rad = 3.0 * z / k[0][0]  # ~6 px across
            sphere_ply(os.path.join(tmp, f"tiny{i}.ply"), rad, p_body, 4)
            spheres.append((p_body, rad))
            meshes.append({"path": f"tiny{i}.ply", "unit_scale_m": 1.0, "albedo": [1.0, 1.0, 1.0]})
        # white spheres in a white furnace (radiance exactly 1) on undrawn (black) sky: image = coverage
        img, _ = run("projection_" + label.split()[0], scene(meshes, W, H, k, R, t, E=0.0, ambient=1.0))
        mask = img.mean(axis=2)
        for (p_body, rad) in spheres:
            p = R @ p_body + t
            u, v = k[0][0] * p[0] / p[2] + k[0][2], k[1][1] * p[1] / p[2] + k[1][2]
            win = ((int(u) - 8, int(u) + 9), (int(v) - 8, int(v) + 9))
            m = mask[win[1][0]:win[1][1], win[0][0]:win[0][1]]
            vv, uu = np.mgrid[win[1][0]:win[1][1], win[0][0]:win[0][1]]
            cu, cv = (m * uu).sum() / m.sum(), (m * vv).sum() / m.sum()
            cov = coverage(W, H, k, R, t, p_body, rad, win)
            eu, ev = (cov * uu).sum() / cov.sum(), (cov * vv).sum() / cov.sum()
            q = f"mask centroid u,v (K proj. {u:.2f},{v:.2f})"
            ROWS.append((f"projection {label}", q, f"{cu:.4f}, {cv:.4f}", f"{u:.4f}, {v:.4f}",
                         f"du {cu - u:+.4f}, dv {cv - v:+.4f} px"))
            print(f"{ROWS[-1][0]:<24} {q:<36} {ROWS[-1][2]:>32} {ROWS[-1][3]:>32} {ROWS[-1][4]:>28}")
            print(f"{'':<24} {'':<36} vs exact box-filtered coverage centroid ({eu:.4f}, {ev:.4f}): "
                  f"du {cu - eu:+.4f}, dv {cv - ev:+.4f} px; mask area {m.sum():.3f} vs {cov.sum():.3f} px", flush=True)


def sphere_reference(W, H, k, R, t, centre, radius, sun, rho, E, L):
    """Box-filtered float64 reference of a Lambert sphere lit by a point sun (radiance
    rho E max(n.s, 0)/pi) in front of a sky of radiance L: 4x4 rays per pixel,
    64x64 in and around limb pixels. Returns radiance, Earth coverage and the mean Earth
    radiance over the covered part of each pixel."""
    C = -R.T @ t

    def shade(us, vs, ss):
        o = (np.arange(ss) + 0.5) / ss - 0.5
        U = (us[:, None] + o[None, :])[:, None, :].repeat(ss, 1)   # (n, ss, ss): [pixel, row, col]
        V = (vs[:, None] + o[None, :])[:, :, None].repeat(ss, 2)
        d = np.stack([(U - k[0][2]) / k[0][0], (V - k[1][2]) / k[1][1], np.ones_like(U)], -1) @ R
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        oc = C - centre
        b = d @ oc
        disc = b * b - (oc @ oc - radius * radius)
        tt = -b - np.sqrt(np.maximum(disc, 0))
        hit = (disc >= 0) & (tt > 0)
        n = (C + tt[..., None] * d - centre) / radius
        earth = np.where(hit, rho * E * np.maximum(n @ sun, 0) / math.pi, 0.0)
        cov = hit.mean(axis=(1, 2))
        return earth.mean(axis=(1, 2)) + L * (1 - cov), cov, earth.mean(axis=(1, 2)) / np.maximum(cov, 1e-12)

    vv, uu = np.mgrid[0:H, 0:W]
    ref, cov, er = (a.reshape(H, W) for a in shade(uu.ravel().astype(float), vv.ravel().astype(float), 4))
    part = (cov > 0) & (cov < 1)
    near = np.zeros_like(part)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            near |= np.roll(np.roll(part, dv, 0), du, 1)
    for a, b in zip((ref, cov, er), shade(uu[near].astype(float), vv[near].astype(float), 64)):
        a[near] = b
    return ref, cov, er


def earth_tests(run, tmp):
    W, H, f = 320, 240, 280.0
    k = K(f, (W - 1) / 2, (H - 1) / 2)
    e_dir = np.array([0.0, 0.0, -1.0])
    centre = e_dir * D_EARTH
    sun = np.array([1.0, -0.3, 0.0]) / np.linalg.norm([1.0, -0.3, 0.0])  # terminator and lit limb in view
    L, rho_e = 5.0, 0.3
    earth = {"earth_dir_body": e_dir.tolist(), "earth_distance_m": D_EARTH, "radius_m": R_EARTH, "albedo": rho_e}
    # camera 10 m from the target origin, looking 50 deg below the horizontal: limb in view, terminator too
    C = np.array([0.0, -10.0, 0.0])
    look = C + np.array([0.6, math.cos(math.radians(50)), -math.sin(math.radians(50))])
    R, t = look_at(C, look, [0, 0, 1])
    img, _ = run("earth_view", scene([], W, H, k, R, t, sun_dir=sun, ambient=L, earth=earth))
    # the sky is not drawn (camera rays see 0 where they miss the Earth)
    ref, cov, earth_rad = sphere_reference(W, H, k, R, t, centre, R_EARTH, sun, rho_e, E_SUN, 0.0)
    g = img.mean(axis=2)
    pad = np.pad(cov, 1, mode="edge")
    nb = [pad[1 + dv:1 + dv + H, 1 + du:1 + du + W] for dv in (-1, 0, 1) for du in (-1, 0, 1)]
    inside, sky = np.all([a == 1 for a in nb], axis=0), np.all([a == 0 for a in nb], axis=0)
    lit, night = inside & (ref > 1.0), inside & (ref == 0)
    rel = np.abs(g[lit] / ref[lit] - 1)
    row("earth_view", "Earth radiance, day-side px mean", g[lit].mean(), ref[lit].mean())
    print(f"{'':<24} {'':<36} per-pixel |rel err| day side: max {rel.max():.2e}, "
          f"p99 {np.quantile(rel, 0.99):.2e} ({lit.sum()} px); night side max {np.abs(g[night]).max():.2e} "
          f"({night.sum()} px); sky max |I| {np.abs(g[sky]).max():.2e} ({sky.sum()} px)")
    row("earth_view", "sky pixels mean (not drawn: 0)", g[sky].mean(), 0.0)
    limb = (cov > 0) & (cov < 1) & (earth_rad > 1.0)
    cov_meas = g[limb] / earth_rad[limb]
    row("earth_view", "limb: Earth area in limb px [px^2]", cov_meas.sum(), cov[limb].sum())
    print(f"{'':<24} {'':<36} {limb.sum()} limb px; mean limb offset "
          f"{(cov_meas.sum() - cov[limb].sum()) / limb.sum():+.4f} px (+ = Earth bigger)")

    # plate facing a full Earth (sun behind the plate) + ambient; then the sun behind the Earth
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False).export(os.path.join(tmp, "plate.ply"))
    rho = np.array([0.6, 0.6, 0.6])
    Wp = 64
    R, t = look_at([0.3, 0.2, -3.0], [0, 0, 0], [0, 1, 0])  # camera between plate and Earth, looking up
    kp = K(60.0, (Wp - 1) / 2, (Wp - 1) / 2)
    d, Re = D_EARTH, R_EARTH
    # irradiance on the plate (normal -z, at distance d from the Earth's centre) from the cap, radiance
    # rho_e E cos(gamma)/pi, gamma = angle from the sub-plate point; Gauss-Legendre in gamma
    gmax = math.acos(Re / d)
    x, w = np.polynomial.legendre.leggauss(400)
    g = 0.5 * gmax * (x + 1)
    wz = d - Re * np.cos(g)                              # plate-to-point vertical distance
    dist2 = (Re * np.sin(g)) ** 2 + wz ** 2
    cos_plate = wz / np.sqrt(dist2)
    cos_surf = (d * np.cos(g) - Re) / np.sqrt(dist2)    # n . (plate - P) / |plate - P|
    E_earth = 2 * math.pi * 0.5 * gmax * np.sum(w * rho_e * E_SUN * np.cos(g) / math.pi * cos_plate * cos_surf
                                                   / dist2 * Re ** 2 * np.sin(g))
    cos2b = 1 - (Re / d) ** 2
    full = rho / math.pi * (E_earth + L * math.pi * cos2b)
    img, _ = run("plate_earth", scene([{"path": "plate.ply", "unit_scale_m": 1.0, "albedo": rho.tolist()}],
                                      Wp, Wp, kp, R, t, sun_dir=[0, 0, 1], ambient=L, earth=earth))
    row("plate_earth", "plate radiance (full Earth + sky)", img[24:40, 24:40].reshape(-1, 3).mean(0), full)
    print(f"{'':<24} {'':<36} E_earth on plate {E_earth:.3f} W/m2 (quadrature), sky {L * math.pi * cos2b:.3f} W/m2")
    img, _ = run("plate_sun_behind_earth", scene([{"path": "plate.ply", "unit_scale_m": 1.0, "albedo": rho.tolist()}],
                                                 Wp, Wp, kp, R, t, sun_dir=[0, 0, -1], ambient=L, earth=earth))
    row("plate_sun_behind_earth", "plate radiance (sun + night + sky)", img[24:40, 24:40].reshape(-1, 3).mean(0),
        rho / math.pi * (E_SUN + L * math.pi * cos2b))


def shadow_test(run, tmp):
    """Target self-shadowing still works with the Earth present (the sun's shadow linking)."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    trimesh.Trimesh(v, f, process=False).export(os.path.join(tmp, "plate.ply"))
    trimesh.Trimesh(v * 0.2 + [-0.45, 0, 0.5], f, process=False).export(os.path.join(tmp, "occluder.ply"))
    W, fpx = 64, 60.0
    R, t = look_at([0, 0, 3], [0, 0, 0], [0, 1, 0])
    k = K(fpx, (W - 1) / 2, (W - 1) / 2)
    sun = [-math.sin(math.radians(60)), 0, math.cos(math.radians(60))]  # shadow centred at x = 0.416 m
    meshes = [{"path": "plate.ply", "unit_scale_m": 1.0, "albedo": [0.5] * 3},
              {"path": "occluder.ply", "unit_scale_m": 1.0, "albedo": [0.5] * 3}]
    earth = {"earth_dir_body": [0, 0, -1], "earth_distance_m": D_EARTH, "radius_m": R_EARTH, "albedo": 0.3}
    u_sh, u_lit = round(0.416 * fpx / 3 + (W - 1) / 2), round(0.85 * fpx / 3 + (W - 1) / 2)
    vc = (W - 1) // 2
    vals = {}
    for name, e in (("no Earth", None), ("Earth", earth)):
        img, _ = run("shadow_" + name.replace(" ", "_"), scene(meshes, W, W, k, R, t, sun_dir=sun, earth=e))
        g = img.mean(axis=2)
        vals[name] = (g[vc - 1:vc + 2, u_sh - 1:u_sh + 2].mean(), g[vc - 1:vc + 2, u_lit - 1:u_lit + 2].mean())
    q = "shadowed/lit radiance (Earth | none)"
    ROWS.append(("shadow_with_earth", q, f"{vals['Earth'][0] / vals['Earth'][1]:.4f}",
                 f"{vals['no Earth'][0] / vals['no Earth'][1]:.4f}", "shadow kept (Earth adds bounce)"))
    print(f"{ROWS[-1][0]:<24} {q:<36} {ROWS[-1][2]:>32} {ROWS[-1][3]:>32} {ROWS[-1][4]:>28}")
    row("shadow_with_earth", "lit plate (+ occluder bounce)", vals["Earth"][1], 0.5 * E_SUN * 0.5 / math.pi)


def timing(run, tmp, repeats=1):
    sphere_ply(os.path.join(tmp, "bus.ply"), 1.0, [0, 0, 0], 5)
    v = np.array([[1.2, -0.5, -0.02], [4.2, -0.5, -0.02], [4.2, 0.5, -0.02], [1.2, 0.5, -0.02],
                  [1.2, -0.5, 0.02], [4.2, -0.5, 0.02], [4.2, 0.5, 0.02], [1.2, 0.5, 0.02]]) * 1000
    box = trimesh.creation.box(bounds=[v.min(0), v.max(0)])
    box.export(os.path.join(tmp, "panel.obj"))
    W, H, f = 1280, 960, 4.0e-3 / 3.45e-6
    R, t = look_at([2.0, -7.0, 3.0], [1.0, 0, 0], [0, 0, 1])
    sc = scene([{"path": "bus.ply", "unit_scale_m": 1.0, "albedo": [0.6, 0.6, 0.6]},
                {"path": "panel.obj", "unit_scale_m": 0.001, "albedo": [0.2, 0.2, 0.25]}],
               W, H, K(f, (W - 1) / 2, (H - 1) / 2), R, t, sun_dir=[0.5, -0.6, 0.62], ambient=5.0,
               earth={"earth_dir_body": [0.0, 0.3, -1.0], "earth_distance_m": D_EARTH, "radius_m": R_EARTH,
                      "albedo": 0.3})
    print(f"\ntiming: 1280x960, sphere bus + box panel + Earth + ambient, threads={run.threads}")
    times = {}
    for _ in range(repeats):
        for spp in (1, 16, 64, 256):
            _, info = run(f"timing_{spp}", sc, spp=spp)
            print(json.dumps(info), flush=True)
            times.setdefault(spp, []).append(info["render_s"])
    for spp, ts in times.items():
        print(f"spp {spp:>4}: render_s median {np.median(ts):.3f} (min {min(ts):.3f}, max {max(ts):.3f}, n={len(ts)})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--keep", help="keep scenes and EXRs in this folder (default: a temp dir)")
    ap.add_argument("--timing", action="store_true")
    ap.add_argument("--repeats", type=int, default=1, help="timing repeats")
    ap.add_argument("--only", nargs="*", default=["plate", "sphere", "projection", "earth"])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = a.keep or tmp
        os.makedirs(tmp, exist_ok=True)
        run = Runner(tmp, a.spp, a.threads)
        print(f"{'test':<24} {'quantity':<36} {'Cycles':>32} {'analytic':>32} {'rel. error':>28}")
        factors = plate_tests(run, tmp) if "plate" in a.only else {}
        if "plate" in a.only:
            cube_test(run, tmp)
        if "sphere" in a.only:
            sphere_tests(run, tmp)
        if "projection" in a.only:
            projection_tests(run, tmp)
        if "earth" in a.only:
            earth_tests(run, tmp)
            shadow_test(run, tmp)
        if factors:
            print("\nunit factor Cycles/analytic: " + ", ".join(f"{k}: {v:.6f}" for k, v in factors.items()))
        if a.timing:
            timing(run, tmp, a.repeats)


if __name__ == "__main__":
    main()
