"""Relative orbital motion for close-range spacecraft imaging.

Clohessy–Wiltshire dynamics in the target's LVLH frame, the four relative-motion patterns
(elliptical, spiral, drip-drop, drift), the reference orbit in ECI, the Sun, visibility,
a nonlinear reference propagator, target attitude laws and camera pose labels.

``orbit`` knows nothing of pixels: it hands the pipeline states, rotations and flags.
Conventions: docs/conventions.md; equations, patterns, visibility and attitude: docs/orbit.md;
accuracy of the CW model: docs/accuracy.md.

Submodules (imported lazily, so ``import orbit`` stays cheap): ``constants``, ``epoch``,
``cw``, ``patterns``, ``sampling``, ``reference``, ``sun``, ``visibility``, ``nonlinear``,
``rotations``, ``attitude``, ``pose``.
"""

import importlib

__all__ = ["constants", "epoch", "cw", "patterns", "sampling", "reference", "sun", "visibility",
           "nonlinear", "rotations", "attitude", "pose"]


def __getattr__(name: str):
    if name in __all__:
        module = importlib.import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    raise AttributeError(f"module 'orbit' has no attribute {name!r}")
