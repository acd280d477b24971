"""``cli.py export`` (raytrace.export.command, raytrace.export.splits) and the BOP dataset it
writes, against independent answers:

* splits: counts worked out by hand (largest remainder), the seeded shuffle redone with numpy;
* merging two sequences of two targets: one obj_id per distinct model (PLY bytes), one scene
  per sequence, no file written twice;
* resume: an export interrupted after k frames (the frame writer raising KeyboardInterrupt)
  keeps its staging folder; the same command then writes only the other frames, and the result
  equals an uninterrupted export byte for byte; other arguments start afresh;
* bad input: one line, exit status 2, nothing on disk;
* BOP: the model PLY read by a reader that follows bop_toolkit ``inout.load_ply``'s rules; the
  masks equal a numpy rasteriser of the exported model under the exported ``cam_K`` sampling at
  pixel centres (i + 0.5, j + 0.5), as the toolkit's OpenGL renderers do, and its visible
  fraction on the 3W × 3H canvas; ``scene_gt_coco.json`` read by pycocotools; the test targets.
"""

import json
import os
import shutil

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from raytrace.export import bop as bop_module
from raytrace.export.command import export_main
from raytrace.export.splits import assign, parse_split_spec, share_counts
from raytrace.scene import Scene
from raytrace.targets import load_target
from tests.raytrace.test_export import H, W, make_sequence, read_image


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def two_targets(tmp_path_factory):
    """Two sequence folders (ICESat, Space Dragon), three rendered frames each (0, 3, 7)."""
    base = tmp_path_factory.mktemp("seqs")
    out = {}
    for target in ("icesat", "spacedragon"):
        scene = Scene(load_target(target))
        out[target] = (base / target, make_sequence(base / target, scene), scene)
    return out


def run(argv, capsys):
    try:
        status = export_main([*argv, "--quiet"])
    except SystemExit as exc:  # argparse's refusal of an option (cli.py exits with it)
        status = exc.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def tree(folder):
    """Relative path → bytes of every file under ``folder``."""
    out = {}
    for root, _, names in os.walk(folder):
        for name in names:
            p = os.path.join(root, name)
            with open(p, "rb") as fh:
                out[os.path.relpath(p, folder)] = fh.read()
    return out


# --------------------------------------------------------------------------- splits
def test_split_counts_by_largest_remainder():
    # 7 × (1/3, 1/3, 1/3) = 2.33 each: floors 2, 2, 2; the one left goes to the first of the ties
    assert share_counts(parse_split_spec("a=0.3333333333333333,b=0.3333333333333333,c=0.3333333333333334"), 7) \
        == [2, 2, 3]  # c's remainder is (a hair) the largest
    assert share_counts(parse_split_spec("train=0.8,val=0.1,test=0.1"), 13) == [11, 1, 1]  # 10.4, 1.3, 1.3
    assert share_counts(parse_split_spec("train=0.5,val=0.5"), 5) == [3, 2]  # 2.5, 2.5: tie to the first
    assert share_counts(parse_split_spec("train=4,test=2"), 6) == [4, 2]
    assert share_counts(parse_split_spec("train=1"), 6) == [6]  # one split: everything, not a count of 1
    with pytest.raises(ValueError, match="counts sum to 6 but there are 7"):
        share_counts(parse_split_spec("train=4,test=2"), 7)
    with pytest.raises(ValueError, match="split 'test' gets no frame of 3"):
        share_counts(parse_split_spec("train=0.9,test=0.1"), 3)


def test_split_assignment_is_the_seeded_permutation():
    items = [[("s0", k) for k in range(5)], [("s1", k) for k in range(4)]]
    spec = parse_split_spec("train=0.7,test=0.3")  # 9 → 6.3, 2.7: 6 + 1, remainder .7 > .3 → 6, 3
    got = assign(items, spec, by="frame", seed=11)
    pooled = [x for seq in items for x in seq]
    perm = np.random.default_rng(11).permutation(9)
    assert got["train"] == [pooled[i] for i in sorted(perm[:6])]
    assert got["test"] == [pooled[i] for i in sorted(perm[6:])]
    assert assign(items, spec, by="frame", seed=11) == got
    assert assign(items, spec, by="frame", seed=12) != got
    by_seq = assign(items, parse_split_spec("train=1,test=1"), by="sequence", seed=3)
    order = np.random.default_rng(3).permutation(2)
    assert by_seq == {"train": items[order[0]], "test": items[order[1]]}
    with pytest.raises(ValueError, match="split 'c' gets no sequence of 2"):
        assign(items, parse_split_spec("a=0.4,b=0.3,c=0.3"), by="sequence")


@pytest.mark.parametrize("spec, match", [
    ("train=0.8,val=0.1", "must sum to 1"),
    ("train=0.5,train=0.5", "'train' appears twice"),
    ("train=nan,val=0.5", r"finite numbers in \(0, 1\]"),
    ("train=0.5,val=x", "must be NAME=SHARE"),
    ("../x=1", "must be NAME=SHARE"),
    ("train", "must be NAME=SHARE"),
    ("train=0,val=3", "whole numbers >= 1"),
])
def test_bad_split_specs(spec, match):
    with pytest.raises(ValueError, match=match):
        parse_split_spec(spec)


# --------------------------------------------------------------------------- merge
@pytest.fixture(scope="module")
def merged(two_targets, tmp_path_factory):
    """BOP export of ICESat, Space Dragon and a copy of the ICESat sequence (same model), split
    by frame into train/test."""
    base = tmp_path_factory.mktemp("merged")
    ice, dragon = two_targets["icesat"][0], two_targets["spacedragon"][0]
    copy = base / "icesat_copy"
    shutil.copytree(ice, copy)
    out = base / "bop"
    status = export_main(["--format", "bop", str(ice), str(dragon), str(copy), "--out", str(out),
                          "--split", "train=0.6,test=0.4", "--seed", "5", "--workers", "1", "--quiet"])
    assert status == 0
    return out, two_targets


def test_merge_of_two_targets(merged):
    out, targets = merged
    models = json.loads((out / "models" / "models_info.json").read_text())
    assert sorted(models) == ["1", "2"]  # the copy shares ICESat's model
    assert json.loads((out / "models_eval" / "models_info.json").read_text()) == models
    # 9 frames × (0.6, 0.4) = 5.4, 3.6: floors 5, 3; the one left goes to the larger remainder (test)
    seen = {}
    for split in ("train", "test"):
        for scene_dir in sorted((out / split).iterdir()):
            gt = json.loads((scene_dir / "scene_gt.json").read_text())
            for im, insts in gt.items():
                key = (int(scene_dir.name), int(im))
                assert key not in seen, key  # every (scene, image) once over the splits
                seen[key] = (split, insts[0]["obj_id"])
                assert (scene_dir / "rgb" / f"{int(im):06d}.png").is_file()
    assert sorted(seen) == [(s, im) for s in range(3) for im in (0, 3, 7)]
    assert {obj for (s, _), (_, obj) in seen.items() if s in (0, 2)} == {1}
    assert {obj for (s, _), (_, obj) in seen.items() if s == 1} == {2}
    assert [sp for _, (sp, _) in seen.items()].count("train") == 5
    # the models are the two targets' meshes in mm
    for obj_id, target in ((1, "icesat"), (2, "spacedragon")):
        mesh = targets[target][2].model.combined_mesh()
        hi, lo = mesh.vertices.max(axis=0) * 1000, mesh.vertices.min(axis=0) * 1000
        assert_allclose(models[str(obj_id)]["size_x"], hi[0] - lo[0], rtol=1e-6)


def test_finished_export_is_recognised_and_a_foreign_folder_refused(merged, capsys, tmp_path):
    out, _ = merged
    record = json.loads((out / ".export.json").read_text())
    argv = ["--format", "bop", *record["sequences"], "--out", str(out), "--split", "train=0.6,test=0.4",
            "--seed", "5", "--workers", "1"]
    status, stdout, _ = run(argv, capsys)
    assert status == 0 and "already this export, finished" in stdout
    status, _, err = run([*argv[:-4], "--seed", "6", "--workers", "1"], capsys)  # other arguments
    assert status == 2 and "exists and is not empty" in err


# --------------------------------------------------------------------------- resume
def test_resume_after_an_interruption(two_targets, tmp_path, monkeypatch, capsys):
    ice, dragon = two_targets["icesat"][0], two_targets["spacedragon"][0]
    argv = ["--format", "bop", str(ice), str(dragon), "--split", "train=4,val=2", "--workers", "1"]
    reference = tmp_path / "reference" / "bop"  # the same name: scene_gt_coco.json names the dataset
    assert run([*argv, "--out", str(reference)], capsys)[0] == 0

    real = bop_module._export_frame
    calls = []

    def failing(job):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(job["im"])
        return real(job)

    monkeypatch.setattr(bop_module, "_export_frame", failing)
    out = tmp_path / "sub" / "bop"
    status, _, err = run([*argv, "--out", str(out)], capsys)
    assert status == 130 and "rerun the same command to continue" in err
    staging = tmp_path / "sub" / ".bop.export-partial"
    assert staging.is_dir() and not out.exists()

    def counting(job):
        calls.append(job["im"])
        return real(job)

    monkeypatch.setattr(bop_module, "_export_frame", counting)
    assert run([*argv, "--out", str(out)], capsys)[0] == 0
    assert len(calls) == 6  # 2 before the interruption, the other 4 now
    assert not staging.exists()
    assert tree(out) == tree(reference)


def test_other_arguments_start_afresh(two_targets, tmp_path, monkeypatch, capsys):
    ice = two_targets["icesat"][0]
    real = bop_module._export_frame
    calls = []

    def failing(job):
        if len(calls) == 1:
            raise KeyboardInterrupt
        calls.append(job["im"])
        return real(job)

    monkeypatch.setattr(bop_module, "_export_frame", failing)
    out = tmp_path / "bop"
    assert run(["--format", "bop", str(ice), "--out", str(out), "--workers", "1"], capsys)[0] == 130
    monkeypatch.setattr(bop_module, "_export_frame", lambda job: (calls.append(job["im"]), real(job))[1])
    assert run(["--format", "bop", str(ice), "--out", str(out), "--workers", "1", "--modality", "rgb_degraded"],
               capsys)[0] == 0
    assert len(calls) == 1 + 3  # the staging folder of the other export was not reused
    assert read_image(out / "train" / "000000" / "rgb" / "000003.png").tolist() == \
        read_image(ice / "rgb_degraded" / "000003.png").tolist()


# --------------------------------------------------------------------------- bad input
def _distorted(src, dst):
    shutil.copytree(src, dst)
    cam = json.loads((dst / "camera.json").read_text())
    cam["distCoeffs"] = [0.1, 0, 0, 0, 0]
    (dst / "camera.json").write_text(json.dumps(cam))


def _unfinished(src, dst):
    shutil.copytree(src, dst)
    (dst / "labels.json").unlink()


@pytest.mark.parametrize("make, args, match", [
    (None, ["--format", "pascal"], r"argument --format: must be one of bop, speedplus, coco; got 'pascal'"),
    (None, ["--split", "train=0.7,val=0.2"], r"argument --split: fractions must sum to 1"),
    ("two", ["--split", "a=0.4,b=0.3,c=0.3", "--split-by", "sequence"], r"argument --split: split 'c' gets no sequence of 2"),
    (None, ["--seed", "-1"], r"argument --seed: must be an integer"),
    (None, ["--modality", "depth"], r"argument --modality: must be one of rgb, rgb_degraded"),
    ("missing", [], r"argument SEQ_DIR: .*missing is not a folder"),
    ("twice", [], r"argument SEQ_DIR: .* is given twice"),
    (_unfinished, [], r"argument SEQ_DIR: .* is not a finished sequence folder \(no labels\.json"),
    (_distorted, [], r"BOP has no lens distortion"),
    (None, ["--split", "models=1"], r"split names must be folder names .* other than models and models_eval"),
])
def test_bad_input_one_line_exit_2_nothing_written(two_targets, tmp_path, capsys, make, args, match):
    ice = two_targets["icesat"][0]
    seqs = [str(ice)]
    if make == "missing":
        seqs.append(str(tmp_path / "missing"))
    elif make == "twice":
        seqs.append(str(ice) + "/")
    elif make == "two":
        seqs.append(str(two_targets["spacedragon"][0]))
    elif make is not None:
        make(ice, tmp_path / "odd")
        seqs.append(str(tmp_path / "odd"))
    if "--format" not in args:
        args = ["--format", "bop", *args]
    before = sorted(os.listdir(tmp_path))
    status, _, err = run([*seqs, *args, "--out", str(tmp_path / "x" / "out"), "--workers", "1"], capsys)
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cli.py: error: "), err
    assert __import__("re").search(match, lines[0]), lines[0]
    assert sorted(os.listdir(tmp_path)) == before


def test_a_bad_frame_found_while_writing_leaves_nothing(two_targets, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(two_targets["icesat"][0], broken)
    (broken / "mask" / "000007.png").write_bytes(b"not a png")
    status, _, err = run(["--format", "bop", str(broken), "--out", str(tmp_path / "a" / "out"), "--workers", "1"],
                         capsys)
    assert status == 2 and "mask/000007.png is not a readable image" in err
    assert sorted(os.listdir(tmp_path)) == ["broken"]


def test_an_error_while_the_bar_runs_starts_its_own_line(two_targets, tmp_path, capsys):
    """With the progress bar (no --quiet), the bar's line is cleared before the one-line error:
    a log of stderr shows ``cli.py: error: …`` at the start of a line, not after the bar."""
    broken = tmp_path / "broken"
    shutil.copytree(two_targets["icesat"][0], broken)
    (broken / "mask" / "000007.png").write_bytes(b"not a png")
    status = export_main(["--format", "bop", str(broken), "--out", str(tmp_path / "out"), "--workers", "1"])
    err = capsys.readouterr().err
    assert status == 2 and "export bop" in err  # the bar was drawn
    last = err.rstrip("\n").split("\n")[-1].split("\r")[-1]  # what a terminal shows on the last line
    assert last.startswith("cli.py: error: ") and "mask/000007.png is not a readable image" in last


# --------------------------------------------------------------------------- BOP, third-party views
def load_ply_like_bop_toolkit(path):
    """A reader following bop_toolkit ``inout.load_ply`` (bop_toolkit_lib/inout.py): header
    lines ``element vertex/face N``, vertex ``property TYPE NAME`` with TYPE one of its
    ``formats`` keys (float, double, int, uint, uchar; binary files are read by those and fail
    on any other), faces ``property list uchar int vertex_indices`` (other face properties only
    warn: their values are not consumed in a binary file); only triangles. Returns (points,
    normals, faces) or raises ValueError where load_ply would fail or misread."""
    formats = {"float": "f4", "double": "f8", "int": "i4", "uint": "u4", "uchar": "u1"}
    with open(path, "rb") as fh:
        lines = []
        while True:
            line = fh.readline().decode("utf8").rstrip("\n").rstrip("\r")
            lines.append(line)
            if line.startswith("end_header"):
                break
        body = fh.read()
    binary = any(ln.startswith("format") and "binary" in ln for ln in lines)
    n_pts = n_faces = 0
    section, pt_props, face_props = None, [], []
    for ln in lines:
        if ln.startswith("element vertex"):
            n_pts, section = int(ln.split()[-1]), "v"
        elif ln.startswith("element face"):
            n_faces, section = int(ln.split()[-1]), "f"
        elif ln.startswith("element"):
            section = None
        elif ln.startswith("property") and section == "v":
            pt_props.append((ln.split()[-1], ln.split()[-2]))
        elif ln.startswith("property list") and section == "f":
            face_props.append(ln.split())
        elif ln.startswith("property") and section == "f":
            raise ValueError(f"face property {ln!r} is not consumed by load_ply")
    if binary:
        if any(t not in formats for _, t in pt_props):
            raise ValueError(f"vertex property types {pt_props} outside load_ply's {sorted(formats)}")
        raise ValueError("binary: not what the export writes")
    if [p[-1] for p in face_props] != ["vertex_indices"]:
        raise ValueError(f"face properties {face_props}")
    rows = body.decode("utf8").splitlines()
    names = [n for n, _ in pt_props]
    verts = np.array([[float(x) for x in r.split()] for r in rows[:n_pts]])
    faces = np.array([[int(x) for x in r.split()] for r in rows[n_pts:n_pts + n_faces]])
    if not (faces[:, 0] == 3).all():
        raise ValueError("Only triangular faces are supported.")
    cols = {n: verts[:, i] for i, n in enumerate(names)}
    pts = np.column_stack([cols["x"], cols["y"], cols["z"]])
    normals = np.column_stack([cols["nx"], cols["ny"], cols["nz"]]) if "nx" in cols else None
    return pts, normals, faces[:, 1:4]


def test_bop_model_reads_as_bop_toolkit_reads_it(merged):
    out, targets = merged
    mesh = targets["icesat"][2].model.combined_mesh()
    for sub in ("models", "models_eval"):
        pts, normals, faces = load_ply_like_bop_toolkit(out / sub / "obj_000001.ply")
        assert_allclose(pts, mesh.vertices * 1000.0, atol=1e-3)
        assert_array_equal(faces, mesh.faces)
        assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)
    # the sequence's own PLY (binary, double vertices, a ushort face property) is what load_ply cannot read
    with pytest.raises(ValueError):
        load_ply_like_bop_toolkit(next((targets["icesat"][0] / "model").glob("*.ply")))


def rasterise(pts_mm, faces, K, R, t_mm, width, height):
    """Silhouette of a triangle mesh sampled at pixel centres (i + 0.5, j + 0.5) of a pinhole
    with matrix K, as OpenGL rasterises with the toolkit's projection (renderer_vispy.py,
    _calc_calib_proj): a pixel is covered when its centre lies inside a triangle's projection."""
    p = pts_mm @ R.T + t_mm
    uv = (p @ K.T)[:, :2] / p[:, 2:3]
    out = np.zeros((height, width), bool)
    tri = uv[faces]  # (n, 3, 2)
    # pixel i's centre i + 0.5 lies in [min, max] for i in [ceil(min − 0.5), floor(max − 0.5)]
    lo = np.maximum(np.ceil(tri.min(axis=1) - 0.5), 0).astype(int)
    hi = np.minimum(np.floor(tri.max(axis=1) - 0.5), [width - 1, height - 1]).astype(int)
    for k in np.flatnonzero((hi >= lo).all(axis=1)):  # triangles that can cover a pixel centre
        (x0, y0), (x1, y1) = lo[k], hi[k]
        xs, ys = np.meshgrid(np.arange(x0, x1 + 1) + 0.5, np.arange(y0, y1 + 1) + 0.5)
        a, b, c = tri[k]
        e0 = (b[0] - a[0]) * (ys - a[1]) - (b[1] - a[1]) * (xs - a[0])
        e1 = (c[0] - b[0]) * (ys - b[1]) - (c[1] - b[1]) * (xs - b[0])
        e2 = (a[0] - c[0]) * (ys - c[1]) - (a[1] - c[1]) * (xs - c[0])
        inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
        out[y0:y1 + 1, x0:x1 + 1] |= inside
    return out


def test_bop_cam_K_puts_the_toolkits_render_on_our_mask(merged):
    out, _ = merged
    pts, _, faces = load_ply_like_bop_toolkit(out / "models" / "obj_000001.ply")
    checked = inside = 0
    for split in ("train", "test"):
        for scene_dir in sorted((out / split).iterdir()):
            if scene_dir.name == "000001":
                continue  # the other model
            cams = json.loads((scene_dir / "scene_camera.json").read_text())
            gts = json.loads((scene_dir / "scene_gt.json").read_text())
            infos = json.loads((scene_dir / "scene_gt_info.json").read_text())
            for im, cam in cams.items():
                K = np.reshape(cam["cam_K"], (3, 3))
                gt = gts[im][0]
                R, t = np.reshape(gt["cam_R_m2c"], (3, 3)), np.asarray(gt["cam_t_m2c"])
                ours = read_image(scene_dir / "mask" / f"{int(im):06d}_000000.png") > 0
                theirs = rasterise(pts, faces, K, R, t, W, H)
                iou = (ours & theirs).sum() / (ours | theirs).sum()
                assert iou >= 0.99, (scene_dir, im, iou)
                # without the +0.5 the render is off by half a pixel: visibly worse
                K0 = K.copy()
                K0[:2, 2] -= 0.5
                shifted = rasterise(pts, faces, K0, R, t, W, H)
                assert (ours & shifted).sum() / (ours | shifted).sum() < iou
                # visib_fract as calc_gt_info makes it: the same render on the 3W × 3H canvas
                K_big = K.copy()
                K_big[0, 2] += W
                K_big[1, 2] += H
                n_all = rasterise(pts, faces, K_big, R, t, 3 * W, 3 * H).sum()
                assert_allclose(infos[im][0]["visib_fract"], theirs.sum() / n_all, atol=0.01)
                if infos[im][0]["visib_fract"] == 1.0:  # wholly in the image
                    assert theirs.sum() / n_all > 0.999
                    inside += 1
                checked += 1
    assert checked == 6 and inside >= 2


def test_bop_coco_annotations_read_by_pycocotools(merged):
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO

    out, _ = merged
    n = 0
    for scene_dir in sorted((out / "train").iterdir()) + sorted((out / "test").iterdir()):
        coco = COCO(str(scene_dir / "scene_gt_coco.json"))
        gts = json.loads((scene_dir / "scene_gt.json").read_text())
        infos = json.loads((scene_dir / "scene_gt_info.json").read_text())
        assert sorted(coco.getImgIds()) == sorted(int(i) for i in gts)
        for ann in coco.loadAnns(coco.getAnnIds()):
            im = ann["image_id"]
            img = coco.loadImgs(im)[0]
            assert (scene_dir / img["file_name"]).is_file()
            ours = read_image(scene_dir / "mask" / f"{im:06d}_000000.png") > 0
            assert_array_equal(coco.annToMask(ann).astype(bool), ours)
            rle = mask_utils.encode(np.asfortranarray(ours.astype(np.uint8)))
            assert mask_utils.area(rle) == ann["area"] == ours.sum()
            assert_allclose(mask_utils.toBbox(rle), ann["bbox"])  # [x, y, w, h], w counting pixels
            assert ann["category_id"] == gts[str(im)][0]["obj_id"]
            assert ann["ignore"] == (infos[str(im)][0]["visib_fract"] < 0.1)
            n += 1
    assert n == 9


def test_bop_test_targets(merged):
    out, _ = merged
    bop19 = json.loads((out / "test_targets_bop19.json").read_text())
    bop24 = json.loads((out / "test_targets_bop24.json").read_text())
    expected = []
    for scene_dir in sorted((out / "test").iterdir()):
        for im in sorted(int(i) for i in json.loads((scene_dir / "scene_gt.json").read_text())):
            expected.append({"im_id": im, "scene_id": int(scene_dir.name)})
    assert bop24 == expected and len(bop24) == 4
    for t in bop19:
        gt = json.loads((out / "test" / f"{t['scene_id']:06d}" / "scene_gt.json").read_text())[str(t["im_id"])]
        info = json.loads((out / "test" / f"{t['scene_id']:06d}" / "scene_gt_info.json").read_text())[str(t["im_id"])]
        assert t["obj_id"] == gt[0]["obj_id"] and t["inst_count"] == 1 and info[0]["visib_fract"] >= 0.1
    assert len(bop19) == sum(1 for e in expected if json.loads(
        (out / "test" / f"{e['scene_id']:06d}" / "scene_gt_info.json").read_text())[str(e["im_id"])][0]["visib_fract"]
        >= 0.1)
    assert not (out / "train" / "test_targets_bop19.json").exists()


@pytest.mark.parametrize("case", ["first_pixel", "last_column", "middle", "full"])
def test_rle_of_a_window_decodes_with_pycocotools(case):
    from pycocotools import mask as mask_utils

    m = np.zeros((7, 9), bool)
    x0, x1 = {"first_pixel": (0, 3), "last_column": (6, 9), "middle": (3, 6), "full": (0, 9)}[case]
    rng = np.random.default_rng(len(case))
    m[:, x0:x1] = rng.random((7, x1 - x0)) < 0.5
    m[0, x0] = True
    m[-1, x1 - 1] = case != "middle"
    rle = bop_module._rle(m, x0, x1)
    assert sum(rle["counts"]) == m.size
    decoded = mask_utils.decode(mask_utils.frPyObjects(rle, *rle["size"]))
    assert_array_equal(decoded.astype(bool), m)


def test_a_pool_of_workers_writes_the_same_bytes(merged, tmp_path, capsys):
    out, _ = merged
    record = json.loads((out / ".export.json").read_text())
    pooled = tmp_path / "bop"  # the same folder name: scene_gt_coco.json names the dataset
    assert run(["--format", "bop", *record["sequences"], "--out", str(pooled), "--split", "train=0.6,test=0.4",
                "--seed", "5", "--workers", "2"], capsys)[0] == 0
    assert tree(pooled) == tree(out)


def test_a_failure_while_writing_keeps_the_finished_part(two_targets, tmp_path, monkeypatch, capsys):
    ice = two_targets["icesat"][0]
    real = bop_module._export_frame
    calls = []

    def full_disk(job):
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        calls.append(job["im"])
        return real(job)

    monkeypatch.setattr(bop_module, "_export_frame", full_disk)
    out = tmp_path / "bop"
    status, _, err = run(["--format", "bop", str(ice), "--out", str(out), "--workers", "1"], capsys)
    assert status == 1 and "No space left on device" in err and "rerun the same command" in err
    assert (tmp_path / ".bop.export-partial").is_dir() and not out.exists()
    monkeypatch.setattr(bop_module, "_export_frame", lambda job: (calls.append(job["im"]), real(job))[1])
    assert run(["--format", "bop", str(ice), "--out", str(out), "--workers", "1"], capsys)[0] == 0
    assert len(calls) == 3 and sorted(os.listdir(tmp_path)) == ["bop"]


def test_a_second_export_into_the_same_folder_is_refused(two_targets, tmp_path, capsys):
    import fcntl

    fd = os.open(tmp_path / ".bop.export-lock", os.O_CREAT | os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)  # as a running export holds it (flock is per open file)
    try:
        status, _, err = run(["--format", "bop", str(two_targets["icesat"][0]), "--out", str(tmp_path / "bop"),
                              "--workers", "1"], capsys)
    finally:
        os.close(fd)
    assert status == 2 and "is being exported by another run" in err
    assert sorted(os.listdir(tmp_path)) == [".bop.export-lock"]


def test_cli_dispatches_export_and_calls_a_writer_with_the_shared_signature(two_targets, tmp_path, monkeypatch,
                                                                             capsys):
    """``cli.py export`` reaches the command; a format writer gets the staging folder, the splits
    as (sequence, frame) lists, modality, link and progress, and its folder becomes --out."""
    import cli
    from raytrace.export import command

    seen = {}

    def writer(tmp, splits, *, modality, link, progress=None):
        seen.update(tmp=tmp, splits={k: [(s.root, f.frame) for s, f in v] for k, v in splits.items()},
                    modality=modality, link=link)
        (tmp / "listing.txt").write_text(repr(seen["splits"]))
        if progress is not None:  # None with --quiet
            progress(sum(len(v) for v in splits.values()))

    monkeypatch.setattr(command, "_writer", lambda fmt: writer)
    ice, dragon = two_targets["icesat"][0], two_targets["spacedragon"][0]
    out = tmp_path / "sp"
    assert cli.main(["export", "--format", "speedplus", str(ice), str(dragon), "--out", str(out), "--split",
                     "train=1,val=1", "--split-by", "sequence", "--seed", "1", "--modality", "rgb_degraded",
                     "--copy", "--quiet"]) == 0
    order = np.random.default_rng(1).permutation(2)
    roots = [ice, dragon]
    assert seen["splits"] == {"train": [(roots[order[0]], k) for k in (0, 3, 7)],
                              "val": [(roots[order[1]], k) for k in (0, 3, 7)]}
    assert (seen["modality"], seen["link"]) == ("rgb_degraded", False)
    assert seen["tmp"] == tmp_path / ".sp.export-partial"
    assert (out / "listing.txt").is_file() and not seen["tmp"].exists()
    assert "2 sequence(s), 6 frames (train 3, val 3)" in capsys.readouterr().out
    assert cli.main(["export", "--format", "bop", str(ice), "--out", str(tmp_path / "x"), "--split", "train=2"]) == 2
    assert "argument --split: counts sum to 2 but there are 3 frame(s) to split" in capsys.readouterr().err


def test_cameras_of_different_sizes_merge_in_bop_not_in_speedplus(two_targets, tmp_path, monkeypatch, capsys):
    import tests.raytrace.test_export as te
    from raytrace.camera import Camera

    small = Camera(width=128, height=96, fx=110.0, fy=110.0, cx=63.5, cy=47.5)
    monkeypatch.setattr(te, "CAMERA", small)
    monkeypatch.setattr(te, "W", 128)
    monkeypatch.setattr(te, "H", 96)
    other = tmp_path / "small"
    te.make_sequence(other, two_targets["icesat"][2])
    ice = two_targets["icesat"][0]
    out = tmp_path / "bop"
    assert run(["--format", "bop", str(ice), str(other), "--out", str(out), "--workers", "1"], capsys)[0] == 0
    for scene, (w, h, K) in {0: (W, H, te.Camera(width=W, height=H, fx=145.0, fy=145.0, cx=79.5, cy=59.5).K),
                             1: (128, 96, small.K)}.items():
        scene_dir = out / "train" / f"{scene:06d}"
        cam = json.loads((scene_dir / "scene_camera.json").read_text())["3"]
        assert_allclose(np.reshape(cam["cam_K"], (3, 3)), K + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])
        assert read_image(scene_dir / "mask" / "000003_000000.png").shape == (h, w)
        coco = json.loads((scene_dir / "scene_gt_coco.json").read_text())
        assert {(i["width"], i["height"]) for i in coco["images"]} == {(w, h)}
    status, _, err = run(["--format", "speedplus", str(ice), str(other), "--out", str(tmp_path / "sp")], capsys)
    assert status == 2 and "has another camera (K, size or distCoeffs)" in err
    assert not (tmp_path / "sp").exists()


def test_an_export_killed_mid_way_resumes(two_targets, tmp_path):
    """``cli.py export`` as a program, killed with SIGKILL (a crash: no clean-up runs) once some
    frames are complete: the staging folder stays, the same command finishes the export, and
    no temporary file is left in it (nor one of the rerun: renaming a hard link onto another link
    of the same file, an image placed before the kill, does nothing and keeps the temporary)."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    src = two_targets["icesat"][0]
    seq = tmp_path / "long"
    shutil.copytree(src, seq, ignore=shutil.ignore_patterns("rgb*", "mask", "depth", "normal"))
    labels = [r for r in json.loads((src / "labels.json").read_text()) if r.get("files")]
    long = []
    for k in range(300):  # hard links of the three rendered frames
        rec = dict(labels[k % 3], frame=k, files={})
        for m, rel in labels[k % 3]["files"].items():
            (seq / m).mkdir(exist_ok=True)
            os.link(src / rel, seq / m / f"{k:06d}{Path(rel).suffix}")
            rec["files"][m] = f"{m}/{k:06d}{Path(rel).suffix}"
        long.append(rec)
    (seq / "labels.json").write_text(json.dumps(long))
    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "bop"
    cmd = [sys.executable, str(root / "cli.py"), "export", "--format", "bop", str(seq), "--out", str(out),
           "--workers", "1", "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(root))
    proc = subprocess.Popen(cmd, cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    records = tmp_path / ".bop.export-partial" / ".frames" / "train" / "000000"
    deadline = time.monotonic() + 120
    while proc.poll() is None and time.monotonic() < deadline:
        if records.is_dir() and len(os.listdir(records)) >= 20:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.01)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL, "the export finished before it could be killed"
    assert not out.exists() and (tmp_path / ".bop.export-partial" / ".export.json").is_file()
    done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    gt = json.loads((out / "train" / "000000" / "scene_gt.json").read_text())
    assert sorted(int(k) for k in gt) == list(range(300))
    leftovers = [n for _, _, names in os.walk(out) for n in names if ".tmp" in n]
    assert leftovers == [] and len(os.listdir(out / "train" / "000000" / "depth")) == 300
    assert sorted(os.listdir(tmp_path)) == ["bop", "long"]
