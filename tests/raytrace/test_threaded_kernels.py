"""Kernels built twice (raytrace._jit.ThreadedKernel and its mirror in degrade._jit): a call on
one numba thread runs the serial build, on more the parallel one; the two builds have their own
entries in numba's cache; and a frame is the same bits whichever ran."""
from __future__ import annotations

import numba
import numpy as np
import pytest

import degrade._jit as DJ
import raytrace._jit as RJ
from raytrace import _precompile as P

TWO_THREADS = numba.config.NUMBA_NUM_THREADS >= 2


def _row_sums(a, out):
    for i in numba.prange(a.shape[0]):
        s = 0.0
        for j in range(a.shape[1]):
            s += a[i, j] * (j + 1)
        out[i] = s


class _threads:
    def __init__(self, n):
        self.n = n

    def __enter__(self):
        self.before = numba.get_num_threads()
        numba.set_num_threads(self.n)

    def __exit__(self, *exc):
        numba.set_num_threads(self.before)


@pytest.mark.parametrize("jit_module", [RJ, DJ], ids=["raytrace", "degrade"])
def test_a_call_runs_the_serial_build_on_one_thread_and_the_parallel_one_on_more(jit_module):
    k = jit_module.ThreadedKernel(_row_sums, nogil=True)
    a = np.random.default_rng(0).random((257, 33))
    expected = a @ np.arange(1, 34)
    out1 = np.empty(257)
    with _threads(1):
        k(a, out1)
    assert k.serial.signatures and not k.parallel.signatures
    assert k.serial.py_func.__qualname__ == "_row_sums" + jit_module.SERIAL_SUFFIX
    np.testing.assert_allclose(out1, expected, rtol=1e-12)
    if TWO_THREADS:
        out2 = np.empty(257)
        with _threads(2):
            k(a, out2)
        assert k.parallel.signatures
        assert out2.tobytes() == out1.tobytes()
    assert (k.build(True), k.build(False)) == (k.serial, k.parallel)
    assert k.__name__ == "_row_sums" and k.py_func is _row_sums


def test_both_builds_have_their_own_entries_in_numbas_cache(tmp_path, monkeypatch):
    """numba keys a cache entry by the function's name and the signature, not by ``parallel``:
    the serial build is cached under its own name, so that compiling one build never replaces
    the other (a process would then load code of the other kind)."""
    qualname = "raytrace._edges.ray_groups"
    assert P._threaded(P.kernel(qualname))
    table = {qualname: P.group_signatures()[qualname]}
    monkeypatch.setattr(P, "entries_to_compile", lambda groups=("fast",): dict(table))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert P.precompile(1, serial=True) == []
    assert [p.name.split("-")[0] for p in (tmp_path / "numba").rglob("*.nbi")] == ["_edges.ray_groups.serial"]
    assert P.precompile(1, serial=False) == []
    assert sorted(p.name.split("-")[0] for p in (tmp_path / "numba").rglob("*.nbi")) == \
        ["_edges.ray_groups", "_edges.ray_groups.serial"]


@pytest.mark.skipif(not TWO_THREADS, reason="one numba thread: only the serial builds run here")
@pytest.mark.parametrize("quality", ["fast", "balanced"])
def test_a_frame_is_the_same_bits_on_the_serial_and_the_parallel_builds(quality):
    """Every kernel of a preset's frame (Cassini: mirrors, glints, edges, Earth behind) on one
    thread (the serial builds: the CLI's pool workers) and on two (the parallel builds)."""
    from orbit.pose import look_at
    from raytrace.camera import Camera
    from raytrace.lighting import Earth, Lighting
    from raytrace.scene import Scene
    from raytrace.shade import render
    from raytrace.targets import load_target
    cam = Camera(160, 120, 200.0, 200.0, 79.5, 59.5)
    sun = np.array([0.6, 0.3, 0.74])
    frames = {}
    for threads in (1, 2):
        # a scene and a light of its own for each: nothing one render computed (the radiance
        # cache, the environment's tables) is reused by the other
        scene = Scene(load_target("cassini"))
        rho = np.array([3.0, -25.0, 8.0])
        rho *= 0.6 * scene.scale_m / np.linalg.norm(rho)  # the body and antenna in view, ~15 % of the pixels
        R = look_at(rho)
        light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)), earth=Earth((0, 0, -1), 6.778e6, albedo=0.3))
        with _threads(threads):
            frames[threads] = render(scene, cam, R, -R @ rho, light, quality=quality, seed=3,
                                     samples=8 if quality == "balanced" else None)
    a, b = frames[1], frames[2]
    assert (a.geometry.instance > 0).mean() > 0.1
    assert a.radiance.tobytes() == b.radiance.tobytes()
    assert a.geometry.depth_m.tobytes() == b.geometry.depth_m.tobytes()
