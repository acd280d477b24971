"""BOP export (T. Hodaň et al., ECCV 2018; format: ``docs/bop_datasets_format.md`` and
``scripts/calc_gt_info.py`` of https://github.com/thodan/bop_toolkit)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..files import write_image
from ._read import (
    _diameter,
    _flag,
    _Frame,
    _frame_file,
    _hull_points,
    _load_mesh,
    _modality,
    _place,
    _read_image,
    _read_sequence,
    _render_scene,
    _rendered,
    _staging,
    _write_json,
)

__all__ = ["BOP_DEPTH_MAX_CODE", "export_bop"]

BOP_DEPTH_MAX_CODE = 60_000
"""Largest 16-bit depth code the chosen BOP ``depth_scale`` lets the farthest possible target
point reach (8 % below 65 535)."""


def _bop_bbox(cols: np.ndarray, rows: np.ndarray) -> list:
    """BOP [x, y, w, h] with w = x_max − x_min, h = y_max − y_min (bop_toolkit misc.calc_2d_bbox)."""
    return [int(cols.min()), int(rows.min()), int(cols.max() - cols.min()), int(rows.max() - rows.min())]


def _silhouette_beyond(scene, K: np.ndarray, width: int, height: int, R: np.ndarray, t: np.ndarray,
                       hull_m: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The target's silhouette on the image's pixel grid extended by one image size on every
    side (bop_toolkit calc_gt_info's 3W × 3H canvas), outside the image: (pixel count, columns,
    rows). Rays are cast only in the rectangle the projected model hull can cover."""
    from ..camera import Camera

    p = hull_m @ R.T + t
    u0, v0, u1, v1 = -width, -height, 2 * width, 2 * height  # canvas, end exclusive
    if np.all(p[:, 2] > 0):
        uvw = p @ K.T
        u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
        u0, u1 = max(u0, math.floor(u.min())), min(u1, math.ceil(u.max()) + 1)
        v0, v1 = max(v0, math.floor(v.min())), min(v1, math.ceil(v.max()) + 1)
    if u1 <= u0 or v1 <= v0:
        return 0, np.empty(0, np.int64), np.empty(0, np.int64)
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


# --------------------------------------------------------------------------- BOP
def export_bop(sequence_dir, out_dir, *, obj_id: int = 1, scene_id: int = 0, split: str = "train",
               modality: str = "rgb", link: bool = True) -> Path:
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

    Returns
    -------
    out_dir : pathlib.Path
        The dataset folder::

            camera.json                       fx, fy, cx, cy, width, height, depth_scale
            models/obj_{obj_id:06d}.ply       the mesh in millimetres (ASCII, vertex normals)
            models/models_info.json           diameter, min_x/y/z, size_x/y/z [mm]
            {split}/{scene_id:06d}/scene_camera.json   per image: cam_K (row-major), depth_scale
            {split}/{scene_id:06d}/scene_gt.json       per image: [{obj_id, cam_R_m2c, cam_t_m2c [mm]}]
            {split}/{scene_id:06d}/scene_gt_info.json  per image: [{bbox_obj, bbox_visib, px_count_*, visib_fract}]
            {split}/{scene_id:06d}/rgb/{im_id:06d}.png
            {split}/{scene_id:06d}/depth/{im_id:06d}.png       uint16, depth [mm] = value × depth_scale
            {split}/{scene_id:06d}/mask/{im_id:06d}_000000.png        0/255
            {split}/{scene_id:06d}/mask_visib/{im_id:06d}_000000.png  0/255

    Notes
    -----
    * ``im_id`` is the sequence's frame number; ``gt_id`` is 0 (one object per image).
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
    frames = _rendered(seq, (modality, "mask", "depth"))

    mesh = _load_mesh(seq.model_path)
    scene_rt = _render_scene(seq.model_path)
    vertices_m = np.asarray(mesh.vertices, dtype=np.float64)
    hull_m = _hull_points(vertices_m)
    z_max_m = max(float(np.max(hull_m @ f.R_cam_from_body[2] + f.t_cam_m[2])) for f in frames)
    depth_scale = _depth_scale(max(z_max_m, 1e-6) * 1000.0)
    K = seq.K

    with _staging(out_dir) as tmp:
        models = tmp / "models"
        models.mkdir()
        mesh_mm = mesh.copy()
        mesh_mm.apply_scale(1000.0)
        (models / f"obj_{obj_id:06d}.ply").write_bytes(_ply_bytes(mesh_mm))
        lo, hi = vertices_m.min(axis=0) * 1000.0, vertices_m.max(axis=0) * 1000.0
        _write_json(models / "models_info.json", {str(obj_id): {
            "diameter": _diameter(hull_m) * 1000.0,
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}})
        _write_json(tmp / "camera.json", {"cx": float(K[0, 2]), "cy": float(K[1, 2]), "depth_scale": depth_scale,
                                          "fx": float(K[0, 0]), "fy": float(K[1, 1]),
                                          "height": seq.height, "width": seq.width})

        scene = tmp / split / f"{scene_id:06d}"
        for sub in ("rgb", "depth", "mask", "mask_visib"):
            (scene / sub).mkdir(parents=True)
        scene_camera, scene_gt, scene_gt_info = {}, {}, {}
        shape = (seq.height, seq.width)
        for f in frames:
            im = f.frame
            src = _frame_file(seq, f, modality)
            _place(src, scene / "rgb" / f"{im:06d}{src.suffix.lower()}", link)

            ids = _read_image(_frame_file(seq, f, "mask"), "uint16", shape)
            depth_path = _frame_file(seq, f, "depth")
            depth_m = _read_image(depth_path, "float", shape)
            if np.isnan(depth_m).any() or (depth_m < 0).any():
                raise ValueError(f"{depth_path} must hold depths >= 0 [m] or inf, got NaN or negative values")
            codes = np.rint(depth_m.astype(np.float64) * (1000.0 / depth_scale))
            codes[~np.isfinite(codes) | (codes > 65535)] = 0  # background, or beyond 16 bits: no depth
            codes = codes.astype(np.uint16)
            write_image(str(scene / "depth" / f"{im:06d}.png"), codes)

            visib = ids > 0
            mask8 = np.where(visib, np.uint8(255), np.uint8(0))
            write_image(str(scene / "mask" / f"{im:06d}_000000.png"), mask8)
            write_image(str(scene / "mask_visib" / f"{im:06d}_000000.png"), mask8)

            scene_camera[str(im)] = {"cam_K": K.ravel().tolist(), "depth_scale": depth_scale}
            scene_gt[str(im)] = [{"cam_R_m2c": f.R_cam_from_body.ravel().tolist(),
                                  "cam_t_m2c": (f.t_cam_m * 1000.0).tolist(), "obj_id": obj_id}]
            scene_gt_info[str(im)] = [_gt_info(visib, codes, f, scene_rt, K, hull_m)]

        _write_json(scene / "scene_camera.json", scene_camera)
        _write_json(scene / "scene_gt.json", scene_gt)
        _write_json(scene / "scene_gt_info.json", scene_gt_info)
    return Path(out_dir)


def _gt_info(visib: np.ndarray, codes: np.ndarray, f: _Frame, scene, K: np.ndarray, hull_m: np.ndarray) -> dict:
    n_visib = int(np.count_nonzero(visib))
    n_valid = int(np.count_nonzero(visib & (codes > 0)))
    bbox_visib = bbox_obj = [-1, -1, -1, -1]
    # as calc_gt_info: px_count_all over the 3W × 3H canvas for every object, even one wholly
    # outside the image; the boxes only for a visible one
    n_out, cols_out, rows_out = _silhouette_beyond(scene, K, visib.shape[1], visib.shape[0],
                                                   f.R_cam_from_body, f.t_cam_m, hull_m)
    n_all = n_visib + n_out
    if n_visib > 0:
        rows, cols = np.nonzero(visib)
        bbox_visib = _bop_bbox(cols, rows)
        bbox_obj = _bop_bbox(np.concatenate([cols, cols_out]), np.concatenate([rows, rows_out]))
    return {"bbox_obj": bbox_obj, "bbox_visib": bbox_visib, "px_count_all": n_all, "px_count_valid": n_valid,
            "px_count_visib": n_visib, "visib_fract": n_visib / n_all if n_all > 0 else 0.0}


def _ply_bytes(mesh) -> bytes:
    from trimesh.exchange.ply import export_ply

    return export_ply(mesh, encoding="ascii", vertex_normal=True, include_attributes=False)


def _id_in_range(name: str, value, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= 999_999:
        raise ValueError(f"{name} must be an integer in [{lo}, 999999], got {value!r}")
    return int(value)
