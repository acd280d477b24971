"""Sequence folders and the machinery that fills them.

What turns per-frame renders into a dataset on disk, apart from how a frame is made: the table
of output modalities (:mod:`.modalities`), the sequence folder format, its claim, resume and
completion (:mod:`.folder`), each process's scenes (:mod:`.scenes`), the worker pool, its
signals and memory fit (:mod:`.pool`), the first run's kernel compilation (:mod:`.jit`),
running planned sequences (:mod:`.run`), the render snapshots (:mod:`.snapshots`), and the
options of the camera's artefacts (:mod:`.camera_options`, typed by :mod:`.options`).

The frame itself comes in as a function: the command line (``cli.py``) composes the orbit
plan, the renderer and the degradation, and hands :func:`.run.run_plans` its per-frame
function, so this package imports neither ``orbit`` nor ``degrade``. docs/formats.md
describes the folder; docs/cli.md what a run guarantees.
"""

from __future__ import annotations

import sys

__all__ = ["PROG", "UsageError", "warn"]

PROG = "cli.py"
"""The program name that starts this package's one-line messages (the command line's)."""


class UsageError(Exception):
    """A refusal of what the user asked for (a folder, a flag's value): one line naming the
    option, exit status 2, nothing written."""


def warn(message: str) -> None:
    """One line ``PROG: warning: message`` on stderr."""
    sys.stderr.write(f"{PROG}: warning: {message}\n")
