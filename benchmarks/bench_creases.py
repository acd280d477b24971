"""Open meshes with concave creases: a white box without a lid, rendered against our path tracer.

    python benchmarks/bench_creases.py --out bench_out/creases [--spp 1024] [--width 320]

The twelve scenes of ``bench_time_error.py`` are the built-in targets, whose parts are closed
shells meeting at convex edges and contacts. A user's mesh is often a single open sheet with
inner corners (a box without a lid, a bus with a recess, panels meeting at a fold), where light
bounces most. Each scene here is such a box, 2 m, one open mesh (five faces of a cube), seen
from above one rim:

* ``sun_lambert``: Lambertian albedo 0.8, the Sun entering through the opening;
* ``sun_paint``: the ``white_paint`` material (diffuse 0.8 with a GGX lobe), the same light;
* ``sky``: Lambertian 0.8, no Sun, an ambient sky of 5 W/(m²·sr);
* ``sun_closed``: the control, the same box built of five closed 2 cm slabs (every part a
  closed shell: no open crease), Lambertian 0.8, the Sun.

Our ``reference`` path tracer renders each at ``--spp``, seeds 1 and 2; ``fast``,
``balanced``-12 and ``balanced``-64 at seeds 3 and 4. Errors are relative RMS over the target
pixels against the references' mean, the references' noise (half their difference) removed in
quadrature, and averaged (in the square) over the two seeds. ``inner`` is the ratio of the
preset's mean radiance to the reference's over the box's inner walls and floor lit only
indirectly or in part (the faces whose mean reference radiance is below 60 % of the
brightest face's, three pixels in from their edges; pixels below 2 % of it left out). Writes ``results.json`` and the scene files under
``--out``; run it on two commits (a ``git worktree``) to compare them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import trimesh  # noqa: E402
from scipy.ndimage import binary_erosion  # noqa: E402

from orbit.pose import look_at  # noqa: E402
from raytrace.scene import Scene  # noqa: E402
from raytrace.scenefile import load_scene_file  # noqa: E402
from raytrace.shade import render  # noqa: E402

PRESETS = (("fast", None), ("balanced", 12), ("balanced", 64))


def _meshes(out: Path) -> None:
    box = trimesh.creation.box((2.0, 2.0, 2.0))
    keep = box.face_normals[:, 2] < 0.5  # every face but the lid's
    trimesh.Trimesh(box.vertices, box.faces[keep], process=False).export(out / "open_box.ply")
    slabs, t = [], 0.02
    for axis, side in ((0, -1), (0, 1), (1, -1), (1, 1), (2, -1)):
        ext = [2.0 + 2 * t] * 3
        ext[axis] = t
        s = trimesh.creation.box(ext)
        at = [0.0, 0.0, 0.0]
        at[axis] = side * (1.0 + t / 2)
        s.apply_translation(at)
        slabs.append(s)
    trimesh.util.concatenate(slabs).export(out / "slab_box.ply")


def _scene(out: Path, name: str, mesh: str, surface: dict, sun_W_m2: float, sky: float, width: int) -> Path:
    W, H = width, width * 3 // 4
    f = 0.906 * W
    cam = np.array([3.0, -4.0, 6.0])
    R = look_at(cam, up_ref_lvlh=(0.0, 0.0, 1.0))
    sun = np.array([0.3, 0.2, 1.0])
    doc = {"meshes": [{"path": mesh, **surface}],
           "camera": {"K": [[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]], "width": W, "height": H,
                      "R_cam_from_body": R.ravel().tolist(), "t_cam_m": (-R @ cam).tolist()},
           "sun": {"sun_dir_body": (sun / np.linalg.norm(sun)).tolist(), "sun_irradiance_W_m2": sun_W_m2},
           "ambient_radiance_W_m2_sr": sky}
    path = out / f"{name}.json"
    path.write_text(json.dumps(doc, indent=1))
    return path


def _err2(img, ref, m) -> float:
    return float(np.mean((img - ref)[m] ** 2) / np.mean(ref[m] ** 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--width", type=int, default=320)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _meshes(out)
    lamb = {"albedo": [0.8, 0.8, 0.8]}
    scenes = {"sun_lambert": ("open_box.ply", lamb, 1361.0, 0.0),
              "sun_paint": ("open_box.ply", {"material": "white_paint"}, 1361.0, 0.0),
              "sky": ("open_box.ply", lamb, 0.0, 5.0),
              "sun_closed": ("slab_box.ply", lamb, 1361.0, 0.0)}
    results = {}
    for name, (mesh, surface, sun, sky) in scenes.items():
        spec = load_scene_file(str(_scene(out, name, mesh, surface, sun, sky, args.width)))
        a = (Scene(spec.model), spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting)
        f1, f2 = (render(*a, quality="reference", samples=args.spp, seed=s) for s in (1, 2))
        geo = f1.geometry
        m = geo.mask
        r1, r2 = f1.radiance.astype(np.float64), f2.radiance.astype(np.float64)
        ref = 0.5 * (r1 + r2)
        noise2 = 0.25 * float(np.mean((r1 - r2)[m] ** 2) / np.mean(ref[m] ** 2))  # of the mean of two
        # faces by their camera-frame normal; the dim ones (lit by bounces), eroded
        key = np.round(geo.normal_cam * 4).astype(int)
        lum = ref.sum(axis=2)
        inner = np.zeros_like(m)
        faces = [binary_erosion(m & np.all(key == k, axis=-1), iterations=3) for k in np.unique(key[m], axis=0)]
        faces = [f & (lum > 0.0) for f in faces if f.sum() >= 50]
        top = max(lum[f].mean() for f in faces if f.any())
        for f in faces:
            f &= lum > 0.02 * top
            if f.sum() >= 50 and lum[f].mean() < 0.6 * top:
                inner |= f
        row = {"target_px": int(m.sum()), "ref_noise": float(np.sqrt(noise2)), "inner_px": int(inner.sum())}
        for q, n in PRESETS:
            label = q if n is None else f"{q}:{n}"
            imgs = [render(*a, quality=q, samples=n, seed=s).radiance.astype(np.float64) for s in (3, 4)]
            row[label] = float(np.sqrt(max(np.mean([_err2(x, ref, m) for x in imgs]) - noise2, 0.0)))
            row[f"{label} inner"] = float(np.mean([x[inner].mean() for x in imgs]) / ref[inner].mean()) \
                if inner.any() else None
        results[name] = row
        print(f"{name:12s} px {row['target_px']:6d} (inner {row['inner_px']:5d})  ref noise {100 * row['ref_noise']:.2f} %  "
              + "  ".join(f"{q if n is None else f'{q}:{n}'} {100 * row[q if n is None else f'{q}:{n}']:.2f} % "
                          f"(inner ×{row[(q if n is None else f'{q}:{n}') + ' inner'] or float('nan'):.4f})"
                          for q, n in PRESETS), flush=True)
    (out / "results.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
