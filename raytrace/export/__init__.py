"""Export rendered sequence folders to the BOP, SPEED+ and COCO dataset formats.

Input: a sequence folder as the pipeline writes it — ``camera.json`` (``K``, ``width``,
``height``; SPEED+ fields ``cameraMatrix``, ``distCoeffs``, ``Nu``, ``Nv``), ``labels.json``
(a list of per-frame records, or an object whose ``"frames"`` holds that list: ``frame``,
``R_cam_from_body`` (9 numbers, row-major), ``t_cam_m``, ``q_cam_from_body``, ``files``:
modality → path relative to the folder), the images ``rgb/``, ``rgb_degraded/``, ``mask/``
(uint16 component ids, 0 background), ``depth/`` (float32 z-depth [m], inf on background)
and ``model/`` holding the rendered mesh as one PLY in metres (and ``keypoints.json``, whose
per-frame ``keypoints_px``/``keypoints_state`` the labels carry). Pose convention
(docs/conventions.md): ``p_cam = R_cam_from_body @ p_body + t_cam_m``, OpenCV camera axes,
integer pixel coordinates at pixel centres.

Frames whose ``files`` lack an image the export needs (frames the pipeline did not render)
are left out; a file that is listed but missing or unreadable is an error.

The command ``cli.py export`` (:mod:`raytrace.export.command`) exports many sequences at once,
split into train/val/test, resumably; the functions below export one sequence.

Every export is all or nothing: everything is written into a hidden temporary folder next
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

from .bop import BOP_DEPTH_MAX_CODE, BOP_PIXEL_CENTRE_SHIFT, export_bop, write_bop
from .coco import export_coco, write_coco
from .speedplus import export_speedplus, write_speedplus

__all__ = ["BOP_DEPTH_MAX_CODE", "BOP_PIXEL_CENTRE_SHIFT", "export_bop", "export_coco", "export_speedplus",
           "write_bop", "write_coco", "write_speedplus"]
