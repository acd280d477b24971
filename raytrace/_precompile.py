"""Compile the numba kernels into numba's on-disk cache on several processes at once.

On a fresh install the first frame of ``python cli.py --target … --pattern …`` waits for numba
to compile some fifty kernels, ~40 s on one core, and every worker process compiles all of
them; ``--quality balanced`` adds ~110 s of kernels on one core (the fused final gather and
lobe paths ~80 s of it), ``reference`` ~15 s (a 2-core AMD EPYC, 2026-11-27). :func:`precompile` splits the kernels of the requested groups over
``processes`` spawned processes, each calling ``Dispatcher.compile`` on its share with
``cache=True``, so the cache is written once, in parallel; the workers then load every kernel
from it. A kernel whose recorded signature no longer matches the code is skipped (it compiles
on first call, as without this step).

The groups (``raytrace/_jit_signatures.py``): ``fast``, the kernels one frame of the main job
calls (:data:`SIGNATURES`); then, each holding only what the one before did not compile,
``balanced`` (a ``--quality balanced`` frame), ``batched`` (the same frame through the
batched fallback, :data:`raytrace.shade._FUSED_GATHER` and
:data:`raytrace.scene._CAST_IN_ONE_KERNEL` False: what a machine whose embreex wheel has no
Embree 4 library runs) and ``reference``. Regenerate them after changing a
kernel's arguments::

    python -m raytrace._precompile --record

which runs the four frames in a fresh process with an empty numba cache and writes each
kernel's signatures and compile time (the time balances the shares).
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[1]
_OUT = Path(__file__).with_name("_jit_signatures.py")


def _namespace() -> dict:
    """Names of numba's types, for reading back the recorded signatures (``repr`` of each)."""
    from numba.core import types
    ns = {k: getattr(types, k) for k in dir(types) if not k.startswith("_")}
    ns["bool"] = types.boolean
    return ns


def signature_types(sig: str) -> tuple:
    """The tuple of numba types a recorded signature string stands for."""
    return eval(sig, {"__builtins__": {}}, _namespace())  # noqa: S307 (our own file's reprs)


def dispatcher(qualname: str):
    """The numba dispatcher ``module.function`` of a recorded entry."""
    module, _, name = qualname.rpartition(".")
    return getattr(importlib.import_module(module), name)


def _compile_share(items: list) -> list:
    """Compile (into the on-disk cache) the recorded signatures of ``items`` = [(qualname,
    signatures)]; returns the entries that could not be compiled, with the reason."""
    failed = []
    for qualname, sigs in items:
        for sig in sigs:
            try:
                dispatcher(qualname).compile(signature_types(sig))
            except Exception as exc:  # a stale entry: it compiles on first call instead
                failed.append(f"{qualname}{sig}: {type(exc).__name__}")
    return failed


def shares(signatures: dict, processes: int) -> list:
    """The entries split into ``processes`` shares of about equal recorded compile time
    (longest first, each to the least loaded share)."""
    out = [[] for _ in range(max(1, processes))]
    load = [0.0] * len(out)
    for qualname, (cost, sigs) in sorted(signatures.items(), key=lambda kv: (-kv[1][0], kv[0])):
        k = load.index(min(load))
        out[k].append((qualname, sigs))
        load[k] += cost
    return [s for s in out if s]


GROUPS = ("fast", "balanced", "batched", "reference")


def group_signatures(groups=("fast",)) -> dict:
    """{qualname: (seconds, [signatures])} of the kernels of ``groups`` (names in
    :data:`GROUPS`), merged: a kernel in several groups gets the union of its signatures and
    the sum of their compile times."""
    from ._jit_signatures import EXTRA_SIGNATURES, SIGNATURES
    out = {}
    for g in groups:
        if g not in GROUPS:
            raise ValueError(f"precompile group must be one of {', '.join(GROUPS)}, got {g!r}")
        for qualname, (cost, sigs) in (SIGNATURES if g == "fast" else EXTRA_SIGNATURES[g]).items():
            c0, s0 = out.get(qualname, (0.0, []))
            out[qualname] = (round(c0 + cost, 2), s0 + [x for x in sigs if x not in s0])
    return out


# modules whose kernels call Embree themselves: they cannot compile (link) where the embreex
# wheel has no Embree 4 library, so none of them may stand for a group (it would never be
# found in the cache, and every run would compile the group again)
_DIRECT_EMBREE = ("raytrace._paths.", "raytrace._embree.")


def probe(group: str) -> str | None:
    """The kernel whose presence in numba's cache stands for ``group`` being compiled: its
    costliest kernel that no earlier group holds and that does not call Embree itself (None if
    it has none such)."""
    earlier = set(group_signatures(GROUPS[:GROUPS.index(group)]))
    own = [(c, q) for q, (c, _) in group_signatures([group]).items()
           if q not in earlier and not q.startswith(_DIRECT_EMBREE)]
    return max(own)[1] if own else None


def entries_to_compile(groups=("fast",)) -> dict:
    """:func:`group_signatures` of ``groups``, without the kernels that call Embree themselves
    where the embreex wheel has no Embree 4 library (they could not link; the batched fallback
    runs instead)."""
    from . import _embree
    entries = group_signatures(groups)
    if not _embree.available():
        entries = {q: e for q, e in entries.items() if not q.startswith(_DIRECT_EMBREE)}
    return entries


def load_here(groups=("fast",)) -> list:
    """The kernels of ``groups`` (:func:`entries_to_compile`) in this process, from numba's
    on-disk cache where it holds them (compiled where not); returns the entries that failed.
    What a first call would do, done ahead (the CLI's pool workers, while their scenes are
    built)."""
    return _compile_share(list(entries_to_compile(groups).items()))


def precompile(processes: int, groups=("fast",)) -> list:
    """Compile the kernels of ``groups`` (see the module notes; :func:`entries_to_compile`) on
    ``processes`` spawned processes; returns the entries that failed (empty when all
    compiled)."""
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing
    from ._threads import exit_with_parent, pool_processes
    parts = shares(entries_to_compile(groups), processes)
    pool = ProcessPoolExecutor(max_workers=len(parts), mp_context=multiprocessing.get_context("spawn"),
                               initializer=exit_with_parent, initargs=(os.getpid(),))
    try:
        return [f for failed in pool.map(_compile_share, parts) for f in failed]
    except KeyboardInterrupt:  # Ctrl-C, or the CLI's SIGTERM: stop compiling now, not in a minute
        # numba writes each cache file under a temporary name and renames it: a compiler killed
        # mid-write leaves no broken entry
        for proc in pool_processes(pool):
            proc.kill()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _dispatchers() -> dict:
    """{qualname: [signature reprs]} of every compiled kernel of our packages loaded now
    (literal-typed signatures left out: they cannot be compiled ahead)."""
    from numba.core.registry import CPUDispatcher
    out = {}
    for name, mod in sorted(sys.modules.items()):
        if name.split(".")[0] not in ("raytrace", "degrade", "orbit"):
            continue
        for attr, obj in sorted(vars(mod).items()):
            if isinstance(obj, CPUDispatcher) and obj.__module__ == name and obj.signatures:
                sigs = [repr(tuple(s)) for s in obj.signatures if "Literal" not in repr(tuple(s))]
                if sigs:
                    out[f"{name}.{attr}"] = sigs
    return out


# the frames each group is recorded from (after the main job's, group "fast"): full-size
# frames, so that every stage of the preset runs (edge pixels, coverage, Earth behind)
_RECORD_ARGS = {
    "fast": [],
    "balanced": ["--quality", "balanced", "--samples", "16"],
    "batched": ["--quality", "balanced", "--samples", "16"],
    "reference": ["--quality", "reference", "--samples", "2"],
}


def _record_here(out_dir: str) -> dict:
    """One frame per group (:data:`GROUPS`) in this process (numba's cache empty), with every
    kernel's compile time: {group: {qualname: (seconds, [signature reprs new in the group])}}."""
    from numba.core import event
    sys.path.insert(0, str(_ROOT))
    import cli
    from raytrace import scene, shade
    cli._kernels_not_compiled = lambda *a, **k: []  # compile here, where the recorder sees it
    seen: dict = {}
    result = {}
    for group in GROUPS:
        shade._FUSED_GATHER = group != "batched"
        scene._CAST_IN_ONE_KERNEL = group != "batched"  # the geometry pass's fallback too
        with event.install_recorder("numba:compile") as rec:
            status = cli.main(["--target", "cassini", "--pattern", "spiral", "--frames", "1", "--workers", "1",
                               "--out", str(Path(out_dir) / group), "--quiet", *_RECORD_ARGS[group]])
        if status != 0:
            raise RuntimeError(f"the {group} frame failed (exit {status})")
        spent, start = {}, {}
        for ts, ev in rec.buffer:
            d = ev.data["dispatcher"]
            key = (f"{d.py_func.__module__}.{d.py_func.__name__}", str(ev.data.get("args")))
            if ev.is_start:
                start[key] = ts
            elif key in start:
                spent[key[0]] = spent.get(key[0], 0.0) + ts - start.pop(key)
        out = {}
        for qualname, sigs in _dispatchers().items():
            new = [x for x in sigs if x not in seen.get(qualname, ())]
            if new:
                out[qualname] = (round(spent.get(qualname, 0.0), 2), new)
                seen.setdefault(qualname, set()).update(new)
        result[group] = out
    shade._FUSED_GATHER = True
    return result


def _entries(sig: dict, indent: str) -> list:
    lines = []
    for qualname, (cost, sigs) in sig.items():
        lines.append(f"{indent}{qualname!r}: ({cost}, [")
        lines += [f"{indent}    {s!r}," for s in sigs]
        lines.append(f"{indent}]),")
    return lines


def record() -> None:
    """Write ``raytrace/_jit_signatures.py`` from one frame per group in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
        res = subprocess.run([sys.executable, "-m", "raytrace._precompile", "--record-here", str(Path(tmp) / "o")],
                             cwd=_ROOT, env=env, capture_output=True, text=True, check=True)
    groups = json.loads(res.stdout.strip().splitlines()[-1])
    lines = ['"""Signatures and compile times [s] of the numba kernels one frame of the main job calls',
             "(SIGNATURES, group ``fast``), and those a ``balanced``, a batched ``balanced`` and a",
             "``reference`` frame add (EXTRA_SIGNATURES); generated by",
             '``python -m raytrace._precompile --record`` (see raytrace._precompile)."""', "",
             "SIGNATURES = {"]
    lines += _entries(groups["fast"], "    ")
    lines += ["}", "", "EXTRA_SIGNATURES = {"]
    for g in GROUPS[1:]:
        lines.append(f"    {g!r}: {{")
        lines += _entries(groups[g], "        ")
        lines.append("    },")
    lines.append("}")
    _OUT.write_text("\n".join(lines) + "\n")
    for g in GROUPS:
        sig = groups[g]
        print(f"{g}: {len(sig)} kernels, {sum(len(v[1]) for v in sig.values())} signatures, "
              f"{sum(v[0] for v in sig.values()):.1f} s of compile time")
    print(f"-> {_OUT}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--record"]:
        record()
    elif sys.argv[1:2] == ["--record-here"]:
        result = _record_here(sys.argv[2])
        print(json.dumps(result))
    elif sys.argv[1:2] == ["--time"]:
        t0 = time.perf_counter()
        bad = precompile(int(sys.argv[2]) if len(sys.argv) > 2 else 2, sys.argv[3:] or ("fast",))
        print(f"{time.perf_counter() - t0:.1f} s, failed: {bad}")
    else:
        sys.exit("usage: python -m raytrace._precompile --record | --time [processes [group ...]]")
