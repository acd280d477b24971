"""Export a rendered sequence folder to the BOP and SPEED+ dataset formats.

Input: a sequence folder as the pipeline writes it — ``camera.json`` (``K``, ``width``,
``height``; SPEED+ fields ``cameraMatrix``, ``distCoeffs``, ``Nu``, ``Nv``), ``labels.json``
(a list of per-frame records, or an object whose ``"frames"`` holds that list: ``frame``,
``R_cam_from_body`` (9 numbers, row-major), ``t_cam_m``, ``q_cam_from_body``, ``files``:
modality → path relative to the folder), the images ``rgb/``, ``rgb_degraded/``, ``mask/``
(uint16 component ids, 0 background), ``depth/`` (float32 z-depth [m], inf on background)
and ``model/`` holding the rendered mesh as one PLY in metres. Pose convention
(docs/conventions.md): ``p_cam = R_cam_from_body @ p_body + t_cam_m``, OpenCV camera axes,
integer pixel coordinates at pixel centres.

Frames whose ``files`` lack an image the export needs (frames the pipeline did not render)
are left out; a file that is listed but missing or unreadable is an error.

Both exports are all or nothing: everything is written into a hidden temporary folder next
to ``out_dir`` (same file system) and renamed to ``out_dir`` at the end; on any failure the
temporary folder (and any parent folder the call created) is removed. ``out_dir`` must not
exist yet, or be an empty folder. Errors about the input are ``ValueError`` naming the file
and what is wrong with it.

References
----------
T. Hodaň et al., "BOP: Benchmark for 6D Object Pose Estimation", ECCV 2018,
doi:10.1007/978-3-030-01249-6_2; format: ``docs/bop_datasets_format.md`` and
``scripts/calc_gt_info.py`` of https://github.com/thodan/bop_toolkit.

T. H. Park, M. Märtens, G. Lecuyer, D. Izzo, S. D'Amico, "SPEED+: Next-Generation Dataset
for Spacecraft Pose Estimation across Domain Gap", IEEE Aerospace Conference 2022,
doi:10.1109/AERO53065.2022.9843439; label convention as used by the authors' baseline
(https://github.com/tpark94/speedplusbaseline, ``src/utils/utils.py``: ``quat2dcm``,
``project_keypoints``).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._checks import finite_numbers
from .dataset.modalities import PICTURES
from .files import process_folder, remove_stale_process_folders, write_image

__all__ = ["BOP_DEPTH_MAX_CODE", "export_bop", "export_speedplus"]

BOP_DEPTH_MAX_CODE = 60_000
"""Largest 16-bit depth code the chosen BOP ``depth_scale`` lets the farthest possible target
point reach (8 % below 65 535)."""

_IMAGE_MODALITIES = PICTURES
_ROTATION_TOL = 1e-6


# --------------------------------------------------------------------------- reading
@dataclass(frozen=True, slots=True)
class _Frame:
    """One labelled frame of a sequence."""

    frame: int
    R_cam_from_body: np.ndarray  # (3, 3) float64
    t_cam_m: np.ndarray  # (3,) float64
    q_cam_from_body: np.ndarray  # (4,) float64, Hamilton, scalar first
    files: dict


@dataclass(frozen=True, slots=True)
class _Sequence:
    """What the exporters need from a sequence folder."""

    root: Path
    camera: dict
    K: np.ndarray  # (3, 3) float64 [px]
    width: int
    height: int
    frames: tuple
    model_path: Path


def _load_json(path: Path, what: str):
    if not path.is_file():
        raise ValueError(f"{what}: {path} is missing")
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{what}: {path} is not readable JSON ({exc})") from None


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Hamilton quaternion [q0, q1, q2, q3] (scalar first, q0 ≥ 0) of the active rotation R."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()  # scipy: scalar last
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def _matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Active rotation matrix R(q) of a unit Hamilton quaternion, scalar first."""
    q0, q1, q2, q3 = q
    return np.array([
        [1 - 2 * (q2 * q2 + q3 * q3), 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), 1 - 2 * (q1 * q1 + q3 * q3), 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 1 - 2 * (q1 * q1 + q2 * q2)],
    ])


def _parse_frame(i: int, rec) -> _Frame:
    where = f"labels.json frame record {i}"
    is_object = isinstance(rec, dict)  # ValueError at public boundaries, also for a type
    if not is_object:
        raise ValueError(f"{where} must be a JSON object, got {type(rec).__name__}")
    missing = [k for k in ("frame", "R_cam_from_body", "t_cam_m") if k not in rec]
    if missing:
        raise ValueError(f"{where} lacks {', '.join(missing)}")
    frame = rec["frame"]
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        raise ValueError(f"{where}: frame must be an integer >= 0, got {frame!r}")
    where = f"labels.json frame {frame}"
    R = finite_numbers(f"{where}: R_cam_from_body", rec["R_cam_from_body"], 9).reshape(3, 3)
    if not np.allclose(R @ R.T, np.eye(3), atol=_ROTATION_TOL) or np.linalg.det(R) < 0:
        raise ValueError(f"{where}: R_cam_from_body must be a rotation matrix (orthonormal, det +1)")
    t = finite_numbers(f"{where}: t_cam_m", rec["t_cam_m"], 3)
    if rec.get("q_cam_from_body") is None:
        q = _quat_from_matrix(R)
    else:
        q = finite_numbers(f"{where}: q_cam_from_body", rec["q_cam_from_body"], 4)
        q = q / np.linalg.norm(q)
        if not np.allclose(_matrix_from_quat(q), R, atol=1e-6):
            raise ValueError(f"{where}: q_cam_from_body does not describe R_cam_from_body "
                             "(Hamilton, scalar first, active; docs/conventions.md)")
    files = rec.get("files") or {}
    is_object = isinstance(files, dict)
    if not is_object:
        raise ValueError(f"{where}: files must be an object (modality → relative path), got {files!r}")
    return _Frame(frame, R, t, q, dict(files))


def _read_sequence(sequence_dir) -> _Sequence:
    root = Path(sequence_dir)
    if not root.is_dir():
        raise ValueError(f"sequence_dir must be a sequence folder, got {str(root)!r} (not a folder)")
    cam = _load_json(root / "camera.json", "camera.json")
    is_object = isinstance(cam, dict)
    if not is_object:
        raise ValueError(f"camera.json must hold a JSON object, got {type(cam).__name__}")
    K_src = cam.get("K", cam.get("cameraMatrix"))
    if K_src is None:
        raise ValueError("camera.json lacks K (3×3 intrinsic matrix, or cameraMatrix)")
    K = finite_numbers("camera.json: K", K_src, 9).reshape(3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(K[[0, 1, 2, 2], [1, 0, 0, 1]] != 0) or K[2, 2] != 1:
        raise ValueError(f"camera.json: K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                         f"got {K.tolist()}")
    width = _count("camera.json: width", cam.get("width", cam.get("Nu")))
    height = _count("camera.json: height", cam.get("height", cam.get("Nv")))

    labels = _load_json(root / "labels.json", "labels.json")
    if isinstance(labels, dict):
        if "frames" not in labels:
            raise ValueError("labels.json must be a list of frame records or an object with key 'frames'")
        labels = labels["frames"]
    is_list = isinstance(labels, list)
    if not is_list:
        raise ValueError(f"labels.json frames must be a list, got {type(labels).__name__}")
    frames = [_parse_frame(i, rec) for i, rec in enumerate(labels)]
    seen = set()
    for f in frames:
        if f.frame in seen:
            raise ValueError(f"labels.json: frame {f.frame} appears twice")
        seen.add(f.frame)
    frames.sort(key=lambda f: f.frame)

    model_dir = root / "model"
    plys = sorted(model_dir.glob("*.ply")) if model_dir.is_dir() else []
    if len(plys) != 1:
        found = ", ".join(p.name for p in plys) or "none"
        raise ValueError(f"model/ must hold exactly one .ply (the rendered mesh in metres), found {found}")
    return _Sequence(root, cam, K, width, height, tuple(frames), plys[0])


def _frame_file(seq: _Sequence, f: _Frame, modality: str) -> Path | None:
    """Path of a frame's image, None if the frame has none (not rendered); raise if listed but missing."""
    rel = f.files.get(modality)
    if rel is None:
        return None
    path = seq.root / rel
    if not path.is_file():
        raise ValueError(f"labels.json frame {f.frame}: files[{modality!r}] = {rel!r} is missing")
    return path


def _read_image(path: Path, fmt: str, shape: tuple) -> np.ndarray:
    """First channel (or all, for RGB) of an image file via OpenImageIO, checked against (H, W)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"{path} is not a readable image ({oiio.geterror()})")
    try:
        pixels = inp.read_image(0, 0, 0, 1, {"uint16": oiio.UINT16, "float": oiio.FLOAT}[fmt])
    finally:
        inp.close()
    if pixels is None or pixels.ndim != 3:
        raise ValueError(f"{path} is not a readable image ({oiio.geterror()})")
    if pixels.shape[:2] != shape:
        raise ValueError(f"{path} must be {shape[1]}×{shape[0]} px (camera.json), got "
                         f"{pixels.shape[1]}×{pixels.shape[0]}")
    return pixels[:, :, 0]


def _place(src: Path, dst: Path, link: bool) -> None:
    """Hard-link ``src`` to ``dst`` (same bytes, no copy), or copy when linking is off or fails."""
    if link:
        try:
            os.link(src, dst)
            return
        except OSError:  # another file system, or links not supported
            pass
    shutil.copyfile(src, dst)


def _write_json(path: Path, content) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(content, fh, indent=1)
        fh.write("\n")


# --------------------------------------------------------------------------- atomic output
@contextlib.contextmanager
def _staging(out_dir):
    """Yield a temporary folder beside ``out_dir``; rename it to ``out_dir`` on success,
    remove it (and any parent folder created here) on failure."""
    out = Path(out_dir).absolute()
    if out.exists() and not (out.is_dir() and not any(out.iterdir())):
        raise ValueError(f"out_dir must be a new or empty folder, got {str(out_dir)!r} (exists and is not empty)")
    created = []
    parent = out.parent
    while not parent.exists():
        created.append(parent)
        parent = parent.parent
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        # named after this host and process: one left by a killed export is removed here
        remove_stale_process_folders(f".{out.name}.partial-", str(out.parent))
        tmp = Path(process_folder(f".{out.name}.partial-", str(out.parent)))
    except OSError as exc:
        for d in created:
            with contextlib.suppress(OSError):
                d.rmdir()
        raise ValueError(f"out_dir: cannot create a folder beside {out} ({exc.strerror})") from None
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp made it private
        if out.exists():
            out.rmdir()
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for d in created:  # deepest first
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


# --------------------------------------------------------------------------- geometry
def _load_mesh(path: Path):
    import trimesh

    try:
        mesh = trimesh.load(str(path), process=False, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for a corrupt file
        raise ValueError(f"model/{path.name} is not a readable PLY mesh ({exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"model/{path.name} must hold a triangle mesh with finite vertices")
    return mesh


def _render_scene(path: Path):
    """A ray-tracing scene of the model file (metres), for silhouettes beyond the image."""
    from .meshio import load_mesh
    from .scene import Scene

    model, _ = load_mesh(path, unit_scale_m=1.0)
    return Scene(model)


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull (all vertices if the mesh is flat)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):
        return vertices


def _diameter(points: np.ndarray) -> float:
    """Largest distance between two points (attained between hull vertices) [unit of points]."""
    best = 0.0
    for i in range(0, len(points), 2048):
        d2 = ((points[i:i + 2048, None, :] - points[None, :, :]) ** 2).sum(axis=2)
        best = max(best, float(d2.max()))
    return math.sqrt(best)


def _bop_bbox(cols: np.ndarray, rows: np.ndarray) -> list:
    """BOP [x, y, w, h] with w = x_max − x_min, h = y_max − y_min (bop_toolkit misc.calc_2d_bbox)."""
    return [int(cols.min()), int(rows.min()), int(cols.max() - cols.min()), int(rows.max() - rows.min())]


def _silhouette_beyond(scene, K: np.ndarray, width: int, height: int, R: np.ndarray, t: np.ndarray,
                       hull_m: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The target's silhouette on the image's pixel grid extended by one image size on every
    side (bop_toolkit calc_gt_info's 3W × 3H canvas), outside the image: (pixel count, columns,
    rows). Rays are cast only in the rectangle the projected model hull can cover."""
    from .camera import Camera

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


def _modality(value) -> str:
    if value not in _IMAGE_MODALITIES:
        raise ValueError(f"modality must be one of {', '.join(map(repr, _IMAGE_MODALITIES))}; got {value!r}")
    return value


def _flag(name: str, value) -> bool:
    is_bool = isinstance(value, (bool, np.bool_))
    if not is_bool:
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _rendered(seq: _Sequence, needed: tuple) -> list:
    """Frames that list every modality in ``needed``; ValueError if there is none."""
    frames = [f for f in seq.frames if all(f.files.get(m) is not None for m in needed)]
    if not frames:
        raise ValueError(f"labels.json lists no frame with files {', '.join(needed)} "
                         f"({len(seq.frames)} frame record(s)); nothing to export")
    return frames


# --------------------------------------------------------------------------- SPEED+
def _pixel_pitch(cam: dict, K: np.ndarray) -> tuple[float, float]:
    """Pixel pitch (x, y) [m] from camera.json: ppx/ppy, pixel_pitch_m, pixel_pitch_um, or
    focal_length_m / (fx, fy)."""
    if "ppx" in cam or "ppy" in cam:
        pp, unit = [cam.get("ppx", cam.get("ppy")), cam.get("ppy", cam.get("ppx"))], 1.0
    elif "pixel_pitch_m" in cam:
        pp, unit = [cam["pixel_pitch_m"]] * 2, 1.0
    elif "pixel_pitch_um" in cam:
        pp, unit = [cam["pixel_pitch_um"]] * 2, 1e-6
    elif "focal_length_m" in cam:
        f = finite_numbers("camera.json: focal_length_m", cam["focal_length_m"], 1)[0]
        pp, unit = [f / K[0, 0], f / K[1, 1]], 1.0
    else:
        raise ValueError("camera.json lacks the pixel pitch SPEED+ needs: one of ppx/ppy, pixel_pitch_m, "
                         "pixel_pitch_um or focal_length_m")
    out = finite_numbers("camera.json: pixel pitch", pp, 2) * unit
    if np.any(out <= 0):
        raise ValueError(f"camera.json: pixel pitch must be > 0 [m], got {pp!r}")
    return float(out[0]), float(out[1])


def export_speedplus(sequence_dir, out_dir, *, split: str = "train", domain: str = "synthetic",
                     modality: str = "rgb", link: bool = True) -> Path:
    """Write a sequence folder in the SPEED+ layout and label convention.

    Parameters
    ----------
    sequence_dir : str or path-like
        Sequence folder (see the module docstring).
    out_dir : str or path-like
        New (or empty) folder for the dataset.
    split : str, keyword-only
        Name of the label file, ``{domain}/{split}.json`` (SPEED+: ``train``,
        ``validation``, ``test``). Default ``"train"``.
    domain : str, keyword-only
        Domain folder (SPEED+: ``synthetic``, ``lightbox``, ``sunlamp``). Default
        ``"synthetic"``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        Which image goes to ``{domain}/images/``.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible (default True).

    Returns
    -------
    out_dir : pathlib.Path
        The dataset folder::

            camera.json                 cameraMatrix, distCoeffs, Nu, Nv, ppx, ppy, fx, fy, ccx, ccy
            {domain}/{split}.json       [{filename, q_vbs2tango_true, r_Vo2To_vbs_true}, ...]
            {domain}/images/{frame:06d}.png

    Notes
    -----
    SPEED+ convention, verified against the authors' baseline (``quat2dcm`` and
    ``project_keypoints`` in speedplusbaseline ``src/utils/utils.py``): a camera-frame
    ("VBS", OpenCV axes) point is ``p_cam = quat2dcm(q)ᵀ · p_tango + r`` where ``quat2dcm``
    is the direction-cosine (passive) matrix of the scalar-first quaternion q, i.e. the
    transpose of the active Hamilton rotation matrix R(q) (docs/conventions.md, "Rotations and
    quaternions"). Hence

    * ``q_vbs2tango_true = q_cam_from_body`` (Hamilton, **scalar first** [q0, q1, q2, q3]):
      the rotation that turns the camera (VBS) axes into the target (Tango) axes;
      ``quat2dcm(q)`` maps camera-frame coordinates to body-frame ones;
    * ``r_Vo2To_vbs_true = t_cam_m``: the target origin in the camera frame [m].

    ``camera.json`` follows SPEED+: ``cameraMatrix`` = K [px], ``distCoeffs`` (from the
    sequence's camera.json, else five zeros: the renderer is a pinhole), ``Nu``/``Nv`` the
    image width/height [px], ``ppx``/``ppy`` the pixel pitch [m], ``fx``/``fy`` the focal
    length [**m**] (= K₀₀·ppx, K₁₁·ppy, as in SPEED+), ``ccx``/``ccy`` the principal point
    [px]. Pixel coordinates keep this project's convention (integer values at pixel
    centres), which ``cameraMatrix`` already encodes.
    """
    seq = _read_sequence(sequence_dir)
    for name, value in (("split", split), ("domain", domain)):
        if not isinstance(value, str) or not value or any(c in value for c in "/\\") or value.startswith("."):
            raise ValueError(f"{name} must be a plain file/folder name, got {value!r}")
    modality = _modality(modality)
    link = _flag("link", link)
    frames = _rendered(seq, (modality,))
    K = seq.K
    ppx, ppy = _pixel_pitch(seq.camera, K)
    dist = seq.camera.get("distCoeffs")
    if dist is None:
        dist = [0.0] * 5
    elif not isinstance(dist, list) or not 4 <= len(dist) <= 14:
        raise ValueError(f"camera.json: distCoeffs must be a list of 4 to 14 numbers (OpenCV), got {dist!r}")
    else:
        dist = finite_numbers("camera.json: distCoeffs", dist, len(dist)).tolist()
    camera = {"Nu": seq.width, "Nv": seq.height, "ppx": ppx, "ppy": ppy,
              "fx": float(K[0, 0]) * ppx, "fy": float(K[1, 1]) * ppy,
              "ccx": float(K[0, 2]), "ccy": float(K[1, 2]),
              "cameraMatrix": K.tolist(), "distCoeffs": dist}

    with _staging(out_dir) as tmp:
        images = tmp / domain / "images"
        images.mkdir(parents=True)
        labels = []
        for f in frames:
            src = _frame_file(seq, f, modality)
            name = f"{f.frame:06d}{src.suffix.lower()}"
            _place(src, images / name, link)
            labels.append({"filename": name, "q_vbs2tango_true": f.q_cam_from_body.tolist(),
                           "r_Vo2To_vbs_true": f.t_cam_m.tolist()})
        _write_json(tmp / domain / f"{split}.json", labels)
        _write_json(tmp / "camera.json", camera)
    return Path(out_dir)
