"""BOP export (T. Hodaň et al., ECCV 2018; format: ``docs/bop_datasets_format.md``,
``scripts/calc_gt_info.py``, ``scripts/calc_gt_coco.py``, ``bop_toolkit_lib/pycoco_utils.py``
and ``bop_toolkit_lib/inout.py`` of https://github.com/thodan/bop_toolkit).

:func:`write_bop` writes any number of sequences, split into named subsets, into a staging
folder, frame by frame (in a process pool), resumably: each frame's files are written under a
temporary name and renamed, then its record ``.frames/{split}/{scene_id}/{im_id}.json``; a
frame whose record exists is not written again. The scene files are assembled from the records
at the end. :func:`export_bop` is the one-sequence form.

Camera matrix. This project's K puts pixel centres at integer coordinates; the toolkit's
renderers (``renderer_vispy.py``/``renderer_py.py``: ``_calc_calib_proj`` maps u = fx·x/z + cx
to OpenGL window coordinates, whose pixel i is covered when its centre i + 0.5 is, and the
read-back is flipped so that rows count from the top) put pixel i's centre at u = i + 0.5. So the
exported ``cam_K`` is K with cx + 0.5 and cy + 0.5: the toolkit then renders the model onto
the same pixels as our mask.
"""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np

from ..files import sha256_file
from ._atomic import place, write_bytes, write_data_png, write_json
from ._read import (
    _diameter,
    _flag,
    _frame_file,
    _hull_points,
    _load_mesh,
    _modality,
    _read_image,
    _read_sequence,
    _render_scene,
    _rendered,
    _staging,
)

__all__ = ["BOP_DEPTH_MAX_CODE", "BOP_PIXEL_CENTRE_SHIFT", "export_bop", "write_bop"]

BOP_DEPTH_MAX_CODE = 60_000
"""Largest 16-bit depth code the chosen BOP ``depth_scale`` lets the farthest possible target
point reach (8 % below 65 535)."""

BOP_PIXEL_CENTRE_SHIFT = 0.5
"""Added to cx and cy of K for ``cam_K`` (module docstring): the toolkit's pixel i has its centre at i + 0.5."""

BOP_VISIB_MIN = 0.1
"""``visib_fract`` below which calc_gt_coco.py marks an annotation ``ignore`` and below which
an instance is no BOP'19 localisation target."""

_NEEDED = ("mask", "depth")
_SPLIT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_RECORDS = ".frames"


def _bop_bbox(cols: np.ndarray, rows: np.ndarray) -> list:
    """BOP [x, y, w, h] with w = x_max − x_min, h = y_max − y_min (bop_toolkit misc.calc_2d_bbox)."""
    return [int(cols.min()), int(rows.min()), int(cols.max() - cols.min()), int(rows.max() - rows.min())]


def _silhouette_beyond(scene, K: np.ndarray, width: int, height: int, R: np.ndarray, t: np.ndarray,
                       hull_m: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The target's silhouette on the image's pixel grid extended by one image size on every
    side (bop_toolkit calc_gt_info's 3W × 3H canvas), outside the image: (pixel count, columns,
    rows). Rays are cast only in the rectangle the projected model hull can cover, and not at all
    when that rectangle holds no pixel centre outside the image (``scene`` is then not called:
    it may be a function returning the scene, built on first need)."""
    from ..camera import Camera

    empty = 0, np.empty(0, np.int64), np.empty(0, np.int64)
    p = hull_m @ R.T + t
    u0, v0, u1, v1 = -width, -height, 2 * width, 2 * height  # canvas, end exclusive
    if np.all(p[:, 2] > 0):
        uvw = p @ K.T
        u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
        # the silhouette lies within the hull's projection: no pixel centre (integers) outside the
        # image is covered when the projection stays within (-1, W) × (-1, H)
        if u.min() > -1 and u.max() < width and v.min() > -1 and v.max() < height:
            return empty
        u0, u1 = max(u0, math.floor(u.min())), min(u1, math.ceil(u.max()) + 1)
        v0, v1 = max(v0, math.floor(v.min())), min(v1, math.ceil(v.max()) + 1)
    if u1 <= u0 or v1 <= v0:
        return empty
    if callable(scene):
        scene = scene()
    window = Camera(width=u1 - u0, height=v1 - v0, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] - u0, cy=K[1, 2] - v0)
    rows, cols = np.nonzero(scene.render_geometry(window, R, t, visible_fraction=False).instance)
    rows, cols = rows + v0, cols + u0
    out = (cols < 0) | (cols >= width) | (rows < 0) | (rows >= height)
    return int(np.count_nonzero(out)), cols[out], rows[out]


def _depth_scale(max_depth_mm: float) -> float:
    """Smallest depth_scale in the 1-2-5 series with max_depth_mm/scale ≤ BOP_DEPTH_MAX_CODE [mm]."""
    need = max_depth_mm / BOP_DEPTH_MAX_CODE
    exponent = math.floor(math.log10(need)) if need > 0 else -3
    for k in range(max(exponent, -3), 10):
        for m in (1, 2, 5):
            scale = float(f"{m}e{k}")
            if scale >= need:
                return scale
    raise ValueError(f"depth of {max_depth_mm} mm does not fit a 16-bit BOP depth image")  # pragma: no cover


def _gt_info(visib: np.ndarray, codes: np.ndarray, R: np.ndarray, t: np.ndarray, scene, K: np.ndarray,
             hull_m: np.ndarray, box: tuple | None = None) -> dict:
    """calc_gt_info's record of one object; ``box`` = (x0, y0, x1, y1), end exclusive, holds
    every set pixel of ``visib`` (only that window is scanned; default the whole image)."""
    x0, y0, x1, y1 = box or (0, 0, visib.shape[1], visib.shape[0])
    visib_box = visib[y0:y1, x0:x1]
    n_visib = int(np.count_nonzero(visib_box))
    n_valid = int(np.count_nonzero(visib_box & (codes[y0:y1, x0:x1] > 0)))
    bbox_visib = bbox_obj = [-1, -1, -1, -1]
    # as calc_gt_info: px_count_all over the 3W × 3H canvas for every object, even one wholly
    # outside the image; the boxes only for a visible one
    n_out, cols_out, rows_out = _silhouette_beyond(scene, K, visib.shape[1], visib.shape[0], R, t, hull_m)
    n_all = n_visib + n_out
    if n_visib > 0:
        rows, cols = np.nonzero(visib_box)
        rows, cols = rows + y0, cols + x0
        bbox_visib = _bop_bbox(cols, rows)
        bbox_obj = _bop_bbox(np.concatenate([cols, cols_out]), np.concatenate([rows, rows_out]))
    return {"bbox_obj": bbox_obj, "bbox_visib": bbox_visib, "px_count_all": n_all, "px_count_valid": n_valid,
            "px_count_visib": n_visib, "visib_fract": n_visib / n_all if n_all > 0 else 0.0}


def _rle(mask: np.ndarray, x0: int = 0, x1: int | None = None) -> dict:
    """Uncompressed COCO RLE of a binary mask, as bop_toolkit ``pycoco_utils.binary_mask_to_rle``
    makes it: run lengths over the column-major (Fortran) order, starting with a run of zeros
    (0 when the first pixel is set). Columns outside [x0, x1) must be empty; only those inside
    are scanned."""
    H, W = mask.shape
    x1 = W if x1 is None else x1
    flat = mask[:, x0:x1].ravel(order="F")
    runs = []
    if flat.size:
        changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
        runs = np.diff(np.concatenate(([0], changes, [flat.size]))).tolist()
        if flat[0]:
            runs.insert(0, 0)
    else:
        runs = [0]
    runs[0] += x0 * H  # the empty columns before: zeros
    if len(runs) % 2 == 1:  # ends with zeros
        runs[-1] += (W - x1) * H
    elif W > x1:
        runs.append((W - x1) * H)
    return {"counts": runs, "size": [H, W]}


def _read_depth_rows(path: Path, y0: int, y1: int, shape: tuple) -> np.ndarray:
    """Rows y0 … y1 − 1 of a float depth image [m] (the rest is not decoded), checked against (H, W)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"{path} is not a readable image ({oiio.geterror()})")
    try:
        spec = inp.spec()
        if (spec.height, spec.width) != shape:
            raise ValueError(f"{path} must be {shape[1]}×{shape[0]} px (camera.json), got {spec.width}×{spec.height}")
        pixels = inp.read_scanlines(0, 0, y0, y1, 0, 0, 1, oiio.FLOAT)
    finally:
        inp.close()
    if pixels is None:
        raise ValueError(f"{path} is not a readable image ({oiio.geterror()})")
    depth = np.asarray(pixels).reshape(y1 - y0, shape[1])
    if np.isnan(depth).any() or (depth < 0).any():
        raise ValueError(f"{path} must hold depths >= 0 [m] or inf, got NaN or negative values")
    return depth


_SCENES = {}  # model path → its ray-tracing scene, built in this process on first need


def _scene_of(model_path: str):
    if model_path not in _SCENES:
        _SCENES.clear()  # one model at a time is enough: jobs come grouped by sequence
        _SCENES[model_path] = _render_scene(Path(model_path))
    return _SCENES[model_path]


def _export_frame(job: dict) -> dict:
    """Write one frame's images (rgb linked or copied, depth, mask, mask_visib) into its scene
    folder and its record; returns the record."""
    H, W = job["height"], job["width"]
    scene_dir, im = Path(job["scene_dir"]), job["im"]
    src = Path(job["rgb"])
    place(src, scene_dir / "rgb" / f"{im:06d}{src.suffix.lower()}", job["link"])
    visib = _read_image(Path(job["mask"]), "uint16", (H, W)) > 0
    codes = np.zeros((H, W), np.uint16)
    rows = np.flatnonzero(visib.any(axis=1))
    box = (0, 0, 0, 0)
    if rows.size:  # depth only where the target is: the rest of the rows are background (0)
        y0, y1 = int(rows[0]), int(rows[-1]) + 1
        cols = np.flatnonzero(visib[y0:y1].any(axis=0))
        box = (int(cols[0]), y0, int(cols[-1]) + 1, y1)
        z = np.rint(_read_depth_rows(Path(job["depth"]), y0, y1, (H, W)).astype(np.float64)
                    * (1000.0 / job["depth_scale"]))
        z[~np.isfinite(z) | (z > 65535)] = 0  # background, or beyond 16 bits: no depth
        codes[y0:y1] = z.astype(np.uint16)
    write_data_png(scene_dir / "depth" / f"{im:06d}.png", codes)
    mask_path = scene_dir / "mask" / f"{im:06d}_000000.png"
    write_data_png(mask_path, np.where(visib, np.uint8(255), np.uint8(0)))
    place(mask_path, scene_dir / "mask_visib" / f"{im:06d}_000000.png", True)

    R, t = np.asarray(job["R"]), np.asarray(job["t"])
    K = np.asarray(job["K"])
    info = _gt_info(visib, codes, R, t, lambda: _scene_of(job["model"]), K, np.asarray(job["hull"]), box)
    coco = None
    if info["px_count_visib"] > 0:
        x0, y0, x1, y1 = box
        coco = {"category_id": job["obj_id"], "iscrowd": 0, "area": info["px_count_visib"],
                "bbox": [x0, y0, x1 - x0, y1 - y0],  # pycoco_utils.bbox_from_binary_mask: w = x_max − x_min + 1
                "segmentation": _rle(visib, x0, x1), "width": W, "height": H,
                "ignore": info["visib_fract"] < BOP_VISIB_MIN}
    K_bop = K.copy()
    K_bop[:2, 2] += BOP_PIXEL_CENTRE_SHIFT
    record = {"im_id": im, "rgb": f"rgb/{im:06d}{src.suffix.lower()}", "width": W, "height": H,
              "camera": {"cam_K": K_bop.ravel().tolist(), "depth_scale": job["depth_scale"]},
              "gt": [{"cam_R_m2c": R.ravel().tolist(), "cam_t_m2c": (t * 1000.0).tolist(), "obj_id": job["obj_id"]}],
              "gt_info": [info], "coco": coco}
    write_json(Path(job["record"]), record, indent=None)
    return record


def _worker_init() -> None:
    """Pool worker: one thread for everything (the workers share the cores)."""
    import OpenImageIO as oiio

    from ..dataset.pool import _worker_init as pool_worker_init
    pool_worker_init(1)
    oiio.attribute("threads", 1)


def _run_jobs(jobs: list, workers: int, progress) -> list:
    """:func:`_export_frame` of every job, in this process (``workers`` 1) or a process pool."""
    if workers <= 1 or len(jobs) <= 1:
        out = []
        for job in jobs:
            out.append(_export_frame(job))
            if progress is not None:
                progress(1)
        return out
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from ..dataset.pool import _stop_workers
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init)
    try:
        out = []
        chunk = max(1, min(16, len(jobs) // (8 * workers)))
        for record in pool.map(_export_frame, jobs, chunksize=chunk):
            out.append(record)
            if progress is not None:
                progress(1)
    except BaseException:
        _stop_workers(pool)
        raise
    pool.shutdown(wait=True)
    return out


# --------------------------------------------------------------------------- models
def _ply_bytes(mesh) -> bytes:
    """ASCII PLY of the mesh in mm with vertex normals, as bop_toolkit's ``inout.save_ply`` writes
    models: ``float`` x y z nx ny nz, faces ``list uchar int vertex_indices``, nothing else (its
    ``load_ply`` reads only these types and face properties)."""
    from trimesh.exchange.ply import export_ply

    return export_ply(mesh, encoding="ascii", vertex_normal=True, include_attributes=False)


def _model_info(hull_mm: np.ndarray, vertices_mm: np.ndarray) -> dict:
    lo, hi = vertices_mm.min(axis=0), vertices_mm.max(axis=0)
    return {"diameter": _diameter(hull_mm),
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}


def _write_models(tmp: Path, models: dict) -> None:
    """``models/`` and ``models_eval/``: each distinct mesh in mm and ``models_info.json``."""
    infos = {}
    for obj_id, (path, mesh) in models.items():
        vertices_mm = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
        infos[str(obj_id)] = _model_info(_hull_points(vertices_mm), vertices_mm)
        data = None
        for sub in ("models", "models_eval"):
            dst = tmp / sub / f"obj_{obj_id:06d}.ply"
            if dst.is_file():
                continue
            if data is None:
                mesh_mm = mesh.copy()
                mesh_mm.apply_scale(1000.0)
                data = _ply_bytes(mesh_mm)
            dst.parent.mkdir(exist_ok=True)
            write_bytes(dst, data)
    for sub in ("models", "models_eval"):
        write_json(tmp / sub / "models_info.json", infos)


# --------------------------------------------------------------------------- writer
def _check_camera(seq) -> None:
    dist = seq.camera.get("distCoeffs")
    if dist is not None and any(float(d) != 0.0 for d in np.ravel(np.asarray(dist, dtype=object)) if d is not None):
        raise ValueError(f"{seq.root}: camera.json has non-zero distCoeffs {dist!r}; BOP has no lens distortion "
                         "(cam_K is a pinhole), export this sequence to another format")


def _scene_files(records: list, name: str, split: str, categories: list) -> dict:
    records = sorted(records, key=lambda r: r["im_id"])
    coco = {"info": {"description": f"{name}_{split}", "url": "https://github.com/thodan/bop_toolkit",
                     "version": "0.1.0"},
            "licenses": [], "categories": categories, "images": [], "annotations": []}
    for r in records:
        coco["images"].append({"id": r["im_id"], "file_name": r["rgb"], "width": r["width"], "height": r["height"]})
        if r["coco"] is not None:
            coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": r["im_id"], **r["coco"]})
    return {"scene_camera": {str(r["im_id"]): r["camera"] for r in records},
            "scene_gt": {str(r["im_id"]): r["gt"] for r in records},
            "scene_gt_info": {str(r["im_id"]): r["gt_info"] for r in records},
            "scene_gt_coco": coco}


def is_test_split(name: str) -> bool:
    """Whether a split is a test split for ``test_targets_bop19/24.json``: ``test`` or ``test_*``."""
    return name == "test" or name.startswith("test_")


def write_bop(tmp, splits: dict, *, modality: str, link: bool, progress=None, workers: int | None = None,
              sequences: list | None = None, scene_id_start: int = 0, obj_id_start: int = 1,
              name: str | None = None) -> None:
    """Write the (sequence, frame) items of ``splits`` as a BOP dataset into the folder ``tmp``.

    Parameters
    ----------
    tmp : path-like
        The (staging) folder; files already complete there from an interrupted run are kept.
    splits : dict
        Split name (folder: ``train``, ``val``, ``test``, ...) → list of ``(_Sequence, _Frame)``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        The image that goes to ``rgb/``.
    link : bool, keyword-only
        Hard-link images (else copy).
    progress : callable, optional
        ``progress(n)`` after every n frames written (or found complete).
    workers : int, optional
        Processes for the frames (default: the usable cores; 1: in this process).
    sequences : list of _Sequence, optional
        Order of the scene ids (default: as the sequences first appear in ``splits``);
        ``scene_id = scene_id_start + index``.
    obj_id_start : int
        Object id of the first distinct model (models told apart by their PLY's SHA-256).
    name : str, optional
        Dataset name for ``scene_gt_coco.json`` (default: the folder's name).

    Layout: see :func:`export_bop` (the root ``camera.json`` is the first sequence's camera with
    the largest ``depth_scale``: BOP's is for sensor simulation, each image's ``cam_K`` is in
    ``scene_camera.json``); besides ``models_eval/`` (the same meshes: for
    spacecraft there is no resampled model), ``scene_gt_coco.json`` per scene (calc_gt_coco.py,
    amodal boxes, RLE) and, when a split is named ``test`` or ``test_*``, ``test_targets_bop19.json``
    (instances with ``visib_fract`` ≥ 0.1) and ``test_targets_bop24.json`` (every image).
    """
    from .._threads import available_cores

    tmp = Path(tmp)
    modality = _modality(modality)
    link = _flag("link", link)
    workers = available_cores() if workers is None else int(workers)
    order = list(sequences) if sequences is not None else []
    for items in splits.values():
        for seq, _ in items:
            if not any(s is seq for s in order):
                order.append(seq)
    if not order:
        raise ValueError("splits must hold at least one (sequence, frame) item")
    for seq in order:
        _check_camera(seq)
    for split, items in splits.items():
        if not isinstance(split, str) or not _SPLIT_NAME.match(split) or split in ("models", "models_eval"):
            raise ValueError(f"split names must be folder names (letters, digits, '_', '-') other than models and "
                             f"models_eval, got {split!r}")
        for seq, f in items:
            missing = [m for m in (modality, *_NEEDED) if f.files.get(m) is None]
            if missing:
                raise ValueError(f"{seq.root}: labels.json frame {f.frame} lists no {', '.join(missing)} file")

    # models: one obj_id per distinct PLY; hull and farthest depth per sequence
    models, obj_of, hull_of = {}, {}, {}
    by_hash = {}
    for seq in order:
        digest = sha256_file(seq.model_path)
        if digest not in by_hash:
            obj_id = obj_id_start + len(by_hash)
            mesh = _load_mesh(seq.model_path)
            by_hash[digest] = (obj_id, _hull_points(np.asarray(mesh.vertices, dtype=np.float64)))
            models[obj_id] = (seq.model_path, mesh)
        obj_of[id(seq)], hull_of[id(seq)] = by_hash[digest]
    frames_of = {id(seq): [] for seq in order}
    for items in splits.values():
        for seq, f in items:
            frames_of[id(seq)].append(f)
    scale_of = {}
    for seq in order:
        hull = hull_of[id(seq)]
        z = [float(np.max(hull @ f.R_cam_from_body[2] + f.t_cam_m[2])) for f in frames_of[id(seq)]]
        scale_of[id(seq)] = _depth_scale(max(max(z, default=0.0), 1e-6) * 1000.0)

    _write_models(tmp, models)
    first = order[0]
    K0 = first.K
    write_json(tmp / "camera.json", {"cx": float(K0[0, 2]) + BOP_PIXEL_CENTRE_SHIFT,
                                     "cy": float(K0[1, 2]) + BOP_PIXEL_CENTRE_SHIFT,
                                     "depth_scale": max(scale_of.values()), "fx": float(K0[0, 0]),
                                     "fy": float(K0[1, 1]), "height": first.height, "width": first.width})

    jobs, records, done = [], {}, 0
    for split, items in splits.items():
        for seq, f in items:
            scene_id = scene_id_start + next(i for i, s in enumerate(order) if s is seq)
            scene_dir = tmp / split / f"{scene_id:06d}"
            rec_path = tmp / _RECORDS / split / f"{scene_id:06d}" / f"{f.frame:06d}.json"
            key = (split, scene_id)
            records.setdefault(key, [])
            if rec_path.is_file():  # complete in an interrupted run
                records[key].append(_load_record(rec_path))
                done += 1
                continue
            if not rec_path.parent.is_dir():
                for sub in ("rgb", "depth", "mask", "mask_visib"):
                    (scene_dir / sub).mkdir(parents=True, exist_ok=True)
                rec_path.parent.mkdir(parents=True, exist_ok=True)
            jobs.append((key, {
                "im": f.frame, "width": seq.width, "height": seq.height, "scene_dir": str(scene_dir),
                "record": str(rec_path), "rgb": str(_frame_file(seq, f, modality)),
                "mask": str(_frame_file(seq, f, "mask")), "depth": str(_frame_file(seq, f, "depth")),
                "link": link, "K": seq.K.tolist(), "R": f.R_cam_from_body.tolist(), "t": f.t_cam_m.tolist(),
                "depth_scale": scale_of[id(seq)], "obj_id": obj_of[id(seq)], "model": str(seq.model_path),
                "hull": hull_of[id(seq)]}))
    if progress is not None and done:
        progress(done)
    for (key, _), record in zip(jobs, _run_jobs([j for _, j in jobs], workers, progress)):
        records[key].append(record)

    name = name or tmp.name
    categories = [{"id": obj_id, "name": str(obj_id), "supercategory": name} for obj_id in models]
    for (split, scene_id), recs in records.items():
        scene_dir = tmp / split / f"{scene_id:06d}"
        for fname, content in _scene_files(recs, name, split, categories).items():
            # the RLE counts would take a line each: the COCO file is written compact
            write_json(scene_dir / f"{fname}.json", content, indent=None if fname == "scene_gt_coco" else 1)
    _write_test_targets(tmp, records)
    shutil.rmtree(tmp / _RECORDS, ignore_errors=True)


def _load_record(path: Path) -> dict:
    import json

    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _write_test_targets(tmp: Path, records: dict) -> None:
    """``test_targets_bop19.json`` ([{im_id, inst_count, obj_id, scene_id}], instances with
    visib_fract ≥ 0.1) and ``test_targets_bop24.json`` ([{im_id, scene_id}], every image) of the
    test splits (bop_toolkit ``scripts/eval_calc_errors.py`` reads both)."""
    bop19, bop24 = [], []
    for (split, scene_id), recs in sorted(records.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        if not is_test_split(split):
            continue
        for r in sorted(recs, key=lambda r: r["im_id"]):
            bop24.append({"im_id": r["im_id"], "scene_id": scene_id})
            counts = {}
            for gt, info in zip(r["gt"], r["gt_info"]):
                if info["visib_fract"] >= BOP_VISIB_MIN:
                    counts[gt["obj_id"]] = counts.get(gt["obj_id"], 0) + 1
            bop19.extend({"im_id": r["im_id"], "inst_count": n, "obj_id": o, "scene_id": scene_id}
                         for o, n in sorted(counts.items()))
    if bop24:
        write_json(tmp / "test_targets_bop19.json", bop19)
        write_json(tmp / "test_targets_bop24.json", bop24)


# --------------------------------------------------------------------------- one sequence
def export_bop(sequence_dir, out_dir, *, obj_id: int = 1, scene_id: int = 0, split: str = "train",
               modality: str = "rgb", link: bool = True, workers: int = 1) -> Path:
    """Write a sequence folder as a BOP dataset with one object and one scene.

    Parameters
    ----------
    sequence_dir : str or path-like
        Sequence folder (see the module docstring).
    out_dir : str or path-like
        New (or empty) folder for the dataset.
    obj_id : int, keyword-only
        BOP object id of the target, 1 … 999 999. Default 1.
    scene_id : int, keyword-only
        BOP scene id of the sequence, 0 … 999 999. Default 0.
    split : str, keyword-only
        Split folder name (``train``, ``val``, ``test``, optionally with a type suffix such
        as ``train_pbr``). Default ``"train"``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        Which image goes to ``rgb/``: the clean render or the degraded one.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible (default True).
    workers : int, keyword-only
        Processes writing the frames (default 1: this one).

    Returns
    -------
    out_dir : pathlib.Path
        The dataset folder::

            camera.json                       fx, fy, cx, cy (+0.5), width, height, depth_scale
            models/obj_{obj_id:06d}.ply       the mesh in millimetres (ASCII, vertex normals)
            models/models_info.json           diameter, min_x/y/z, size_x/y/z [mm]
            models_eval/                      the same
            {split}/{scene_id:06d}/scene_camera.json   per image: cam_K (row-major, cx, cy + 0.5), depth_scale
            {split}/{scene_id:06d}/scene_gt_coco.json  COCO: images, annotations (RLE, amodal box)
            {split}/{scene_id:06d}/scene_gt.json       per image: [{obj_id, cam_R_m2c, cam_t_m2c [mm]}]
            {split}/{scene_id:06d}/scene_gt_info.json  per image: [{bbox_obj, bbox_visib, px_count_*, visib_fract}]
            {split}/{scene_id:06d}/rgb/{im_id:06d}.png
            {split}/{scene_id:06d}/depth/{im_id:06d}.png       uint16, depth [mm] = value × depth_scale
            {split}/{scene_id:06d}/mask/{im_id:06d}_000000.png        0/255
            {split}/{scene_id:06d}/mask_visib/{im_id:06d}_000000.png  0/255

    Notes
    -----
    * ``im_id`` is the sequence's frame number; ``gt_id`` is 0 (one object per image).
    * ``cam_K`` is K with cx, cy + 0.5 (:data:`BOP_PIXEL_CENTRE_SHIFT`, the module docstring):
      the toolkit's renderers put pixel centres at i + 0.5, this project at integers.
    * Pose: ``cam_R_m2c = R_cam_from_body`` (row-major), ``cam_t_m2c = 1000 · t_cam_m``
      (docs/conventions.md). The model frame is the target's body frame (origin at the centre of
      mass, not at the bounding-box centre BOP models usually use; poses refer to this frame).
    * Depth: z-depth [mm] = code × ``depth_scale``, rounded to the nearest code; 0 where the
      render has no target (inf) or the depth would overflow 16 bits. ``depth_scale`` is one
      value for the scene, the smallest of 1, 2, 5 × 10^k mm that keeps the farthest possible
      target point — max over frames and model hull vertices of the camera-frame z — at or
      below :data:`BOP_DEPTH_MAX_CODE`; the quantisation error is ≤ depth_scale/2.
    * ``mask`` and ``mask_visib`` are the same image. BOP's ``mask`` is the full silhouette
      of the object within the image and ``mask_visib`` the part not hidden by *other*
      objects; there is only one rigid object here and a silhouette already includes the
      parts the object hides of itself, so the two coincide (the render's mask > 0).
    * ``scene_gt_info`` follows ``bop_toolkit/scripts/calc_gt_info.py``: boxes are
      [x, y, w, h] with w = x_max − x_min and h = y_max − y_min (pixel indices, not counts;
      labels.json's ``bbox`` counts pixels, w = x_max − x_min + 1); ``[-1, -1, -1, -1]`` when
      nothing is visible. ``px_count_visib``, ``bbox_visib``: the mask; ``px_count_valid``:
      mask pixels with a non-zero depth code. ``px_count_all`` and ``bbox_obj`` count the
      whole silhouette, including its part outside the image: as calc_gt_info does, the
      model (from ``model/``) is ray-traced on the image's pixel grid extended by one image
      width and height on every side (only where its projected hull falls) and the pixels
      outside the image are added to the mask. ``visib_fract`` = ``px_count_visib /
      px_count_all``: the share of the silhouette inside the image (there is nothing else to
      occlude the target). A projection of the model vertices would not do for ``bbox_obj``:
      parts thinner than a pixel (booms, antennas) reach beyond the pixels the silhouette
      covers.
    """
    seq = _read_sequence(sequence_dir)
    dist = seq.camera.get("distCoeffs")
    if isinstance(dist, list) and any(v != 0 for v in dist):
        raise ValueError(f"BOP has no lens distortion: camera.json distCoeffs is {dist!r} (export a sequence "
                         "rendered without --distortion)")
    obj_id = _id_in_range("obj_id", obj_id, 1)
    scene_id = _id_in_range("scene_id", scene_id, 0)
    if not isinstance(split, str) or not split or any(c in split for c in "/\\") or split.startswith("."):
        raise ValueError(f"split must be a folder name such as 'train', 'val' or 'test', got {split!r}")
    modality = _modality(modality)
    link = _flag("link", link)
    _check_camera(seq)
    frames = _rendered(seq, (modality, *_NEEDED))
    with _staging(out_dir) as tmp:
        write_bop(tmp, {split: [(seq, f) for f in frames]}, modality=modality, link=link, workers=workers,
                  scene_id_start=scene_id, obj_id_start=obj_id, name=Path(out_dir).name)
    return Path(out_dir)


def _id_in_range(name: str, value, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= 999_999:
        raise ValueError(f"{name} must be an integer in [{lo}, 999999], got {value!r}")
    return int(value)
