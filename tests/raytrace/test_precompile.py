"""raytrace._precompile: the recorded signatures of the main job's kernels still match the code
(regenerate with ``python -m raytrace._precompile --record`` when this fails), the shares are
balanced, and compiling a share reports stale entries instead of failing."""
import inspect

from numba.core import types
from numba.core.registry import CPUDispatcher

from raytrace import _precompile as P
from raytrace._jit_signatures import SIGNATURES


def test_every_recorded_kernel_exists_and_takes_its_recorded_arguments():
    assert len(SIGNATURES) >= 30
    for qualname, (cost, sigs) in SIGNATURES.items():
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
