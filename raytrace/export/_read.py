"""Reading a sequence folder for the exports, and what every export shares: the all-or-nothing
staging folder, file placement, the model's hull. The format itself is in :mod:`raytrace.export`."""


from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._checks import finite_numbers
from ..dataset.modalities import PICTURES
from ..files import process_folder, remove_stale_process_folders

_IMAGE_MODALITIES = PICTURES
_ROTATION_TOL = 1e-6
_KEYPOINT_STATES = ("visible", "shadowed", "occluded", "outside")


# --------------------------------------------------------------------------- reading
@dataclass(frozen=True, slots=True)
class _Frame:
    """One labelled frame of a sequence."""

    frame: int
    R_cam_from_body: np.ndarray  # (3, 3) float64
    t_cam_m: np.ndarray  # (3,) float64
    q_cam_from_body: np.ndarray  # (4,) float64, Hamilton, scalar first
    files: dict
    keypoints_px: np.ndarray | None = None  # (N, 2) float64 [px], NaN for null; None: no keypoints
    keypoints_state: tuple | None = None  # N of _KEYPOINT_STATES


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
    keypoints_body_m: np.ndarray | None = None  # (N, 3) float64 [m], model/keypoints.json
    keypoint_names: tuple | None = None


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
    return _Frame(frame, R, t, q, dict(files), *_frame_keypoints(where, rec))


def _frame_keypoints(where: str, rec: dict) -> tuple:
    """(keypoints_px, keypoints_state) of a frame record, (None, None) without keypoints."""
    if rec.get("keypoints_px") is None:
        return None, None
    pts, states = rec["keypoints_px"], rec.get("keypoints_state")
    if not isinstance(pts, list) or not isinstance(states, list) or len(states) != len(pts):
        raise ValueError(f"{where}: keypoints_px and keypoints_state must be lists of the same length")
    uv = np.array([[np.nan, np.nan] if p is None else finite_numbers(f"{where}: keypoints_px", p, 2)
                   for p in pts], dtype=np.float64).reshape(-1, 2)
    bad = [s for s in states if s not in _KEYPOINT_STATES]
    if bad:
        raise ValueError(f"{where}: keypoints_state must hold {', '.join(_KEYPOINT_STATES)}; got {bad[0]!r}")
    return uv, tuple(states)


def _keypoints_model(root: Path) -> tuple:
    """(points_body_m (N, 3), names) from model/keypoints.json, (None, None) if absent."""
    path = root / "model" / "keypoints.json"
    if not path.is_file():
        return None, None
    doc = _load_json(path, "model/keypoints.json")
    if not isinstance(doc, dict) or doc.get("frame") != "body" or doc.get("unit") != "m":
        raise ValueError("model/keypoints.json must be an object with frame 'body' and unit 'm'")
    names = doc.get("names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ValueError("model/keypoints.json: names must be a non-empty list of strings")
    pts = finite_numbers("model/keypoints.json: points_body_m", doc.get("points_body_m"), 3 * len(names))
    return pts.reshape(-1, 3), tuple(names)


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
    kp_body, kp_names = _keypoints_model(root)
    return _Sequence(root, cam, K, width, height, tuple(frames), plys[0], kp_body, kp_names)


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
    from ..meshio import load_mesh
    from ..scene import Scene

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
