"""Relative orbital motion for close-range spacecraft imaging.

Clohessy–Wiltshire dynamics in the target's LVLH frame, the four relative-motion patterns
(elliptical, spiral, drip-drop, drift), the reference orbit in ECI, the Sun, visibility,
a nonlinear reference propagator, target attitude laws and camera pose labels.

``orbit`` knows nothing of pixels: it hands the pipeline states, rotations and flags.
Conventions and equations: SPEC.md (shipped beside the project) §0–§9, §11.
"""

from . import constants, cw

__all__ = ["constants", "cw"]
