"""The cores this process may use."""

from __future__ import annotations

import os


def available_cores() -> int:
    """All cores this process may use (its CPU affinity where the system has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)
