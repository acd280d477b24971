"""A golden set for refactors: the same outputs rendered by two checkouts, compared byte for byte.

    git worktree add /tmp/before <commit>
    python tests/golden_set.py /tmp/before . [--out DIR] [--keep]

With ``--out DIR``, a tree already rendered completely into ``DIR/a`` (it holds the marker
``.complete``) is reused, so one rendering of the checkout before serves many checks after.

Each checkout's ``cli.py`` runs as a process (its own packages first on ``sys.path``) and
writes, under ``OUT/<a|b>/``:

* ``seq/<target>_<quality>/``: the main job of each built-in target at ``fast``, ``balanced``
  and ``reference`` (``--samples 2``), 3 frames at 320×240, every modality, ``physical``
  degradation;
* ``dry/<target>_<pattern>.json``: ``--dry-run --json`` of each target and pattern;
* ``export/<target>_{bop,speedplus}/``: the BOP and SPEED+ exports of each ``fast`` sequence
  (``raytrace.export``, files copied, not linked);
* ``scene/``: ``render-scene`` of a scene file (a Cassini view with Earth behind).

Then every file of the two trees is compared: the same relative paths, the same bytes, except
the fields that hold the time a run took or the absolute path it wrote to (:data:`VOLATILE`),
which are dropped from JSON before comparing. Prints each difference and exits 1 if any.
Not a pytest module (it takes minutes and two checkouts): run by hand before and after a
change meant to keep the outputs. The kernels compiled with fastmath can differ in a last bit
with the way numba's cache was filled (which kernel compiled a shared helper first): compare
checkouts whose caches were filled alike, e.g. both from empty with
``NUMBA_CACHE_DIR=$(mktemp -d) python tests/golden_set.py /tmp/before .``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

TARGETS = ("tiangong", "spacedragon", "icesat", "cassini")
QUALITIES = ("fast", "balanced", "reference")
PATTERNS = ("elliptical", "spiral", "drip-drop", "drift")
SMALL = ["--frames", "3", "--width", "320", "--height", "240", "--workers", "2", "--quiet",
         "--modalities", "rgb,rgb_degraded,mask,depth,normal,hdr", "--degrade", "physical"]
VOLATILE = {"seconds", "render_s", "timings_s", "elapsed_s", "scene", "out", "created_utc", "wall_s"}
"""JSON keys dropped before comparing: a run's own times and the absolute paths it was given."""

_EXPORT = """
import sys
from raytrace.export import export_bop, export_speedplus
seq, out = sys.argv[1], sys.argv[2]
export_bop(seq, out + "_bop", link=False)
export_speedplus(seq, out + "_speedplus", link=False)
"""

_SCENE = {
    "target": "cassini",
    "camera": {"K": [[400.0, 0, 159.5], [0, 400.0, 119.5], [0, 0, 1]], "width": 320, "height": 240,
               "R_cam_from_body": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t_cam_m": [0, -1, 18]},
    "sun": {"sun_dir_body": [0.6, -0.48, 0.64]},
    "earth": {"earth_dir_body": [0, 0, 1], "earth_distance_m": 6778137.0, "albedo": 0.3},
}


def _run(tree: Path, args: list, cwd: Path, stdout=None) -> None:
    env = dict(os.environ, PYTHONPATH=str(tree))
    res = subprocess.run([sys.executable, *args], cwd=cwd, env=env, stdout=stdout or subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"{tree}: {' '.join(map(str, args))} failed: {res.stderr.strip()[-600:]}")


def render(tree: Path, out: Path) -> None:
    """The golden set of checkout ``tree`` into ``out`` (see the module notes)."""
    cli = str(tree / "cli.py")
    out.mkdir(parents=True, exist_ok=True)
    for target in TARGETS:
        for quality in QUALITIES:
            extra = ["--samples", "2"] if quality == "reference" else []
            _run(tree, [cli, "--target", target, "--quality", quality, *SMALL, *extra,
                        "--out", str(out / "seq" / f"{target}_{quality}")], out.parent)
        for pattern in PATTERNS:
            (out / "dry").mkdir(parents=True, exist_ok=True)
            with open(out / "dry" / f"{target}_{pattern}.json", "w") as fh:
                _run(tree, [cli, "--target", target, "--pattern", pattern, "--dry-run", "--json"], out.parent, fh)
        (out / "export").mkdir(parents=True, exist_ok=True)
        _run(tree, ["-c", _EXPORT, str(out / "seq" / f"{target}_fast"), str(out / "export" / target)], out.parent)
    scene = out / "scene.json"
    scene.write_text(json.dumps(_SCENE))
    _run(tree, [cli, "render-scene", str(scene), "--out", str(out / "scene")], out.parent)


def _strip(doc):
    if isinstance(doc, dict):
        return {k: _strip(v) for k, v in doc.items() if k not in VOLATILE}
    if isinstance(doc, list):
        return [_strip(v) for v in doc]
    return doc


def digest(path: Path) -> str:
    """SHA-256 of a file; of a JSON file, of its content without :data:`VOLATILE` keys."""
    data = path.read_bytes()
    if path.suffix == ".json":
        try:
            data = json.dumps(_strip(json.loads(data)), sort_keys=True).encode()
        except ValueError:
            pass
    return hashlib.sha256(data).hexdigest()


def compare(a: Path, b: Path) -> list:
    """The differences between the trees ``a`` and ``b``: files only in one, files that differ."""
    def files(root):
        return {p.relative_to(root).as_posix(): p for p in root.rglob("*") if p.is_file() and p.name != ".complete"}
    fa, fb = files(a), files(b)
    out = [f"only in a: {k}" for k in sorted(fa.keys() - fb.keys())]
    out += [f"only in b: {k}" for k in sorted(fb.keys() - fa.keys())]
    out += [f"differs: {k}" for k in sorted(fa.keys() & fb.keys()) if digest(fa[k]) != digest(fb[k])]
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a", type=Path, help="the checkout before")
    p.add_argument("b", type=Path, help="the checkout after")
    p.add_argument("--out", type=Path, default=None, help="where to write (default: a temporary folder)")
    p.add_argument("--keep", action="store_true", help="keep the outputs")
    args = p.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="golden-"))
    try:
        for name, tree in (("a", args.a.resolve()), ("b", args.b.resolve())):
            done = root / name / ".complete"
            if name == "a" and args.out is not None and done.is_file():
                print(f"reusing the golden set in {root / name}", flush=True)
                continue
            if (root / name).exists():
                shutil.rmtree(root / name)
            print(f"rendering the golden set of {tree} ...", flush=True)
            render(tree, root / name)
            done.write_text(str(tree))
        diffs = compare(root / "a", root / "b")
        n = sum(1 for p in (root / "a").rglob("*") if p.name != ".complete")
        print("\n".join(diffs) if diffs else f"the same: {n} paths")
        return 1 if diffs else 0
    finally:
        if not args.keep and args.out is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
