"""raytrace._precompile: the recorded signatures of every group's kernels still match the code
(regenerate with ``python benchmarks/record_kernel_signatures.py`` when this fails), the groups merge
without losing a signature, each helper compiles once, within the first kernel that calls it,
compiling reports stale entries instead of failing, and its progress as each entry finishes."""
import os
import sys
from pathlib import Path
import inspect

import pytest

from numba.core import types
from numba.core.registry import CPUDispatcher

from raytrace import _precompile as P
from raytrace._jit_signatures import EXTRA_SIGNATURES, SIGNATURES


@pytest.mark.parametrize("group", P.GROUPS)
def test_every_recorded_kernel_exists_and_takes_its_recorded_arguments(group):
    entries = SIGNATURES if group == "fast" else EXTRA_SIGNATURES[group]
    assert len(entries) >= (30 if group == "fast" else 1)
    for qualname, (cost, sigs) in entries.items():
        f = P.dispatcher(qualname)
        assert isinstance(f, CPUDispatcher), qualname
        assert isinstance(P.dispatcher(qualname, serial=True), CPUDispatcher), qualname
        assert cost >= 0.0 and sigs
        n_args = len(inspect.signature(f.py_func).parameters)
        for sig in sigs:
            tys = P.signature_types(sig)
            assert isinstance(tys, tuple) and len(tys) == n_args, (qualname, sig)
            assert all(isinstance(t, types.Type) for t in tys)


def test_each_helper_is_compiled_once_within_the_first_kernel_that_calls_it():
    """raytrace._precompile.dependencies reads which entries a kernel's code calls (also through
    inlined helpers and module attributes such as ``env.earth_albedo``); the schedule starts
    the longest entries first but never two tasks that would compile the same helper, so each
    helper is compiled once, within its first caller (as a first call compiles it), and read
    from the cache by the others."""
    deps = P.dependencies(SIGNATURES)
    assert set(deps) == set(SIGNATURES)
    assert {"raytrace.brdf.brdf_cos", "raytrace.brdf._lambda"} <= deps["raytrace._surface.add_mirror"]
    assert "raytrace.environment.procedural_albedo" in deps["raytrace._background.earth_background"]
    assert "raytrace._earth._hash3" in deps["raytrace.environment.procedural_albedo"]
    assert deps["raytrace.brdf._lambda"] == set()
    d = {"k1": {"h", "g"}, "k2": {"h"}, "k3": set(), "h": {"g"}, "g": set()}
    waiting = ["k1", "k2", "k3", "h", "g"]
    assert P._next_tasks(waiting, d, set(), set(), 2) == [("k1", {"k1", "h", "g"}), ("k3", {"k3"})]
    assert P._next_tasks(["k2", "h", "g"], d, {"k3"}, {"k1", "h", "g"}, 1) == []  # h is being compiled
    # once k1 has compiled h and g, k2 compiles only itself and h's own task nothing new
    assert P._next_tasks(["k2", "h", "g"], d, {"k1", "h", "g", "k3"}, set(), 3) == \
        [("k2", {"k2"}), ("h", set()), ("g", set())]


def test_a_share_compiles_into_the_cache_and_reports_a_stale_entry():
    good = ("raytrace._edges.ray_groups", SIGNATURES["raytrace._edges.ray_groups"][1])
    stale = ("raytrace._edges.ray_groups", ["(int64,)"])  # wrong arity: a signature from older code
    assert P._compile_share([good]) == []
    failed = P._compile_share([stale])
    assert len(failed) == 1 and failed[0].startswith("raytrace._edges.ray_groups(int64,)")


def test_precompile_reports_its_progress_as_each_entry_finishes(tmp_path, monkeypatch):
    """precompile(..., progress=callable) calls back in the calling process once per entry, in
    recorded seconds, the last call (total, total): here on a table of its own (two cheap
    helpers, one calling the other, and a stale entry; the costs made up) compiled by two
    spawned processes into a temporary numba cache."""
    table = {
        "raytrace._sampling._hash32": (1.0, SIGNATURES["raytrace._sampling._hash32"][1]),
        "raytrace._sampling._hash01": (2.0, SIGNATURES["raytrace._sampling._hash01"][1]),  # calls _hash32
        "raytrace._sampling.permute": (0.5, ["(int64,)"]),  # wrong arity: a signature from older code
    }
    monkeypatch.setattr(P, "entries_to_compile", lambda groups=("fast",): dict(table))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))  # the workers' cache
    calls = []
    failed = P.precompile(2, ["fast"], progress=lambda done, total: calls.append((done, total)))
    assert len(failed) == 1 and failed[0].startswith("raytrace._sampling.permute(int64,)")
    assert len(calls) == len(table)
    assert all(total == 3.5 for _, total in calls)
    done = [d for d, _ in calls]
    assert done[-1] == 3.5 and done == sorted(done)
    # one call per entry; _hash01 (the longest) compiles _hash32 within it, and counts it: the
    # task of _hash32 that waited for it adds nothing
    assert sorted(b - a for a, b in zip([0.0] + done, done)) == [0.0, 0.5, 3.0]
    index = {p.name.split("-")[0] for p in (tmp_path / "numba").rglob("*.nbi")}
    assert {"_sampling._hash32", "_sampling._hash01"} <= index


def test_precompile_without_a_callback_compiles_and_returns_the_failures(tmp_path, monkeypatch):
    table = {"raytrace._sampling._hash32": (1.0, SIGNATURES["raytrace._sampling._hash32"][1])}
    monkeypatch.setattr(P, "entries_to_compile", lambda groups=("fast",): dict(table))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert P.precompile(2) == []
    assert [p.name.split("-")[0] for p in (tmp_path / "numba").rglob("*.nbi")] == ["_sampling._hash32"]


def _recorder_module():
    import importlib.util
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "record_kernel_signatures.py"
    spec = importlib.util.spec_from_file_location("record_kernel_signatures", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_recorded_compile_times_are_each_kernels_own(monkeypatch):
    """The recorder (``benchmarks/record_kernel_signatures.py``) charges a nested compile of one of our dispatchers (a
    helper a kernel calls) to the helper alone, and one of numba's own (an overload) to the
    kernel that needed it: the times add up to the compile's total."""
    from types import SimpleNamespace
    R = _recorder_module()
    clock = iter([0.0, 1.0, 3.0, 4.0, 4.5, 7.0])  # kernel, helper, numba overload
    monkeypatch.setattr(R.time, "thread_time", lambda: next(clock))

    def event(module, name, start):
        func = SimpleNamespace(__module__=module, __name__=name)
        return SimpleNamespace(data={"dispatcher": SimpleNamespace(py_func=func)}, is_start=start)

    rec = R._compile_time_recorder()
    rec.on_start(event("raytrace._surface", "add_mirror", True))  # 0.0
    rec.on_start(event("raytrace.brdf", "brdf_cos", True))  # 1.0
    rec.on_end(event("raytrace.brdf", "brdf_cos", False))  # 3.0: 2 s its own
    rec.on_start(event("numba.np.arrayobj", "impl", True))  # 4.0
    rec.on_end(event("numba.np.arrayobj", "impl", False))  # 4.5: stays with the kernel
    rec.on_end(event("raytrace._surface", "add_mirror", False))  # 7.0
    assert rec.spent["raytrace.brdf.brdf_cos"] == 2.0
    assert rec.spent["raytrace._surface.add_mirror"] == 5.0


def test_numbas_flag_comparison_keeps_its_results():
    """raytrace._jit.fast_flag_comparison: numba's compiler flags compare, hash and list their
    values as numba's own code does (every option read through its property)."""
    from numba.core.compiler import Flags
    from raytrace import _jit
    assert _jit.FAST_FLAG_COMPARISON

    def reference(f):
        return {k: getattr(f, k) for k in type(f).options}

    a, b, c = Flags(), Flags(), Flags()
    a.nrt = b.nrt = True
    c.nrt = True
    c.fastmath = {"nsz"}
    d = Flags()
    d.nrt = True
    d.boundscheck = Flags.options["boundscheck"].default  # set, to its default: equal to unset
    for f in (a, b, c, d):
        assert f.values() == reference(f) and list(f.values()) == list(reference(f))
        assert hash(f) == hash(tuple(sorted(type(f).options)))
    assert a == b and a == d and not (a == c) and a != c
    assert (a == 3) is False


def test_load_here_loads_the_recorded_kernels_into_this_process(monkeypatch):
    """load_here (the CLI's pool workers, while the scenes are built): every entry of the table
    compiled or loaded here, none reported as failed."""
    qualname = "raytrace._edges.ray_groups"
    monkeypatch.setattr(P, "entries_to_compile", lambda groups=("fast",): {qualname: SIGNATURES[qualname]})
    assert P.load_here() == []
    assert set(SIGNATURES[qualname][1]) <= {repr(tuple(s)) for s in P.dispatcher(qualname).signatures}


def test_groups_merge_into_the_union_of_their_signatures():
    merged = P.group_signatures(P.GROUPS)
    for group in P.GROUPS:
        for qualname, (cost, sigs) in (SIGNATURES if group == "fast" else EXTRA_SIGNATURES[group]).items():
            assert set(sigs) <= set(merged[qualname][1]), (group, qualname)
            assert merged[qualname][0] >= cost
    for qualname, (cost, sigs) in merged.items():
        assert len(set(sigs)) == len(sigs), qualname  # a signature in two groups is compiled once
    assert P.group_signatures() == {q: (c, list(s)) for q, (c, s) in SIGNATURES.items()}
    with pytest.raises(ValueError, match="precompile group must be one of fast, balanced, batched, reference"):
        P.group_signatures(["slow"])


def test_each_preset_group_is_probed_by_a_kernel_of_its_own():
    """The probe of a group (the kernel whose cache entry says the group is compiled) is one
    that no earlier group compiles: otherwise a warm ``fast`` cache would hide a cold
    ``balanced`` one; and one that does not call Embree itself, so that it compiles where the
    embreex wheel has no Embree 4 (where the fused gather never could, and would be looked for
    in vain on every run)."""
    assert P.probe("fast") in SIGNATURES
    for group in P.GROUPS[1:]:
        name = P.probe(group)
        assert name in EXTRA_SIGNATURES[group]
        assert name not in P.group_signatures(P.GROUPS[:P.GROUPS.index(group)])
        assert P.dispatcher(name).__module__ in ("raytrace._background", "raytrace._cache_kernels", "raytrace._edges",
                                                 "raytrace._filter", "raytrace._gather", "raytrace._rows",
                                                 "raytrace._sampling", "raytrace._surface", "raytrace.pathtrace",
                                                 "raytrace.environment")
    assert "raytrace._paths.gather_traced" in EXTRA_SIGNATURES["balanced"]


def test_kernels_calling_embree_are_left_out_only_where_embree_4_is_missing(monkeypatch):
    from raytrace import _embree
    monkeypatch.setattr(_embree, "available", lambda: True)
    with_embree = P.entries_to_compile(P.GROUPS)
    assert with_embree == P.group_signatures(P.GROUPS)
    assert "raytrace._paths.gather_traced" in with_embree
    monkeypatch.setattr(_embree, "available", lambda: False)
    without = P.entries_to_compile(P.GROUPS)
    assert not [q for q in without if q.startswith(("raytrace._paths.", "raytrace._embree."))]
    assert "raytrace._gather.gather_sum" in without  # the batched fallback's own gather
    assert set(without) == {q for q in with_embree if not q.startswith(("raytrace._paths.", "raytrace._embree."))}


def test_pool_workers_exit_when_their_parent_is_killed(tmp_path):
    """raytrace._threads.exit_with_parent (in the compile and frame pools' initializers): a
    worker whose parent is killed with SIGKILL exits instead of waiting for tasks for ever."""
    import signal
    import subprocess
    import time
    script = tmp_path / "parent.py"
    script.write_text(
        "import multiprocessing, os, time\n"
        "from concurrent.futures import ProcessPoolExecutor\n"
        "from raytrace._threads import exit_with_parent\n"
        "if __name__ == '__main__':\n"
        "    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'),\n"
        "                               initializer=exit_with_parent, initargs=(os.getpid(), 0.05))\n"
        "    print(pool.submit(os.getpid).result(), flush=True)\n"
        "    pool.submit(time.sleep, 120)\n"
        "    time.sleep(120)\n")
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, str(script)], cwd=root, stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(root)})
    worker = int(proc.stdout.readline())

    def running(pid):
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except (OSError, IndexError):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return False
            return True

    assert running(worker)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 20
    while running(worker) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not running(worker)
