"""The four built-in targets, built procedurally from trimesh primitives (no download).

``load_target(name)`` builds a target on first use and caches it; generation is
deterministic. Each builder lives in its own module and returns a :class:`TargetModel`
in the body frame (metres, origin at the centre of mass).
"""

from __future__ import annotations

import functools
import importlib

from ..model import TargetModel

__all__ = ["BUILTIN_TARGETS", "load_target"]

BUILTIN_TARGETS = ("tiangong", "spacedragon", "icesat", "cassini")


@functools.cache
def load_target(name: str) -> TargetModel:
    """Build (once) and return the built-in target ``name``.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`BUILTIN_TARGETS`.
    """
    if name not in BUILTIN_TARGETS:
        raise ValueError(f"target must be one of {', '.join(BUILTIN_TARGETS)}; got {name!r}")
    module = importlib.import_module(f".{name}", __name__)
    return module.build()
