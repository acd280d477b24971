"""The allocator thresholds set by raytrace._jit: MB-sized arrays freed and allocated again are
served from the heap, not mapped and zero-filled by the kernel again on every round."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# 64 arrays of 2 MiB written, all freed, five rounds; minor page faults of rounds 2–5 per page
# written. Sizes chosen so that glibc's dynamic thresholds (mmap threshold raised to a freed
# block's size, trim threshold twice that) give the heap back between rounds.
_PROBE = r"""
import resource, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
import raytrace._jit as J
pages = 0
faults = 0
for r in range(5):
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.ones(1 << 18) for _ in range(64)]  # 2 MiB each
    del arrays
    if r:
        faults += resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
        pages += 64 * (2 << 20) // 4096
print(J.ALLOCATOR_TUNED, faults / pages)
"""


def _probe(env_extra):
    env = {k: v for k, v in os.environ.items()
           if k not in ("ORBITSYNTH_KEEP_MALLOC", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", _PROBE, str(ROOT)], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    return out[0] == "True", float(out[1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_tuned_allocator_reuses_freed_arrays():
    tuned, per_page = _probe({})
    if not tuned:
        pytest.skip("not glibc: the allocator is left alone")
    kept, per_page_kept = _probe({"ORBITSYNTH_KEEP_MALLOC": "1"})
    assert not kept
    # each page written once per round: ~1 fault per page if the memory went back to the system
    assert per_page < 0.05, (per_page, per_page_kept)


def test_user_settings_win():
    tuned, _ = _probe({"MALLOC_TRIM_THRESHOLD_": "1048576"})
    assert not tuned
    tuned, _ = _probe({"ORBITSYNTH_KEEP_MALLOC": "1"})
    assert not tuned
