"""A small rendered sequence folder with keypoints, for the SPEED+ and COCO export tests.

ICESat at 160×120, four rendered frames (one cut by the right image border, one with the target
wholly outside the image) and one frame record without files, written in the pipeline's contract
format (docs/formats.md) with the keypoint schema: ``model/keypoints.json`` and per frame
``keypoints_px`` / ``keypoints_state``. The keypoints are computed here independently of the
exporters: pixel positions with OpenCV's ``cv2.projectPoints`` (K, Rodrigues vector, t,
distortion), states from the render's depth at the nearest pixel. Keypoints kp00…kp10 are surface
points back-projected from frame 0's depth at pixel centres; kp11 lies 30 m in front of the
camera of frame 0 along its axis, i.e. behind the camera (null) in frame 0. "shadowed" is given
to every seen keypoint with an index ≡ 1 (mod 4): there is no Sun in this fixture, the state only
has to reach the exporters.
"""

import json

import cv2
import numpy as np
import OpenImageIO as oiio
from scipy.spatial.transform import Rotation

from raytrace.camera import Camera
from raytrace.scene import Scene
from raytrace.targets import load_target

W, H = 160, 120
CAMERA = Camera(width=W, height=H, fx=145.0, fy=145.0, cx=79.5, cy=59.5)
PITCH_M = 3.45e-6 * 1280 / W
POSES = {  # frame → (Euler ZYX [deg], t_cam_m)
    0: ((30.0, 20.0, 10.0), (0.0, 0.0, 12.0)),
    3: ((-120.0, 45.0, 60.0), (-0.5, 0.3, 9.0)),
    7: ((75.0, -10.0, 170.0), (4.5, 0.0, 12.0)),  # cut by the right border
    9: ((0.0, 0.0, 0.0), (40.0, 0.0, 12.0)),  # wholly outside the image: empty mask
}
N_SURFACE = 11


def write_image(path, pixels):
    out = oiio.ImageOutput.create(str(path))
    pixels = pixels if pixels.ndim == 3 else pixels[:, :, None]
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16, np.dtype(np.float32): oiio.FLOAT}
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2],
                                              fmt[pixels.dtype]))
    assert out.write_image(np.ascontiguousarray(pixels))
    out.close()


def quat_scalar_first(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def project_cv2(points_body_m, R, t, dist):
    """(N, 2) pixel positions by OpenCV, and the camera-frame z of each point."""
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(points_body_m.reshape(-1, 1, 3), rvec, np.asarray(t, float), CAMERA.K,
                              np.asarray(dist, float))
    return uv.reshape(-1, 2), points_body_m @ R[2] + t[2]


def keypoint_labels(points_body_m, R, t, depth_m, dist):
    """keypoints_px (list of [u, v] or None) and keypoints_state of one frame."""
    uv, z = project_cv2(points_body_m, R, np.asarray(t, float), dist)
    px, states = [], []
    for i, ((u, v), zi) in enumerate(zip(uv, z)):
        if zi <= 0:
            px.append(None)
            states.append("outside")
            continue
        px.append([float(u), float(v)])
        if not (-0.5 <= u < W - 0.5 and -0.5 <= v < H - 0.5):
            states.append("outside")
            continue
        d = depth_m[int(np.rint(v)), int(np.rint(u))]
        if zi <= d + 0.1:  # in front of the surface the pixel sees (inf: background)
            states.append("shadowed" if i % 4 == 1 else "visible")
        else:
            states.append("occluded")
    return px, states


def keypoints_from_frame0(R, t, depth_m):
    """kp00…kp10: body-frame surface points at 11 pixel centres of frame 0's target (interior of
    the mask), and kp11 behind frame 0's camera."""
    hit = np.isfinite(depth_m)
    inner = hit.copy()
    inner[1:-1, 1:-1] &= hit[:-2, 1:-1] & hit[2:, 1:-1] & hit[1:-1, :-2] & hit[1:-1, 2:]
    v, u = np.nonzero(inner)
    pick = np.random.default_rng(5).choice(u.size, N_SURFACE, replace=False)
    u, v = u[pick].astype(float), v[pick].astype(float)
    z = depth_m[v.astype(int), u.astype(int)].astype(np.float64)
    p_cam = np.column_stack([(u - CAMERA.cx) / CAMERA.fx * z, (v - CAMERA.cy) / CAMERA.fy * z, z])
    behind = np.array([[0.0, 0.0, -30.0]])  # camera frame of frame 0
    return (np.vstack([p_cam, behind]) - t) @ R  # R^T (p − t), row vectors


def make_sequence(root, scene=None):
    """Write the sequence folder; return ({frame: (R, t, GeometryFrame)}, keypoints_body_m, scene)."""
    scene = scene or Scene(load_target("icesat"))
    for sub in ("rgb", "rgb_degraded", "mask", "depth", "model"):
        (root / sub).mkdir(parents=True)
    scene.model.combined_mesh().export(root / "model" / "icesat.ply")
    comps = [{"id": k + 1, "name": c.name, "material": c.material, "semantic": c.semantic}
             for k, c in enumerate(scene.model.components)]
    (root / "scenario.json").write_text(json.dumps({
        "target": "icesat", "seed": 0, "target_model": {"file": "model/icesat.ply", "components": comps}}))
    K = CAMERA.K
    dist = [0.0] * 5
    (root / "camera.json").write_text(json.dumps({
        "K": K.tolist(), "width": W, "height": H, "cameraMatrix": K.tolist(), "distCoeffs": dist,
        "Nu": W, "Nv": H, "pixel_pitch_m": PITCH_M,
        "convention": "OpenCV: x right, y down, z forward; integer pixel coordinates are pixel centres"}))
    geometry = {}
    for frame, (euler, t) in POSES.items():
        R = Rotation.from_euler("ZYX", euler, degrees=True).as_matrix()
        geometry[frame] = (R, np.array(t), scene.render_geometry(CAMERA, R, t))
    R0, t0, g0 = geometry[0]
    kp_body = keypoints_from_frame0(R0, t0, g0.depth_m)
    names = [f"kp{i:02d}" for i in range(len(kp_body))]
    (root / "model" / "keypoints.json").write_text(json.dumps({
        "frame": "body", "unit": "m", "source": "test fixture: surface points seen in frame 0, one behind its camera",
        "names": names, "points_body_m": kp_body.tolist()}))
    labels = []
    for frame, (R, t, g) in geometry.items():
        name = f"{frame:06d}"
        shade = np.rint(255 * np.abs(g.normal_cam[:, :, 2])).astype(np.uint8)
        write_image(root / "rgb" / f"{name}.png", np.repeat(shade[:, :, None], 3, axis=2))
        write_image(root / "rgb_degraded" / f"{name}.png", np.repeat((shade // 2)[:, :, None], 3, axis=2))
        write_image(root / "mask" / f"{name}.png", g.instance.astype(np.uint16))
        write_image(root / "depth" / f"{name}.exr", g.depth_m.astype(np.float32))
        px, states = keypoint_labels(kp_body, R, t, g.depth_m, dist)
        labels.append({
            "frame": frame, "q_cam_from_body": quat_scalar_first(R).tolist(), "R_cam_from_body": R.ravel().tolist(),
            "t_cam_m": list(t), "bbox": g.bbox_xywh, "keypoints_px": px, "keypoints_state": states,
            "files": {m: f"{m}/{name}.{'exr' if m == 'depth' else 'png'}"
                      for m in ("rgb", "rgb_degraded", "mask", "depth")}})
    labels.insert(1, {"frame": 1, "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 50],
                      "files": {}})  # not rendered
    (root / "labels.json").write_text(json.dumps(labels))
    return geometry, kp_body, scene
