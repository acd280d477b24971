"""SPEED+ export (T. H. Park et al., IEEE Aerospace Conference 2022; label convention of the
authors' baseline, https://github.com/tpark94/speedplusbaseline ``src/utils/utils.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._checks import finite_numbers
from ._read import (
    _flag,
    _frame_file,
    _modality,
    _place,
    _read_sequence,
    _rendered,
    _staging,
    _write_json,
)

__all__ = ["export_speedplus"]


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
