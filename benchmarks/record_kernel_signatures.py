"""Record the numba kernels' signatures and compile times into ``raytrace/_jit_signatures.py``.

    python benchmarks/record_kernel_signatures.py

Runs the frames of each kernel group of :mod:`raytrace._precompile` (``fast``: the main job's;
``balanced``, ``batched``, ``reference``: what those frames add) in a fresh process with an
empty numba cache, and writes each kernel's signatures and its own compile time in CPU seconds
(the time orders the compile of a fresh install and measures its progress). Run it after
changing a kernel's arguments (``tests/raytrace/test_precompile.py`` fails until then).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from raytrace._precompile import GROUPS, _threaded  # noqa: E402

OUT = ROOT / "raytrace" / "_jit_signatures.py"
PACKAGES = ("raytrace", "degrade", "orbit")  # whose kernels are recorded


def _dispatchers() -> dict:
    """{qualname: [signature reprs]} of every compiled kernel of our packages loaded now
    (literal-typed signatures left out: they cannot be compiled ahead)."""
    from numba.core.registry import CPUDispatcher
    out = {}
    for name, mod in sorted(sys.modules.items()):
        if name.split(".")[0] not in PACKAGES:
            continue
        for attr, obj in sorted(vars(mod).items()):
            if getattr(obj, "__module__", None) != name:
                continue
            builds = [obj] if isinstance(obj, CPUDispatcher) else [obj.parallel, obj.serial] if _threaded(obj) else []
            sigs = []
            for build in builds:
                sigs += [r for r in map(repr, map(tuple, build.signatures)) if "Literal" not in r and r not in sigs]
            if sigs:
                out[f"{name}.{attr}"] = sigs
    return out


# the frames each group is recorded from (after the main job's, group "fast"): full-size
# frames, so that every stage of the preset runs (edge pixels, coverage, Earth behind). The
# main job's from two frames: the first has no penumbra to sample (no solar-disc shadow rays,
# raytrace._surface.sun_disc_dirs), the second has, as most frames of the job do
_RECORD_ARGS = {
    "fast": ["--frames", "2"],
    "balanced": ["--frames", "1", "--quality", "balanced", "--samples", "16"],
    "batched": ["--frames", "1", "--quality", "balanced", "--samples", "16"],
    "reference": ["--frames", "1", "--quality", "reference", "--samples", "2"],
}


def _compile_time_recorder():
    """A numba ``numba:compile`` listener whose ``spent`` collects {qualname: seconds}: each of
    our dispatchers' own compile time, the CPU seconds of the compiling thread between the
    event's start and end less those of the compiles of our other dispatchers nested in it (a
    kernel's first call compiles the helpers it calls, which are entries of their own; numba's
    internal overloads stay with the kernel that needed them first). Own times add up to the
    whole compile's, the total that :func:`precompile`'s ``progress`` and the CLI's estimate
    count in; CPU seconds, so that a busy machine does not inflate them."""
    from numba.core.event import Listener

    class CompileTimes(Listener):
        def __init__(self):
            self.spent: dict = {}
            self._stack: list = []

        def on_start(self, event) -> None:
            d = event.data["dispatcher"]
            self._stack.append([f"{d.py_func.__module__}.{d.py_func.__name__}", time.thread_time(), 0.0])

        def on_end(self, event) -> None:
            qualname, t0, nested = self._stack.pop()
            seconds = time.thread_time() - t0
            if self._stack and qualname.split(".")[0] in PACKAGES:
                self._stack[-1][2] += seconds
            self.spent[qualname] = self.spent.get(qualname, 0.0) + seconds - nested

    return CompileTimes()


def _record_here(out_dir: str) -> dict:
    """The frames of each group (:data:`GROUPS`, :data:`_RECORD_ARGS`) in this process (numba's
    cache empty), with every
    kernel's own compile time (:func:`_compile_time_recorder`): {group: {qualname: (seconds,
    [signature reprs new in the group])}}."""
    from numba.core import event
    import cli
    from raytrace import presets
    from raytrace.dataset import jit
    jit.kernels_not_compiled = lambda *a, **k: []  # compile here, where the recorder sees it
    seen: dict = {}
    result = {}
    for group in GROUPS:
        presets.FUSED_GATHER = group != "batched"
        presets.CAST_IN_ONE_KERNEL = group != "batched"  # the geometry pass's fallback too
        times = _compile_time_recorder()
        with event.install_listener("numba:compile", times):
            status = cli.main(["--target", "cassini", "--pattern", "spiral", "--workers", "1",
                               "--out", str(Path(out_dir) / group), "--quiet", *_RECORD_ARGS[group]])
        if status != 0:
            raise RuntimeError(f"the {group} frame failed (exit {status})")
        out = {}
        for qualname, sigs in _dispatchers().items():
            new = [x for x in sigs if x not in seen.get(qualname, ())]
            if new:
                out[qualname] = (round(times.spent.get(qualname, 0.0), 2), new)
                seen.setdefault(qualname, set()).update(new)
        result[group] = out
    presets.FUSED_GATHER = True
    presets.CAST_IN_ONE_KERNEL = True
    return result


def _entries(sig: dict, indent: str) -> list:
    lines = []
    for qualname, (cost, sigs) in sig.items():
        lines.append(f"{indent}{qualname!r}: ({cost}, [")
        lines += [f"{indent}    {s!r}," for s in sigs]
        lines.append(f"{indent}]),")
    return lines


def record() -> None:
    """Write ``raytrace/_jit_signatures.py`` from the frames of each group in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
        res = subprocess.run([sys.executable, __file__, "--here", str(Path(tmp) / "o")],
                             cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    groups = json.loads(res.stdout.strip().splitlines()[-1])
    lines = ['"""Signatures and own compile times [CPU s] of the numba kernels the main job\'s frames call',
             "(SIGNATURES, group ``fast``), and those a ``balanced``, a batched ``balanced`` and a",
             "``reference`` frame add (EXTRA_SIGNATURES); generated by",
             '``python benchmarks/record_kernel_signatures.py`` (see raytrace._precompile)."""', "",
             "SIGNATURES = {"]
    lines += _entries(groups["fast"], "    ")
    lines += ["}", "", "EXTRA_SIGNATURES = {"]
    for g in GROUPS[1:]:
        lines.append(f"    {g!r}: {{")
        lines += _entries(groups[g], "        ")
        lines.append("    },")
    lines.append("}")
    OUT.write_text("\n".join(lines) + "\n")
    for g in GROUPS:
        sig = groups[g]
        print(f"{g}: {len(sig)} kernels, {sum(len(v[1]) for v in sig.values())} signatures, "
              f"{sum(v[0] for v in sig.values()):.1f} s of compile time")
    print(f"-> {OUT}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--here"]:
        print(json.dumps(_record_here(sys.argv[2])))
    elif len(sys.argv) == 1:
        record()
    else:
        sys.exit("usage: python benchmarks/record_kernel_signatures.py")
