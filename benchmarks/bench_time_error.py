"""Time against error: our quality presets and Blender Cycles on the same scenes.

    python benchmarks/bench_time_error.py --out bench_out/time_error [--width 1280]
        [--targets tiangong spacedragon icesat cassini | issue-satellite] [--ref-spp 512] [--cycles-spp 1 4 16 64 256]
        [--no-cycles] [--repeats 3] [--ref-dir DIR]

Scenes: each built-in target with a Lambertian stand-in albedo per part (diffuse + F0 of its
material preset, capped at 0.9, because the Cycles bridge takes albedo meshes only), written
as per-part PLY files and one ``SCENE.json`` per viewpoint (``raytrace/scenefile.py`` schema),
so both renderers read exactly the same input. Three viewpoints per target, at 1.1× the
distance at which the target fills a 40° field:

* ``sunlit``   oblique view of the sunlit side, looking away from Earth (out of view);
* ``earth``    looking down towards Earth (nadir), which fills the background; Sun from the side;
* ``backlit``  from below, looking away from Earth, with the Sun behind the target: what the
  camera sees is lit mostly by Earth (behind the camera) and by light bouncing between parts.

Lighting: Sun 1361 W/m² (0.533° disc), Earth (uniform albedo 0.3, true size at 400 km) and a
1 W/(m²·sr) ambient sky (lights the target, not drawn).

``--targets issue-satellite`` renders instead a reference scene ("bus + panels + dish at 25 m",
:func:`issue_satellite`) on which Cycles' times on another 2-core machine are known, from three
views of its own (``oblique``, ``side``, ``backlit``; Sun and sky, no Earth): Cycles' seconds
there against those times tell how fast this machine is against that one.

Reference: our path tracer (``quality="reference"``), ``--ref-spp`` samples per pixel, twice
with two seeds. Their mean is the yardstick; half their difference estimates its own noise,
which is removed in quadrature from every measured error ("corrected"). The path tracer
agrees with Cycles' analytic calibration scenes (``benchmarks/cycles_calibration.py``); here
Cycles at its highest spp is a second, independent check of the yardstick.

Error: relative RMS over target pixels (mask of the exact geometry pass), all channels:
‖I − I_ref‖₂ / ‖I_ref‖₂. Time: median seconds per frame over ``--repeats`` runs after a
warm-up, both renderers on the same 2 threads, run one after the other in this process
(side by side). For Cycles the time is ``bpy.ops.render.render`` (scene sync + BVH + render).

Writes ``results.json``, ``table.md`` and ``time_error.png`` (log–log curves) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from orbit.pose import look_at
from raytrace.camera import Camera
from raytrace.lighting import Earth, Lighting
from raytrace.materials import material_of
from raytrace.scene import Scene
from raytrace.scenefile import load_scene_file, scene_to_dict
from raytrace.shade import render
from raytrace.targets import BUILTIN_TARGETS, load_target

PRESETS = [("fast", None), ("balanced", 8), ("balanced", 16), ("balanced", 64), ("balanced", 256)]
EARTH_DISTANCE_M = 6378137.0 + 400e3


def viewpoints():
    """(name, direction from target to camera, Sun direction, Earth direction), body frame."""
    earth = np.array([-1.0, 0.0, 0.0])
    return [
        ("sunlit", np.array([-0.4, -1.0, 0.3]), np.array([0.5, -0.5, 0.70710678]), earth),
        ("earth", np.array([1.0, -0.35, 0.25]), np.array([0.2, 0.6, 0.77459667]), earth),
        ("backlit", np.array([-0.6, -0.7, -0.4]), np.array([0.3, 0.8, 0.52]), earth),
    ]


def write_scene(target: str, folder: Path, width: int) -> list[tuple[str, Path]]:
    """Per-part PLYs and one SCENE.json per viewpoint; returns [(viewpoint, path)]."""
    model = load_target(target)
    parts = folder / "parts"
    parts.mkdir(parents=True, exist_ok=True)
    meshes = []
    for k, comp in enumerate(model.components):
        m = material_of(comp)
        albedo = np.minimum(np.asarray(m.diffuse) + np.asarray(m.f0), 0.9)
        path = parts / f"{k:02d}_{comp.name}.ply"
        comp.mesh.export(path)
        meshes.append({"path": f"parts/{path.name}", "unit_scale_m": 1.0,
                       "albedo": [round(float(a), 4) for a in albedo]})
    H = width * 3 // 4
    f = width / 1280 * 4e-3 / 3.45e-6
    cam = Camera(width, H, f, f, (width - 1) / 2, (H - 1) / 2)
    dist = 1.1 * model.bounding_radius_m / math.tan(math.radians(20))
    out = []
    for name, rho_dir, sun, earth in viewpoints():
        rho = rho_dir / np.linalg.norm(rho_dir) * dist
        R = look_at(rho)
        t = -R @ rho
        light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)),
                         earth=Earth(tuple(earth), EARTH_DISTANCE_M, albedo=0.3), ambient_radiance_W_m2_sr=1.0)
        doc = scene_to_dict(cam, R, t, light, meshes)
        path = folder / f"{name}.json"
        path.write_text(json.dumps(doc, indent=1) + "\n")
        out.append((name, path))
    return out


# a reference scene ("a satellite of bus + panels + dish at 25 m, sun 1361 W/m² plus a constant
# ambient sky"), on which Cycles 5.0 took 0.24 / 2.0 / 7.5 / 29.7 s at 1 / 16 / 64 / 256 spp on
# a 2-core machine: rendered here it tells how fast this machine is against that one, and how
# our presets do on a scene with fewer parts and edges than the four targets
ISSUE_SCENE = "issue-satellite"
ISSUE_DISTANCE_M = 25.0


def issue_satellite() -> list[tuple[str, trimesh.Trimesh, tuple]]:
    """(name, mesh [m], Lambertian albedo) of the reference satellite, body frame (z up): a bus
    1.8 × 1.8 × 2.4 m (gold-MLI-like albedo), two solar wings 5.0 × 1.8 m, 4 cm thick, on yokes
    0.6 m from the bus (solar-cell blue-grey), and a parabolic dish 2.2 m across on a strut
    above the bus (white paint; an open mesh, both sides visible)."""
    parts = [("bus", trimesh.creation.box((1.8, 1.8, 2.4)), (0.65, 0.5, 0.25))]
    for sx, nm in ((1.0, "wing_px"), (-1.0, "wing_mx")):
        wing = trimesh.creation.box((5.0, 1.8, 0.04))
        wing.apply_translation((sx * 4.0, 0.0, 0.0))
        parts.append((nm, wing, (0.2, 0.22, 0.35)))
        yoke = trimesh.creation.cylinder(radius=0.04, height=0.62, sections=12)
        yoke.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0.0, 1.0, 0.0)))
        yoke.apply_translation((sx * 1.2, 0.0, 0.0))
        parts.append((nm.replace("wing", "yoke"), yoke, (0.7, 0.7, 0.7)))
    strut = trimesh.creation.cylinder(radius=0.06, height=0.5, sections=16)
    strut.apply_translation((0.0, 0.0, 1.2 + 0.25))
    parts.append(("strut", strut, (0.7, 0.7, 0.7)))
    # the dish z = r² / (4 f), f = 0.8 m, r ≤ 1.1 m: 24 rings × 48 sectors
    nr, ns, focal = 24, 48, 0.8
    r = np.linspace(0.0, 1.1, nr + 1)[1:]
    a = np.linspace(0.0, 2 * math.pi, ns, endpoint=False)
    rr, aa = np.meshgrid(r, a, indexing="ij")
    ring = np.stack([rr * np.cos(aa), rr * np.sin(aa), rr ** 2 / (4 * focal)], axis=-1).reshape(-1, 3)
    verts = np.vstack([[0.0, 0.0, 0.0], ring]) + (0.0, 0.0, 1.7)
    faces = [(0, 1 + j, 1 + (j + 1) % ns) for j in range(ns)]
    for i in range(nr - 1):
        for j in range(ns):
            p, q = 1 + i * ns + j, 1 + i * ns + (j + 1) % ns
            faces += [(p, p + ns, q + ns), (p, q + ns, q)]
    parts.append(("dish", trimesh.Trimesh(verts, np.array(faces), process=False), (0.85, 0.85, 0.85)))
    return parts


def issue_viewpoints():
    """(name, direction from the satellite to the camera, Sun direction) of the reference scene."""
    return [
        ("oblique", np.array([0.5, -1.0, 0.45]), np.array([0.6, -0.45, 0.66])),
        ("side", np.array([0.05, -1.0, 0.1]), np.array([-0.7, -0.35, 0.62])),
        ("backlit", np.array([-0.45, -1.0, -0.25]), np.array([0.3, 0.85, 0.43])),
    ]


def write_issue_scene(folder: Path, width: int) -> list[tuple[str, Path]]:
    """The reference satellite as per-part PLYs and one SCENE.json per viewpoint (camera 25 m from
    its centre, the lens of the other scenes; Sun 1361 W/m², ambient sky 1 W/(m²·sr), no Earth);
    returns [(viewpoint, path)]."""
    parts = folder / "parts"
    parts.mkdir(parents=True, exist_ok=True)
    meshes = []
    for k, (name, mesh, albedo) in enumerate(issue_satellite()):
        path = parts / f"{k:02d}_{name}.ply"
        mesh.export(path)
        meshes.append({"path": f"parts/{path.name}", "unit_scale_m": 1.0, "albedo": list(albedo)})
    H = width * 3 // 4
    f = width / 1280 * 4e-3 / 3.45e-6
    cam = Camera(width, H, f, f, (width - 1) / 2, (H - 1) / 2)
    out = []
    for name, rho_dir, sun in issue_viewpoints():
        rho = rho_dir / np.linalg.norm(rho_dir) * ISSUE_DISTANCE_M
        R = look_at(rho)
        t = -R @ rho
        light = Lighting(sun_dir_body=tuple(sun / np.linalg.norm(sun)), ambient_radiance_W_m2_sr=1.0)
        path = folder / f"{name}.json"
        path.write_text(json.dumps(scene_to_dict(cam, R, t, light, meshes), indent=1) + "\n")
        out.append((name, path))
    return out


def scenes_of(target: str, folder: Path, width: int) -> list[tuple[str, Path]]:
    """:func:`write_scene`, or :func:`write_issue_scene` for ``ISSUE_SCENE``."""
    return write_issue_scene(folder, width) if target == ISSUE_SCENE else write_scene(target, folder, width)


def reference_renders(pose, spp: int, ref_file: Path | None = None):
    """Our path tracer's two reference renders of a scene (``pose``: the first five arguments
    of :func:`raytrace.shade.render`) at ``spp``, seeds 1 and 2: (a, b float64 radiance, mask,
    instance ids, seconds of the first render). With ``ref_file`` (.npz), they are read from it
    if it exists (seconds NaN), else rendered and written there."""
    if ref_file is not None and Path(ref_file).exists():
        z = np.load(ref_file)
        return z["a"].astype(np.float64), z["b"].astype(np.float64), z["mask"], z["inst"], float("nan")
    t0 = time.perf_counter()
    r1 = render(*pose, quality="reference", samples=spp, seed=1)
    seconds = time.perf_counter() - t0
    r2 = render(*pose, quality="reference", samples=spp, seed=2)
    if ref_file is not None:
        Path(ref_file).parent.mkdir(parents=True, exist_ok=True)
        np.savez(ref_file, a=r1.radiance, b=r2.radiance, mask=r1.geometry.mask, inst=r1.geometry.instance)
    return (r1.radiance.astype(np.float64), r2.radiance.astype(np.float64), r1.geometry.mask, r1.geometry.instance,
            seconds)


def scene_frames(folder: Path, width: int, targets, views, per_target: bool = False):
    """The benchmark scenes (written into ``folder`` if missing), one at a time with its
    radiance cache built: (target, view, scene file, the first five arguments of
    :func:`raytrace.shade.render`). ``per_target``: one scene (and cache) per target, shared by
    its views, instead of one per view."""
    for target in targets:
        scene = None
        for view, spath in scenes_of(target, Path(folder) / target, width):
            if views is not None and view not in views:
                continue
            spec = load_scene_file(str(spath))
            if scene is None or not per_target:
                scene = Scene(spec.model)
                scene.radiance_cache()
            yield target, view, spath, (scene, spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting)


def add_scene_options(ap, presets=("fast", "balanced:16", "balanced:64")) -> None:
    """The options of the side-by-side timing scripts on these scenes: --scenes (folder, written
    if missing), --width, --repeats, --presets (``name`` or ``name:samples``), --targets,
    --views."""
    ap.add_argument("--scenes", required=True, help="folder of the bench_time_error.py scenes (written if missing)")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", nargs="*", default=list(presets))
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS))
    ap.add_argument("--views", nargs="*", default=[v[0] for v in viewpoints()])


def parse_presets(specs) -> list:
    """[(quality, samples or None)] of --presets entries ``name`` / ``name:samples``."""
    return [(p.split(":")[0], int(p.split(":")[1]) if ":" in p else None) for p in specs]


def rel_err(a: np.ndarray, b: np.ndarray, m: np.ndarray) -> float:
    return float(np.sqrt(((a[m] - b[m]) ** 2).sum() / (b[m] ** 2).sum()))


def read_exr(path: str) -> np.ndarray:
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(path)
    return np.asarray(buf.get_pixels(oiio.FLOAT))[:, :, :3].astype(np.float64)


def cycles(scene_path: Path, spp: int, out_exr: Path, python: str, threads: int = 2) -> tuple[float, np.ndarray]:
    cmd = [python, str(ROOT / "benchmarks" / "cycles_render.py"), str(scene_path), "--spp", str(spp),
           "--out", str(out_exr), "--threads", str(threads)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"cycles_render failed: {res.stderr.strip().splitlines()[-1:]}")
    info = json.loads(res.stdout.strip().splitlines()[-1])
    return float(info["render_s"]), read_exr(str(out_exr))


def bpy_python() -> str | None:
    env = os.environ.get("BPY_PYTHON")
    if env:
        return env
    cand = ROOT / ".bpyenv" / "bin" / "python"
    return str(cand) if cand.exists() else None


def plot(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=110)
    series = {}
    for r in results:
        key = "Cycles" if r["renderer"] == "cycles" else ("fast" if r["preset"] == "fast" else "balanced")
        series.setdefault(key, {}).setdefault(r["samples"] or 0, []).append(r)
    style = {"fast": ("C0", "s"), "balanced": ("C0", "o"), "Cycles": ("C3", "^")}
    for key, by_n in series.items():
        ns = sorted(by_n)
        t = [statistics.median(x["s_per_frame"] for x in by_n[n]) for n in ns]
        e = [100 * statistics.median(x["err_corrected"] for x in by_n[n]) for n in ns]
        c, mk = style[key]
        ax.loglog(t, e, marker=mk, color=c, ls="-" if key != "fast" else "", label=key, ms=7)
        for ti, ei, n in zip(t, e, ns, strict=True):
            if n:
                ax.annotate(str(n), (ti, ei), textcoords="offset points", xytext=(4, 4), fontsize=8, color=c)
    for g, lbl in ((2.0, "2 %"), (1.0, "1 %")):
        ax.axhline(g, color="0.7", lw=0.8, ls=":")
        ax.annotate(lbl, (0.0, g), xycoords=("axes fraction", "data"), xytext=(3, 2), textcoords="offset points",
                    fontsize=8, color="0.4")
    ax.set_xlabel("seconds per 1280×960 frame (median over scenes, 2 cores)")
    ax.set_ylabel("relative RMS error on target pixels [%] (median over scenes)")
    ax.set_title("Time against error: orbitsynth presets vs Blender Cycles 5.0 (same scenes)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--targets", nargs="*", default=list(BUILTIN_TARGETS),
                    help=f"built-in targets, or {ISSUE_SCENE} (reference bus + panels + dish, views "
                         f"{' '.join(v[0] for v in issue_viewpoints())})")
    ap.add_argument("--views", nargs="*", default=None, help="default: every view of each target")
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--ref-dir", default=None,
                    help="keep the reference renders here and reuse them (the files of bench_bias_noise.py's "
                         "--ref-dir: REF_DIR/w<width>/ref_<target>_<view>_<spp>.npz, the same seeds 1 and 2)")
    ap.add_argument("--cycles-spp", type=int, nargs="*", default=[1, 4, 16, 64, 256])
    ap.add_argument("--no-cycles", action="store_true")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--presets", nargs="*", default=None,
                    help="only these of ours, e.g. fast balanced:8 (default: all)")
    ap.add_argument("--merge", default=None,
                    help="results.json of an earlier run: its rows for renderers/presets not re-run here are kept")
    args = ap.parse_args()
    presets = PRESETS if args.presets is None else [
        (p.split(":")[0], int(p.split(":")[1]) if ":" in p else None) for p in args.presets]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    py = None if args.no_cycles else bpy_python()
    if not args.no_cycles and py is None:
        print("# Cycles skipped: no .bpyenv/bin/python and BPY_PYTHON unset (see benchmarks/README_cycles.md)")
    results = []
    for target in args.targets:
        for view, spath in scenes_of(target, out / target, args.width):
            if args.views is not None and view not in args.views:
                continue
            spec = load_scene_file(str(spath))
            scene = Scene(spec.model)
            cam, R, t, light = spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting
            t0 = time.perf_counter()
            scene.radiance_cache()
            build_s = time.perf_counter() - t0
            ref_file = None if args.ref_dir is None else \
                Path(args.ref_dir) / f"w{args.width}" / f"ref_{target}_{view}_{args.ref_spp}.npz"
            a, b, mask, _, ref_s = reference_renders((scene, cam, R, t, light), args.ref_spp, ref_file)
            ref = (a + b) / 2
            noise = rel_err(a, b, mask) / 2
            head = {"target": target, "view": view, "coverage": float(mask.mean()), "ref_noise": noise}
            took = f"in {ref_s:.1f} s each" if math.isfinite(ref_s) else f"from {ref_file}"
            print(f"# {target}/{view}: cover {100 * mask.mean():.1f} %, reference {args.ref_spp} spp x2 {took}, "
                  f"its noise {100 * noise:.2f} %, cache build {build_s:.2f} s", flush=True)

            def record(renderer, preset, n, times, img, ref=ref, mask=mask, head=head, noise=noise, target=target,
                       view=view):
                e = rel_err(img, ref, mask)
                row = dict(head, renderer=renderer, preset=preset, samples=n, s_per_frame=statistics.median(times),
                           err=e, err_corrected=math.sqrt(max(e * e - noise * noise, 0.0)))
                results.append(row)
                print(f"{target:12s} {view:8s} {renderer:9s} {preset:9s} {n or '-':>5} "
                      f"{row['s_per_frame']:8.3f} s  {100 * e:6.2f} %  corrected {100 * row['err_corrected']:6.2f} %",
                      flush=True)

            for q, n in presets:
                render(scene, cam, R, t, light, quality=q, samples=n, seed=0)  # warm-up (JIT, cache)
                times = []
                for k in range(args.repeats):
                    t0 = time.perf_counter()
                    img = render(scene, cam, R, t, light, quality=q, samples=n, seed=k).radiance
                    times.append(time.perf_counter() - t0)
                record("orbitsynth", q, n, times, img.astype(np.float64))
            if py is not None:
                for n in args.cycles_spp:
                    reps = args.repeats if n <= 16 else 1
                    times, img = [], None
                    for _ in range(reps):
                        s, img = cycles(spath, n, out / target / f"{view}_cycles_{n}.exr", py)
                        times.append(s)
                    record("cycles", "cycles", n, times, img)
            (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    if args.merge:
        redone = {(r["target"], r["view"], r["renderer"], r["preset"], r["samples"]) for r in results}
        kept = [r for r in json.loads(Path(args.merge).read_text())
                if (r["target"], r["view"], r["renderer"], r["preset"], r["samples"]) not in redone]
        results = kept + results
        (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    write_table(results, out / "table.md")
    plot(results, out / "time_error.png")
    print((out / "table.md").read_text())


def write_table(results: list[dict], path: Path) -> None:
    """Median over scenes of time and corrected error, per renderer and sample count; then the
    speed-up at equal error (log-log interpolation of the Cycles curve)."""
    groups = {}
    for r in results:
        groups.setdefault((r["renderer"], r["preset"], r["samples"] or 0), []).append(r)
    lines = ["| renderer | preset | samples | s / frame (median) | error (median, corrected) | error (max) |",
             "|---|---|---|---|---|---|"]
    cyc = []
    for (ren, preset, n), rows in sorted(groups.items(), key=lambda kv: (kv[0][0] != "orbitsynth", kv[0][1], kv[0][2])):
        t = statistics.median(r["s_per_frame"] for r in rows)
        e = statistics.median(r["err_corrected"] for r in rows)
        emax = max(r["err_corrected"] for r in rows)
        lines.append(f"| {ren} | {preset} | {n or '-'} | {t:.3f} | {100 * e:.2f} % | {100 * emax:.2f} % |")
        if ren == "cycles":
            cyc.append((e, t))
    if len(cyc) >= 2:
        cyc.sort()
        lines += ["", "| preset | samples | error | Cycles time at that error | speed-up |", "|---|---|---|---|---|"]
        le = np.log([c[0] for c in cyc])  # ascending error
        lt = np.log([c[1] for c in cyc])
        for (ren, preset, n), rows in sorted(groups.items()):
            if ren != "orbitsynth":
                continue
            t = statistics.median(r["s_per_frame"] for r in rows)
            e = statistics.median(r["err_corrected"] for r in rows)
            if e <= 0 or not (le.min() <= math.log(e) <= le.max()):
                note = "outside Cycles' range"
                lines.append(f"| {preset} | {n or '-'} | {100 * e:.2f} % | {note} | |")
                continue
            tc = float(np.exp(np.interp(math.log(e), le, lt)))
            lines.append(f"| {preset} | {n or '-'} | {100 * e:.2f} % | {tc:.2f} s | {tc / t:.1f}× |")
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
