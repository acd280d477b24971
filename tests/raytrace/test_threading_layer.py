"""numba's threading layer: TBB where its wheel is installed (``raytrace._jit.prefer_tbb``),
the user's ``NUMBA_THREADING_LAYER`` otherwise, and the same files under either.

Each case runs ``cli.py render-scene`` (or a probe) in a fresh interpreter: numba picks its
layer once per process, at the first parallel kernel.
"""

import hashlib
import importlib.metadata
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# one parallel kernel run: numba picks (and launches) its threading layer here
KERNEL = ("import numba, numpy as np\n"
          "@numba.njit(parallel=True)\n"
          "def f(a):\n"
          "    for i in numba.prange(a.size):\n"
          "        a[i] += 1.0\n"
          "f(np.zeros(8))\n")
PROBE = "import raytrace._jit as j\n" + KERNEL + "print(j.TBB, numba.threading_layer())\n"


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    env.update(extra)
    return env


def _layer_available(name: str) -> bool:
    """Whether numba can run ``name`` here (a fresh interpreter that asks for it)."""
    r = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=_env(NUMBA_THREADING_LAYER=name),
                       capture_output=True, text=True, timeout=300)
    return r.returncode == 0 and r.stdout.split()[-1:] == [name]


def _tbb_installed() -> bool:
    try:
        importlib.metadata.distribution("tbb")
        return True
    except importlib.metadata.PackageNotFoundError:
        return False


@pytest.mark.skipif(not _tbb_installed(), reason="the tbb wheel is not installed (not an x86-64 platform)")
def test_tbb_chosen_when_installed():
    r = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["True", "tbb"]


def test_user_choice_wins():
    # workqueue: numba's own layer, present everywhere
    r = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=_env(NUMBA_THREADING_LAYER="workqueue"),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "workqueue"]


def test_layer_already_running_stays():
    """A program that ran a parallel kernel before importing ``raytrace`` keeps its layer, and
    ``TBB`` says which it is."""
    late = KERNEL + ("before = numba.threading_layer()\n"
                     "import raytrace._jit as j\n"
                     "print(before, numba.threading_layer(), j.TBB)\n")
    r = subprocess.run([sys.executable, "-c", late], cwd=ROOT, env=_env(), capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    before, after, tbb = r.stdout.split()
    assert after == before and tbb == str(before == "tbb")


def _render(scene: Path, out: Path, layer: str) -> dict:
    """``cli.py render-scene`` of ``scene`` with ``fast`` and ``balanced`` (one process, two
    numba threads) into ``out/fast`` and ``out/balanced``; the images' digests."""
    code = ("import sys, cli\n"
            "scene, out = sys.argv[1:]\n"
            "sys.exit(max(cli.main(['render-scene', scene, '--out', f'{out}/{q}', '--quality', q])"
            " for q in ('fast', 'balanced')))\n")
    r = subprocess.run([sys.executable, "-c", code, str(scene), str(out)], cwd=ROOT,
                       env=_env(NUMBA_THREADING_LAYER=layer, NUMBA_NUM_THREADS="2"),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.suffix in (".png", ".exr")}


def test_same_files_under_tbb_and_openmp(tmp_path):
    """Every kernel splits its loop into numba's per-thread ranges, whichever layer runs them,
    and none sums across ranges: the images are the same bytes. Two threads, so the lighting
    context is built on its side thread while the geometry pass runs (the case TBB speeds up)."""
    if not (_layer_available("tbb") and _layer_available("omp")):
        pytest.skip("needs both the tbb and the omp threading layers")
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({
        "target": "cassini",
        "camera": {"K": [[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]], "width": 320, "height": 240,
                   "R_cam_from_body": [0.8, 0.6, 0, -0.36, 0.48, 0.8, 0.48, -0.64, 0.6], "t_cam_m": [0.1, -0.2, 14.0]},
        "sun": {"sun_dir_body": [0.6, -0.48, 0.64], "sun_irradiance_W_m2": 1361.0},
        "earth": {"earth_dir_body": [-0.48, 0.64, -0.6], "earth_distance_m": 6778137.0, "albedo": 0.3},
        "ambient_radiance_W_m2_sr": 0.5, "seed": 7}))
    a = _render(scene, tmp_path / "omp", "omp")
    b = _render(scene, tmp_path / "tbb", "tbb")
    assert len(a) == 10 and a == b
