"""COCO export: object and part instance annotations with run-length masks and keypoints.

Format: T.-Y. Lin et al., "Microsoft COCO: Common Objects in Context", ECCV 2014,
doi:10.1007/978-3-319-10602-1_48; data format https://cocodataset.org/#format-data; masks,
areas and boxes as ``pycocotools.mask`` (https://github.com/cocodataset/cocoapi,
``PythonAPI/pycocotools/mask.py``: ``encode``, ``area``, ``toBbox``) computes them. Keypoint
coordinates as detectron2 reads and writes them (``detectron2/data/datasets/coco.py``:
``load_coco_json`` adds 0.5 to COCO keypoints, "pixel indices", ``convert_to_coco_dict``
subtracts it again).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model import SEMANTIC_CLASSES
from ._read import (
    _flag,
    _load_json,
    _modality,
    _place,
    _read_image,
    _read_sequence,
    _rendered,
    _staging,
)
from ._items import _check_splits, _frame_files, _image_stems

__all__ = ["COCO_KEYPOINT_VISIBILITY", "export_coco", "write_coco"]

COCO_KEYPOINT_VISIBILITY = {"visible": 2, "shadowed": 1, "occluded": 1, "outside": 0}
"""COCO keypoint flag v of each ``keypoints_state``: 2 labelled and visible; 1 labelled, not
visible (hidden by the target itself, or in its shadow: in line of sight but unlit, so not seen in
the picture); 0 not labelled (outside the image or behind the camera; x = y = 0)."""


# --------------------------------------------------------------------------- masks
def _rle(crop: np.ndarray, y0: int, x0: int, height: int, width: int) -> dict:
    """COCO run-length encoding (compressed, ``counts`` as str) of a (height, width) mask that is
    zero outside ``crop`` (bool, placed with its top-left pixel at row y0, column x0).

    Runs are counted in column-major order, zeros first, as ``pycocotools.mask.encode`` does;
    only the crop is scanned (a zero row above and below it keeps runs from crossing columns)."""
    from pycocotools import mask as mask_util

    h = crop.shape[0]
    padded = np.zeros((h + 2, crop.shape[1]), np.int8)
    padded[1:-1] = crop
    flat = padded.T.ravel()  # column-major
    step = np.diff(flat)
    start, end = np.flatnonzero(step == 1) + 1, np.flatnonzero(step == -1) + 1  # padded flat indices
    col_s, row_s = np.divmod(start, h + 2)
    col_e, row_e = np.divmod(end, h + 2)
    s = (x0 + col_s) * height + (y0 + row_s - 1)
    e = (x0 + col_e) * height + (y0 + row_e - 1)
    joined = e[:-1] == s[1:]  # a run down to the last row going on at the top of the next column
    s, e = s[np.r_[True, ~joined]], e[np.r_[~joined, True]]
    bounds = np.empty(2 * s.size + 2, np.int64)
    bounds[0], bounds[1:-1:2], bounds[2:-1:2], bounds[-1] = 0, s, e, height * width
    counts = np.diff(bounds).tolist()
    if counts[-1] == 0:  # as pycocotools: no empty run after a mask that reaches the last pixel
        counts.pop()
    rle = mask_util.frPyObjects({"size": [height, width], "counts": counts}, height, width)
    return {"size": [height, width], "counts": rle["counts"].decode("ascii")}


def _bbox(mask: np.ndarray) -> tuple | None:
    """(y0, x0, y1, x1) inclusive of a non-empty bool mask, None if empty."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]), int(cols[-1])


def _annotation(crop: np.ndarray, y0: int, x0: int, shape: tuple) -> dict:
    """segmentation (RLE), area (pixel count), bbox [x, y, w, h] (w = x_max − x_min + 1, as
    pycocotools toBbox) and iscrowd of a mask given by its crop."""
    rows, cols = np.flatnonzero(crop.any(axis=1)), np.flatnonzero(crop.any(axis=0))
    return {"segmentation": _rle(crop, y0, x0, *shape), "area": int(np.count_nonzero(crop)),
            "bbox": [x0 + int(cols[0]), y0 + int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)],
            "iscrowd": 0}


def _keypoints(seq, f, n: int) -> tuple[list, int]:
    """COCO ``keypoints`` [x1, y1, v1, ...] and ``num_keypoints`` of a frame. Coordinates are the
    label's ``keypoints_px`` unchanged: COCO keypoints are pixel indices (detectron2 adds 0.5 to
    reach the continuous coordinates in which a pixel's centre is at index + 0.5), which is this
    project's convention (integer values at pixel centres)."""
    if f.keypoints_px is None or len(f.keypoints_px) != n:
        got = "none" if f.keypoints_px is None else len(f.keypoints_px)
        raise ValueError(f"{seq.root / 'labels.json'}: frame {f.frame} must have keypoints_px for the {n} "
                         f"keypoints of model/keypoints.json, got {got}")
    out, count = [], 0
    for (u, v), state in zip(f.keypoints_px, f.keypoints_state):
        flag = COCO_KEYPOINT_VISIBILITY[state] if np.isfinite(u) else 0
        out += [float(u), float(v), flag] if flag else [0, 0, 0]
        count += flag > 0
    return out, count


# --------------------------------------------------------------------------- targets and parts
def _components(seq) -> dict | None:
    """Instance id → (component name, semantic class id) from scenario.json's target_model, None
    when scenario.json does not list the components."""
    path = seq.root / "scenario.json"
    if not path.is_file():
        return None
    comps = (_load_json(path, "scenario.json").get("target_model") or {}).get("components")
    if comps is None:
        return None
    out = {}
    for c in comps:
        if not isinstance(c, dict) or c.get("semantic") not in SEMANTIC_CLASSES or not isinstance(c.get("id"), int):
            raise ValueError(f"{path}: target_model.components entries must hold an integer id and a semantic "
                             f"class of raytrace.model.SEMANTIC_CLASSES, got {c!r}")
        out[c["id"]] = (str(c.get("name", c["id"])), SEMANTIC_CLASSES.index(c["semantic"]) + 1)
    return out


def _categories(sequences: list) -> tuple[list, dict]:
    """COCO object categories (one per target, by model file name) and sequence root → category id."""
    cats, by_name, of_seq = [], {}, {}
    for seq in sequences:
        name = seq.model_path.stem
        names = list(seq.keypoint_names or ())
        if name not in by_name:
            by_name[name] = len(cats) + 1
            cats.append({"id": len(cats) + 1, "name": name, "supercategory": "spacecraft",
                         "keypoints": names, "skeleton": []})
        elif cats[by_name[name] - 1]["keypoints"] != names:
            raise ValueError(f"{seq.root / 'model/keypoints.json'}: keypoint names differ from another sequence "
                             f"of target {name!r}; one category holds one keypoint set")
        of_seq[seq.root.resolve()] = by_name[name]
    return cats, of_seq


PART_CATEGORIES = [{"id": k + 1, "name": c, "supercategory": "part"} for k, c in enumerate(SEMANTIC_CLASSES)]
"""Categories of ``instances_parts_{split}.json``: every semantic class, id = the ``semantic``
modality's pixel value (raytrace.model.SEMANTIC_CLASSES index + 1)."""


# --------------------------------------------------------------------------- writer
def _write_compact(path: Path, content) -> None:
    """JSON without indentation (json's C encoder: an annotation file of thousands of frames
    writes in a fraction of the time), no NaN."""
    import json

    with open(path, "w", encoding="utf-8") as fh:
        json.dump(content, fh, separators=(",", ":"), allow_nan=False)
        fh.write("\n")


def write_coco(tmp: Path, splits: dict, *, modality: str, link: bool, progress=None) -> None:
    """Write sequences' frames as COCO instance annotations into the (staging) folder ``tmp``.

    Parameters
    ----------
    tmp : path-like
        Existing empty folder that receives the dataset.
    splits : dict of str → list of (_Sequence, _Frame)
        Split name → frames in order; every frame needs its ``modality`` picture and its ``mask``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        The picture that goes to ``images/{split}/``.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible.
    progress : callable or None, keyword-only
        Called with 1 after each frame.

    Notes
    -----
    Layout (``docs/formats.md``, "COCO")::

        annotations/instances_{split}.json        one annotation per frame whose mask is not empty
        annotations/instances_parts_{split}.json  one per (frame, component in view)
        images/{split}/{stem}.png                 stem: NNNNNN, or {sequence folder}_NNNNNN

    ``images``: id (unique over all splits), file_name (relative to ``images/{split}``), width,
    height, and ``sequence`` (folder name), ``frame``. Object ``categories``: one per target
    (model file name), with the ``keypoints`` names of ``model/keypoints.json`` (empty without)
    and ``skeleton`` []. Annotations: ``segmentation`` compressed RLE of the mask (id > 0),
    ``area`` its pixel count, ``bbox`` [x, y, w, h] with w = x_max − x_min + 1 (pycocotools
    ``toBbox``), ``iscrowd`` 0, and with keypoints ``keypoints`` (:func:`_keypoints`,
    :data:`COCO_KEYPOINT_VISIBILITY`) and ``num_keypoints`` (flags > 0). The parts file (written
    when every sequence's scenario.json lists its components) has :data:`PART_CATEGORIES` and
    one annotation per component in view (mask == instance id), ``category_id`` its semantic
    class, plus ``component`` (its name) and ``instance_id``.
    """
    from scipy import ndimage

    tmp = Path(tmp)
    splits = _check_splits(splits)
    modality = _modality(modality)
    link = _flag("link", link)
    sequences = {}
    for seq, _ in (it for its in splits.values() for it in its):
        sequences.setdefault(seq.root.resolve(), seq)
    categories, category_of = _categories(list(sequences.values()))
    components = {root: _components(seq) for root, seq in sequences.items()}
    with_parts = [c is not None for c in components.values()]
    if any(with_parts) and not all(with_parts):
        missing = next(r for r, c in components.items() if c is None)
        raise ValueError(f"{missing / 'scenario.json'} lists no target_model.components while other sequences "
                         f"do; part annotations need them for all sequences or none")
    stems = _image_stems(splits)
    (tmp / "annotations").mkdir()
    image_id = ann_id = part_id = 0
    for split, items in splits.items():
        folder = tmp / "images" / split
        folder.mkdir(parents=True)
        images, anns, parts = [], [], []
        for seq, f in items:
            root = seq.root.resolve()
            picture, mask_path = _frame_files(seq, f, (modality, "mask"))
            name = f"{stems[(root, f.frame)]}{picture.suffix.lower()}"
            _place(picture, folder / name, link)
            image_id += 1
            images.append({"id": image_id, "file_name": name, "width": seq.width, "height": seq.height,
                           "sequence": seq.root.name, "frame": f.frame})
            shape = (seq.height, seq.width)
            ids = _read_image(mask_path, "uint16", shape)
            box = _bbox(ids > 0)
            if box is not None:
                y0, x0, y1, x1 = box
                crop = ids[y0:y1 + 1, x0:x1 + 1]
                ann_id += 1
                ann = {"id": ann_id, "image_id": image_id, "category_id": category_of[root],
                       **_annotation(crop > 0, y0, x0, shape)}
                n = len(categories[category_of[root] - 1]["keypoints"])
                if n:
                    ann["keypoints"], ann["num_keypoints"] = _keypoints(seq, f, n)
                anns.append(ann)
                if components[root] is not None:
                    for k, sl in enumerate(ndimage.find_objects(crop), start=1):  # each id's bounding slices
                        if sl is None:
                            continue
                        if k not in components[root]:
                            raise ValueError(f"{mask_path} holds instance id {k}, which scenario.json's "
                                             f"target_model.components does not list")
                        part_id += 1
                        comp, semantic = components[root][k]
                        parts.append({"id": part_id, "image_id": image_id, "category_id": semantic,
                                      **_annotation(crop[sl] == k, y0 + sl[0].start, x0 + sl[1].start, shape),
                                      "component": comp, "instance_id": k})
            if progress is not None:
                progress(1)
        _write_compact(tmp / "annotations" / f"instances_{split}.json",
                    {"info": {"description": "orbitsynth COCO export"}, "licenses": [], "images": images,
                     "annotations": anns, "categories": categories})
        if all(with_parts):
            _write_compact(tmp / "annotations" / f"instances_parts_{split}.json",
                        {"info": {"description": "orbitsynth COCO export: spacecraft parts"}, "licenses": [],
                         "images": images, "annotations": parts, "categories": PART_CATEGORIES})


def export_coco(sequence_dir, out_dir, *, split: str = "train", modality: str = "rgb", link: bool = True) -> Path:
    """Write one sequence folder as a COCO dataset (:func:`write_coco` with one split).

    Parameters
    ----------
    sequence_dir : str or path-like
        Sequence folder (see :mod:`raytrace.export`).
    out_dir : str or path-like
        New (or empty) folder for the dataset; written all or nothing.
    split : str, keyword-only
        Split of all frames (``annotations/instances_{split}.json``). Default ``"train"``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        Which picture goes to ``images/{split}/``.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible (default True).

    Returns
    -------
    out_dir : pathlib.Path
        The dataset folder (layout: :func:`write_coco`). Frames that list no ``modality`` or
        ``mask`` file (not rendered) are left out.
    """
    seq = _read_sequence(sequence_dir)
    modality = _modality(modality)
    frames = _rendered(seq, (modality, "mask"))
    splits = _check_splits({split: [(seq, f) for f in frames]})
    with _staging(out_dir) as tmp:
        write_coco(tmp, splits, modality=modality, link=link)
    return Path(out_dir)
