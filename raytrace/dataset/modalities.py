"""The output modalities: one table that the writers, the folder checks, the exports and
``render-scene`` read.

Each :class:`Modality` names its folder (the modality's name) and file extension, what it
holds, whether making it needs the shaded radiance, and, for those made from the frame's
geometry or radiance alone, the function that makes its pixels. ``rgb`` and ``rgb_degraded``
are made by the pipeline (exposure and sRGB encoding, then the degradation chain, which live
outside ``raytrace``) and have no producer here, nor have ``signal_e`` and ``saturation``, made
by the same simulation as ``rgb_degraded`` (physical preset only). A new modality is one entry here and its
producer (docs/formats.md lists the files).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _light_parts

__all__ = [
    "CAMERA",
    "DEFAULT",
    "MODALITIES",
    "NAMES",
    "PICTURES",
    "Modality",
    "needs_radiance",
    "preset_error",
    "relpath",
    "write_options",
]


@dataclass(frozen=True)
class Modality:
    """One output modality of a frame.

    Attributes
    ----------
    name : str
        Its name, its folder's name and the file stem's prefix in a sequence folder.
    ext : str
        File extension (``.png``: 8-bit sRGB or 16-bit data; ``.exr``: float32).
    holds : str
        What the pixels are, in one line (units, background value).
    shaded : bool
        Making it needs the shaded radiance (not the geometry alone).
    noisy : bool
        Mostly noise (a degraded camera frame): written with the fast PNG settings
        (:func:`raytrace.files.write_image`).
    sparse : bool
        Zero on most pixels (the background): written with the EXR settings for that
        (:func:`raytrace.files.write_image`).
    picture : bool
        An 8-bit sRGB colour image: what the exports (:mod:`raytrace.export`) take as a frame's
        picture.
    default : bool
        Written when the user names no modalities (``--modalities`` unset).
    produce : callable or None
        ``produce(geometry, radiance) -> pixels`` from a :class:`raytrace.scene.GeometryFrame`
        and the linear radiance (None when not shaded; with ``light_parts``, the render's
        parts of the radiance in its place); None: made by the pipeline.
    hits : bool
        ``produce`` takes a third argument, the frame's :class:`raytrace.correspondence.FrameHits`
        (scene, camera, pose, next frame's pose; the hit points computed once for all such modalities).
    light_parts : bool
        Made from the render's split of the radiance by source
        (:attr:`raytrace.shade.RenderFrame.light_parts`, ``render(..., parts=True)``): the
        render computes it only when such a modality is asked for.
    channels : tuple of str or None
        The file's channel names (None: the writer's default).
    presets : tuple of str or None
        The degradation presets (``--degrade``) that make it; None: made without one.
    half_option : str or None
        The ``[output]`` option that stores it as half floats when set to ``"half"``
        (``normal_format``); None: always as made.
    """

    name: str
    ext: str
    holds: str
    shaded: bool = False
    noisy: bool = False
    sparse: bool = False
    picture: bool = False
    default: bool = True
    produce: object = None
    hits: bool = False
    light_parts: bool = False
    channels: tuple | None = None
    presets: tuple | None = None
    half_option: str | None = None


MODALITIES = {m.name: m for m in (
    Modality("rgb", ".png", "clean sRGB, 8 bit (exposure fixed or auto)", shaded=True, picture=True),
    Modality("rgb_degraded", ".png", "the camera's copy: the degradation preset applied, sRGB 8 bit", shaded=True,
             noisy=True, picture=True, presets=("paper", "physical")),
    Modality("mask", ".png", "instance ids, 16 bit (component index + 1; 0 background)",
             produce=lambda geo, radiance: geo.instance.astype(np.uint16)),
    Modality("depth", ".exr", "z-depth along the optical axis, float32 m (inf on background)",
             produce=lambda geo, radiance: geo.depth_m.astype(np.float32)),
    Modality("normal", ".exr", "unit surface normal in the camera frame, float32 (half with --normal-format half; "
             "0 on background)", sparse=True, half_option="normal_format",
             produce=lambda geo, radiance: geo.normal_cam.astype(np.float32)),
    Modality("semantic", ".png", "part class, 8 bit (raytrace.model.SEMANTIC_CLASSES index + 1; 0 background)",
             default=False, produce=lambda geo, radiance: geo.semantic),
    Modality("hdr", ".exr", "linear radiance, float32 W/(m²·sr)", shaded=True, default=False,
             produce=lambda geo, radiance: radiance.astype(np.float32)),
    Modality("coords", ".exr", "body-frame point of the pixel's hit, float32 m (0 on background)", default=False,
             hits=True, produce=lambda geo, radiance, hits: hits.coords()),
    Modality("flow", ".exr", "du, dv to the next planned frame, float32 px, and validity 1/0 (0 on background and "
             "in the last frame)", default=False, hits=True, produce=lambda geo, radiance, hits: hits.flow()),
    Modality("light", ".exr", "hdr split by source, float32 W/(m²·sr), layers earth, inter, sky, sun (RGB); "
             "their sum is hdr", shaded=True, default=False, light_parts=True, channels=_light_parts.CHANNELS,
             produce=lambda geo, parts: parts.astype(np.float32)),
    Modality("signal_e", ".exr", "electrons per photosite at the ADC's input (noise, artefacts, blooming, full-well "
             "clip), float32 e-, one channel on the RGGB mosaic", shaded=True, default=False,
             presets=("physical",)),
    Modality("saturation", ".png", "photosites at full well, 8 bit (255 saturated, 0 not), on the RGGB mosaic",
             shaded=True, default=False, presets=("physical",)),
)}
"""Every modality by name, in the order they are listed and written."""

NAMES = tuple(MODALITIES)
"""The modality names, in order."""
DEFAULT = tuple(m.name for m in MODALITIES.values() if m.default)
"""The modalities written when none are named."""
PICTURES = tuple(m.name for m in MODALITIES.values() if m.picture)
"""The 8-bit sRGB colour modalities."""
CAMERA = tuple(m.name for m in MODALITIES.values() if m.presets is not None)
"""The modalities the degradation preset makes (one simulation per frame)."""


def preset_error(names, preset: str) -> str | None:
    """The one-line error when a modality of ``names`` cannot be made with ``--degrade preset``
    (``argument --modalities: ...``), else None."""
    for n in names:
        allowed = MODALITIES[n].presets
        if allowed is not None and preset not in allowed:
            return (f"argument --modalities: {n} needs --degrade {' or '.join(allowed)}, got --degrade {preset}")
    return None


def needs_radiance(names) -> bool:
    """Whether making the modalities ``names`` needs the shaded radiance."""
    return any(MODALITIES[n].shaded for n in names)


def relpath(name: str, frame: int | str) -> str:
    """The file of modality ``name`` of frame ``frame`` (a number or a stem) in a sequence
    folder: ``mask/000012.png``."""
    stem = f"{frame:06d}" if isinstance(frame, int) else frame
    return f"{name}/{stem}{MODALITIES[name].ext}"


def write_options(name: str, output: dict) -> dict:
    """The keyword options of :func:`raytrace.files.write_image` for modality ``name`` with the
    ``[output]`` configuration ``output`` (``compression``, ``normal_format``; missing: the
    defaults, fast and float32)."""
    m = MODALITIES[name]
    return {"noisy": m.noisy, "sparse": m.sparse, "channel_names": m.channels,
            "compression": output.get("compression", "fast"),
            "half": m.half_option is not None and output.get(m.half_option) == "half"}
