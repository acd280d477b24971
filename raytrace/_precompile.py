"""Compile the main job's numba kernels into numba's on-disk cache on several processes at once.

On a fresh install the first frame of ``python cli.py --target … --pattern …`` waits for numba
to compile some fifty kernels, ~40 s on one core, and every worker process compiles all of
them. :func:`precompile` splits the kernels the main job calls (:data:`SIGNATURES`, from
``raytrace/_jit_signatures.py``) over ``processes`` spawned processes, each calling
``Dispatcher.compile`` on its share with ``cache=True``, so the cache is written once, in
parallel; the workers then load every kernel from it. A kernel whose recorded signature no
longer matches the code is skipped (it compiles on first call, as without this step).

Regenerate the signatures after changing a kernel's arguments::

    python -m raytrace._precompile --record

which runs one frame of the main job in a fresh process with an empty numba cache and writes
each kernel's signatures and compile time (the time balances the shares).
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


def precompile(processes: int) -> list:
    """Compile the main job's kernels on ``processes`` spawned processes (see the module
    notes); returns the entries that failed (empty when all compiled)."""
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing
    from ._jit_signatures import SIGNATURES
    parts = shares(SIGNATURES, processes)
    with ProcessPoolExecutor(max_workers=len(parts), mp_context=multiprocessing.get_context("spawn")) as pool:
        return [f for failed in pool.map(_compile_share, parts) for f in failed]


def _record_here(out_dir: str) -> dict:
    """One frame of the main job in this process (numba's cache empty), with every kernel's
    compile time: {qualname: (seconds, [signature reprs])}."""
    from numba.core import event
    from numba.core.registry import CPUDispatcher
    sys.path.insert(0, str(_ROOT))
    import cli
    cli._kernels_not_compiled = lambda: False  # compile here, where the recorder sees it
    with event.install_recorder("numba:compile") as rec:
        status = cli.main(["--target", "cassini", "--pattern", "spiral", "--frames", "1", "--workers", "1",
                           "--out", out_dir, "--quiet"])
    if status != 0:
        raise RuntimeError(f"the main job failed (exit {status})")
    spent, start = {}, {}
    for ts, ev in rec.buffer:
        d = ev.data["dispatcher"]
        key = (f"{d.py_func.__module__}.{d.py_func.__name__}", str(ev.data.get("args")))
        if ev.is_start:
            start[key] = ts
        elif key in start:
            spent[key[0]] = spent.get(key[0], 0.0) + ts - start.pop(key)
    out = {}
    for name, mod in sorted(sys.modules.items()):
        if name.split(".")[0] not in ("raytrace", "degrade", "orbit"):
            continue
        for attr, obj in sorted(vars(mod).items()):
            if isinstance(obj, CPUDispatcher) and obj.__module__ == name and obj.signatures:
                sigs = [repr(tuple(s)) for s in obj.signatures if "Literal" not in repr(tuple(s))]
                if sigs:
                    out[f"{name}.{attr}"] = (round(spent.get(f"{name}.{attr}", 0.0), 2), sigs)
    return out


def record() -> None:
    """Write ``raytrace/_jit_signatures.py`` from one frame of the main job in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
        res = subprocess.run([sys.executable, "-m", "raytrace._precompile", "--record-here", str(Path(tmp) / "o")],
                             cwd=_ROOT, env=env, capture_output=True, text=True, check=True)
    sig = json.loads(res.stdout.strip().splitlines()[-1])
    lines = ['"""Signatures and compile times [s] of the numba kernels one frame of the main job calls',
             '(generated by ``python -m raytrace._precompile --record``; see raytrace._precompile)."""', "",
             "SIGNATURES = {"]
    for qualname, (cost, sigs) in sig.items():
        lines.append(f"    {qualname!r}: ({cost}, [")
        lines += [f"        {s!r}," for s in sigs]
        lines.append("    ]),")
    lines.append("}")
    _OUT.write_text("\n".join(lines) + "\n")
    print(f"{len(sig)} kernels, {sum(len(v[1]) for v in sig.values())} signatures, "
          f"{sum(v[0] for v in sig.values()):.1f} s of compile time -> {_OUT}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--record"]:
        record()
    elif sys.argv[1:2] == ["--record-here"]:
        result = _record_here(sys.argv[2])
        print(json.dumps(result))
    elif sys.argv[1:2] == ["--time"]:
        t0 = time.perf_counter()
        bad = precompile(int(sys.argv[2]) if len(sys.argv) > 2 else 2)
        print(f"{time.perf_counter() - t0:.1f} s, failed: {bad}")
    else:
        sys.exit("usage: python -m raytrace._precompile --record | --time [processes]")
