"""Test-suite settings.

Hypothesis explores new random examples on every local run; under CI (``CI`` set) it is
derandomised so a landing never depends on luck. Property tests set ``deadline=None``
themselves where a first call compiles or integrates.
"""

import os
import shutil
import tempfile

import numpy as np
import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_sessionstart(session):
    """Fill numba's on-disk cache with the kernels of every preset on every core at once
    (:func:`raytrace._precompile.precompile`, all groups) before the tests call them one by
    one: their parallel builds (what a test's own process calls on two numba threads) and, of
    the main job's and a ``balanced`` frame's kernels, their serial builds (the CLI's pool
    workers, tests/raytrace/test_threaded_kernels.py). From a fresh clone ~150 s on two cores
    (BENCHMARKS.md, "The test suite from a cold cache"); ~3 s with a warm cache. Under
    pytest-xdist only in the controller, before its workers start. A failure here only means
    the kernels compile on first call, as they would without it."""
    if hasattr(session.config, "workerinput"):  # a pytest-xdist worker: its controller compiled them
        return
    try:
        from raytrace._precompile import GROUPS, precompile
        processes = max(1, min(os.cpu_count() or 1, 4))
        precompile(processes, GROUPS)
        precompile(processes, ("fast", "balanced"), serial=True)
    except Exception as exc:  # noqa: BLE001 (a speed-up only; the tests report real errors)
        print(f"conftest: precompile skipped ({type(exc).__name__}: {exc})")


_SESSION_CACHE_DIR = tempfile.mkdtemp(prefix="orbitsynth-test-cache-")
os.environ["ORBITSYNTH_CACHE_DIR"] = _SESSION_CACHE_DIR  # module-scoped fixtures too: never the user's cache


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(_SESSION_CACHE_DIR, ignore_errors=True)


@pytest.fixture(autouse=True)
def _private_cache_dir(tmp_path_factory, monkeypatch):
    """Each test's own persistent cache (raytrace._diskcache), never the user's: what one test
    stores (or breaks) no other test reads (module-scoped fixtures share the session's)."""
    monkeypatch.setenv("ORBITSYNTH_CACHE_DIR", str(tmp_path_factory.mktemp("orbitsynth-cache")))


@pytest.fixture
def nan_box_obj():
    """Writes a 2 × 1 × 1 box (8 vertices, 12 triangles) as OBJ with its first vertex NaN, and
    returns how many triangles touch that vertex."""
    def write(path):
        import trimesh
        box = trimesh.creation.box((2.0, 1.0, 1.0))
        v = box.vertices.copy()
        v[0, 0] = np.nan
        lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in box.faces]
        path.write_text("\n".join(lines) + "\n")
        return int((box.faces == 0).any(axis=1).sum())
    return write
