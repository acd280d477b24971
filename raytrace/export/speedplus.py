"""SPEED+ export (T. H. Park et al., IEEE Aerospace Conference 2022), laid out for the authors'
own loaders: the baseline https://github.com/tpark94/speedplusbaseline (``preprocess.py``,
``src/utils/utils.py``: ``quat2dcm``, ``project_keypoints``, ``load_tango_3d_keypoints``,
``load_camera_intrinsics``) and SPNv2 https://github.com/tpark94/spnv2 (``tools/preprocess.py``,
``core/dataset/SPEEDPLUSDataset.py``, ``core/utils/utils.py``: ``load_camera_intrinsics``,
``load_cad_model``)."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np

from .._checks import finite_numbers
from ..files import write_image
from ._read import (
    _flag,
    _load_mesh,
    _modality,
    _place,
    _read_image,
    _read_sequence,
    _rendered,
    _staging,
    _write_json,
)
from ._items import _check_splits, _frame_files, _image_stems

__all__ = ["SPEEDPLUS_SPLIT_NAMES", "export_speedplus", "write_speedplus"]

SPEEDPLUS_SPLIT_NAMES = {"val": "validation"}
"""Split names renamed to SPEED+'s label file names (``synthetic/validation.json``); any other
split keeps its name (``train.json``, ``test.json``)."""

KEYPOINTS_MAT_KEY = "tango3Dpoints"
"""Variable of the keypoints .mat both loaders read (``loadmat(path)['tango3Dpoints']``, 3 × N [m])."""


# --------------------------------------------------------------------------- camera and target
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


def _dist_coeffs(seq) -> list:
    """The five OpenCV coefficients (k1, k2, p1, p2, k3) the SPEED+ tools read (``distCoeffs[0..4]``
    in ``project_keypoints``); four are padded with k3 = 0, longer lists must be zero beyond five."""
    dist = seq.camera.get("distCoeffs")
    if dist is None:
        return [0.0] * 5
    n = len(dist) if isinstance(dist, list) else 0
    if n not in (4, 5, 8, 12, 14):
        raise ValueError(f"{seq.root / 'camera.json'}: distCoeffs must be a list of 4, 5, 8, 12 or 14 numbers "
                         f"(OpenCV order), got {dist!r}")
    d = finite_numbers(f"{seq.root / 'camera.json'}: distCoeffs", dist, n).tolist() + [0.0] * (5 - n)
    if any(d[5:]):
        raise ValueError(f"{seq.root / 'camera.json'}: distCoeffs beyond (k1, k2, p1, p2, k3) must be 0 for "
                         f"SPEED+ (its tools apply five), got {dist!r}")
    return d[:5]


def _speedplus_camera(seq) -> dict:
    """SPEED+ ``camera.json`` of a sequence: numbers only (SPNv2's load_camera_intrinsics makes every
    value a float32 array)."""
    K = seq.K
    ppx, ppy = _pixel_pitch(seq.camera, K)
    return {"Nu": seq.width, "Nv": seq.height, "ppx": ppx, "ppy": ppy,
            "fx": float(K[0, 0]) * ppx, "fy": float(K[1, 1]) * ppy,
            "ccx": float(K[0, 2]), "ccy": float(K[1, 2]),
            "cameraMatrix": K.tolist(), "distCoeffs": _dist_coeffs(seq)}


def _one_target_one_camera(sequences: list) -> dict:
    """The SPEED+ camera shared by all ``sequences``; ValueError if they differ in target (model file,
    keypoints) or camera."""
    first = sequences[0]
    digest = hashlib.sha256(first.model_path.read_bytes()).hexdigest()
    camera = _speedplus_camera(first)
    for seq in sequences[1:]:
        if hashlib.sha256(seq.model_path.read_bytes()).hexdigest() != digest:
            raise ValueError(f"sequences must show one target (one SPEED+ dataset = one spacecraft): "
                             f"{seq.model_path} differs from {first.model_path}")
        if seq.keypoint_names != first.keypoint_names or not (
                seq.keypoints_body_m is None or np.array_equal(seq.keypoints_body_m, first.keypoints_body_m)):
            raise ValueError(f"sequences must share one keypoint set: {seq.root / 'model/keypoints.json'} "
                             f"differs from {first.root / 'model/keypoints.json'} (or one of them is missing)")
        if _speedplus_camera(seq) != camera:
            raise ValueError(f"sequences must share one camera (K, size, distCoeffs, pixel pitch): "
                             f"{seq.root / 'camera.json'} differs from {first.root / 'camera.json'}")
    return camera


_MAT_TEXT = b"MATLAB 5.0 MAT-file, written by orbitsynth's SPEED+ export"
_MAT_TEXT_BYTES = 116


def _write_models(models: Path, seq, link: bool) -> None:
    """The target's mesh in metres (the sequence's PLY) and in millimetres (what SPNv2's
    load_cad_model reads: vertex x, y, z divided by 1000), and its keypoints (.mat and .json)."""
    from scipy.io import savemat
    from trimesh.exchange.ply import export_ply

    target = seq.model_path.stem
    models.mkdir()
    _place(seq.model_path, models / f"{target}_m.ply", link)
    mesh_mm = _load_mesh(seq.model_path).copy()
    mesh_mm.apply_scale(1000.0)
    (models / f"{target}.ply").write_bytes(export_ply(mesh_mm, encoding="binary", include_attributes=False))
    if seq.keypoints_body_m is not None:
        buf = io.BytesIO()
        savemat(buf, {KEYPOINTS_MAT_KEY: seq.keypoints_body_m.T.copy()})
        # the header's 116-byte text holds the time of writing (MAT-file format, level 5): a fixed
        # text instead, so that the same sequence exports to the same bytes
        mat = bytearray(buf.getvalue())
        mat[:_MAT_TEXT_BYTES] = _MAT_TEXT.ljust(_MAT_TEXT_BYTES)
        (models / f"{target}Points.mat").write_bytes(bytes(mat))
        _write_json(models / "keypoints.json", {
            "frame": "body", "unit": "m", "source": f"{seq.root.name}/model/keypoints.json",
            "names": list(seq.keypoint_names), "points_body_m": seq.keypoints_body_m.tolist()})


# --------------------------------------------------------------------------- writer
def write_speedplus(tmp: Path, splits: dict, *, modality: str, link: bool, progress=None,
                    domain: str = "synthetic") -> None:
    """Write sequences' frames as one SPEED+ dataset into the (staging) folder ``tmp``.

    Parameters
    ----------
    tmp : path-like
        Existing empty folder that receives the dataset.
    splits : dict of str → list of (_Sequence, _Frame)
        Split name → frames in order. ``val`` is written as SPEED+'s ``validation``
        (:data:`SPEEDPLUS_SPLIT_NAMES`); other names are kept. All sequences must show the same
        target (identical ``model/*.ply`` and ``model/keypoints.json``) through the same camera.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        The picture that goes to ``{domain}/images/``.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible.
    progress : callable or None, keyword-only
        Called with 1 after each frame.
    domain : str, keyword-only
        Domain folder (SPEED+: ``synthetic``, ``lightbox``, ``sunlamp``). Default ``"synthetic"``.

    Notes
    -----
    Layout (``docs/formats.md``, "SPEED+")::

        camera.json                      Nu, Nv, ppx, ppy [m], fx, fy [m], ccx, ccy [px], cameraMatrix, distCoeffs
        {domain}/{split}.json            [{filename, q_vbs2tango_true, r_Vo2To_vbs_true}, ...]
        {domain}/images/{stem}.png       the pictures (links or copies)
        {domain}/masks/{stem}.png        8-bit 0/255 target silhouette (when every frame has a mask)
        models/{target}Points.mat        tango3Dpoints: 3 × N keypoints, body frame [m] (with keypoints)
        models/keypoints.json            the keypoints' names and body-frame points [m] (with keypoints)
        models/{target}.ply              the mesh in millimetres (SPNv2 load_cad_model divides by 1000)
        models/{target}_m.ply            the mesh in metres (the sequence's PLY)

    ``stem`` is the frame number ``NNNNNN`` for one sequence, ``{sequence folder}_NNNNNN`` for
    several. Pose convention (speedplusbaseline ``src/utils/utils.py``, ``quat2dcm`` and
    ``project_keypoints``): ``p_cam = quat2dcm(q)ᵀ p_body + r``, where ``quat2dcm`` is the
    direction-cosine (passive) matrix of the scalar-first q, the transpose of the active
    Hamilton R(q) (docs/conventions.md). Hence ``q_vbs2tango_true = q_cam_from_body`` (scalar
    first) and ``r_Vo2To_vbs_true = t_cam_m``. Pixel coordinates keep integer values at pixel
    centres, which ``cameraMatrix`` encodes; SPNv2's mask-derived boxes (``np.where(mask > 0)``
    indices) use the same convention.
    """
    tmp = Path(tmp)
    splits = _check_splits(splits)
    modality = _modality(modality)
    link = _flag("link", link)
    if not isinstance(domain, str) or not domain or any(c in domain for c in "/\\") or domain.startswith("."):
        raise ValueError(f"domain must be a plain folder name such as 'synthetic', got {domain!r}")
    names = {}
    for split in splits:
        out = SPEEDPLUS_SPLIT_NAMES.get(split, split)
        if out in names.values():
            raise ValueError(f"splits {split!r} and {next(k for k, v in names.items() if v == out)!r} would both "
                             f"be written to {domain}/{out}.json")
        names[split] = out
    items = [it for its in splits.values() for it in its]
    sequences = {}
    for seq, _ in items:
        sequences.setdefault(seq.root.resolve(), seq)
    sequences = list(sequences.values())
    camera = _one_target_one_camera(sequences)
    with_mask = [f.files.get("mask") is not None for _, f in items]
    if any(with_mask) and not all(with_mask):
        seq, f = items[with_mask.index(False)]
        raise ValueError(f"{seq.root / 'labels.json'}: frame {f.frame} lists no 'mask' file while other "
                         f"frames do; SPEED+ masks are written for all frames or none")
    masked = all(with_mask)
    stems = _image_stems(splits)

    _write_models(tmp / "models", sequences[0], link)
    _write_json(tmp / "camera.json", camera)
    images = tmp / domain / "images"
    images.mkdir(parents=True)
    masks = tmp / domain / "masks"
    if masked:
        masks.mkdir()
    for split, its in splits.items():
        labels = []
        for seq, f in its:
            src, = _frame_files(seq, f, (modality,))
            name = f"{stems[(seq.root.resolve(), f.frame)]}{src.suffix.lower()}"
            _place(src, images / name, link)
            if masked:
                ids = _read_image(_frame_files(seq, f, ("mask",))[0], "uint16", (seq.height, seq.width))
                write_image(str(masks / name), np.where(ids > 0, np.uint8(255), np.uint8(0)))
            labels.append({"filename": name, "q_vbs2tango_true": f.q_cam_from_body.tolist(),
                           "r_Vo2To_vbs_true": f.t_cam_m.tolist()})
            if progress is not None:
                progress(1)
        _write_json(tmp / domain / f"{names[split]}.json", labels)


def export_speedplus(sequence_dir, out_dir, *, split: str = "train", domain: str = "synthetic",
                     modality: str = "rgb", link: bool = True) -> Path:
    """Write one sequence folder as a SPEED+ dataset (:func:`write_speedplus` with one split).

    Parameters
    ----------
    sequence_dir : str or path-like
        Sequence folder (see :mod:`raytrace.export`).
    out_dir : str or path-like
        New (or empty) folder for the dataset; written all or nothing.
    split : str, keyword-only
        Split of all frames: the label file ``{domain}/{split}.json`` (``val`` is written as
        ``validation.json``). Default ``"train"``.
    domain : str, keyword-only
        Domain folder (SPEED+: ``synthetic``, ``lightbox``, ``sunlamp``). Default ``"synthetic"``.
    modality : {"rgb", "rgb_degraded"}, keyword-only
        Which image goes to ``{domain}/images/``.
    link : bool, keyword-only
        Hard-link the images instead of copying them when possible (default True).

    Returns
    -------
    out_dir : pathlib.Path
        The dataset folder (layout: :func:`write_speedplus`). Frames that list no
        ``modality`` file (not rendered) are left out.
    """
    seq = _read_sequence(sequence_dir)
    modality = _modality(modality)
    frames = _rendered(seq, (modality,))
    splits = _check_splits({split: [(seq, f) for f in frames]})
    with _staging(out_dir) as tmp:
        write_speedplus(tmp, splits, modality=modality, link=link, domain=domain)
    return Path(out_dir)
