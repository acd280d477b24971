"""BOP and SPEED+ exporters against independent answers.

A tiny sequence folder (ICESat, 160×120, three rendered frames — one cut by the image border —
and one frame record without files) is written here in the pipeline's contract format. The
checks never reuse the exporter's arithmetic:

* BOP: back-projecting the 16-bit depth with cam_K, depth_scale and the pose (mm) lands on
  the exported millimetre model; the depth equals the render's within quantisation; masks
  and pixel counts equal the render's; ``bbox_obj`` and ``px_count_all`` equal a render on a
  3W × 3H canvas, as ``bop_toolkit/scripts/calc_gt_info.py`` makes them (the exporter
  renders only the window the projected hull covers); the diameter is the brute-force
  largest vertex distance.
* SPEED+: with the authors' own ``quat2dcm`` (speedplusbaseline ``src/utils/utils.py``,
  transcribed below) a camera point back-projected from the render's depth maps onto the
  body mesh, and scipy (scalar last) rebuilds R_cam_from_body.
"""

import json
import os
import shutil

import numpy as np
import OpenImageIO as oiio
import pytest
import trimesh
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.distance import pdist
from scipy.spatial.transform import Rotation

from raytrace.camera import Camera
from raytrace.export import BOP_DEPTH_MAX_CODE, export_bop, export_speedplus
from raytrace.scene import Scene
from raytrace.targets import load_target
from tests.raytrace.oracles import png_chunks, point_mesh_distance

W, H = 160, 120
CAMERA = Camera(width=W, height=H, fx=145.0, fy=145.0, cx=79.5, cy=59.5)
POSES = {  # frame → (Euler ZYX [deg], t_cam_m); frame 7 is cut by the right image border
    0: ((30.0, 20.0, 10.0), (0.0, 0.0, 12.0)),
    3: ((-120.0, 45.0, 60.0), (-0.5, 0.3, 9.0)),
    7: ((75.0, -10.0, 170.0), (4.5, 0.0, 12.0)),
}


def write_image(path, pixels):
    out = oiio.ImageOutput.create(str(path))
    pixels = pixels if pixels.ndim == 3 else pixels[:, :, None]
    fmt = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16, np.dtype(np.float32): oiio.FLOAT}
    assert out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2],
                                              fmt[pixels.dtype]))
    assert out.write_image(np.ascontiguousarray(pixels))
    out.close()


def read_image(path):
    buf = oiio.ImageBuf(str(path))
    pixels = buf.get_pixels(buf.spec().format)
    return pixels[:, :, 0] if pixels.shape[2] == 1 else pixels


def quat_scalar_first(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def speedplus_quat2dcm(q):
    """speedplusbaseline src/utils/utils.py ``quat2dcm`` (scalar-first q → DCM), transcribed."""
    q = q / np.linalg.norm(q)
    q0, q1, q2, q3 = q
    dcm = np.zeros((3, 3))
    dcm[0, 0] = 2 * q0**2 - 1 + 2 * q1**2
    dcm[1, 1] = 2 * q0**2 - 1 + 2 * q2**2
    dcm[2, 2] = 2 * q0**2 - 1 + 2 * q3**2
    dcm[0, 1] = 2 * q1 * q2 + 2 * q0 * q3
    dcm[0, 2] = 2 * q1 * q3 - 2 * q0 * q2
    dcm[1, 0] = 2 * q1 * q2 - 2 * q0 * q3
    dcm[1, 2] = 2 * q2 * q3 + 2 * q0 * q1
    dcm[2, 0] = 2 * q1 * q3 + 2 * q0 * q2
    dcm[2, 1] = 2 * q2 * q3 - 2 * q0 * q1
    return dcm


def make_sequence(root, scene):
    """Write a sequence folder in the pipeline's contract format; return the geometry frames."""
    for sub in ("rgb", "rgb_degraded", "mask", "depth", "normal", "model"):
        (root / sub).mkdir(parents=True)
    scene.model.combined_mesh().export(root / "model" / "icesat.ply")
    (root / "scenario.json").write_text(json.dumps({"target": "icesat", "seed": 0}))
    K = CAMERA.K
    (root / "camera.json").write_text(json.dumps({
        "K": K.tolist(), "width": W, "height": H, "cameraMatrix": K.tolist(), "distCoeffs": [0.0] * 5,
        "Nu": W, "Nv": H, "pixel_pitch_m": 3.45e-6 * 1280 / W}))
    labels, geometry = [], {}
    for frame, (euler, t) in POSES.items():
        R = Rotation.from_euler("ZYX", euler, degrees=True).as_matrix()
        g = scene.render_geometry(CAMERA, R, t)
        geometry[frame] = (R, np.array(t), g)
        name = f"{frame:06d}"
        shade = np.rint(255 * np.abs(g.normal_cam[:, :, 2])).astype(np.uint8)
        write_image(root / "rgb" / f"{name}.png", np.repeat(shade[:, :, None], 3, axis=2))
        write_image(root / "rgb_degraded" / f"{name}.png", np.repeat((shade // 2)[:, :, None], 3, axis=2))
        write_image(root / "mask" / f"{name}.png", g.instance)
        write_image(root / "depth" / f"{name}.exr", g.depth_m)
        write_image(root / "normal" / f"{name}.exr", g.normal_cam)
        labels.append({
            "frame": frame, "t_s": 10.0 * frame, "utc": "2026-03-20T12:00:00Z", "r_lvlh": [0, -12, 0],
            "v_lvlh": [0, 0, 0], "q_cam_from_body": quat_scalar_first(R).tolist(),
            "R_cam_from_body": R.ravel().tolist(), "t_cam_m": list(t), "bbox": g.bbox_xywh,
            "visible_fraction": g.visible_fraction, "pixel_counts": g.pixel_counts.tolist(),
            "files": {m: f"{m}/{name}.{'exr' if m in ('depth', 'normal') else 'png'}"
                      for m in ("rgb", "rgb_degraded", "mask", "depth", "normal")},
            "line_of_sight": True, "visible": True})
    labels.insert(1, {"frame": 1, "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 50],
                      "visible_fraction": 0.0, "files": {}, "visible": False})  # not rendered
    (root / "labels.json").write_text(json.dumps(labels))
    return geometry


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    scene = Scene(load_target("icesat"))
    root = tmp_path_factory.mktemp("seq") / "sequence"
    return root, make_sequence(root, scene), scene


@pytest.fixture(scope="module")
def bop(sequence, tmp_path_factory):
    root, geometry, scene = sequence
    out = export_bop(root, tmp_path_factory.mktemp("bop") / "icesat_bop", obj_id=3, scene_id=12)
    scene_dir = out / "train" / "000012"
    js = {name: json.loads((scene_dir / f"{name}.json").read_text())
          for name in ("scene_camera", "scene_gt", "scene_gt_info")}
    return out, scene_dir, js, geometry, scene


def test_bop_layout(bop):
    out, scene_dir, js, geometry, _ = bop
    assert sorted(int(k) for k in js["scene_gt"]) == sorted(geometry)  # frame 1 (no files) left out
    for im in geometry:
        for rel in (f"rgb/{im:06d}.png", f"depth/{im:06d}.png", f"mask/{im:06d}_000000.png",
                    f"mask_visib/{im:06d}_000000.png"):
            assert (scene_dir / rel).is_file(), rel
        assert js["scene_gt"][str(im)][0]["obj_id"] == 3
        # bop_toolkit's renderers put pixel centres at i + 0.5, this project's K at integers
        assert_allclose(js["scene_camera"][str(im)]["cam_K"], (CAMERA.K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]).ravel())
    cam = json.loads((out / "camera.json").read_text())
    assert (cam["width"], cam["height"], cam["fx"], cam["cx"], cam["cy"]) == (W, H, 145.0, 80.0, 60.0)
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no staging folder left


def test_bop_model_in_mm(bop, sequence):
    out, _, _, _, scene = bop
    model = trimesh.load(out / "models" / "obj_000003.ply", process=False)
    source = scene.model.combined_mesh()
    assert_allclose(model.vertices, source.vertices * 1000.0, atol=1e-3)  # float32 PLY, mm
    assert_array_equal(model.faces, source.faces)
    info = json.loads((out / "models" / "models_info.json").read_text())["3"]
    assert_allclose(info["diameter"], 1000.0 * pdist(source.vertices).max(), rtol=1e-6)  # float32 PLY in metres
    lo, hi = source.bounds * 1000.0
    assert_allclose([info["min_x"], info["min_y"], info["min_z"]], lo, rtol=1e-6)
    assert_allclose([info["size_x"], info["size_y"], info["size_z"]], hi - lo, rtol=1e-6)


def test_bop_depth_equals_render_within_quantisation(bop):
    _, scene_dir, js, geometry, _ = bop
    for im, (_, _, g) in geometry.items():
        scale = js["scene_camera"][str(im)]["depth_scale"]
        codes = read_image(scene_dir / "depth" / f"{im:06d}.png")
        assert codes.dtype == np.uint16 and codes.max() <= BOP_DEPTH_MAX_CODE
        depth_mm = codes.astype(np.float64) * scale
        hit = np.isfinite(g.depth_m)
        assert np.all(codes[~hit] == 0)
        assert np.abs(depth_mm[hit] - 1000.0 * g.depth_m[hit].astype(np.float64)).max() <= 0.5 * scale + 1e-6


def test_bop_pose_and_depth_back_project_onto_the_model(bop):
    out, scene_dir, js, geometry, _ = bop
    model = trimesh.load(out / "models" / "obj_000003.ply", process=False)
    V, F = np.asarray(model.vertices, np.float64), np.asarray(model.faces)
    rng = np.random.default_rng(0)
    for im in geometry:
        K = np.reshape(js["scene_camera"][str(im)]["cam_K"], (3, 3))
        scale = js["scene_camera"][str(im)]["depth_scale"]
        gt = js["scene_gt"][str(im)][0]
        R, t = np.reshape(gt["cam_R_m2c"], (3, 3)), np.asarray(gt["cam_t_m2c"])
        z = read_image(scene_dir / "depth" / f"{im:06d}.png").astype(np.float64) * scale
        v, u = np.nonzero(z)
        pick = rng.choice(u.size, 60, replace=False)
        u, v, z = u[pick], v[pick], z[v[pick], u[pick]]
        u, v = u + 0.5, v + 0.5  # the toolkit's pixel centres (cam_K has cx, cy + 0.5)
        p_cam = np.column_stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
        p_model = (p_cam - t) @ R  # R^T (p − t), row vectors
        assert point_mesh_distance(p_model, V, F).max() < scale  # quantisation ≤ scale/2 along the ray


def large_canvas(scene, R, t):
    """bop_toolkit calc_gt_info: render the object alone on a 3W × 3H canvas, offset (W, H)."""
    big = Camera(width=3 * W, height=3 * H, fx=CAMERA.fx, fy=CAMERA.fy, cx=CAMERA.cx + W, cy=CAMERA.cy + H)
    g = scene.render_geometry(big, R, t)
    x0, y0, x1, y1 = g.bbox_xyxy
    return int(g.mask.sum()), (x0 - W, y0 - H, x1 - W, y1 - H)


def test_bop_gt_info(bop):
    _, scene_dir, js, geometry, scene = bop
    for im, (R, t, g) in geometry.items():
        info = js["scene_gt_info"][str(im)][0]
        mask = read_image(scene_dir / "mask" / f"{im:06d}_000000.png")
        assert mask.dtype == np.uint8 and set(np.unique(mask)) == {0, 255}
        assert_array_equal(mask > 0, g.instance > 0)
        assert_array_equal(read_image(scene_dir / "mask_visib" / f"{im:06d}_000000.png"), mask)
        n = int(np.count_nonzero(g.instance))
        assert info["px_count_visib"] == info["px_count_valid"] == n
        rows, cols = np.nonzero(g.instance)
        assert info["bbox_visib"] == [cols.min(), rows.min(), cols.max() - cols.min(), rows.max() - rows.min()]
        # the whole silhouette, truncated part included, as bop_toolkit renders it (3× canvas)
        n_all, (x0, y0, x1, y1) = large_canvas(scene, R, t)
        assert info["bbox_obj"] == [x0, y0, x1 - x0, y1 - y0]
        assert info["px_count_all"] == n_all
        assert_allclose(info["visib_fract"], n / n_all, rtol=1e-12)
        assert_allclose(info["visib_fract"], g.visible_fraction, atol=0.03)  # the renderer's own estimate
    cut = js["scene_gt_info"]["7"][0]
    assert cut["bbox_obj"][0] + cut["bbox_obj"][2] > W - 1  # reaches beyond the image
    assert cut["visib_fract"] < 0.95 and cut["px_count_all"] > cut["px_count_visib"]


def test_bop_data_pngs_carry_no_colour_space(bop):
    """Depth codes and masks are plain PNGs, as bop_toolkit's inout.save_depth writes them (no sRGB/gAMA/cHRM)."""
    _, scene_dir, *_ = bop
    for sub in ("depth", "mask", "mask_visib"):
        for path in sorted((scene_dir / sub).iterdir()):
            assert not {"sRGB", "gAMA", "cHRM", "iCCP"} & set(png_chunks(path)), path


def test_bop_gt_info_of_an_object_wholly_outside_the_image(tmp_path, monkeypatch):
    """calc_gt_info counts px_count_all on its 3W × 3H canvas for every object; one wholly beyond the
    image's right border but on the canvas got 0 (the boxes stay [-1, -1, -1, -1], visib_fract 0)."""
    import tests.raytrace.test_export as me
    monkeypatch.setattr(me, "POSES", {0: ((30.0, 20.0, 10.0), (13.3, 0.0, 12.0))})
    scene = Scene(load_target("icesat"))
    (R, t, g), = make_sequence(tmp_path / "seq", scene).values()
    n_all, _ = large_canvas(scene, R, t)
    assert not g.instance.any() and n_all > 500  # nothing in the image, a silhouette on the canvas
    out = export_bop(tmp_path / "seq", tmp_path / "bop")
    info = json.loads((out / "train" / "000000" / "scene_gt_info.json").read_text())["0"][0]
    assert info == {"bbox_obj": [-1, -1, -1, -1], "bbox_visib": [-1, -1, -1, -1], "px_count_all": n_all,
                    "px_count_valid": 0, "px_count_visib": 0, "visib_fract": 0.0}


def test_bop_images_linked_or_copied(sequence, tmp_path):
    root = sequence[0]
    out = export_bop(root, tmp_path / "linked", modality="rgb_degraded")
    src, dst = root / "rgb_degraded" / "000003.png", out / "train" / "000000" / "rgb" / "000003.png"
    assert os.stat(src).st_ino == os.stat(dst).st_ino
    out = export_bop(root, tmp_path / "copied", link=False)
    src, dst = root / "rgb" / "000003.png", out / "train" / "000000" / "rgb" / "000003.png"
    assert os.stat(src).st_ino != os.stat(dst).st_ino and src.read_bytes() == dst.read_bytes()


def test_labels_as_object_with_frames(sequence, tmp_path):
    root = sequence[0]
    copy = tmp_path / "seq"
    shutil.copytree(root, copy)
    labels = json.loads((copy / "labels.json").read_text())
    (copy / "labels.json").write_text(json.dumps({"sequence": "x", "frames": labels}))
    a = export_bop(root, tmp_path / "a")
    b = export_bop(copy, tmp_path / "b")
    for name in ("scene_gt", "scene_gt_info", "scene_camera"):
        assert (a / "train/000000" / f"{name}.json").read_text() == (b / "train/000000" / f"{name}.json").read_text()


def test_speedplus(sequence, tmp_path):
    root, geometry, scene = sequence
    out = export_speedplus(root, tmp_path / "speedplus")
    labels = json.loads((out / "synthetic" / "train.json").read_text())
    cam = json.loads((out / "camera.json").read_text())
    assert [e["filename"] for e in labels] == [f"{im:06d}.png" for im in sorted(geometry)]
    pitch = 3.45e-6 * 1280 / W
    assert (cam["Nu"], cam["Nv"]) == (W, H)
    assert_allclose([cam["ppx"], cam["ppy"], cam["fx"], cam["fy"]], [pitch, pitch, 145 * pitch, 145 * pitch])
    assert_allclose(cam["cameraMatrix"], CAMERA.K)
    assert cam["distCoeffs"] == [0.0] * 5
    V = np.asarray(scene.model.combined_mesh().vertices)
    F = np.asarray(scene.model.combined_mesh().faces)
    rng = np.random.default_rng(1)
    for entry in labels:
        im = int(entry["filename"][:6])
        R, t, g = geometry[im]
        assert (out / "synthetic" / "images" / entry["filename"]).read_bytes() == \
            (root / "rgb" / entry["filename"]).read_bytes()
        q, r = np.asarray(entry["q_vbs2tango_true"]), np.asarray(entry["r_Vo2To_vbs_true"])
        assert_allclose(Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix(), R, atol=1e-12)
        assert_allclose(r, t, atol=1e-12)
        # SPEED+'s own convention: p_cam = quat2dcm(q)^T p_tango + r, so p_tango = quat2dcm(q) (p_cam − r);
        # camera points back-projected from the rendered depth must land on the body mesh
        v, u = np.nonzero(np.isfinite(g.depth_m))
        pick = rng.choice(u.size, 40, replace=False)
        u, v = u[pick], v[pick]
        z = g.depth_m[v, u].astype(np.float64)
        p_cam = np.column_stack([(u - CAMERA.cx) / CAMERA.fx * z, (v - CAMERA.cy) / CAMERA.fy * z, z])
        p_body = (p_cam - r) @ speedplus_quat2dcm(q).T
        assert point_mesh_distance(p_body, V, F).max() < 1e-5 * z.max()


def leftovers(parent):
    return sorted(p.name for p in parent.iterdir())


BOP_ONLY = {"depth", "mask", "model"}  # SPEED+ reads neither depth, masks nor the model


@pytest.mark.parametrize("breakage, match", [
    (lambda d: (d / "labels.json").unlink(), r"labels\.json: .* is missing"),
    (lambda d: (d / "labels.json").write_text("[{"), r"labels\.json: .* not readable JSON"),
    (lambda d: (d / "camera.json").unlink(), r"camera\.json: .* is missing"),
    (lambda d: (d / "depth" / "000007.exr").unlink(), r"frame 7: files\['depth'\] = 'depth/000007\.exr' is missing"),
    (lambda d: (d / "mask" / "000003.png").write_bytes(b"not a png"), r"mask/000003\.png is not a readable image"),
    (lambda d: shutil.rmtree(d / "model"), r"model/ must hold exactly one \.ply"),
    (lambda d: (d / "labels.json").write_text(json.dumps([{"frame": 0, "t_cam_m": [0, 0, 1]}])),
     r"frame record 0 lacks R_cam_from_body"),
    (lambda d: (d / "labels.json").write_text(json.dumps(
        [{"frame": 0, "R_cam_from_body": [2, 0, 0, 0, 1, 0, 0, 0, 1], "t_cam_m": [0, 0, 1]}])),
     r"frame 0: R_cam_from_body must be a rotation"),
    (lambda d: (d / "labels.json").write_text(json.dumps(
        [{"frame": 0, "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 1], "files": {}}])),
     r"no frame with files"),
])
def test_broken_sequence_leaves_nothing(sequence, tmp_path, breakage, match):
    broken = tmp_path / "broken"
    shutil.copytree(sequence[0], broken)
    breakage(broken)
    dest = tmp_path / "exports"
    dest.mkdir()
    for export in (export_bop, export_speedplus):
        if export is export_speedplus and any(word in match for word in BOP_ONLY):
            continue
        with pytest.raises(ValueError, match=match):
            export(broken, dest / "deeper" / "out")
        assert leftovers(dest) == []  # no partial folder, no created parent


def test_a_killed_exports_staging_folder_is_removed_by_the_next(sequence, tmp_path):
    """An export killed before its clean-up leaves its staging folder beside the output, named
    after its host and process; the next export into that folder removes it (and keeps one of a
    live process)."""
    import subprocess
    import sys

    from raytrace import files
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                              capture_output=True, text=True).stdout)
    stale = tmp_path / f".out.partial-{files._HOST}.{dead}-abc"
    live = tmp_path / f".out.partial-{files._HOST}.{os.getpid()}-abc"
    for d in (stale, live):
        d.mkdir()
        (d / "scene_gt.json").write_text("{")
    export_speedplus(sequence[0], tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, "out"])


def test_argument_errors(sequence, tmp_path):
    root = sequence[0]
    with pytest.raises(ValueError, match="sequence_dir must be a sequence folder"):
        export_bop(tmp_path / "nowhere", tmp_path / "out")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    with pytest.raises(ValueError, match="out_dir must be a new or empty folder"):
        export_bop(root, tmp_path / "full")
    with pytest.raises(ValueError, match="modality must be one of 'rgb', 'rgb_degraded'; got 'depth'"):
        export_speedplus(root, tmp_path / "out", modality="depth")
    with pytest.raises(ValueError, match=r"obj_id must be an integer in \[1, 999999\], got 0"):
        export_bop(root, tmp_path / "out", obj_id=0)
    with pytest.raises(ValueError, match="split must be a folder name"):
        export_bop(root, tmp_path / "out", split="../x")
    assert leftovers(tmp_path) == ["full"]
    (tmp_path / "empty").mkdir()
    assert export_speedplus(root, tmp_path / "empty") == tmp_path / "empty"  # an empty folder is fine


def test_bop_toolkit_reads_the_export(bop):
    inout = pytest.importorskip("bop_toolkit_lib.inout")
    _, scene_dir, _, geometry, _ = bop
    cams = inout.load_scene_camera(str(scene_dir / "scene_camera.json"))
    gts = inout.load_scene_gt(str(scene_dir / "scene_gt.json"))
    info = inout.load_json(str(scene_dir / "scene_gt_info.json"), keys_to_int=True)
    for im, (R, t, g) in geometry.items():
        assert_allclose(cams[im]["cam_K"], CAMERA.K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
        assert_allclose(gts[im][0]["cam_R_m2c"], R, atol=1e-12)
        assert_allclose(gts[im][0]["cam_t_m2c"].ravel(), 1000 * t)
        assert info[im][0]["px_count_visib"] == int(np.count_nonzero(g.instance))
        depth = inout.load_depth(str(scene_dir / "depth" / f"{im:06d}.png")) * cams[im]["depth_scale"]
        hit = np.isfinite(g.depth_m)
        assert np.abs(depth[hit] - 1000 * g.depth_m[hit]).max() <= 0.5 * cams[im]["depth_scale"] + 1e-3
