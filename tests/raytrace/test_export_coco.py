"""COCO export read with pycocotools (https://github.com/cocodataset/cocoapi): ``COCO`` loads the
files, ``annToMask`` / ``mask.encode`` / ``toBbox`` / ``area`` decode and recompute the masks,
``COCOeval`` scores the annotations against themselves. Answers come from the fixture's render
(instance ids, the separately rendered semantic classes) and its OpenCV-projected keypoints,
never from the exporter. Keypoint pixel convention: detectron2 ``data/datasets/coco.py``
(``load_coco_json``) reads a COCO keypoint as a pixel index and adds 0.5 to reach continuous
coordinates in which pixel i spans [i, i + 1).
"""

import contextlib
import io
import json
import shutil

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from pycocotools import mask as mask_util
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from raytrace.export._read import _read_sequence, _staging
from raytrace.export.coco import export_coco, write_coco
from raytrace.model import SEMANTIC_CLASSES
from tests.raytrace.keypoint_sequence import N_SURFACE, H, W, make_sequence

pytestmark = pytest.mark.filterwarnings(  # pycocotools' own decode under numpy 2
    "ignore:__array__ implementation doesn't accept a copy keyword:DeprecationWarning")
FLAG = {"visible": 2, "shadowed": 1, "occluded": 1, "outside": 0}


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("seq") / "icesat_seq"
    geometry, kp_body, scene = make_sequence(root)
    return root, geometry, kp_body, scene


@pytest.fixture(scope="module")
def exported(sequence, tmp_path_factory):
    out = export_coco(sequence[0], tmp_path_factory.mktemp("coco") / "coco")
    with contextlib.redirect_stdout(io.StringIO()):
        objects = COCO(str(out / "annotations" / "instances_train.json"))
        parts = COCO(str(out / "annotations" / "instances_parts_train.json"))
    return out, objects, parts


def by_frame(coco):
    return {img["frame"]: img for img in coco.dataset["images"]}


def test_images_and_object_masks(exported, sequence):
    out, coco, _ = exported
    root, geometry, _, _ = sequence
    labels = {r["frame"]: r for r in json.loads((root / "labels.json").read_text())}
    images = by_frame(coco)
    assert sorted(images) == sorted(geometry)  # frame 1 (no files) left out, frame 9 (empty) kept
    for frame, (_, _, g) in geometry.items():
        img = images[frame]
        assert (img["width"], img["height"], img["file_name"]) == (W, H, f"{frame:06d}.png")
        assert (out / "images" / "train" / img["file_name"]).read_bytes() == \
            (root / "rgb" / f"{frame:06d}.png").read_bytes()
        anns = coco.loadAnns(coco.getAnnIds(imgIds=[img["id"]]))
        target = (g.instance > 0).astype(np.uint8)
        if not target.any():
            assert anns == []  # an empty mask: the image, no annotation
            continue
        ann, = anns
        assert_array_equal(coco.annToMask(ann), target)
        rle = coco.annToRLE(ann)
        assert rle["counts"] == mask_util.encode(np.asfortranarray(target))["counts"].decode("ascii")
        assert list(mask_util.toBbox(rle)) == ann["bbox"] == labels[frame]["bbox"]
        assert ann["area"] == int(mask_util.area(rle)) == int(target.sum())
        assert ann["iscrowd"] == 0 and coco.loadCats(ann["category_id"])[0]["name"] == "icesat"


def test_keypoints(exported, sequence):
    _, coco, _ = exported
    root, geometry, _, _ = sequence
    cat, = coco.dataset["categories"]
    names = json.loads((root / "model" / "keypoints.json").read_text())["names"]
    assert (cat["keypoints"], cat["skeleton"], cat["supercategory"]) == (names, [], "spacecraft")
    labels = {r["frame"]: r for r in json.loads((root / "labels.json").read_text())}
    images = by_frame(coco)
    seen = set()
    for frame, rec in labels.items():
        if frame not in geometry or rec["bbox"] is None:
            continue
        ann, = coco.loadAnns(coco.getAnnIds(imgIds=[images[frame]["id"]]))
        kp = np.reshape(ann["keypoints"], (-1, 3))
        mask = coco.annToMask(ann)
        assert len(kp) == len(names)
        for i, (px, state) in enumerate(zip(rec["keypoints_px"], rec["keypoints_state"])):
            x, y, v = kp[i]
            seen.add(state)
            assert v == FLAG[state]
            if v == 0:
                assert (x, y) == (0, 0)
                continue
            assert (x, y) == tuple(px)  # COCO keypoints are pixel indices: this project's pixel centres
            if i < N_SURFACE:  # detectron2's continuous coordinate x + 0.5 falls in a pixel of the silhouette
                assert mask[int(np.floor(y + 0.5)), int(np.floor(x + 0.5))] == 1
        assert ann["num_keypoints"] == int(np.count_nonzero(kp[:, 2]))
    assert seen == set(FLAG)  # every state met


def test_parts_against_instance_ids_and_the_semantic_render(exported, sequence):
    _, _, parts = exported
    root, geometry, _, scene = sequence
    assert [c["name"] for c in parts.dataset["categories"]] == list(SEMANTIC_CLASSES)
    images = by_frame(parts)
    for frame, (_, _, g) in geometry.items():
        anns = parts.loadAnns(parts.getAnnIds(imgIds=[images[frame]["id"]]))
        assert sorted(a["instance_id"] for a in anns) == sorted(set(np.unique(g.instance).tolist()) - {0})
        union = np.zeros((H, W), np.uint8)
        for a in anns:
            comp = scene.model.components[a["instance_id"] - 1]
            assert (a["component"], a["category_id"]) == (comp.name, comp.semantic_id)
            m = parts.annToMask(a)
            assert_array_equal(m, (g.instance == a["instance_id"]).astype(np.uint8))
            assert list(mask_util.toBbox(parts.annToRLE(a))) == a["bbox"] and a["area"] == int(m.sum())
            union[m == 1] = a["category_id"]
        assert_array_equal(union, g.semantic)  # the part classes rendered on their own


def test_cocoeval_scores_the_annotations_against_themselves(exported):
    _, coco, parts = exported
    out = io.StringIO()
    for gt, kinds in ((coco, ("segm", "bbox", "keypoints")), (parts, ("segm",))):
        dets = [dict(a, score=1.0) for a in gt.dataset["annotations"]]
        with contextlib.redirect_stdout(out):
            dt = gt.loadRes(dets)
            for kind in kinds:
                ev = COCOeval(gt, dt, kind)
                if kind == "keypoints":
                    ev.params.kpt_oks_sigmas = np.full(len(gt.dataset["categories"][0]["keypoints"]), 0.05)
                ev.evaluate()
                ev.accumulate()
                ev.summarize()
                assert ev.stats[0] == pytest.approx(1.0), kind  # AP at IoU/OKS .50:.95


def test_two_sequences_two_splits_two_targets(sequence, tmp_path):
    root = sequence[0]
    other = tmp_path / "other_seq"
    shutil.copytree(root, other)
    (other / "model" / "icesat.ply").rename(other / "model" / "icesat_b.ply")  # another target name
    a, b = _read_sequence(root), _read_sequence(other)
    calls = []
    with _staging(tmp_path / "out") as tmp:
        write_coco(tmp, {"train": [(a, f) for f in a.frames if f.files],
                         "val": [(b, f) for f in b.frames if f.files][:2]},
                   modality="rgb_degraded", link=True, progress=calls.append)
    assert calls == [1] * 6
    out = tmp_path / "out"
    docs = {s: json.loads((out / "annotations" / f"instances_{s}.json").read_text()) for s in ("train", "val")}
    assert docs["train"]["categories"] == docs["val"]["categories"]
    assert [c["name"] for c in docs["train"]["categories"]] == ["icesat", "icesat_b"]
    assert {a["category_id"] for a in docs["val"]["annotations"]} == {2}
    ids = [i["id"] for d in docs.values() for i in d["images"]]
    assert len(ids) == len(set(ids)) == 6
    assert [i["file_name"] for i in docs["val"]["images"]] == ["other_seq_000000.png", "other_seq_000003.png"]
    for s, d in docs.items():
        for img in d["images"]:
            src = (root if s == "train" else other) / "rgb_degraded" / f"{img['frame']:06d}.png"
            assert (out / "images" / s / img["file_name"]).read_bytes() == src.read_bytes()


@pytest.mark.parametrize("change, match", [
    (lambda d: d.joinpath("labels.json").write_text(d.joinpath("labels.json").read_text().replace(
        '"keypoints_state": ["visible"', '"keypoints_state": ["lit"')), "keypoints_state must hold"),
    (lambda d: d.joinpath("scenario.json").write_text(json.dumps({"target_model": {"components": [
        {"id": 1, "name": "bus", "semantic": "bus"}]}})), "holds instance id .* does not list"),
    (lambda d: d.joinpath("model", "keypoints.json").write_text(json.dumps({
        "frame": "body", "unit": "m", "source": "x", "names": ["a"], "points_body_m": [[0, 0, 0]]})),
     "must have keypoints_px for the 1 keypoints"),
])
def test_bad_input_leaves_nothing(sequence, tmp_path, change, match):
    broken = tmp_path / "broken"
    shutil.copytree(sequence[0], broken)
    change(broken)
    with pytest.raises(ValueError, match=match):
        export_coco(broken, tmp_path / "deeper" / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken"]


def test_run_lengths_from_a_crop_equal_pycocotools_encode():
    """The exporter counts runs in the mask's bounding box only; pycocotools encodes the whole image.
    Random masks, masks filling whole columns (runs that go on into the next column) and the full image."""
    from raytrace.export.coco import _rle

    rng = np.random.default_rng(3)
    for trial in range(600):
        h, w = (int(n) for n in rng.integers(1, 14, 2))
        m = rng.random((h, w)) < rng.random()
        if trial % 5 == 0:
            m[:, : w // 2 + 1] = True
        if trial % 7 == 0:
            m[:] = True
        if not m.any():
            continue
        rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
        crop = m[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
        ours = _rle(crop, int(rows[0]), int(cols[0]), h, w)
        assert ours["counts"] == mask_util.encode(np.asfortranarray(m.astype(np.uint8)))["counts"].decode("ascii")
        assert ours["size"] == [h, w]
