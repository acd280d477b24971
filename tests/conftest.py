"""Test-suite settings.

Hypothesis explores new random examples on every local run; under CI (``CI`` set) it is
derandomised so a landing never depends on luck. Property tests set ``deadline=None``
themselves where a first call compiles or integrates.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


def pytest_sessionstart(session):
    """Fill numba's on-disk cache with the main job's kernels on every core at once
    (:func:`raytrace._precompile.precompile`) before the tests call them one by one: on a fresh
    clone that is ~60 s of compiling spread over the cores instead of ~95 s on one (a 2-core
    AMD EPYC); with a warm cache it takes ~2 s. A failure here only means the kernels
    compile on first call, as they would without it."""
    try:
        from raytrace._precompile import precompile
        precompile(max(1, min(os.cpu_count() or 1, 4)))
    except Exception as exc:  # noqa: BLE001 (a speed-up only; the tests report real errors)
        print(f"conftest: precompile skipped ({type(exc).__name__}: {exc})")
