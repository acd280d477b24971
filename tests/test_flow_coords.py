"""The ``coords`` and ``flow`` modalities (raytrace.correspondence): body points of the hits against
a brute-force Möller–Trumbore ray caster in numpy (no Embree), reprojection onto the pixel
centres, the flow against the next frame's own coordinates (the sub-pixel position of the point
from an OpenCV homography of its triangle's plane to the image), and the validity against the same
brute-force caster (hidden by the target, leaving the image); then a small sequence written by
the command line, read back with OpenImageIO."""

import json

import numpy as np
import OpenImageIO as oiio
import pytest
import trimesh

import cli
from raytrace import correspondence
from raytrace.camera import Camera
from raytrace.correspondence import (
    FrameHits,
    coords_image,
    flow_image,
    pixel_hits,
    seen_from,
)
from raytrace.dataset import folder
from raytrace.model import Component, TargetModel
from raytrace.scene import Scene
from tests.cli_helpers import run_main


# ------------------------------------------------------------------ independent helpers
def nearest_hits(V, F, O, D, eps=1e-12):
    """Brute-force closest hit of each ray O + t·D over every triangle (Möller & Trumbore, "Fast,
    minimum storage ray-triangle intersection", J. Graphics Tools 2(1), 1997): (t, face), t = inf
    and face −1 on a miss."""
    V, F = np.asarray(V, float), np.asarray(F, int)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    t_best = np.full(len(O), np.inf)
    f_best = np.full(len(O), -1)
    for lo in range(0, len(O), 64):
        o, d = O[lo:lo + 64, None, :], D[lo:lo + 64, None, :]
        p = np.cross(d, e2)
        det = np.sum(e1 * p, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = o - a
            u = np.sum(s * p, axis=-1) * inv
            q = np.cross(s, e1)
            v = np.sum(d * q, axis=-1) * inv
            t = np.sum(e2 * q, axis=-1) * inv
            ok = (np.abs(det) > eps) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        t = np.where(ok, t, np.inf)
        k = np.argmin(t, axis=1)
        t_best[lo:lo + 64] = t[np.arange(len(k)), k]
        f_best[lo:lo + 64] = np.where(np.isfinite(t_best[lo:lo + 64]), k, -1)
    return t_best, f_best


def looking(cam_pos, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)):
    """R_cam_from_body, t_cam_m of an OpenCV camera at ``cam_pos`` looking at ``target`` (image up ≈ ``up``)."""
    c, g = np.asarray(cam_pos, float), np.asarray(target, float)
    z = (g - c) / np.linalg.norm(g - c)
    y = -(np.asarray(up, float) - np.dot(up, z) * z)
    y /= np.linalg.norm(y)
    R = np.array([np.cross(y, z), y, z])
    return R, -R @ c


def pixel_rays_body(cam, R, t, rows, cols):
    """Origins and directions (body frame) of the pixels' rays, from the pinhole formula."""
    d_cam = np.column_stack([(cols - cam.cx) / cam.fx, (rows - cam.cy) / cam.fy, np.ones(len(rows))])
    return np.broadcast_to(-R.T @ t, d_cam.shape), d_cam @ R


def subpixel_position(coords, face_next, p, face, uv_guess):
    """Where the body point ``p`` (on triangle ``face``) lies in an image of body coordinates:
    the 2×2 pixel centres around ``uv_guess`` must all show ``face``; within one triangle the
    map from its plane to the image is a homography, fitted exactly to those four centres by
    OpenCV (cv2.findHomography) and applied to p; None when the cell leaves the image or the
    triangle."""
    import cv2
    H, W = face_next.shape
    u0, v0 = int(np.floor(uv_guess[0])), int(np.floor(uv_guess[1]))
    if not (0 <= u0 < W - 1 and 0 <= v0 < H - 1) or np.any(face_next[v0:v0 + 2, u0:u0 + 2] != face):
        return None
    P = coords[v0:v0 + 2, u0:u0 + 2].reshape(4, 3).astype(np.float64)
    e1 = P[1] - P[0]
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(np.cross(e1, P[2] - P[0]), e1)
    e2 /= np.linalg.norm(e2)
    plane = np.column_stack([(P - P[0]) @ e1, (P - P[0]) @ e2])
    pix = np.array([[u0, v0], [u0 + 1, v0], [u0, v0 + 1], [u0 + 1, v0 + 1]], dtype=np.float64)
    Hm, _ = cv2.findHomography(plane, pix, 0)
    q = np.array([(p - P[0]) @ e1, (p - P[0]) @ e2, 1.0])
    uvw = Hm @ q
    return uvw[:2] / uvw[2]


# ------------------------------------------------------------------ a two-box target
CAM = Camera(width=120, height=90, fx=95.0, fy=95.0, cx=59.5, cy=44.5)


@pytest.fixture(scope="module")
def two_boxes():
    big = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    small = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    small.apply_translation((0.2, 0.1, 1.7))  # floats 0.4 m above the big box's top face
    model = TargetModel("boxes", (Component("big", big, "white_paint", "bus", 1.0),
                                  Component("small", small, "white_paint", "bus", 1.0)))
    return Scene(model)


# the producers work in batches of correspondence._CHUNK pixels (row bands for the rays): 97 makes
# one image row per band and ~20 batches here
BATCHES = pytest.mark.parametrize("chunk", [correspondence._CHUNK, 97], ids=["one batch", "batches of 97"])


@BATCHES
def test_coords_are_the_pixel_rays_exact_hits_on_their_triangles(two_boxes, chunk, monkeypatch):
    monkeypatch.setattr(correspondence, "_CHUNK", chunk)
    scene = two_boxes
    R, t = looking((4.0, -2.5, 3.0))
    geo = scene.render_geometry(CAM, R, t)
    hits = pixel_hits(scene.vertices, scene.faces, CAM, R, t, geo.face_index)
    assert hits.face.size > 1500
    in_rect = pixel_hits(scene.vertices, scene.faces, CAM, R, t, geo.face_index, rect=geo.cast_rect)
    assert geo.cast_rect != (0, 0, CAM.width, CAM.height)
    assert all(np.array_equal(getattr(hits, k), getattr(in_rect, k)) for k in ("rows", "cols", "face", "p_body_m"))
    # a brute-force caster, independent of Embree and of the plane intersection
    O, D = pixel_rays_body(CAM, R, t, hits.rows.astype(float), hits.cols.astype(float))
    t_ref, f_ref = nearest_hits(scene.vertices, scene.faces, O, D)
    p_ref = O + t_ref[:, None] * D
    # ties on shared edges may pick either triangle: the point is the same
    err = np.linalg.norm(hits.p_body_m - p_ref, axis=1)
    assert np.mean(hits.face == f_ref) > 0.99
    assert err.max() < 1e-12 * 10  # [m], float64 round-off at a 5 m range
    assert np.allclose(hits.depth_m, t_ref, rtol=0, atol=1e-12)
    # reprojected with the same pose they land on the pixel centres; the file's float32 too
    uv = CAM.project(hits.p_body_m @ R.T + t)
    assert np.abs(uv - np.column_stack([hits.cols, hits.rows])).max() < 1e-9
    img = coords_image(hits)
    assert img.dtype == np.float32 and np.all(img[geo.face_index < 0] == 0)
    uv32 = CAM.project(img[hits.rows, hits.cols].astype(np.float64) @ R.T + t)
    assert np.abs(uv32 - np.column_stack([hits.cols, hits.rows])).max() < 1e-3
    # the float32 depth's z·d_cam: off along the ray by up to z·2⁻²⁴·|d|, the plane's by round-off
    d_cam = CAM.ray_directions_cam()[hits.rows * CAM.width + hits.cols]
    p_depth = (geo.depth_m[hits.rows, hits.cols].astype(np.float64)[:, None] * d_cam - t) @ R
    e_depth = np.linalg.norm(p_depth - p_ref, axis=1)
    bound = hits.depth_m * 2.0**-24 * np.linalg.norm(d_cam, axis=1)
    assert np.all(e_depth <= bound * 1.01) and e_depth.max() > 100 * err.max()


@BATCHES
def test_flow_lands_where_the_next_frame_sees_the_point_and_validity_is_the_exact_visibility(two_boxes, chunk,
                                                                                            monkeypatch):
    monkeypatch.setattr(correspondence, "_CHUNK", chunk)
    scene = two_boxes
    R0, t0 = looking((4.0, -2.5, 3.0))
    # the next frame from above, nearer and aside: the small box hides part of the top face,
    # and part of the big box leaves the image
    R1, t1 = looking((0.9, 0.3, 3.0), target=(1.2, 0.2, 0.0), up=(0.0, 1.0, 0.0))
    geo0 = scene.render_geometry(CAM, R0, t0)
    geo1 = scene.render_geometry(CAM, R1, t1)
    hits0 = FrameHits(scene, CAM, R0, t0, geo0, (R1.ravel().tolist(), t1.tolist())).hits
    flow = flow_image(scene, CAM, hits0, (R1, t1))
    assert flow.dtype == np.float32 and np.all(flow[geo0.face_index < 0] == 0)
    f = flow[hits0.rows, hits0.cols].astype(np.float64)
    valid = f[:, 2] == 1.0
    assert set(np.unique(f[:, 2])) <= {0.0, 1.0}
    uv1 = np.column_stack([hits0.cols, hits0.rows]) + f[:, :2]
    W, H = CAM.width, CAM.height
    in_image = (uv1[:, 0] >= -0.5) & (uv1[:, 0] < W - 0.5) & (uv1[:, 1] >= -0.5) & (uv1[:, 1] < H - 0.5)
    # visibility from the next optical centre by brute force: the first hit on the segment
    # from the centre to the point is the point
    c1 = -R1.T @ t1
    p = hits0.p_body_m
    t_hit, _ = nearest_hits(scene.vertices, scene.faces, np.broadcast_to(c1, p.shape), p - c1)
    seen = t_hit > 1.0 - 1e-6
    hidden = in_image & ~seen
    leaving = ~in_image
    assert leaving.sum() > 300 and (in_image & seen).sum() > 300
    # hidden: the big box's far sides, and the top face (facing the next camera) under the small box
    top = np.abs(p[:, 2] - 1.0) < 1e-9
    assert hidden.sum() > 300 and (hidden & top).sum() > 50
    assert np.array_equal(valid, in_image & seen)
    # the warp: each valid pixel's landing point is where frame t+1's own coordinates show its point
    coords1 = coords_image(pixel_hits(scene.vertices, scene.faces, CAM, R1, t1, geo1.face_index))
    errs = []
    for k in np.flatnonzero(valid):
        uv = subpixel_position(coords1, geo1.face_index, p[k], hits0.face[k], uv1[k])
        if uv is not None:
            errs.append(np.abs(uv - uv1[k]).max())
    assert len(errs) > 200 and max(errs) < 1e-4  # measured 4e-6 px: the float32 coordinates


def test_the_last_frame_has_no_flow_and_bad_input_is_refused(two_boxes):
    scene = two_boxes
    R, t = looking((4.0, -2.5, 3.0))
    geo = scene.render_geometry(CAM, R, t)
    last = FrameHits(scene, CAM, R, t, geo, None)
    assert not last.flow().any()
    assert np.array_equal(last.coords(), coords_image(last.hits))
    with pytest.raises(ValueError, match="face_index must have the camera's shape"):
        pixel_hits(scene.vertices, scene.faces, CAM, R, t, geo.face_index[:-1])
    with pytest.raises(ValueError, match="camera must be"):
        pixel_hits(scene.vertices, scene.faces, (120, 90), R, t, geo.face_index)


def test_visibility_from_a_centre_inside_the_targets_hull():
    # two boxes 6 m apart and the camera between them: the segment test must stop at the centre
    # (the box behind it is on the same line); every point of the boxes, by brute force
    a, b = trimesh.creation.box(extents=(1.0, 1.0, 1.0)), trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    a.apply_translation((3.0, 0.0, 0.0))
    b.apply_translation((-3.0, 0.2, 0.1))
    scene = Scene(TargetModel("pair", (Component("a", a, "white_paint", "bus", 1.0),
                                       Component("b", b, "white_paint", "bus", 1.0))))
    rng = np.random.default_rng(3)
    face = rng.integers(0, len(scene.faces), 400)
    w = rng.dirichlet((1.0, 1.0, 1.0), 400)
    p = np.einsum("ij,ijk->ik", w, scene.vertices[scene.faces[face]])
    c = np.array([0.1, 0.05, 0.02])
    seen = seen_from(scene, p, face, c)
    t_hit, _ = nearest_hits(scene.vertices, scene.faces, np.broadcast_to(c, p.shape), p - c)
    # one face of each box faces the centre: about a sixth of the points are seen, on both boxes
    assert np.array_equal(seen, t_hit > 1.0 - 1e-9) and 40 < seen.sum() < 100
    assert seen[p[:, 0] > 0].any() and seen[p[:, 0] < 0].any()


def test_every_hit_is_seen_from_its_own_camera():
    # flow to the frame's own pose: zero motion, and every pixel valid — also where Cassini's thin
    # booms and antennas pass within a fraction of a millimetre of a pixel's ray (a segment from
    # the hit offset sideways, by ray_eps_m off its triangle, would call ~7 of 16 k hidden)
    from raytrace.dataset import scenes
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "cassini", "--frames", "4"]))
    task = folder.tasks_for(cli.plan_sequence(cfg, given), "", None, write=False)[0][1]
    scene, camera = scenes.scene(task["model_spec"]), Camera(*task["camera"])
    R, t = np.reshape(task["R_cam_from_body"], (3, 3)), np.asarray(task["t_cam_m"])
    hits = FrameHits(scene, camera, R, t, scene.render_geometry(camera, R, t), (R, t))
    f = hits.flow()[hits.hits.rows, hits.hits.cols]
    assert hits.hits.face.size > 10_000 and np.all(f[:, 2] == 1.0) and np.abs(f[:, :2]).max() < 1e-9


def test_each_frame_task_carries_the_next_planned_frames_pose():
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--target", "icesat", "--frames", "4"]))
    plan = cli.plan_sequence(cfg, given)
    frames = plan["result"]["frames"]
    tasks, _ = folder.tasks_for(plan, "", None, write=False, frames=[0, 2, 3])  # frame 1 not written
    assert [t["frame"] for t in tasks] == [0, 2, 3]
    assert tasks[0]["next_pose"] == (frames[1]["R_cam_from_body"], frames[1]["t_cam_m"])
    assert tasks[1]["next_pose"] == (frames[3]["R_cam_from_body"], frames[3]["t_cam_m"])
    assert tasks[2]["next_pose"] is None


# ------------------------------------------------------------------ the command line
def read_exr(path):
    img = oiio.ImageInput.open(str(path))
    assert img is not None, oiio.geterror()
    try:
        assert img.spec().format == oiio.FLOAT and img.spec().nchannels == 3
        return img.read_image(format=oiio.FLOAT)
    finally:
        img.close()


def test_a_sequence_writes_coords_and_flow_that_agree_with_the_model_and_poses(tmp_path, capsys):
    seq = tmp_path / "seq"
    assert run_main("--target", "icesat", "--pattern", "spiral", "--frames", "5", "--width", "96", "--height", "72",
                    "--focal-length-mm", "1.5", "--modalities", "mask,depth,coords,flow", "--quiet", "--workers", "1",
                    "--out", seq) == 0
    labels = json.loads((seq / "labels.json").read_text())
    cam = json.loads((seq / "camera.json").read_text())
    camera = Camera(cam["width"], cam["height"], cam["fx"], cam["fy"], cam["cx"], cam["cy"])
    mesh = trimesh.load(seq / "model" / "icesat.ply", process=False)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    poses = [(np.reshape(lab["R_cam_from_body"], (3, 3)), np.asarray(lab["t_cam_m"])) for lab in labels]
    rng = np.random.default_rng(1)
    all_coords = [read_exr(seq / lab["files"]["coords"]) for lab in labels]
    for k, lab in enumerate(labels):
        assert set(lab["files"]) == {"mask", "depth", "coords", "flow"}
        coords, flow = all_coords[k], read_exr(seq / lab["files"]["flow"])
        mask = oiio.ImageBuf(str(seq / lab["files"]["mask"])).get_pixels(oiio.UINT16)[..., 0]
        R, t = poses[k]
        rows, cols = np.nonzero(mask)
        assert rows.size > 100 and not coords[mask == 0].any() and not flow[mask == 0].any()
        # on the pixel centres, reprojected with the frame's pose
        uv = camera.project(coords[rows, cols].astype(np.float64) @ R.T + t)
        assert np.abs(uv - np.column_stack([cols, rows])).max() < 1e-3
        # the model's triangles, cast by brute force at sampled pixels
        pick = rng.choice(rows.size, 40, replace=False)
        O, D = pixel_rays_body(camera, R, t, rows[pick].astype(float), cols[pick].astype(float))
        t_ref, _ = nearest_hits(V, F, O, D)
        assert np.abs(coords[rows[pick], cols[pick]] - (O + t_ref[:, None] * D)).max() < 1e-5
        if k == len(labels) - 1:
            assert not flow.any()  # no next frame
            continue
        valid = flow[rows, cols, 2] == 1.0
        assert valid.sum() > 500
        R1, t1 = poses[k + 1]
        p = coords[rows, cols].astype(np.float64)
        uv1 = np.column_stack([cols, rows]) + flow[rows, cols, :2]
        assert np.abs(uv1[valid] - camera.project(p[valid] @ R1.T + t1)).max() < 1e-3
        # the warp: where the next frame's file shows the point (triangles found by brute force)
        errs = []
        for j in rng.choice(np.flatnonzero(valid), 40, replace=False):
            u0, v0 = np.floor(uv1[j]).astype(int)
            cell_r, cell_c = np.array([v0, v0, v0 + 1, v0 + 1]), np.array([u0, u0 + 1, u0, u0 + 1])
            if u0 < 0 or v0 < 0 or u0 + 1 >= camera.width or v0 + 1 >= camera.height:
                continue
            O, D = pixel_rays_body(camera, R1, t1, cell_r.astype(float), cell_c.astype(float))
            face_next = np.full((camera.height, camera.width), -1)
            face_next[cell_r, cell_c] = nearest_hits(V, F, O, D)[1]
            O, D = pixel_rays_body(camera, R, t, rows[j:j + 1].astype(float), cols[j:j + 1].astype(float))
            uv = subpixel_position(all_coords[k + 1], face_next, p[j], nearest_hits(V, F, O, D)[1][0], uv1[j])
            if uv is not None:
                errs.append(np.abs(uv - uv1[j]).max())
        assert len(errs) >= 10 and max(errs) < 1e-4  # measured 2.4e-6 px
        # validity at sampled pixels, by brute force from the next optical centre
        c1 = -R1.T @ t1
        pick = rng.choice(rows.size, 60, replace=False)
        t_hit, _ = nearest_hits(V, F, np.broadcast_to(c1, (60, 3)), p[pick] - c1)
        W, H = camera.width, camera.height
        inside = (uv1[pick, 0] >= -0.5) & (uv1[pick, 0] < W - 0.5) & (uv1[pick, 1] >= -0.5) & (uv1[pick, 1] < H - 0.5)
        # seen: the first hit is the point itself (to the float32 file's rounding); hidden: well before it
        seen, hidden = t_hit > 1.0 - 1e-6, t_hit < 1.0 - 1e-4
        assert np.all(valid[pick][inside & seen]) and not np.any(valid[pick][~inside | hidden])
        assert np.count_nonzero(seen | hidden) >= 55


def test_coords_through_a_lens_land_on_their_pixel_centres_by_opencvs_projection(two_boxes):
    """With lens distortion, each pixel's body point is where that pixel's distorted ray meets the
    target: OpenCV's own projection (cv2.projectPoints, Brown–Conrady in its order) of the points
    lands on the pixel centres, and the same points lie on the hit triangles' planes."""
    import cv2
    dist = (-0.25, 0.08, 1.5e-3, -1e-3, 0.0)
    cam = Camera(width=120, height=90, fx=95.0, fy=95.0, cx=59.5, cy=44.5, dist_coeffs=dist)
    scene = two_boxes
    R, t = looking((4.0, -2.5, 3.0))
    geo = scene.render_geometry(cam, R, t)
    hits = pixel_hits(scene.vertices, scene.faces, cam, R, t, geo.face_index)
    assert hits.face.size > 1500
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(hits.p_body_m, rvec, np.asarray(t, float), cam.K, np.asarray(dist))
    assert np.abs(uv.reshape(-1, 2) - np.column_stack([hits.cols, hits.rows])).max() < 1e-6
    # on the plane of the triangle hit
    V, F = scene.vertices.astype(np.float64), scene.faces
    a, b, c = V[F[hits.face, 0]], V[F[hits.face, 1]], V[F[hits.face, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    assert np.abs(np.einsum("ij,ij->i", hits.p_body_m - a, n)).max() < 1e-9
    # the distortion moved them: a pinhole camera's points differ
    pin = pixel_hits(scene.vertices, scene.faces, CAM, R, t, scene.render_geometry(CAM, R, t).face_index)
    assert pin.face.size != hits.face.size or not np.allclose(pin.p_body_m, hits.p_body_m)
