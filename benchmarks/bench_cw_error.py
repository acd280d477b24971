#!/usr/bin/env python3
"""Benchmark: error of the closed-form CW solution against nonlinear propagation.

    python benchmarks/bench_cw_error.py            # prints a Markdown report
    python benchmarks/bench_cw_error.py --quick    # fewer points in the exponent fit

For a 400 km circular target orbit (i = 51.6 deg, u₀ = 0) prints |r_nonlinear − r_CW| [m]
for ρ ∈ {10 m, 100 m, 1 km, 10 km} at 1/4, 1 and 5 orbits for

  x₀ = ρ, ẏ₀ = −2n x₀     (closed CW ellipse, radial semi-axis ρ)
  V-bar, y₀ = ρ at rest
  with J2: the ellipse A = ρ/2 (first column of the table in docs/accuracy.md, "CW error after
           one orbit") at ρ = 10 m and 100 m, and its
           along-track drift per orbit

using orbit.nonlinear (DOP853, rtol 1e-12; "rotating" formulation for two-body,
"eci" with J2), the least-squares exponent of error vs ρ over 10 m … 10 km, the prefactor
c of error ≈ c ρ²/a per orbit against its closed-form value, and the agreement of the two
formulations.
Runs in a few seconds.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
import scipy

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from orbit.nonlinear import cw_error, propagate_nonlinear  # noqa: E402
from orbit.reference import ReferenceOrbit  # noqa: E402

ORBIT = ReferenceOrbit()
N, A_M, T = ORBIT.n_rad_s, ORBIT.a_m, ORBIT.period_s
RHOS = (10.0, 100.0, 1e3, 1e4)
HORIZONS = ((0.25, "T/4"), (1.0, "T"), (5.0, "5T"))


def x0_family(rho: float) -> np.ndarray:
    return np.array([rho, 0.0, 0.0, 0.0, -2.0 * N * rho, 0.0])


def vbar_family(rho: float) -> np.ndarray:
    return np.array([0.0, rho, 0.0, 0.0, 0.0, 0.0])


def ellipse_family(rho: float) -> np.ndarray:
    return np.array([rho / 2, 0.0, 0.0, 0.0, -2.0 * N * rho / 2, 0.0])


FAMILIES = {
    "x₀ = ρ, ẏ₀ = −2n x₀": (x0_family, 3 * math.pi, "3π"),
    "V-bar y₀ = ρ": (vbar_family, 6 * math.pi, "6π"),
}


def fmt(x: float) -> str:
    return f"{x:.3e}"


def length(rho: float) -> str:
    return f"{rho / 1e3:g} km" if rho >= 1e3 else f"{rho:g} m"


def error_row(label: str, s0: np.ndarray, rho: float, j2: bool) -> tuple[str, float]:
    t = T * np.array([h for h, _ in HORIZONS])
    err = cw_error(s0, ORBIT, t, j2=j2)
    cells = " | ".join(fmt(e) for e in err.position_error_m)
    return f"| {label} | {length(rho)} | {cells} |", float(err.position_error_m[1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="4 instead of 13 points in the exponent fit")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    cmd = "python benchmarks/bench_cw_error.py" + (" --quick" if args.quick else "")

    print("# CW position error |r_nonlinear − r_CW| [m]")
    print()
    print(f"Regenerate with `{cmd}`.")
    print(f"Python {platform.python_version()}, NumPy {np.__version__}, SciPy {scipy.__version__}, "
          f"{platform.machine()}.")
    print(f"Target orbit: circular, altitude {ORBIT.altitude_m / 1e3:.0f} km (a = {A_M:.0f} m), "
          f"i = {math.degrees(ORBIT.inclination_rad):.1f} deg, u₀ = 0, T = {T:.3f} s. "
          "Nonlinear reference: DOP853, rtol 1e-12 (orbit.nonlinear).")
    print()
    print("| initial state | ρ | " + " | ".join(f"after {name}" for _, name in HORIZONS) + " |")
    print("|---|---:|" + "---:|" * len(HORIZONS))
    one_orbit: dict[str, list[float]] = {}
    for label, (make, _, _) in FAMILIES.items():
        for rho in RHOS:
            row, e1 = error_row(label + " (two-body)", make(rho), rho, j2=False)
            print(row)
            one_orbit.setdefault(label, []).append(e1)
    drifts = []
    for rho in (10.0, 100.0):
        row, _ = error_row("ellipse A = ρ/2, **with J2**", ellipse_family(rho), rho, j2=True)
        print(row)
        k = np.arange(4)
        err = cw_error(ellipse_family(rho), ORBIT, k * T, j2=True)
        drifts.append((rho, float(np.polyfit(k, err.along_track_error_m, 1)[0])))
    print()

    # exponent and prefactor
    rho_fit = np.logspace(1.0, 4.0, 4 if args.quick else 13)
    print(f"Least-squares fit of log(error after T) vs log ρ over {rho_fit.size} values of "
          "ρ = 10 m … 10 km, and the prefactor c = error·a/ρ²:")
    print()
    print("| initial state | exponent | c at 10 m | c at 10 km | c in closed form |")
    print("|---|---:|---:|---:|---:|")
    fits = dict(FAMILIES)
    fits["ellipse A = ρ/2"] = (ellipse_family, 3 * math.pi / 4, "3π/4")
    for label, (make, c_spec, c_name) in fits.items():
        err = np.array([cw_error(make(r), ORBIT, T).max_position_error_m for r in rho_fit])
        slope = np.polyfit(np.log(rho_fit), np.log(err), 1)[0]
        c = err * A_M / rho_fit ** 2
        print(f"| {label} | {slope:.4f} | {c[0]:.4f} | {c[-1]:.4f} | {c_name} = {c_spec:.4f} |")
    print()

    print("J2 along-track drift per orbit of the ellipse A = ρ/2 (slope over 3 orbits):")
    print()
    for rho, drift in drifts:
        print(f"* ρ = {length(rho)}: {drift:+.4f} m/orbit ({100 * drift / rho:+.2f} % of ρ)")
    print()

    s0 = np.concatenate([1e4 * np.array([0.6, -0.5, 0.4]), N * 1e4 * np.array([0.3, 0.7, -0.2])])
    parts = []
    for rtol in (1e-12, 1e-13):
        rot = propagate_nonlinear(s0, ORBIT, T, rtol=rtol, method="rotating")[0]
        eci = propagate_nonlinear(s0, ORBIT, T, rtol=rtol, method="eci")[0]
        parts.append(f"{np.linalg.norm(rot[:3] - eci[:3]):.2e} m at rtol {rtol:.0e}")
    print("Formulations \"rotating\" vs \"eci\" (two-body), |ρ| ≈ 8.8 km, one orbit: "
          + "; ".join(parts) + ".")
    print()
    print(f"Runtime {time.perf_counter() - start:.1f} s.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
