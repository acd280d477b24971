"""Random scenes, our renderer against Blender Cycles: does the whole light model agree?

    python benchmarks/bench_random_vs_cycles.py --out bench_out/random [--n 16] [--seed 0]
        [--spp 256] [--width 320] [--models DIR] [--presets fast balanced:16] [--no-cycles]

The time-against-error study (``bench_time_error.py``) measures our presets against our own
path tracer on twelve fixed views. This one asks whether that yardstick is right on views
nobody chose: each scene draws a target (the four built-ins with their Lambertian stand-in
albedos, as in ``bench_time_error.py``, and every ``.glb`` in ``--models``, one random grey
albedo each), a camera direction, roll, focal length, principal point and range, a Sun
direction and shadow fraction ν ∈ {1, 0.6}, Earth behind the target, elsewhere or absent (true
size, 300–3000 km below, uniform albedo 0.1–0.5), and an ambient sky of 0, 0.5 or 2
W/(m²·sr), from ``numpy.random.default_rng([seed, i])``. Every scene is a ``SCENE.json``
(``raytrace/scenefile.py``), rendered by

* our ``reference`` path tracer at ``--spp``, seeds 1 and 2, and our ``--presets``;
* Cycles 5.0.1 (``benchmarks/cycles_render.py``, the same file) at ``--spp``, seeds 1 and 2.

With ``--no-cycles`` it needs no Blender: each preset renders seeds 1 and 2 and its error
against our reference's mean (the reference's noise removed in quadrature) is the root of the
two squares' mean (``table.md``: preset vs ours).

Errors are relative RMS over the target pixels (the exact geometry mask), all channels. Half
the difference of two seeds estimates the noise of their mean (σ/√2 each), and the noise of
both means is removed in quadrature: ``ref_vs_cycles`` ≈ 0 when both converge to the same
image. A preset's error is given against Cycles' mean (Cycles' noise removed) and against our
reference's mean (ours removed). Writes ``results.jsonl`` (one row per scene, as it goes),
``table.md`` and the scene files under ``--out``. Needs ``.bpyenv`` (``README_cycles.md``).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_time_error import bpy_python, parse_presets, read_exr, rel_err, write_scene  # noqa: E402
from orbit.pose import look_at  # noqa: E402
from raytrace.scene import Scene  # noqa: E402
from raytrace.scenefile import load_scene_file  # noqa: E402
from raytrace.shade import render  # noqa: E402
from raytrace.targets import BUILTIN_TARGETS  # noqa: E402

EARTH_RADIUS_M = 6378137.0


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _meshes(target: str, out: Path, rng) -> list:
    """Mesh entries of ``target`` (a built-in name or a .glb path) for a scene file in ``out``."""
    if target.endswith(".glb"):
        return [{"path": str(Path(target).resolve()), "unit_scale_m": 1.0,
                 "albedo": [round(float(a), 3) for a in rng.uniform(0.3, 0.8, 3)]}]
    folder = out / "targets" / target
    first = folder / "sunlit.json"
    if not first.exists():
        write_scene(target, folder, 64)  # the parts and their albedos; the views are not used
    return [dict(m, path=str((folder / m["path"]).resolve())) for m in json.loads(first.read_text())["meshes"]]


def make_scene(i: int, seed: int, targets: list, out: Path, width: int) -> tuple[str, str, Path]:
    """Scene ``i``: (target, where Earth is, scene file)."""
    rng = np.random.default_rng([seed, i])
    target = targets[int(rng.integers(len(targets)))]
    meshes = _meshes(target, out, rng)
    W, H = width, width * 3 // 4
    path = out / f"scene_{i:03d}.json"
    # the target's bounding box, from the meshes as the scene file reads them
    probe = {"meshes": meshes, "camera": {"K": [[W, 0, W / 2], [0, W, H / 2], [0, 0, 1]], "width": W, "height": H,
                                          "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 1e3]},
             "sun": {"sun_dir_body": [0, 0, 1]}}
    path.write_text(json.dumps(probe))
    spec = load_scene_file(str(path))
    V = np.concatenate([c.mesh.vertices for c in spec.model.components]) + spec.body_offset_m
    centre, radius = 0.5 * (V.min(0) + V.max(0)), 0.5 * float(np.linalg.norm(V.max(0) - V.min(0)))
    f = float(rng.uniform(0.8, 1.4)) * W
    rho = _unit(rng.normal(size=3)) * radius / math.tan(math.atan(0.5 * W / f)) * float(rng.uniform(0.9, 1.6))
    R = look_at(rho, roll_rad=float(rng.uniform(-math.pi, math.pi)))
    t = -R @ (centre + rho)
    cx, cy = (W - 1) / 2 + float(rng.uniform(-0.03, 0.03)) * W, (H - 1) / 2 + float(rng.uniform(-0.03, 0.03)) * W
    doc = {"meshes": meshes,
           "camera": {"K": [[f, 0, cx], [0, f, cy], [0, 0, 1]], "width": W, "height": H,
                      "R_cam_from_body": R.ravel().tolist(), "t_cam_m": t.tolist()},
           "sun": {"sun_dir_body": _unit(rng.normal(size=3)).tolist(), "sun_irradiance_W_m2": 1361.0,
                   "shadow_fraction": float(rng.choice([1.0, 1.0, 0.6]))}}
    earth = str(rng.choice(["behind", "elsewhere", "none"]))
    if earth != "none":
        d = _unit(-rho / np.linalg.norm(rho) + 0.25 * _unit(rng.normal(size=3))) if earth == "behind" \
            else _unit(rng.normal(size=3))
        doc["earth"] = {"earth_dir_body": d.tolist(), "earth_distance_m": EARTH_RADIUS_M + float(rng.uniform(300e3, 3e6)),
                        "albedo": round(float(rng.uniform(0.1, 0.5)), 3), "texture": "uniform"}
    doc["ambient_radiance_W_m2_sr"] = float(rng.choice([0.0, 0.0, 0.5, 2.0]))
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return Path(target).name, earth, path


def cycles(py: str, scene: Path, spp: int, seed: int, exr: Path) -> np.ndarray:
    res = subprocess.run([py, str(ROOT / "benchmarks" / "cycles_render.py"), str(scene), "--spp", str(spp),
                          "--out", str(exr), "--threads", "2", "--seed", str(seed)], capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"cycles_render failed on {scene}: {res.stderr.strip().splitlines()[-1:]}")
    return read_exr(str(exr))


def _minus_noise(e: float, *noise: float) -> float:
    return math.sqrt(max(e * e - sum(n * n for n in noise), 0.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--models", default=None, help="folder whose .glb files join the built-in targets")
    ap.add_argument("--presets", nargs="*", default=["fast", "balanced:16"])
    ap.add_argument("--no-cycles", action="store_true",
                    help="our presets against our reference only (no Blender needed; seeds 1 and 2 each)")
    args = ap.parse_args()
    py = None if args.no_cycles else bpy_python()
    if py is None and not args.no_cycles:
        sys.exit("bench_random_vs_cycles: needs Blender's Python (.bpyenv or BPY_PYTHON; benchmarks/README_cycles.md)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    targets = list(BUILTIN_TARGETS) + (sorted(str(p) for p in Path(args.models).glob("*.glb")) if args.models else [])
    presets = parse_presets(args.presets)
    rows = []
    with open(out / "results.jsonl", "w") as log:
        for i in range(args.n):
            target, earth, path = make_scene(i, args.seed, targets, out, args.width)
            spec = load_scene_file(str(path))
            a = (Scene(spec.model), spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting)
            r1, r2 = (render(*a, quality="reference", samples=args.spp, seed=s) for s in (1, 2))
            m = r1.geometry.mask
            o1, o2 = r1.radiance.astype(np.float64), r2.radiance.astype(np.float64)
            ours = 0.5 * (o1 + o2)
            n_ours = 0.5 * rel_err(o1, o2, m)
            doc = json.loads(path.read_text())
            row = {"scene": path.name, "target": target, "earth": earth, "ambient": doc["ambient_radiance_W_m2_sr"],
                   "shadow_fraction": doc["sun"]["shadow_fraction"], "target_px": int(m.sum()), "noise_ours": n_ours}
            if args.no_cycles:
                for q, n in presets:
                    name = q if n is None else f"{q}:{n}"
                    e2 = [rel_err(render(*a, quality=q, samples=n, seed=s).radiance.astype(np.float64), ours, m) ** 2
                          - n_ours ** 2 for s in (1, 2)]
                    row[f"{name}_vs_ref"] = math.sqrt(max(sum(e2) / 2, 0.0))
                rows.append(row)
                log.write(json.dumps(row) + "\n")
                log.flush()
                print(f"{path.name} {target:18s} earth {earth:9s} target px {m.sum():6d}  "
                      + "  ".join(f"{k[:-7]} {100 * v:.2f} %" for k, v in row.items() if k.endswith("_vs_ref")),
                      flush=True)
                continue
            c1, c2 = (cycles(py, path, args.spp, s, out / f"scene_{i:03d}_cycles{s}.exr") for s in (1, 2))
            cyc = 0.5 * (c1 + c2)
            n_cyc = 0.5 * rel_err(c1, c2, m)
            row.update({"noise_cycles": n_cyc, "ref_vs_cycles": _minus_noise(rel_err(ours, cyc, m), n_ours, n_cyc),
                        "ref_vs_cycles_raw": rel_err(ours, cyc, m),
                        "ref_over_cycles": float(ours[m].sum() / cyc[m].sum())})
            for q, n in presets:
                img = render(*a, quality=q, samples=n, seed=1).radiance.astype(np.float64)
                name = q if n is None else f"{q}:{n}"
                row[f"{name}_vs_cycles"] = _minus_noise(rel_err(img, cyc, m), n_cyc)
                row[f"{name}_vs_ref"] = _minus_noise(rel_err(img, ours, m), n_ours)
            rows.append(row)
            log.write(json.dumps(row) + "\n")
            log.flush()
            print(f"{path.name} {target:18s} earth {earth:9s} target px {m.sum():6d}  ref vs Cycles "
                  f"{100 * row['ref_vs_cycles']:.2f} % (noise {100 * n_ours:.2f} / {100 * n_cyc:.2f} %)  "
                  + "  ".join(f"{k[:-10]} {100 * v:.2f} %" for k, v in row.items() if k.endswith("_vs_cycles")
                              and not k.startswith("ref")), flush=True)
    names = [q if n is None else f"{q}:{n}" for q, n in presets]
    if args.no_cycles:
        lines = ["| scene | target | target px | " + " | ".join(f"{p} vs ours" for p in names) + " |",
                 "|" + "---|" * (3 + len(names))]
        lines += [f"| {r['scene']} | {r['target']} | {r['target_px']} | "
                  + " | ".join(f"{100 * r[f'{p}_vs_ref']:.2f} %" for p in names) + " |" for r in rows]
        lines.append("| median | | | " + " | ".join(f"{100 * statistics.median(r[f'{p}_vs_ref'] for r in rows):.2f} %"
                                                    for p in names) + " |")
        (out / "table.md").write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return
    write_table(rows, out / "table.md", names)


def write_table(rows: list, path: Path, presets: list) -> None:
    head = ["scene", "target", "Earth", "sky", "ν", "target px", "noise ours / Cycles", "ref vs Cycles",
            "ours / Cycles (sum)"] + [f"{p} vs Cycles" for p in presets]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["scene"], r["target"], r["earth"], f"{r['ambient']:g}", f"{r['shadow_fraction']:g}",
                 str(r["target_px"]), f"{100 * r['noise_ours']:.2f} / {100 * r['noise_cycles']:.2f} %",
                 f"{100 * r['ref_vs_cycles']:.2f} %", f"{r['ref_over_cycles']:.4f}"]
        cells += [f"{100 * r[f'{p}_vs_cycles']:.2f} %" for p in presets]
        lines.append("| " + " | ".join(cells) + " |")
    med = [statistics.median(r[k] for r in rows) for k in ["ref_vs_cycles"] + [f"{p}_vs_cycles" for p in presets]]
    lines.append("| median | | | | | | | " + f"{100 * med[0]:.2f} % | {statistics.median(r['ref_over_cycles'] for r in rows):.4f} | "
                 + " | ".join(f"{100 * v:.2f} %" for v in med[1:]) + " |")
    path.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
