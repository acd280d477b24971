"""The ``[degrade]`` options of the flight camera's artefacts (physical preset): one
:class:`raytrace.dataset.options.Option` each, with the defaults of
:class:`degrade.artefacts.ArtefactConfig` (tests/degrade/test_artefacts.py checks they agree;
this module does not import ``degrade``). docs/degradation.md, "Camera artefacts", gives each
model and the source of its default."""

from __future__ import annotations

from . import options as opt

__all__ = ["CAMERA_OPTIONS"]

_P = "physical preset: "


def _camera_options() -> tuple:
    O = opt.Option
    return (
        O("--vignetting", "degrade", opt.boolean, True, _P + "cos^4 relative illumination of the lens", "{true,false}"),
        O("--mechanical-vignetting", "degrade", opt.float_in(0.0, 0.99), 0.0,
          _P + "extra mechanical vignetting 1 - a*rho: the loss a in the image corners"),
        O("--prnu-sigma", "degrade", opt.float_in(0.0, 0.2), 0.01,
          _P + "pixel response non-uniformity, sigma of the gain map (0.01 = 1 %%; 0: off)"),
        O("--dsnu-sigma-e", "degrade", opt.float_in(0.0, 1e6, unit="e-"), 2.0,
          _P + "dark-signal non-uniformity, sigma of the offset map [e-] (0: off)"),
        O("--hot-pixel-fraction", "degrade", opt.float_in(0.0, 0.1), 1e-4, _P + "fraction of hot photosites (0: off)"),
        O("--hot-pixel-dark-e-s", "degrade", opt.float_in(0.0, 1e9, unit="e-/s"), 5e4,
          _P + "mean extra dark current of a hot photosite [e-/s] (exponentially distributed)"),
        O("--blooming", "degrade", opt.boolean, True,
          _P + "charge above the full well spills along the column", "{true,false}"),
        O("--blooming-spill", "degrade", opt.float_in(0.0, 1.0), 1.0,
          _P + "fraction of the excess charge that spills on at each step; the rest is drained by an "
          "anti-blooming gate (1: all, charge conserved)"),
        O("--smear-fraction", "degrade", opt.float_in(0.0, 1.0), 0.0,
          _P + "frame-transfer smear, transfer time / exposure time (0: off, as for CMOS)"),
        O("--stray-light", "degrade", opt.boolean, True,
          _P + "veiling glare and ghost of the Sun outside the field", "{true,false}"),
        O("--pst-edge", "degrade", opt.float_in(0.0, 1.0), 1e-4,
          _P + "stray light: point-source transmittance with the Sun at the field's edge"),
        O("--pst-slope", "degrade", opt.float_in(0.0, 10.0), 3.0,
          _P + "stray light: PST falls as (theta_edge / theta)^slope with the Sun's off-axis angle"),
        O("--sun-exclusion-deg", "degrade", opt.float_in(0.0, 90.0, lo_open=True, unit="deg"), 60.0,
          _P + "stray light: Sun off-axis angle beyond which the baffle blocks it [deg]"),
        O("--glare-gradient", "degrade", opt.float_in(0.0, 1.0), 0.5,
          _P + "stray light: relative glare gradient toward the Sun across the half-diagonal"),
        O("--ghost-reflectance", "degrade", opt.float_in(0.0, 1.0), 0.005,
          _P + "ghost: residual reflectance R of the two surfaces making it (fraction R^2; 0: no ghost)"),
        O("--ghost-radius-px", "degrade", opt.float_in(0.0, 1e4, lo_open=True, unit="px"), 20.0,
          _P + "ghost: radius of the defocused disc [px]"),
        O("--ghost-magnification", "degrade", opt.float_in(-10.0, 10.0), -0.5,
          _P + "ghost: position = centre + m * (Sun's pinhole position - centre)"),
        O("--jpeg-quality", "degrade", opt.int_in(0, 100), 0,
          _P + "on-board JPEG compression of rgb_degraded, quality 1-100 (0: off)"),
        O("--camera-seed", "degrade", opt.int_in(0, 2**63 - 1), None,
          _P + "seed of the camera's fixed maps (PRNU, DSNU, hot pixels) (default: derived from --seed)"),
    )


CAMERA_OPTIONS = _camera_options()
"""The artefact options, in the order ``--help`` lists them."""
