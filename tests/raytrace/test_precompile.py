"""raytrace._precompile: the recorded signatures of every group's kernels still match the code
(regenerate with ``python -m raytrace._precompile --record`` when this fails), the groups merge
without losing a signature, the shares are balanced, and compiling a share reports stale
entries instead of failing."""
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
        assert cost >= 0.0 and sigs
        n_args = len(inspect.signature(f.py_func).parameters)
        for sig in sigs:
            tys = P.signature_types(sig)
            assert isinstance(tys, tuple) and len(tys) == n_args, (qualname, sig)
            assert all(isinstance(t, types.Type) for t in tys)


def test_shares_hold_every_entry_once_and_balance_the_compile_time():
    parts = P.shares(SIGNATURES, 2)
    names = [q for part in parts for q, _ in part]
    assert sorted(names) == sorted(SIGNATURES)
    load = [sum(SIGNATURES[q][0] for q, _ in part) for part in parts]
    biggest = max(c for c, _ in SIGNATURES.values())
    assert abs(load[0] - load[1]) <= biggest + 1e-9  # greedy longest-first: within one entry
    assert P.shares(SIGNATURES, 1) == [sorted(((q, s) for q, (c, s) in SIGNATURES.items()),
                                              key=lambda e: (-SIGNATURES[e[0]][0], e[0]))]


def test_a_share_compiles_into_the_cache_and_reports_a_stale_entry():
    good = ("raytrace._shading.ray_groups", SIGNATURES["raytrace._shading.ray_groups"][1])
    stale = ("raytrace._shading.ray_groups", ["(int64,)"])  # wrong arity: a signature from older code
    assert P._compile_share([good]) == []
    failed = P._compile_share([stale])
    assert len(failed) == 1 and failed[0].startswith("raytrace._shading.ray_groups(int64,)")


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
        assert P.dispatcher(name).__module__ in ("raytrace._shading", "raytrace.pathtrace", "raytrace.cache",
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
    assert "raytrace._shading.gather_sum" in without  # the batched fallback's own gather
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
