"""Brown–Conrady lens distortion (raytrace.camera, raytrace._lens): the undistortion against
OpenCV's and against the forward model, the rays of every kernel through it, and the images
against OpenCV's projection of the mesh (mask) and a trimesh ray cast (depth)."""

import dataclasses
import math

import cv2
import numpy as np
import pytest
import trimesh

from orbit.pose import look_at
from raytrace import _edges
from raytrace.camera import Camera, distort_normalised
from raytrace.lighting import Lighting
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from raytrace.shade import render
from raytrace.targets import load_target

DIST = (-0.2, 0.05, 1e-3, -1e-3, 0.0)  # OpenCV order k1, k2, p1, p2, k3
W, H = 320, 240
F = 300.0  # 56° × 44° field: the corners at r ≈ 0.67, where the distortion moves them ~40 px


def _cam(dist=DIST, **kw):
    return Camera(**{"width": W, "height": H, "fx": F, "fy": F * 1.01, "cx": (W - 1) / 2 + 1.3,
                     "cy": (H - 1) / 2 - 0.7, "dist_coeffs": dist, **kw})


@pytest.fixture(scope="module")
def tiangong():
    model = load_target("tiangong")
    return Scene(model)


def _pose(scene, dist_in_radii, direction=(2.2, 1.5, 1.0), yaw_deg=0.0):
    """Camera looking at the target from ``dist_in_radii`` bounding radii, then turned by
    ``yaw_deg`` about its y axis (the target off-centre)."""
    d = np.asarray(direction, float)
    pos = d / np.linalg.norm(d) * dist_in_radii * scene.model.bounding_radius_m
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    R = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]) @ look_at(pos, up_ref_lvlh=(0.0, 0.0, 1.0))
    return R, -R @ pos


def _first_hit_z(o, d, V, F):
    """Brute-force Möller–Trumbore (NumPy, float64) over every triangle: the camera-frame ray
    parameter of each ray's nearest hit (d unnormalised with z = 1: the z-depth), inf on a miss."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    out = np.full(len(d), np.inf)
    for i, di in enumerate(d):
        p = np.cross(di, e2)
        det = np.einsum("fk,fk->f", e1, p)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        sv = o - a
        u = np.einsum("fk,fk->f", sv, p) * inv
        q = np.cross(sv, e1)
        v = (q @ di) * inv
        tt = np.einsum("fk,fk->f", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (tt > 0)
        if hit.any():
            out[i] = tt[hit].min()
    return out


def _grid_uv(cam, border=0.5):
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(float)
    uv = np.column_stack([u.ravel(), v.ravel()])
    corners = np.array([[-border, -border], [cam.width - 1 + border, -border], [-border, cam.height - 1 + border],
                        [cam.width - 1 + border, cam.height - 1 + border]])
    return np.vstack([uv, corners])


def _cv2_undistort_px(cam, uv):
    """OpenCV's iterative undistortion of pixel points, back to pixels of the ideal camera (P = K)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    return cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, np.array(cam.dist_coeffs), R=None, P=cam.K,
                               criteria=crit).reshape(-1, 2)


def test_undistort_inverts_opencvs_projection_and_agrees_with_its_undistortion():
    cam = _cam()
    uv = _grid_uv(cam)
    xy = cam.undistort(uv)
    assert np.isfinite(xy).all()
    # forward through OpenCV's own projection: back on the pixel to 1e-9 px
    p = np.column_stack([xy, np.ones(len(xy))])
    back, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist_coeffs))
    assert np.abs(back.reshape(-1, 2) - uv).max() <= 1e-9
    # the residual in normalised units, through the model's formula (docstring: ≤ 1e-15)
    xd, yd = distort_normalised(xy[:, 0], xy[:, 1], cam.dist_coeffs)
    assert max(np.abs(xd - (uv[:, 0] - cam.cx) / cam.fx).max(), np.abs(yd - (uv[:, 1] - cam.cy) / cam.fy).max()) < 1e-12
    # OpenCV's undistortion of the distorted pixel centres (P = K): the same ideal pixels
    ideal = xy * [cam.fx, cam.fy] + [cam.cx, cam.cy]
    assert np.abs(_cv2_undistort_px(cam, uv) - ideal).max() <= 0.01
    # and ours projects the same as OpenCV's projectPoints (a camera-frame point cloud)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-3, 3, (500, 2)), rng.uniform(4.5, 9.0, 500)])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist_coeffs))
    assert np.abs(cam.project(pts) - ref.reshape(-1, 2)).max() <= 1e-9


def test_the_cached_table_and_the_sub_pixel_rays_are_the_exact_inverse():
    """Pixel centres: the camera's table; sub-pixel positions (a kernel's jittered samples): the
    Newton step in the kernel. Both project back (OpenCV) onto their image point to 1e-9 px; the
    sub-pixel pattern is the pinhole's, moved by the lens only."""
    cam = _cam()
    pin = dataclasses.replace(cam, dist_coeffs=(0.0,) * 5)
    lens, table = cam.lens_arrays()
    assert table.shape == (H + 4, W + 4, 2) and lens.shape == (9,)
    assert cam.lens_arrays()[1] is table  # cached
    assert pin.lens_arrays()[0].size == 0 and pin.lens_arrays()[1].size == 0  # a pinhole has none
    v, u = np.mgrid[-2:H + 2, -2:W + 2].astype(float)
    t = table.reshape(-1, 2)
    p, _ = cv2.projectPoints(np.column_stack([t, np.ones(len(t))]), np.zeros(3), np.zeros(3), cam.K,
                             np.array(cam.dist_coeffs))
    assert np.abs(p.reshape(-1, 2) - np.column_stack([u.ravel(), v.ravel()])).max() <= 1e-9
    np.testing.assert_array_equal(cam.ray_directions_cam(), np.column_stack([table[2:-2, 2:-2].reshape(-1, 2),
                                                                             np.ones(W * H)]))

    pix = np.array([0, W - 1, (H - 1) * W, H * W - 1, 5 * W + 7, 100 * W + 200], dtype=np.int64)
    n = 4
    d_pin = np.empty((len(pix) * n * n, 3))
    d = np.empty_like(d_pin)
    _edges.subpixel_rays(pix, W, n, 7, np.eye(3), pin.fx, pin.fy, pin.cx, pin.cy, *pin.lens_arrays(), d_pin)
    _edges.subpixel_rays(pix, W, n, 7, np.eye(3), cam.fx, cam.fy, cam.cx, cam.cy, lens, table, d)
    want = d_pin[:, :2] * [pin.fx, pin.fy] + [pin.cx, pin.cy]  # the pinhole's sample points [px]
    got, _ = cv2.projectPoints(d, np.zeros(3), np.zeros(3), cam.K, np.array(cam.dist_coeffs))
    assert np.abs(got.reshape(-1, 2) - want).max() <= 1e-9
    assert np.abs(want - np.repeat(np.column_stack([pix % W, pix // W]), n * n, axis=0)).max() < 0.5


@pytest.mark.parametrize("dist, what", [
    ((float("nan"), 0, 0, 0, 0), "5 finite numbers"),
    ((0.1, 0, 0, 0), "5 finite numbers"),
    ("12345", "5 finite numbers"),
    ((-0.6, 0.0, 0.0, 0.0, 0.0), "fold the image"),  # r(1 − 0.6 r²) turns at r = 0.745 < the corners' 0.80
    ((0.0, 0.0, 0.9, 0.9, 0.0), "not invertible"),
])
def test_bad_coefficients_are_refused_naming_dist_coeffs(dist, what):
    with pytest.raises(ValueError, match=f"dist_coeffs.*{what}"):
        _cam(dist=dist)


def test_mask_equals_opencvs_projection_of_every_triangle(tiangong):
    """The silhouette against OpenCV: cv2.projectPoints of every triangle's edges (32 points an
    edge, so they bend with the distortion), filled with cv2.fillPoly on a 16× finer grid and
    read at the pixel centres. Measured IoU 0.9952 (the pinhole the same way: 0.9962; what
    differs are pixel centres within 1/16 px of an edge, which fillPoly's edge rule takes)."""
    cam = _cam()
    R, t = _pose(tiangong, 1.6, yaw_deg=14.0)
    g = tiangong.render_geometry(cam, R, t)
    V, Fc = tiangong.vertices, tiangong.faces
    n, S = 32, 16
    s = np.linspace(0.0, 1.0, n, endpoint=False)[None, :, None]
    tri = V[Fc]
    poly = np.concatenate([tri[:, a, None] * (1 - s) + tri[:, b, None] * s for a, b in ((0, 1), (1, 2), (2, 0))], axis=1)
    z = (poly.reshape(-1, 3) @ R.T + t)[:, 2].reshape(len(Fc), -1)
    assert (z > 0).all()
    uv, _ = cv2.projectPoints(poly.reshape(-1, 3), cv2.Rodrigues(R)[0], t, cam.K, np.array(cam.dist_coeffs))
    pts = np.round((uv.reshape(len(Fc), -1, 2) * S + S // 2) * 16).astype(np.int32)  # 4 fractional bits
    fine = np.zeros((H * S, W * S), np.uint8)
    for q in pts:  # one at a time: fillPoly's several contours would fill by the even-odd rule
        cv2.fillPoly(fine, [q], 1, shift=4)
    ref = fine[S // 2::S, S // 2::S] > 0
    ours = g.instance > 0
    assert ref.sum() > 5000 and 0.2 < g.visible_fraction < 0.99  # large, and crossing the border
    assert (ref & ours).sum() / (ref | ours).sum() >= 0.995


def test_depth_equals_an_independent_ray_cast_along_opencvs_undistorted_ray(tiangong):
    cam = _cam()
    R, t = _pose(tiangong, 1.3)
    g = tiangong.render_geometry(cam, R, t, ray_distance=True)
    rows, cols = np.nonzero(g.instance)
    pick = np.random.default_rng(3).choice(len(rows), 200, replace=False)
    uv = np.column_stack([cols[pick], rows[pick]]).astype(float)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, np.array(cam.dist_coeffs), criteria=crit).reshape(-1, 2)
    d_cam = np.column_stack([xy, np.ones(len(xy))])
    # in the camera frame: rays from the origin through (x, y, 1), the mesh moved there
    z = _first_hit_z(np.zeros(3), d_cam, tiangong.vertices @ R.T + t, tiangong.faces)
    depth = g.depth_m[rows[pick], cols[pick]].astype(float)
    assert np.isfinite(z).all()
    np.testing.assert_allclose(depth, z, rtol=2e-6)
    np.testing.assert_allclose(g.ray_distance_m[rows[pick], cols[pick]], z * np.linalg.norm(d_cam, axis=1),
                               rtol=2e-6)


def test_a_lens_that_moves_nothing_renders_the_pinholes_geometry_bytes(tiangong):
    """k1 = 1e-30 changes no float64 coordinate: the lens's whole path (table, Newton, no culling
    polytopes, the fraction on the undistorted grid) must give the pinhole's images bit for bit."""
    pin = _cam(dist=(0.0,) * 5)
    cam = _cam(dist=(1e-30, 0.0, 0.0, 0.0, 0.0))
    assert cam.distorted
    for radii, yaw, inside in ((2.5, 0.0, True), (1.6, 14.0, False)):
        R, t = _pose(tiangong, radii, yaw_deg=yaw)
        a = tiangong.render_geometry(pin, R, t, ray_distance=True, geometric_normal=True)
        b = tiangong.render_geometry(cam, R, t, ray_distance=True, geometric_normal=True)
        for k in ("depth_m", "normal_cam", "normal_geom_cam", "instance", "face_index", "ray_distance_m"):
            assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
        if inside:
            assert a.visible_fraction == b.visible_fraction == 1.0
        else:  # both count the silhouette on the same pixel grid (each subsampled its own way)
            assert 0.2 < a.visible_fraction < 0.99
            assert b.visible_fraction == pytest.approx(a.visible_fraction, abs=0.01)


@pytest.fixture(scope="module")
def ball():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    return Scene(TargetModel("ball", (Component("ball", sphere, "white_paint", "bus", 1.0),)))


@pytest.mark.parametrize("quality, samples, tol", [("fast", None, 1e-3), ("balanced", 8, 1e-3),
                                                    ("reference", 16, 5e-3)])
def test_each_preset_renders_the_pinhole_image_seen_through_the_lens(ball, quality, samples, tol):
    """Shading through the lens against OpenCV's remap of the pinhole frame: every distorted
    pixel centre looks up the pinhole image where cv2.undistortPoints sends it. A smooth sphere
    near the image corner, where the distortion moves pixels by 3–20 px: inside its silhouette
    (away from the edge, where the lookup blends in the background) the two agree (measured
    median relative difference 2e-5 for ``fast`` and ``balanced``, 9e-4 for ``reference``'s
    noise; the unwarped pinhole frame: 1.4 %)."""
    cam = _cam()
    pin = dataclasses.replace(cam, dist_coeffs=(0.0,) * 5)
    R, t = np.eye(3), np.array([-1.25, -0.85, 3.2])  # centre towards the top-left corner
    light = Lighting(sun_dir_body=tuple(np.array([0.5, -0.6, -0.62]) / np.linalg.norm([0.5, -0.6, -0.62])))
    a = render(ball, pin, R, t, light, quality=quality, samples=samples, seed=1)
    b = render(ball, cam, R, t, light, quality=quality, samples=samples, seed=1)
    ideal = _cv2_undistort_px(cam, _grid_uv(cam)[:-4]).reshape(H, W, 2).astype(np.float32)
    core = cv2.erode((b.geometry.instance > 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    # (where the lens sees what lies outside the pinhole's image there is nothing to compare)
    core &= (ideal[..., 0] >= 2) & (ideal[..., 0] <= W - 3) & (ideal[..., 1] >= 2) & (ideal[..., 1] <= H - 3)
    shift = np.hypot(*(ideal - np.stack(np.meshgrid(np.arange(W), np.arange(H)), axis=-1))[core].T)
    assert core.sum() > 3000 and np.median(shift) > 3.0
    lum_b = b.radiance[core].sum(axis=1)
    errs = []
    for img in (cv2.remap(a.radiance, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR), a.radiance):
        errs.append(float(np.median(np.abs(lum_b - img[core].sum(axis=1))) / np.median(lum_b)))
    assert errs[0] < tol and errs[1] > 0.01, errs  # the lens's image, not the pinhole's
    # depth the same way
    dz = cv2.remap(a.geometry.depth_m, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR)[core]
    np.testing.assert_allclose(dz, b.geometry.depth_m[core], rtol=2e-3)


def test_visible_fraction_through_the_lens_against_opencv(tiangong):
    """The fraction of the silhouette in view, measured on the undistorted image plane: the
    target's triangles filled (cv2.fillPoly) on the pinhole grid of the same K over a canvas
    that holds all of it, each filled point's ray sent through cv2.projectPoints with the
    lens, in view where it lands in the image."""
    cam = _cam()
    R, t = _pose(tiangong, 1.6, yaw_deg=14.0)
    g = tiangong.render_geometry(cam, R, t)
    p = tiangong.vertices @ R.T + t
    uv = p[:, :2] / p[:, 2:] * [cam.fx, cam.fy] + [cam.cx, cam.cy]  # pinhole pixel coordinates
    lo = np.floor(uv.min(axis=0)).astype(int) - 2
    hi = np.ceil(uv.max(axis=0)).astype(int) + 2
    canvas = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    for q in np.round((uv[tiangong.faces] - lo) * 16).astype(np.int32):
        cv2.fillPoly(canvas, [q], 1, shift=4)
    rows, cols = np.nonzero(canvas)
    xy = (np.column_stack([cols, rows]) + lo - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    d, _ = cv2.projectPoints(np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3), cam.K,
                             np.array(cam.dist_coeffs))
    d = d.reshape(-1, 2)
    inside = (d[:, 0] >= -0.5) & (d[:, 0] < W - 0.5) & (d[:, 1] >= -0.5) & (d[:, 1] < H - 0.5)
    assert 0.3 < inside.mean() < 0.95
    assert g.visible_fraction == pytest.approx(inside.mean(), abs=0.02)
