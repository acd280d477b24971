#!/usr/bin/env python3
"""Benchmark: CW propagation of one state to 10⁶ epochs, three methods side by side.

    python benchmarks/bench_orbit.py            # prints a Markdown table
    python benchmarks/bench_orbit.py --quick    # fewer repeats

Methods, interleaved round-robin in one run so machine noise hits them alike:
  closed form   orbit.cw.propagate (component-wise closed-form solution)
  Φ @ s0        orbit.cw.stm(n, t) @ s0 (build 10⁶ 6×6 matrices, then multiply)
  DOP853        scipy solve_ivp on ṡ = A s with dense output evaluated at the epochs
                (the time-stepping alternative; rtol 1e-10)
Reports the median wall time, ns per epoch, the ratio to the closed form, the maximum
difference to the closed form, and the peak traced memory of one call.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from orbit import cw  # noqa: E402

N = 1.1313666536110223e-3
S0 = np.array([5.0, 30.0, 2.0, 0.012, -0.004, 0.002])  # state E5 of tests/orbit/test_cw.py


def closed_form(t):
    return cw.propagate(S0, N, t)


def phi_matrix(t):
    return cw.stm(N, t) @ S0


def dop853(t):
    A = cw.system_matrix(N)
    sol = solve_ivp(lambda _t, s: A @ s, (t[0], t[-1]), S0, method="DOP853", dense_output=True,
                    rtol=1e-10, atol=1e-10)
    return sol.sol(t).T


METHODS = {"closed form (orbit.cw.propagate)": closed_form, "Φ(t) @ s0 (orbit.cw.stm)": phi_matrix,
           "DOP853 dense output (scipy)": dop853}


def peak_memory_mb(fn, t) -> float:
    tracemalloc.start()
    fn(t)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--epochs", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--quick", action="store_true", help="5 repeats")
    args = ap.parse_args(argv)
    repeats = 5 if args.quick else args.repeats
    T = 2 * math.pi / N
    t = np.linspace(0.0, 10 * T, args.epochs)  # ten orbits

    reference = closed_form(t)
    for fn in METHODS.values():  # warm-up (page faults, imports)
        fn(t)
    times = {name: [] for name in METHODS}
    for _ in range(repeats):
        for name, fn in METHODS.items():
            t0 = time.perf_counter()
            fn(t)
            times[name].append(time.perf_counter() - t0)
    base = statistics.median(times["closed form (orbit.cw.propagate)"])

    print(f"CW propagation of one state to {args.epochs:,} epochs over 10 orbits (400 km), "
          f"median of {repeats} interleaved runs; {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}, NumPy {np.__version__}.")
    print(f"Command: `python benchmarks/bench_orbit.py{' --quick' if args.quick else ''}`\n")
    print("| method | median [s] | ns / epoch | ratio to closed form | max ‖Δr‖ vs closed form [m] | peak memory [MiB] |")
    print("|---|---|---|---|---|---|")
    for name, fn in METHODS.items():
        med = statistics.median(times[name])
        err = float(np.abs(fn(t)[:, :3] - reference[:, :3]).max())
        mem = peak_memory_mb(fn, t)
        print(f"| {name} | {med:.4f} | {med / args.epochs * 1e9:.1f} | {med / base:.2f}× | {err:.1e} | {mem:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
