"""The heap policy of degrade._memory: it is applied on glibc, and its opt-outs are honoured."""

import os
import platform
import resource
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"

PROBE = """
import resource, numpy as np
from degrade._memory import keep_freed_memory
print(int(keep_freed_memory()))
def frame():  # four 24 MB arrays, as a frame's, freed together
    arrays = [np.ones(3_000_000) for _ in range(4)]
    del arrays
frame()
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    frame()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _probe(env_extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "ORBITSYNTH_KEEP_HEAP"}
    env.update(env_extra, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    applied, faults = out.stdout.split()
    return bool(int(applied)), int(faults)


@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt")
def test_freed_arrays_are_reused_without_page_faults():
    """With the policy the pages of a frame's freed arrays serve the next frame (almost no minor
    faults); without it (ORBITSYNTH_KEEP_HEAP=0) glibc hands part of them back and frames fault
    thousands of pages in again (a frame's arrays: 4 × 5860 pages)."""
    applied, kept = _probe({})
    assert applied and kept < 1000
    applied, returned = _probe({"ORBITSYNTH_KEEP_HEAP": "0"})
    assert not applied and returned > 5000 and returned > 10 * kept


@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt")
def test_glibc_variables_of_the_user_win():
    applied, _ = _probe({"MALLOC_TRIM_THRESHOLD_": "131072"})
    assert not applied
