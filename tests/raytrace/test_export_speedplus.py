"""SPEED+ export read the way the authors' tools read it.

Readers, transcribed from the authors' code (cited per function) or third-party: scipy.io.loadmat
for the keypoints .mat (speedplusbaseline ``src/utils/utils.py`` ``load_tango_3d_keypoints``),
``quat2dcm`` and ``project_keypoints`` (same file) for the projection, OpenCV ``cv2.imread`` for
the masks as SPNv2's ``tools/preprocess.py`` and ``core/dataset/SPEEDPLUSDataset.py`` read them,
plyfile for the millimetre model as SPNv2's ``core/utils/utils.py`` ``load_cad_model`` reads it.
The labels they are checked against come from the fixture (``keypoint_sequence``: OpenCV's
projectPoints and the render), never from the exporter.
"""

import json
import shutil

import cv2
import numpy as np
import pytest
import trimesh
from numpy.testing import assert_allclose, assert_array_equal
from scipy.io import loadmat

from raytrace.export._read import _read_sequence, _staging
from raytrace.export.speedplus import export_speedplus, write_speedplus
from tests.raytrace.keypoint_sequence import (
    CAMERA,
    N_SURFACE,
    PITCH_M,
    H,
    W,
    keypoint_labels,
    make_sequence,
)
from tests.raytrace.test_export import speedplus_quat2dcm as quat2dcm


def project_keypoints(q_vbs2tango, r_Vo2To_vbs, cameraMatrix, distCoeffs, keypoints):
    """speedplusbaseline src/utils/utils.py ``project_keypoints``, transcribed: (2, N) pixels."""
    if keypoints.shape[0] != 3:
        keypoints = np.transpose(keypoints)
    keypoints = np.vstack((keypoints, np.ones((1, keypoints.shape[1]))))
    pose_mat = np.hstack((np.transpose(quat2dcm(q_vbs2tango)), np.expand_dims(r_Vo2To_vbs, 1)))
    xyz = np.dot(pose_mat, keypoints)
    x0, y0 = xyz[0, :] / xyz[2, :], xyz[1, :] / xyz[2, :]
    r2 = x0 * x0 + y0 * y0
    cdist = 1 + distCoeffs[0] * r2 + distCoeffs[1] * r2 * r2 + distCoeffs[4] * r2 * r2 * r2
    x = x0 * cdist + distCoeffs[2] * 2 * x0 * y0 + distCoeffs[3] * (r2 + 2 * x0 * x0)
    y = y0 * cdist + distCoeffs[2] * (r2 + 2 * y0 * y0) + distCoeffs[3] * 2 * x0 * y0
    return np.vstack((cameraMatrix[0, 0] * x + cameraMatrix[0, 2], cameraMatrix[1, 1] * y + cameraMatrix[1, 2]))


def load_tango_3d_keypoints(path):
    """speedplusbaseline src/utils/utils.py (and spnv2 core/utils/utils.py) ``load_tango_3d_keypoints``."""
    return np.transpose(np.array(loadmat(path)["tango3Dpoints"], dtype=np.float64))  # (N, 3); theirs: float32


def load_camera_intrinsics(path):
    """spnv2 core/utils/utils.py ``load_camera_intrinsics``: every value to a float32 array."""
    with open(path) as fh:
        cam = json.load(fh)
    cam = {k: np.array(v, dtype=np.float32) for k, v in cam.items()}
    cam["horizontalFOV"] = 2 * np.arctan2(0.5 * cam["ppx"] * cam["Nu"], cam["fx"])
    return cam


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq") / "icesat_seq"
    geometry, kp_body, scene = make_sequence(root)
    return root, geometry, kp_body, scene


@pytest.fixture(scope="module")
def exported(sequence, tmp_path_factory):
    return export_speedplus(sequence[0], tmp_path_factory.mktemp("sp") / "speedplus", split="val")


def labels_of(root):
    return {r["frame"]: r for r in json.loads((root / "labels.json").read_text())}


def test_layout_and_pose_labels(exported, sequence):
    root, geometry, _, _ = sequence
    assert not (exported / "synthetic" / "val.json").exists()
    entries = json.loads((exported / "synthetic" / "validation.json").read_text())  # val → SPEED+'s name
    assert [e["filename"] for e in entries] == [f"{im:06d}.png" for im in sorted(geometry)]
    for e in entries:
        R, t, _ = geometry[int(e["filename"][:6])]
        assert (exported / "synthetic" / "images" / e["filename"]).read_bytes() == \
            (root / "rgb" / e["filename"]).read_bytes()
        # p_cam = quat2dcm(q)^T p_body + r (the baseline's project_keypoints)
        assert_allclose(quat2dcm(np.asarray(e["q_vbs2tango_true"])).T, R, atol=1e-12)
        assert_allclose(e["r_Vo2To_vbs_true"], t, atol=1e-12)
    assert sorted(p.name for p in (exported / "models").iterdir()) == \
        ["icesat.ply", "icesatPoints.mat", "icesat_m.ply", "keypoints.json"]


def test_the_keypoints_mat_file_has_no_time_stamp(sequence, tmp_path, monkeypatch):
    """scipy writes the time into a MAT-file's header; the export writes a fixed text there, so
    an export made at another time is the same bytes (and scipy and MATLAB's header rules still
    read it: 116 bytes of text starting "MATLAB 5.0 MAT-file", then version and endian)."""
    import time
    first = export_speedplus(sequence[0], tmp_path / "a", split="val") / "models" / "icesatPoints.mat"
    monkeypatch.setattr(time, "asctime", lambda *a: "Thu Jan  1 00:00:00 1970")
    second = export_speedplus(sequence[0], tmp_path / "b", split="val") / "models" / "icesatPoints.mat"
    data = first.read_bytes()
    assert data == second.read_bytes()
    assert data.startswith(b"MATLAB 5.0 MAT-file") and b"1970" not in data and b"Created on" not in data
    assert data[126:128] == b"IM"  # little-endian indicator after the 116 + 8 + 2 header bytes
    assert_array_equal(loadmat(first)["tango3Dpoints"], sequence[2].T)


def test_camera_json_reads_with_spnv2(exported):
    cam = load_camera_intrinsics(exported / "camera.json")  # fails on any non-number
    assert (int(cam["Nu"]), int(cam["Nv"])) == (W, H)
    assert_allclose(cam["cameraMatrix"], CAMERA.K)
    assert_allclose(cam["distCoeffs"], np.zeros(5))
    assert_allclose([cam["ppx"], cam["fx"]], [PITCH_M, CAMERA.fx * PITCH_M], rtol=1e-6)
    # the full horizontal field of view through the outer pixel edges, W/2 px either side of the axis
    assert_allclose(cam["horizontalFOV"], 2 * np.arctan(0.5 * W / CAMERA.fx), rtol=1e-6)


def test_baseline_projection_of_the_mat_keypoints_lands_on_the_labels_and_the_mask(exported, sequence):
    root, geometry, kp_body, _ = sequence
    mat = loadmat(exported / "models" / "icesatPoints.mat")
    assert mat["tango3Dpoints"].shape == (3, len(kp_body))
    keypts3d = load_tango_3d_keypoints(exported / "models" / "icesatPoints.mat")
    assert_array_equal(keypts3d, kp_body)  # body frame, metres
    with open(exported / "camera.json") as fh:
        cam = json.load(fh)
    K, dist = np.array(cam["cameraMatrix"]), np.array(cam["distCoeffs"])
    labels = labels_of(root)
    checked = 0
    for e in json.loads((exported / "synthetic" / "validation.json").read_text()):
        frame = int(e["filename"][:6])
        rec = labels[frame]
        uv = project_keypoints(np.array(e["q_vbs2tango_true"]), np.array(e["r_Vo2To_vbs_true"]), K, dist, keypts3d).T
        mask = cv2.imread(str(exported / "synthetic" / "masks" / e["filename"]), cv2.IMREAD_GRAYSCALE)
        for i, ((u, v), want, state) in enumerate(zip(uv, rec["keypoints_px"], rec["keypoints_state"])):
            if want is None:  # behind the camera
                continue
            assert np.hypot(u - want[0], v - want[1]) <= 1e-6
            if i < N_SURFACE and state != "outside":  # a surface point in the image: on the silhouette
                assert mask[int(np.rint(v)), int(np.rint(u))] == 255
                checked += 1
    assert checked >= 20


def test_masks_as_spnv2_reads_them(exported, sequence):
    root, geometry, _, _ = sequence
    labels = labels_of(root)
    for frame, (_, _, g) in geometry.items():
        name = f"{frame:06d}.png"  # SPNv2 reads {domain}/masks/{the image's filename}
        mask = cv2.imread(str(exported / "synthetic" / "masks" / name), cv2.IMREAD_GRAYSCALE)
        assert mask.dtype == np.uint8 and mask.shape == (H, W)
        assert_array_equal(mask, np.where(g.instance > 0, 255, 0))
        # SPEEDPLUSDataset._load_mask: > 128 → 255, else 0 (no change on 0/255)
        assert_array_equal(np.where(mask > 128, 255, 0), mask)
        seg = np.where(mask > 0)  # tools/preprocess.py: the box from the mask
        if labels[frame]["bbox"] is None:
            assert seg[0].size == 0
            continue
        x, y, w, h = labels[frame]["bbox"]
        assert [seg[1].min(), seg[0].min(), seg[1].max(), seg[0].max()] == [x, y, x + w - 1, y + h - 1]


def test_models_in_millimetres_and_metres(exported, sequence):
    from plyfile import PlyData

    root = sequence[0]
    source = trimesh.load(root / "model" / "icesat.ply", process=False)
    vertex = PlyData.read(str(exported / "models" / "icesat.ply"))["vertex"]  # spnv2 load_cad_model
    points_m = np.stack([vertex[:]["x"], vertex[:]["y"], vertex[:]["z"]], axis=-1) / 1000
    assert_allclose(points_m, source.vertices, atol=1e-6)
    assert (exported / "models" / "icesat_m.ply").read_bytes() == (root / "model" / "icesat.ply").read_bytes()
    doc = json.loads((exported / "models" / "keypoints.json").read_text())
    ours = json.loads((root / "model" / "keypoints.json").read_text())
    assert (doc["frame"], doc["unit"], doc["names"]) == ("body", "m", ours["names"])
    assert_array_equal(doc["points_body_m"], ours["points_body_m"])


def test_distortion_reaches_the_baseline_projection(sequence, tmp_path):
    """distCoeffs from the sequence's camera.json, in OpenCV order: keypoints that OpenCV projected
    with them are where the baseline's own distortion model puts them."""
    root, geometry, kp_body, _ = sequence
    seq = tmp_path / "distorted"
    shutil.copytree(root, seq)
    dist = [-0.12, 0.05, 0.001, -0.002, 0.01]
    cam = json.loads((seq / "camera.json").read_text())
    cam["distCoeffs"] = dist
    (seq / "camera.json").write_text(json.dumps(cam))
    labels = json.loads((seq / "labels.json").read_text())
    for rec in labels:
        if rec["frame"] in geometry:
            R, t, g = geometry[rec["frame"]]
            rec["keypoints_px"], rec["keypoints_state"] = keypoint_labels(kp_body, R, t, g.depth_m, dist)
    (seq / "labels.json").write_text(json.dumps(labels))
    out = export_speedplus(seq, tmp_path / "out")
    exported = json.loads((out / "camera.json").read_text())
    assert exported["distCoeffs"] == dist
    keypts3d = load_tango_3d_keypoints(out / "models" / "icesatPoints.mat")
    by_frame = {r["frame"]: r for r in labels}
    for e in json.loads((out / "synthetic" / "train.json").read_text()):
        uv = project_keypoints(np.array(e["q_vbs2tango_true"]), np.array(e["r_Vo2To_vbs_true"]),
                               np.array(exported["cameraMatrix"]), np.array(exported["distCoeffs"]), keypts3d).T
        for (u, v), want in zip(uv, by_frame[int(e["filename"][:6])]["keypoints_px"]):
            if want is not None:
                assert np.hypot(u - want[0], v - want[1]) <= 1e-6


def test_splits_over_two_sequences(sequence, tmp_path):
    root = sequence[0]
    other = tmp_path / "second"
    shutil.copytree(root, other)
    a, b = _read_sequence(root), _read_sequence(other)
    calls = []
    with _staging(tmp_path / "out") as tmp:
        write_speedplus(tmp, {"train": [(a, f) for f in a.frames if f.files][:2],
                              "val": [(b, f) for f in b.frames if f.files][2:],
                              "test": [(b, f) for f in b.frames if f.files][:1]},
                        modality="rgb_degraded", link=False, progress=calls.append)
    out = tmp_path / "out"
    assert calls == [1] * 5
    names = {s: [e["filename"] for e in json.loads((out / "synthetic" / f"{s}.json").read_text())]
             for s in ("train", "validation", "test")}
    assert names == {"train": ["icesat_seq_000000.png", "icesat_seq_000003.png"],
                     "validation": ["second_000007.png", "second_000009.png"], "test": ["second_000000.png"]}
    for split, files in names.items():
        for name in files:
            seq_dir = root if name.startswith("icesat_seq") else other
            src = seq_dir / "rgb_degraded" / name.rsplit("_", 1)[1]
            assert (out / "synthetic" / "images" / name).read_bytes() == src.read_bytes()
            assert (out / "synthetic" / "masks" / name).is_file()


@pytest.mark.parametrize("change, match", [
    (lambda d: trimesh.creation.box().export(d / "model" / "icesat.ply"), "one target"),
    (lambda d: (d / "camera.json").write_text(
        (d / "camera.json").read_text().replace('"K": [[145.0', '"K": [[146.0')), "one camera"),
    (lambda d: (d / "model" / "keypoints.json").unlink(), "one keypoint set"),
])
def test_refuses_to_merge_targets_or_cameras(sequence, tmp_path, change, match):
    root = sequence[0]
    other = tmp_path / "other"
    shutil.copytree(root, other)
    change(other)
    a, b = _read_sequence(root), _read_sequence(other)
    with pytest.raises(ValueError, match=match):
        with _staging(tmp_path / "out") as tmp:
            write_speedplus(tmp, {"train": [(a, a.frames[0])], "val": [(b, b.frames[0])]}, modality="rgb", link=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other"]


def test_bad_input(sequence, tmp_path):
    root = sequence[0]
    a = _read_sequence(root)
    with pytest.raises(ValueError, match="would both be written to synthetic/validation.json"):
        with _staging(tmp_path / "o1") as tmp:
            write_speedplus(tmp, {"val": [(a, a.frames[0])], "validation": [(a, a.frames[2])]}, modality="rgb",
                            link=True)
    with pytest.raises(ValueError, match="frame 0 of .* appears twice"):
        with _staging(tmp_path / "o2") as tmp:
            write_speedplus(tmp, {"train": [(a, a.frames[0])], "val": [(a, a.frames[0])]}, modality="rgb", link=True)
    with pytest.raises(ValueError, match="frame 1 lists no 'rgb' file"):
        with _staging(tmp_path / "o3") as tmp:
            write_speedplus(tmp, {"train": [(a, a.frames[1])]}, modality="rgb", link=True)
    with pytest.raises(ValueError, match="domain must be a plain folder name"):
        export_speedplus(root, tmp_path / "o4", domain="../x")
    bad = tmp_path / "bad"
    shutil.copytree(root, bad)
    cam = json.loads((bad / "camera.json").read_text())
    cam["distCoeffs"] = [0.1, 0, 0, 0, 0, 0.3, 0, 0]
    (bad / "camera.json").write_text(json.dumps(cam))
    with pytest.raises(ValueError, match=r"distCoeffs beyond \(k1, k2, p1, p2, k3\) must be 0"):
        export_speedplus(bad, tmp_path / "o5")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad"]


def spnv2_preprocess_row(datadir, domain, label, camera, keypts3d, load_masks=True):
    """The loop body of spnv2 tools/preprocess.py for one label (image resizing left out), as a
    user runs it on the export: the CSV row [filename, xmin, ymin, xmax, ymax, q (4), t (3),
    origin (2), keypoints (2N)], all image quantities normalised by Nu, Nv. Deviation: the
    script reshapes to 24 numbers (11 keypoints); here 2 (N + 1)."""
    filename = label["filename"]
    mask = cv2.imread(str(datadir / domain / "masks" / filename), cv2.IMREAD_GRAYSCALE) if load_masks else None
    q_vbs2tango = np.array(label["q_vbs2tango_true"], dtype=np.float32)
    r_Vo2To_vbs = np.array(label["r_Vo2To_vbs_true"], dtype=np.float32)
    keypts3d_origin = np.concatenate((np.zeros((3, 1), dtype=np.float32), np.transpose(keypts3d)), axis=1)
    keypts2d = project_keypoints(q_vbs2tango, r_Vo2To_vbs, camera["cameraMatrix"], camera["distCoeffs"],
                                 keypts3d_origin)
    keypts2d[0] = keypts2d[0] / camera["Nu"]
    keypts2d[1] = keypts2d[1] / camera["Nv"]
    keypts2d_vec = np.reshape(np.transpose(keypts2d), (2 * keypts3d_origin.shape[1],))
    if load_masks:
        seg = np.where(mask > 0)
        xmin, ymin = np.min(seg[1]) / camera["Nu"], np.min(seg[0]) / camera["Nv"]
        xmax, ymax = np.max(seg[1]) / camera["Nu"], np.max(seg[0]) / camera["Nv"]
    else:
        xmin, ymin = np.min(keypts2d[0]), np.min(keypts2d[1])
        xmax, ymax = np.max(keypts2d[0]), np.max(keypts2d[1])
    return [filename, xmin, ymin, xmax, ymax] + q_vbs2tango.tolist() + r_Vo2To_vbs.tolist() + keypts2d_vec.tolist()


def test_spnv2_preprocessing_of_the_export(exported, sequence):
    root, geometry, kp_body, _ = sequence
    camera = load_camera_intrinsics(exported / "camera.json")
    keypts3d = np.transpose(np.array(loadmat(exported / "models" / "icesatPoints.mat")["tango3Dpoints"],
                                     dtype=np.float32))  # load_tango_3d_keypoints as SPNv2 has it
    labels = labels_of(root)
    for entry in json.loads((exported / "synthetic" / "validation.json").read_text()):
        frame = int(entry["filename"][:6])
        rec = labels[frame]
        if rec["bbox"] is None:  # target wholly outside: the script stops on the empty mask ...
            with pytest.raises(ValueError):
                spnv2_preprocess_row(exported, "synthetic", entry, camera, keypts3d)
            spnv2_preprocess_row(exported, "synthetic", entry, camera, keypts3d, load_masks=False)  # ... or not
            continue
        row = spnv2_preprocess_row(exported, "synthetic", entry, camera, keypts3d)
        x, y, w, h = rec["bbox"]
        assert_allclose(row[1:5], [x / W, y / H, (x + w - 1) / W, (y + h - 1) / H], rtol=1e-6)
        R, t, _ = geometry[frame]
        assert_allclose(row[12:14], [CAMERA.fx * t[0] / t[2] + CAMERA.cx, CAMERA.fy * t[1] / t[2] + CAMERA.cy]
                        / np.array([W, H]), atol=1e-5)  # the target origin; float32 pose
        for uv, want in zip(np.reshape(row[14:], (-1, 2)), rec["keypoints_px"]):
            if want is not None:
                assert_allclose(uv * [W, H], want, atol=2e-3)  # float32 pose and points, as the script
