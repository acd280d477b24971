"""The main job's pipeline: sequence folder, labels against pixels, reproducibility across
workers, shards and dask, resume, config round trip, and one-line errors for bad input.

Small frames (160×120, same field of view as the default camera) keep the whole module fast.
"""

import filecmp
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

import cli
from raytrace import files as F
from raytrace.dataset import folder, pool, scenes
from tests.cli_helpers import run_main
from tests.raytrace.oracles import png_chunks

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--target", "icesat", "--pattern", "spiral", "--frames", "8", "--width", "160", "--height", "120",
         "--focal-length-mm", "0.5", "--quiet", "--arg-lat-deg", "90"]  # a phase whose last frames are in shadow
MODS = ["--modalities", "rgb,rgb_degraded,mask,depth,normal,hdr"]


def tree(folder: Path) -> dict:
    """Relative path → bytes of every file (hidden manifest records included)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def assert_same_tree(a: Path, b: Path) -> None:
    ta, tb = tree(a), tree(b)
    assert sorted(ta) == sorted(tb)
    different = [k for k in ta if ta[k] != tb[k]]
    assert not different, different


@pytest.fixture(scope="module")
def ref(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "seq"
    assert run_main(*SMALL, *MODS, "--workers", "1", "--out", out) == 0
    return out


# --------------------------------------------------------------------------- folder and labels
def test_sequence_folder_has_every_file(ref, capsys):
    labels = json.loads((ref / "labels.json").read_text())
    scen = json.loads((ref / "scenario.json").read_text())
    cam = json.loads((ref / "camera.json").read_text())
    assert len(labels) == 8 == len(scen["t_s"])
    for i, lab in enumerate(labels):
        name = f"{i:06d}"
        assert lab["files"] == {"rgb": f"rgb/{name}.png", "rgb_degraded": f"rgb_degraded/{name}.png",
                                "mask": f"mask/{name}.png", "depth": f"depth/{name}.exr",
                                "normal": f"normal/{name}.exr", "hdr": f"hdr/{name}.exr"}
        for key in ("frame", "t_s", "utc", "r_lvlh", "v_lvlh", "q_cam_from_body", "R_cam_from_body", "t_cam_m",
                    "sun_dir_cam", "earth_dir_cam", "shadow_fraction", "line_of_sight", "sun_clear",
                    "earth_in_background", "visible", "bbox", "visible_fraction", "pixel_counts"):
            assert key in lab, key
        assert lab["frame"] == i and lab["t_s"] == scen["t_s"][i]
    for key in ("config", "seed", "versions", "reference_orbit", "s0_lvlh", "n", "t_s", "pattern_parameters"):
        assert key in scen, key
    pp = scen["pattern_parameters"]
    for key in ("A", "x_l", "beta", "gamma", "sigma", "kappa", "pattern"):
        assert key in pp
    assert pp["pattern"] == "spiral" and scen["versions"]["numpy"] == np.__version__
    assert cam["width"] == cam["Nu"] == 160 and cam["height"] == cam["Nv"] == 120
    np.testing.assert_allclose(cam["K"], [[0.5e-3 / 3.45e-6, 0, 79.5], [0, 0.5e-3 / 3.45e-6, 59.5], [0, 0, 1]])
    assert cam["cameraMatrix"] == cam["K"] and len(cam["distCoeffs"]) == 5
    # image types and sizes
    assert F.read_image(str(ref / "rgb/000000.png")).dtype == np.uint8
    assert F.read_image(str(ref / "rgb_degraded/000000.png")).shape == (120, 160, 3)
    assert F.read_image(str(ref / "mask/000000.png")).dtype == np.uint16
    assert F.read_image(str(ref / "depth/000000.exr")).shape == (120, 160)
    assert F.read_image(str(ref / "normal/000000.exr")).shape == (120, 160, 3)
    # the manifest's checksums are the files' own
    manifest = json.loads((ref / "manifest.json").read_text())
    assert "labels.json" in manifest["files"] and "model/icesat.ply" in manifest["files"]
    for rel, digest in manifest["files"].items():
        assert F.sha256_file(str(ref / rel)) == digest, rel
    assert not [p for p in ref.rglob("*.tmp*")]


def _triangle_hits(V, Fc, origin, dirs):
    """Closest hit (t, triangle) of each ray by brute-force Möller–Trumbore in float64."""
    a, b, c = V[Fc[:, 0]], V[Fc[:, 1]], V[Fc[:, 2]]
    e1, e2 = b - a, c - a
    t_best = np.full(len(dirs), np.inf)
    tri = np.full(len(dirs), -1)
    for k, d in enumerate(dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = origin - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if hit.any():
            j = np.flatnonzero(hit)[np.argmin(t[hit])]
            t_best[k], tri[k] = t[j], j
    return t_best, tri


def test_labels_agree_with_pixels_and_model(ref):
    labels = json.loads((ref / "labels.json").read_text())
    cam = json.loads((ref / "camera.json").read_text())
    K = np.array(cam["K"])
    V, Fc, comp = F.read_model_ply(str(ref / "model/icesat.ply"))
    rng = np.random.default_rng(0)
    checked = 0
    for lab in labels:
        mask = F.read_image(str(ref / lab["files"]["mask"]))
        depth = F.read_image(str(ref / lab["files"]["depth"]))
        counts = np.bincount(mask.ravel(), minlength=len(lab["pixel_counts"]))
        assert counts.tolist() == lab["pixel_counts"]
        assert np.array_equal(mask > 0, np.isfinite(depth))
        R = np.array(lab["R_cam_from_body"]).reshape(3, 3)
        t = np.array(lab["t_cam_m"])
        uv = K @ t
        np.testing.assert_allclose(uv[:2] / uv[2], [cam["cx"], cam["cy"]], atol=1e-9)  # look-at: origin centred
        if lab["bbox"] is None:
            assert not mask.any()
            continue
        rows, cols = np.nonzero(mask)
        assert lab["bbox"] == [cols.min(), rows.min(), cols.max() - cols.min() + 1, rows.max() - rows.min() + 1]
        # depth back-projects onto the model that was written, on the right component
        pick = rng.choice(len(rows), size=min(40, len(rows)), replace=False)
        v_px, u_px = rows[pick], cols[pick]
        d_cam = np.column_stack([(u_px - cam["cx"]) / cam["fx"], (v_px - cam["cy"]) / cam["fy"], np.ones(len(pick))])
        origin = -R.T @ t
        t_hit, tri = _triangle_hits(V, Fc, origin, d_cam @ R)  # unnormalised rays: t is the z-depth
        np.testing.assert_allclose(depth[v_px, u_px], t_hit, rtol=2e-6)
        assert np.mean(comp[tri] == mask[v_px, u_px]) >= 0.95
        checked += len(pick)
    assert checked > 50


def test_light_directions_in_labels_are_the_renderers(ref):
    for lab in json.loads((ref / "labels.json").read_text()):
        R = np.array(lab["R_cam_from_body"]).reshape(3, 3)
        # the Sun is far: camera and target see it in the same direction to 1e-9
        np.testing.assert_allclose(lab["sun_dir_cam"], R @ np.array(lab["sun_dir_body"]), atol=1e-8)
        # Earth's centre seen from the camera vs from the target: differs by range / 6800 km
        np.testing.assert_allclose(lab["earth_dir_cam"], R @ np.array(lab["earth_dir_body"]), atol=2e-5)
        if lab["shadow_fraction"] == 0.0:  # umbra: no sunlight reaches the target
            hdr = F.read_image(str(ref / lab["files"]["hdr"]))
            mask = F.read_image(str(ref / lab["files"]["mask"]))
            assert hdr[mask > 0].max(initial=0.0) < 5.0  # only earthshine/ambient, far below 1361/π


def test_stars_are_fixed_in_the_inertial_frame_of_the_labels(tmp_path):
    """Every pixel the stars brighten holds a star of the sequence's sky projected with the
    label's inertial attitude R_cam_from_eci, and the stars over black space are all drawn."""
    import OpenImageIO as oiio

    from raytrace.stars import StarField
    args = [*SMALL[:4], "--frames", "3", *SMALL[6:], "--modalities", "hdr,mask", "--workers", "1"]
    assert run_main(*args, "--out", tmp_path / "plain") == 0
    assert run_main(*args, "--star-limit-mag", "5", "--out", tmp_path / "stars") == 0
    labels = json.loads((tmp_path / "stars" / "labels.json").read_text())
    K = np.array(json.loads((tmp_path / "stars" / "camera.json").read_text())["K"])
    sky = StarField.procedural(5.0, seed=0)
    scen = json.loads((tmp_path / "stars" / "scenario.json").read_text())
    earth_radius = math.asin(6378137.0 / scen["reference_orbit"]["a_m"])  # seen from the orbit (±100 m)
    n_checked = 0
    for lab in labels:
        hdr, plain = (oiio.ImageBuf(str(tmp_path / d / lab["files"]["hdr"])).get_pixels(oiio.FLOAT)
                      for d in ("stars", "plain"))
        mask = oiio.ImageBuf(str(tmp_path / "stars" / lab["files"]["mask"])).get_pixels(oiio.UINT16)[..., 0]
        d = sky.dirs_eci @ np.reshape(lab["R_cam_from_eci"], (3, 3)).T
        d = d[d[:, 2] > 0]
        uv = np.floor((d @ K.T)[:, :2] / d[:, 2:] + 0.5).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 160) & (uv[:, 1] >= 0) & (uv[:, 1] < 120)
        uv, d_in = uv[inside], d[inside] / np.linalg.norm(d[inside], axis=1, keepdims=True)
        star_px = {(v, u) for u, v in uv}
        changed = {tuple(p) for p in np.argwhere((hdr != plain).any(-1))}
        assert changed <= star_px
        # over black space: not on the target, not on Earth's disc (night side black too)
        e = np.asarray(lab["earth_dir_cam"])
        off_earth = {(v, u) for (u, v), di in zip(uv, d_in) if di @ e < math.cos(earth_radius + 0.01)}
        space = {p for p in star_px & off_earth if mask[p] == 0 and not plain[p].any()}
        assert space <= changed
        n_checked += len(space)
    assert n_checked > 20


def test_model_ply_reads_with_trimesh(ref):
    import trimesh
    V, Fc, comp = F.read_model_ply(str(ref / "model/icesat.ply"))
    m = trimesh.load(str(ref / "model/icesat.ply"), process=False)
    np.testing.assert_array_equal(m.vertices, V)
    np.testing.assert_array_equal(m.faces, Fc)
    raw = m.metadata["_ply_raw"]["face"]["data"]["component"]
    np.testing.assert_array_equal(np.asarray(raw).ravel(), comp)
    from raytrace.targets import load_target
    model = load_target("icesat")
    assert set(np.unique(comp)) == set(range(1, len(model.components) + 1))


# --------------------------------------------------------------------------- reproducibility
def test_two_workers_and_shards_give_the_same_bytes(ref, tmp_path):
    assert run_main(*SMALL, *MODS, "--workers", "2", "--out", tmp_path / "w2") == 0
    assert_same_tree(ref, tmp_path / "w2")
    sh = tmp_path / "sh"
    assert run_main(*SMALL, *MODS, "--workers", "1", "--shard", "2/2", "--out", sh) == 0
    assert not (sh / "labels.json").exists()  # incomplete until the other shard has run
    assert run_main(*SMALL, *MODS, "--workers", "1", "--shard", "1/2", "--out", sh) == 0
    assert_same_tree(ref, sh)


def test_two_workers_load_the_scene_this_process_built(ref, tmp_path, monkeypatch):
    """With a pool, this process builds the scene and radiance cache once and pickles them
    for the workers (scenes.prebuild_scenes; what a worker does with the file:
    test_a_prebuilt_scene_renders_the_same_bits): the bytes are those of one worker, and the
    temporary folder is gone afterwards."""
    import tempfile

    folders = []
    real_mkdtemp = tempfile.mkdtemp

    def mkdtemp(*args, **kwargs):
        folders.append(real_mkdtemp(*args, **kwargs))
        return folders[-1]

    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    seen = []
    real_prebuild = scenes.prebuild_scenes

    def prebuild(tasks, folder):
        out = real_prebuild(tasks, folder)
        seen.append({spec: os.path.getsize(path) for spec, path in out.items()})
        return out

    monkeypatch.setattr(scenes, "prebuild_scenes", prebuild)
    assert run_main(*SMALL, *MODS, "--workers", "2", "--out", tmp_path / "w2") == 0
    assert_same_tree(ref, tmp_path / "w2")
    assert seen == [{("builtin", "icesat"): seen[0][("builtin", "icesat")]}] and seen[0][("builtin", "icesat")] > 1e6
    assert folders and not any(os.path.exists(f) for f in folders)


def test_workers_build_their_own_scenes_when_the_temporary_folder_fails(ref, tmp_path, monkeypatch, capsys):
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", "/tmp")

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    assert run_main(*SMALL, *MODS, "--workers", "2", "--out", tmp_path / "w2") == 0
    assert_same_tree(ref, tmp_path / "w2")
    assert "the workers build their own scenes" in capsys.readouterr().err


def test_a_prebuilt_scene_renders_the_same_bits(tmp_path):
    """The pickled scene with its cache (what a worker loads) against a scene built afresh:
    the same radiance bit for bit; a cache is only adopted by the scene it was built for."""
    from raytrace.camera import Camera
    from raytrace.lighting import Lighting
    from raytrace.scene import Scene
    from raytrace.shade import render
    from raytrace.targets import load_target

    spec = ("builtin", "icesat")
    task = {"model_spec": spec, "cfg": {"render": {"quality": "fast"}}, "modalities": ["rgb"]}
    paths = scenes.prebuild_scenes([task], str(tmp_path))
    loaded = scenes.load_prebuilt(paths[spec])
    assert loaded is not None and len(loaded._caches) == 1
    fresh = Scene(load_target("icesat"))
    cam = Camera(160, 120, 150.0, 150.0, 79.5, 59.5)
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    light = Lighting(sun_dir_body=(0.6, 0.0, -0.8))
    a = render(loaded, cam, R, [0.0, 0.0, 12.0], light, quality="fast", seed=3)
    b = render(fresh, cam, R, [0.0, 0.0, 12.0], light, quality="fast", seed=3)
    assert a.geometry.mask.any() and np.array_equal(a.radiance, b.radiance)
    with pytest.raises(ValueError, match="another scene"):
        fresh.adopt_radiance_cache(loaded.radiance_cache())


def test_a_prebuilt_scene_carries_the_cache_its_preset_asks_for(tmp_path):
    """``balanced`` with 16 rays renders with a finer cache lattice than the default: the
    scene the main job pickles for its workers carries that cache, under the options a frame
    asks for, and renders the same bits as a scene built afresh."""
    from raytrace.camera import Camera
    from raytrace.lighting import Lighting
    from raytrace.presets import preset_cache_options, quality_preset
    from raytrace.scene import Scene
    from raytrace.shade import render
    from raytrace.targets import load_target

    spec = ("builtin", "cassini")
    task = {"model_spec": spec, "cfg": {"render": {"quality": "balanced", "samples": 16}}, "modalities": ["rgb"]}
    loaded = scenes.load_prebuilt(scenes.prebuild_scenes([task], str(tmp_path))[spec])
    fresh = Scene(load_target("cassini"))
    options = preset_cache_options(quality_preset("balanced", 16), fresh.scale_m)
    assert options and list(loaded._caches) == [tuple(sorted(options.items()))]
    cam = Camera(96, 72, 90.0, 90.0, 47.5, 35.5)
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    light = Lighting(sun_dir_body=(0.6, 0.0, -0.8))
    a = render(loaded, cam, R, [0.0, 0.0, 30.0], light, quality="balanced", samples=16, seed=3)
    b = render(fresh, cam, R, [0.0, 0.0, 30.0], light, quality="balanced", samples=16, seed=3)
    assert a.geometry.mask.any() and np.array_equal(a.radiance, b.radiance)
    assert len(loaded._caches) == 1  # the adopted cache served the frame: none was built
    # geometry-only and reference tasks build nothing
    assert scenes.prebuild_scenes([dict(task, modalities=["mask", "depth"])], str(tmp_path)) == {}
    assert scenes.prebuild_scenes([dict(task, cfg={"render": {"quality": "reference"}})], str(tmp_path)) == {}


def test_config_round_trip_reproduces_the_bytes(ref, tmp_path):
    cfg = tomllib.loads((ref / "config.toml").read_text())
    assert cfg["camera"]["width"] == 160 and cfg["sequence"]["target"] == "icesat"
    assert run_main("--config", ref / "config.toml", "--workers", "1", "--quiet", "--out", tmp_path / "rt") == 0
    assert_same_tree(ref, tmp_path / "rt")
    # flags override the file
    args = cli.build_parser().parse_args(["--config", str(ref / "config.toml"), "--frames", "3"])
    resolved, given = cli.resolve_config(args)
    assert resolved["sequence"]["frames"] == 3 and resolved["camera"]["height"] == 120 and "frames" in given


def test_rerun_skips_complete_frames_and_repairs_deleted_ones(ref, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(ref, seq)
    (seq / "rgb/000003.png").unlink()
    (seq / "depth/000005.exr").write_bytes(b"corrupt")
    (seq / "labels.json").unlink()
    capsys.readouterr()
    assert run_main(*SMALL, *MODS, "--workers", "1", "--out", seq) == 0
    out = capsys.readouterr().out
    assert "rendered 2, skipped 6" in out
    assert_same_tree(ref, seq)


def test_killed_run_leaves_no_partial_file_and_resumes(ref, tmp_path):
    seq = tmp_path / "seq"
    cmd = [sys.executable, str(ROOT / "cli.py"), *SMALL, *MODS, "--workers", "1", "--out", str(seq)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 60
    while not (seq / ".manifest" / "000001.json").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    for p in seq.rglob("*"):  # whatever has a real name is complete
        if p.is_file() and not p.name.startswith(".") and p.suffix in (".png", ".exr"):
            F.read_image(str(p))
    r = subprocess.run(cmd, check=False, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    skipped = int(r.stdout.split("skipped ")[1].split()[0])
    assert skipped >= 1
    assert_same_tree(ref, seq)


def test_interrupted_pool_removes_its_temporary_scenes(tmp_path):
    """Ctrl-C while two workers render: exit 130 with the one-line message, and the scenes the
    parent pickled for them (in TMPDIR, the persistent cache off) are gone."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    cmd = [sys.executable, str(ROOT / "cli.py"), *SMALL[:4], "--frames", "48", *SMALL[6:], "--workers", "2",
           "--out", str(tmp_path / "seq")]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp), "ORBITSYNTH_CACHE_DIR": ""},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not list(tmp.glob("orbitsynth-scenes-*/*.pickle")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()[1]
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err
    assert "interrupted" in err
    assert not list(tmp.glob("orbitsynth-scenes-*"))


def _children(pid: int) -> list:
    """Live (not zombie) child processes of ``pid``, from /proc."""
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        out += [int(c) for c in task.read_text().split()]
    return out


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _pool_job(tmp_path, tmp, frames=48):
    """The main job on two workers, started in its own session with the default SIGINT, its
    temporary folder ``tmp``; returns (process, sequence folder, its workers' pids) once it has
    written a frame."""
    seq = tmp_path / "seq"
    cmd = [sys.executable, str(ROOT / "cli.py"), *SMALL[:4], "--frames", str(frames), *SMALL[6:], "--workers", "2",
           "--out", str(seq)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp), "ORBITSYNTH_CACHE_DIR": ""}, start_new_session=True)
    deadline = time.monotonic() + 120
    while not (seq / ".manifest" / "000001.json").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()[1]
    workers = _children(proc.pid)
    assert len(workers) >= 2  # the two workers (and multiprocessing's resource tracker)
    return proc, seq, workers


def _gone(pids: list, timeout: float = 20.0) -> bool:
    """Whether the processes have all exited within ``timeout`` seconds (the resource tracker
    exits a moment after the parent)."""
    deadline = time.monotonic() + timeout
    while any(_running(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not any(_running(p) for p in pids)


def _no_temporaries(seq: Path) -> None:
    # the folder's lock file stays where its run was killed (the lock itself died with the run)
    hidden = [p for p in seq.rglob(".*") if p.name not in (".manifest", F.LOCK_NAME)]
    assert hidden == [] or all(p.parent.name == ".manifest" and p.suffix == ".json" for p in hidden), hidden


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc")
def test_terminated_pool_stops_its_workers_and_removes_its_temporaries(tmp_path):
    """SIGTERM (a scheduler's time limit, kill) to the parent alone while two workers render:
    the workers stop at once (they were left running, orphaned, for ever), the parent exits
    143 with the one-line message, and neither the scenes it pickled for the pool nor any
    frame's temporary file is left behind. (SIGHUP takes the same path: exit 129.)"""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc, seq, workers = _pool_job(tmp_path, tmp)
    signame, sig = "SIGTERM", signal.SIGTERM
    proc.send_signal(sig)
    err = proc.communicate(timeout=60)[1]  # would hang while an orphaned worker holds stderr
    assert proc.returncode == 128 + sig, err
    assert err.strip().splitlines() == [f"cli.py: terminated by {signame}; complete frames are kept, rerun the same "
                                        "command to resume"]
    assert _gone(workers)
    assert list(tmp.iterdir()) == []
    _no_temporaries(seq)
    assert 1 <= len(list((seq / "rgb").iterdir())) < 48


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc")
def test_workers_stop_when_the_parent_is_killed_and_the_next_run_removes_its_scenes(tmp_path):
    """SIGKILL to the parent alone: its workers notice and exit (within the watchdog's poll
    and one frame's clean-up), leaving no temporary file; the scenes folder the parent could
    not remove is removed by the next run's pool (it names its owner's host and pid)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc, seq, workers = _pool_job(tmp_path, tmp)
    [stale] = list(tmp.iterdir())
    assert stale.name.startswith(f"orbitsynth-scenes-{F._HOST}.{proc.pid}-")
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)  # returns once the workers, which hold its pipes, are gone
    assert _gone(workers)
    _no_temporaries(seq)
    other = tmp / f"orbitsynth-scenes-{F._HOST}.{os.getpid()}-live"  # a live process's: kept
    other.mkdir()
    r = subprocess.run([sys.executable, str(ROOT / "cli.py"), *SMALL[:4], "--frames", "2", *SMALL[6:],
                        "--workers", "2", "--out", str(tmp_path / "next")], cwd=ROOT, capture_output=True, text=True,
                       env={**os.environ, "TMPDIR": str(tmp), "ORBITSYNTH_CACHE_DIR": ""}, timeout=120)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp.iterdir()) == [other.name]


def test_dask_local_cluster_gives_the_same_bytes(ref, tmp_path):
    distributed = pytest.importorskip("distributed")
    import logging
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as lc:
        assert run_main(*SMALL, *MODS, "--scheduler", lc.scheduler_address, "--out", tmp_path / "dask") == 0
    assert_same_tree(ref, tmp_path / "dask")


def test_unreachable_scheduler_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """The scheduler is connected before the sequence folder is prepared (it left scenario.json, the model and
    empty modality folders behind)."""
    pytest.importorskip("distributed")
    from raytrace.dataset import pool
    monkeypatch.setattr(pool, "SCHEDULER_TIMEOUT_S", 2.0)  # nobody answers: the test needs no 10 s wait
    import socket
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    assert run_main(*SMALL, "--frames", "2", "--scheduler", f"tcp://127.0.0.1:{port}", "--out", tmp_path / "seq") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--scheduler" in err and "cannot connect" in err, err
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- options
def test_only_visible_drops_frames_and_keeps_flags(ref, tmp_path):
    out = tmp_path / "vis"
    assert run_main(*SMALL, "--modalities", "mask", "--workers", "1", "--only-visible", "--out", out) == 0
    all_labels = json.loads((ref / "labels.json").read_text())
    visible = [lab["frame"] for lab in all_labels if lab["visible"]]
    assert 0 < len(visible) < len(all_labels)  # this draw has frames in Earth's shadow
    labels = json.loads((out / "labels.json").read_text())
    assert [lab["frame"] for lab in labels] == visible
    assert sorted(p.name for p in (out / "mask").iterdir()) == [f"{i:06d}.png" for i in visible]
    assert json.loads((out / "scenario.json").read_text())["visible"] == [lab["visible"] for lab in all_labels]
    for lab in labels:  # geometry-only modalities match the full render's
        assert (out / lab["files"]["mask"]).read_bytes() == (ref / lab["files"]["mask"]).read_bytes()


def test_explicit_pattern_attitude_and_paper_preset(tmp_path):
    out = tmp_path / "x"
    argv = [*SMALL, "--amplitude-m", "12", "--kappa", "0.2", "--attitude", "spin", "--spin-rate-deg-s", "2",
            "--degrade", "paper", "--frames", "3", "--workers", "1", "--out", out]
    assert run_main(*argv) == 0
    scen = json.loads((out / "scenario.json").read_text())
    assert scen["pattern"] == "spiral" and scen["pattern_source"] == "explicit"
    assert scen["pattern_parameters"]["A"] == pytest.approx(12.0)
    assert scen["pattern_parameters"]["kappa"] == pytest.approx(0.2)
    assert (out / "rgb_degraded/000002.png").is_file()
    labels = json.loads((out / "labels.json").read_text())
    q0, q2 = np.array(labels[0]["q_cam_from_body"]), np.array(labels[2]["q_cam_from_body"])
    assert 2 * math.acos(min(1.0, abs(q0 @ q2))) > 0.1  # the target spun between frames


def test_negative_option_values_are_read_as_values(capsys):
    """`--attitude-ypr-deg -40,5,60` and `--roll-deg -1e-3` (argparse alone stops at a value that starts with '-'
    unless it looks like '-15'), each the same as the `=` form."""
    docs = []
    for argv in (["--attitude-ypr-deg", "-40,5,60", "--roll-deg", "-1e-3"], ["--attitude-ypr-deg=-40,5,60", "--roll-deg=-1e-3"]):
        assert run_main(*SMALL, "--attitude", "inertial", *argv, "--frames", "2", "--json") == 0
        docs.append(json.loads(capsys.readouterr().out))
    assert docs[0] == docs[1]
    assert run_main(*SMALL, "--attitude", "inertial", "--frames", "2", "--json") == 0
    assert json.loads(capsys.readouterr().out)["frames"][1]["q_cam_from_body"] != docs[0]["frames"][1]["q_cam_from_body"]


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_explicit_kappa_on_the_spiral_boundary_is_drip_drop(capsys, sign):
    """|kappa| = kappa* is drip-drop, just below it spiral (docs/orbit.md, "Patterns and their
    thresholds"). kappa recomputed from the state built from kappa* falls an ulp below it; the class
    is that of the kappa given (it refused `--pattern drip-drop`)."""
    from orbit.patterns import KAPPA_STAR
    for kappa, pattern in ((sign * KAPPA_STAR, "drip-drop"), (sign * np.nextafter(KAPPA_STAR, 0.0), "spiral")):
        assert run_main("--target", "spacedragon", "--pattern", pattern, "--amplitude-m", "12", "--kappa", repr(float(kappa)),
                        "--frames", "3", "--json") == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["pattern"] == doc["pattern_parameters"]["pattern"] == pattern
        assert doc["pattern_parameters"]["kappa"] == pytest.approx(kappa, rel=1e-12)


def test_dataset_command_table(tmp_path, capsys):
    argv = ["dataset", "--targets", "icesat", "--patterns", "--frames", "2", "--width", "48", "--height", "36",
            "--focal-length-mm", "0.15", "--workers", "1", "--quiet", "--out", tmp_path / "ds"]
    assert run_main(*argv) == 0
    out = capsys.readouterr().out
    for pattern in ("elliptical", "spiral", "drip-drop", "drift"):
        assert f"icesat_{pattern}" in out
        seq = tmp_path / "ds" / f"icesat_{pattern}"
        assert sorted(p.name for p in seq.iterdir() if not p.name.startswith(".")) == [
            "camera.json", "config.toml", "depth", "labels.json", "manifest.json", "mask", "model", "normal", "rgb",
            "scenario.json"]
    assert "total" in out and "4 sequences x 4 modalities" in out


def test_dataset_of_all_patterns_refuses_one_explicit_pattern_and_writes_nothing(tmp_path, capsys):
    """--patterns with --amplitude-m/--kappa made the same pattern four times into one folder and stopped
    half-way ("holds another sequence"); it is refused up front, as preview --all-patterns does."""
    argv = ["dataset", "--targets", "icesat", "--patterns", "--amplitude-m", "15", "--kappa", "0.1", "--frames", "2",
            "--width", "48", "--height", "36", "--workers", "1", "--quiet", "--out", tmp_path / "ds"]
    assert run_main(*argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--patterns" in err and "--kappa" in err, err
    assert list(tmp_path.iterdir()) == []


def test_ablation_command_prints_the_table(capsys):
    argv = ["ablation", "--targets", "icesat", "--frames", "2", "--width", "64", "--height", "48",
            "--focal-length-mm", "0.2", "--workers", "1", "--quiet"]
    assert run_main(*argv) == 0
    out = capsys.readouterr().out
    assert "D4 blur + Poisson + Gaussian" in out and "+ demosaic" in out and "| icesat |" in out


# --------------------------------------------------------------------------- bad input
def _bad_mesh(tmp_path):
    p = tmp_path / "broken.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2\n")
    return ["--mesh", str(p)]


def _bad_config(text):
    def make(tmp_path):
        p = tmp_path / "bad.toml"
        p.write_text(text)
        return ["--config", str(p)]
    return make


def _out_under_a_file(tmp_path):
    (tmp_path / "afile").write_text("x")
    return ["--out", str(tmp_path / "afile" / "seq")]


BAD = [
    (["--target", "hubble"], ["--target", "cassini"]),
    (["--pattern", "circle"], ["--pattern", "drip-drop"]),
    (["--modalities", "rgb,xray"], ["--modalities", "normal"]),
    (["--degrade", "blurry"], ["--degrade", "physical"]),
    (["--attitude", "wobble"], ["--attitude", "tumble"]),
    (["--quality", "ultra"], ["--quality", "reference"]),
    (["--altitude-km", "nan"], ["--altitude-km"]),
    (["--altitude-km", "50"], ["--altitude-km", "100"]),
    (["--inclination-deg", "200"], ["--inclination-deg"]),
    (["--width", "0"], ["--width", "[1, 65535]"]),
    (["--height", "-5"], ["--height"]),
    (["--focal-length-mm", "-4"], ["--focal-length-mm"]),
    (["--pixel-pitch-um", "0"], ["--pixel-pitch-um"]),
    (["--pixel-pitch-um", "1e-300"], ["--pixel-pitch-um", "[0.1, 1000]"]),  # was fx = 4e+303, an internal name
    (["--full-well-e", "1e-300"], ["--full-well-e", "[1, 1e+09]"]),  # was a NaN image after rendering, exit 1
    (["--spin-axis", "0,0,0"], ["--spin-axis", "non-zero"]),
    # values starting with '-' that argparse alone would not take ("expected one argument"): the option's own check
    (["--attitude-ypr-deg", "-40,5"], ["--attitude-ypr-deg", "3 comma-separated", "-40,5"]),
    (["--roll-deg", "-inf"], ["--roll-deg", "finite", "[-360, 360]"]),
    (["--shard", "3/2"], ["--shard", "K/N"]),
    (["--kappa", "0.1"], ["--amplitude-m"]),
    (["--amplitude-m", "12", "--kappa", "0.5"], ["--kappa", "drip-drop", "spiral"]),
    (["--pattern", "elliptical", "--amplitude-m", "0.2", "--kappa", "0"], ["--amplitude-m", "bounding radius"]),
    (["--modalities", "rgb_degraded", "--degrade", "none"], ["--modalities", "--degrade"]),
    (["--pattern", "drift", "--window-s", "1000000"], ["window_s"]),
    (_bad_mesh, ["--mesh", "broken.ply"]),
    (lambda tmp: ["--mesh", str(tmp / "missing.glb")], ["--mesh", "missing.glb"]),
    (_bad_config("[sequence]\nframes = [\n"), ["--config", "not valid TOML"]),
    (_bad_config("[camera]\nwidht = 3\n"), ["--config", "widht", "width"]),
    (_bad_config("[camera]\nwidth = 'wide'\n"), ["--config", "width", "integer"]),
    (_bad_config("[lens]\nf = 1\n"), ["--config", "[lens]", "[camera]"]),
    (_bad_config("sequence = 5\n"), ["--config", "sequence must be a table"]),  # was "unknown table [sequence]"
    (_bad_config('[sequence]\nframes = "2"\n'), ["--config", "frames must be an integer", "'2'"]),  # was accepted
    (_bad_config('[output]\nonly_visible = "yes"\n'), ["--config", "only_visible must be true or false"]),
    (_bad_config('[attitude]\nspin_axis = "0,0,1"\n'), ["--config", "spin_axis must be an array of 3 numbers"]),
    (_bad_config("[orbit]\nepoch = 2026-03-20T12:00:00Z\n"), ["--config", "epoch", "quoted string"]),
    (lambda tmp: ["--config", str(tmp / "nope.toml")], ["--config", "nope.toml"]),
    (_out_under_a_file, ["--out", "afile"]),
]


@pytest.mark.parametrize("args, names", BAD)
def test_bad_input_is_one_line_exit_2_and_leaves_nothing(tmp_path, capsys, args, names):
    extra = args(tmp_path) if callable(args) else args
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    out = ["--out", str(tmp_path / "seq")] if "--out" not in extra else []
    base = SMALL[2:] if "--mesh" in extra else SMALL  # SMALL's --target would conflict with --mesh
    assert SMALL[:2] == ["--target", "icesat"]
    assert run_main(*base, "--workers", "1", *extra, *out) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    err = cap.err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("cli.py: error: "), err
    for name in names:
        assert name in err, (name, err)
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before  # nothing created


def test_mesh_with_non_finite_vertices_is_repaired_with_a_one_line_warning(tmp_path, capsys, nan_box_obj):
    """The faces touching a NaN vertex are removed (raytrace.meshio), and the main job says so (it was silent)."""
    n_bad = nan_box_obj(tmp_path / "nan.obj")
    assert run_main("--mesh", tmp_path / "nan.obj", "--frames", "2", "--json") == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["frames"]
    assert cap.err.count("\n") == 1 and "warning: --mesh nan.obj" in cap.err, cap.err
    assert f"{n_bad} of 12 triangles touch a NaN/inf vertex" in cap.err


def test_target_and_mesh_flags_and_a_flag_overrides_the_files_model(tmp_path, capsys):
    """--mesh is rendered instead of --target (documented), now with a one-line warning (the target was dropped
    silently); a --target flag replaces the mesh of a --config file, as every flag overrides the file, and a
    --mesh flag its target."""
    import trimesh
    trimesh.creation.box((2.0, 1.0, 1.0)).export(tmp_path / "box.ply")
    assert run_main("--target", "tiangong", "--mesh", tmp_path / "box.ply", "--frames", "2", "--json") == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["target"] == "box"
    assert cap.err.count("\n") == 1 and "warning: --mesh" in cap.err and "instead of --target tiangong" in cap.err
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[sequence]\nmesh = "{tmp_path / "box.ply"}"\nframes = 2\n')
    for flags, target in (([], "box"), (["--target", "icesat"], "icesat")):
        assert run_main("--config", cfg, *flags, "--json") == 0
        assert json.loads(capsys.readouterr().out)["target"] == target
    cfg.write_text('[sequence]\ntarget = "tiangong"\nframes = 2\n')
    assert run_main("--config", cfg, "--mesh", tmp_path / "box.ply", "--json") == 0
    assert json.loads(capsys.readouterr().out)["target"] == "box"


def test_a_library_warning_is_one_line_once(tmp_path, capsys):
    """A mesh far from its origin (raytrace.scene warns) gave Python's two-line warning, twice; now one line."""
    import trimesh
    box = trimesh.creation.box((2.0, 1.0, 1.0))
    box.apply_translation((5000.0, 0.0, 0.0))
    box.export(tmp_path / "far.ply")
    assert run_main(*SMALL[2:], "--mesh", tmp_path / "far.ply", "--frames", "2", "--workers", "1",
                    "--modalities", "mask", "--out", tmp_path / "seq") == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("cli.py: warning: model far:") and "recentre" in err, err


def test_another_sequence_in_the_folder_is_refused(ref, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(ref, seq)
    assert run_main(*SMALL, *MODS, "--seed", "1", "--workers", "1", "--out", seq) == 2
    assert "holds another sequence" in capsys.readouterr().err
    assert filecmp.cmp(seq / "scenario.json", ref / "scenario.json", shallow=False)


# --------------------------------------------------------------------------- files
@pytest.mark.parametrize("dtype,channels", [(np.uint8, 3), (np.uint16, 1)])
def test_noisy_png_is_lossless_deterministic_and_written_its_own_way(tmp_path, dtype, channels):
    """``noisy=True`` (the degraded frames) changes how a PNG is filtered and deflated, not its
    pixels; the same pixels give the same bytes."""
    rng = np.random.default_rng(7)
    px = rng.integers(0, np.iinfo(dtype).max, size=(48, 64, channels), endpoint=True).astype(dtype)
    px[:10] = 0  # some black space, as in a frame
    paths = [str(tmp_path / f"{k}.png") for k in ("noisy1", "noisy2", "default")]
    F.atomic_write_image(paths[0], px, noisy=True)
    F.write_image(paths[1], px, noisy=True)
    F.write_image(paths[2], px)
    for p in paths:
        np.testing.assert_array_equal(F.read_image(p), px[..., 0] if channels == 1 else px)
    assert F.sha256_file(paths[0]) == F.sha256_file(paths[1]) != F.sha256_file(paths[2])


def test_data_pngs_carry_no_colour_space(ref):
    """Instance masks are data: no sRGB/gAMA/cHRM chunk that a colour-managed reader would apply (OpenImageIO
    tagged every PNG sRGB); the RGB frames keep their sRGB tag."""
    lab = json.loads((ref / "labels.json").read_text())[0]
    assert not {"sRGB", "gAMA", "cHRM", "iCCP"} & set(png_chunks(ref / lab["files"]["mask"]))
    assert "sRGB" in png_chunks(ref / lab["files"]["rgb"])


def test_atomic_writes_leave_no_temporary(tmp_path):
    with pytest.raises(ValueError, match="uint8, uint16 or float32"):
        F.atomic_write_image(str(tmp_path / "a.png"), np.zeros((2, 2), np.int64))
    assert list(tmp_path.iterdir()) == []
    F.atomic_write_image(str(tmp_path / "a.exr"), np.ones((2, 3), np.float32))
    assert [p.name for p in tmp_path.iterdir()] == ["a.exr"]
    np.testing.assert_array_equal(F.read_image(str(tmp_path / "a.exr")), np.ones((2, 3)))
    # a temporary of a writer that died is removed; one of a live writer is kept
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          check=True, capture_output=True, text=True)
    host = F._HOST
    stale = tmp_path / f".000001.{host}.{int(dead.stdout)}.tmp.png"
    live = tmp_path / f".000002.{host}.{os.getpid()}.tmp.png"
    stale.write_bytes(b"x")
    live.write_bytes(b"x")
    assert F.remove_stale_temporaries(str(tmp_path)) == 1
    assert not stale.exists() and live.exists()


def test_signal_during_an_image_write_is_raised_after_the_file_is_closed(tmp_path, capfd, monkeypatch):
    """A SIGTERM that reaches a pool worker between OpenImageIO's ``open`` and ``write_image``
    (its handler raises, ``pool._worker_stop``) is held back until the writer is closed, then
    raised: the PNG is complete, the temporary is removed, and libpng prints nothing (it said
    "No IDATs written into file" when the interrupted writer was destroyed unwritten, a second
    line beside the CLI's one-line message: seen in a fresh-clone CI run)."""
    import OpenImageIO as oiio

    create = oiio.ImageOutput.create

    class SignalledAfterOpen:
        """An ImageOutput whose ``open`` is followed at once by a SIGTERM to this process."""

        def __init__(self, path):
            self._out = create(path)

        def open(self, *args):
            ok = self._out.open(*args)
            os.kill(os.getpid(), signal.SIGTERM)  # its handler runs at the next bytecode
            return ok

        def __getattr__(self, name):
            return getattr(self._out, name)

    def stop(signum, frame):
        raise KeyboardInterrupt

    monkeypatch.setattr(oiio.ImageOutput, "create", staticmethod(SignalledAfterOpen))
    previous = signal.signal(signal.SIGTERM, stop)
    try:
        pixels = np.arange(16, dtype=np.uint8).reshape(2, 2, 4)  # RGBA: written by OpenImageIO
        with pytest.raises(KeyboardInterrupt):
            F.write_image(str(tmp_path / "a.png"), pixels)
        with pytest.raises(KeyboardInterrupt):
            F.atomic_write_image(str(tmp_path / "b.png"), pixels)
    finally:
        signal.signal(signal.SIGTERM, previous)
    monkeypatch.undo()
    assert capfd.readouterr().err == ""
    np.testing.assert_array_equal(F.read_image(str(tmp_path / "a.png")), pixels)  # closed whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]  # b's temporary removed


def test_stale_process_folders_are_removed_and_others_kept(tmp_path):
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              check=True, capture_output=True, text=True).stdout)
    host = F._HOST
    made = F.process_folder("job-", str(tmp_path))
    assert os.path.basename(made).startswith(f"job-{host}.{os.getpid()}-")
    names = {"stale": f"job-{host}.{dead}-abc", "other_host": f"job-{host}x.{dead}-abc",
             "other_prefix": f"run-{host}.{dead}-abc", "no_pid": "job-abc"}
    for name in names.values():
        (tmp_path / name).mkdir()
        (tmp_path / name / "f").write_bytes(b"x")
    (tmp_path / f"job-{host}.{dead}-file").write_bytes(b"x")  # a file, not a folder: kept
    assert F.remove_stale_process_folders("job-", str(tmp_path)) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [os.path.basename(made), names["other_host"], names["other_prefix"], names["no_pid"],
         f"job-{host}.{dead}-file"])
    assert F.remove_stale_process_folders("job-", str(tmp_path / "missing")) == 0


def test_frame_seeds_are_the_spawned_children():
    children = np.random.SeedSequence(7).spawn(5)
    for i, child in enumerate(children):
        render_seed, degrade_seq = folder.frame_seeds(7, i)
        assert render_seed == int(child.generate_state(1)[0] % 2**31)
        assert np.array_equal(degrade_seq.generate_state(4), child.spawn(1)[0].generate_state(4))


def test_dry_run_and_json_render_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert run_main(*SMALL, "--dry-run") == 0
    assert run_main(*SMALL, "--json") == 0
    out = capsys.readouterr().out
    assert "frames visible" in out and '"s0_lvlh"' in out
    assert list(tmp_path.iterdir()) == []


def test_user_mesh_renders_and_is_written_back(tmp_path):
    import trimesh
    trimesh.creation.box((3.0, 2.0, 1.0)).export(tmp_path / "box.ply")
    out = tmp_path / "seq"
    argv = [*SMALL, "--mesh", tmp_path / "box.ply", "--frames", "2", "--modalities", "mask,depth", "--workers", "1",
            "--out", out]
    assert run_main(*argv) == 0
    V, Fc, comp = F.read_model_ply(str(out / "model/box.ply"))
    assert len(Fc) == 12 and set(comp.tolist()) == {1}
    np.testing.assert_allclose(np.ptp(V, axis=0), [3.0, 2.0, 1.0])
    labels = json.loads((out / "labels.json").read_text())
    assert all(lab["pixel_counts"][1] > 0 for lab in labels)


def _auto_motion(capsys, *extra):
    argv = ["--target", "icesat", "--pattern", "elliptical", "--frames", "4", "--width", "160", "--height", "120",
            "--attitude", "spin", "--motion-blur", "auto", "--json", *extra]
    assert run_main(*argv) == 0
    frames = json.loads(capsys.readouterr().out)["frames"]
    return np.array([f["motion_blur_px"] for f in frames]), np.array([f["motion_angle_deg"] for f in frames])


def test_auto_motion_blur_follows_the_targets_image_motion(capsys):
    """Properties of the per-frame blur that hold whatever the geometry: it vanishes with the
    exposure, grows linearly with it (small angles), comes from the spin (without it only the
    slow relative-orbit rotation is left), and at the first frame (t = 0, the same attitude for
    any rate) doubling the spin rate doubles it."""
    L1, a1 = _auto_motion(capsys, "--spin-rate-deg-s", "30", "--exposure-us", "10000")
    L2, _ = _auto_motion(capsys, "--spin-rate-deg-s", "30", "--exposure-us", "20000")
    L3, _ = _auto_motion(capsys, "--spin-rate-deg-s", "60", "--exposure-us", "10000")
    L0, _ = _auto_motion(capsys, "--spin-rate-deg-s", "30", "--exposure-us", "0.001")
    assert np.all(L1 > 0.1), L1
    np.testing.assert_allclose(L2, 2 * L1, rtol=1e-3)
    np.testing.assert_allclose(L3[0], 2 * L1[0], rtol=0.01)
    assert np.all(L0 < 1e-4 * L1 / 1e-3)
    Ls, _ = _auto_motion(capsys, "--spin-rate-deg-s", "0", "--exposure-us", "10000")
    assert np.all(Ls < 0.02 * L1), (Ls, L1)
    assert np.all(np.abs(a1) <= 180.0)


@pytest.mark.parametrize("extra", [["--demosaic", "linear"], ["--offset-dn", "64"], ["--dark-current-e-s", "1e6"],
                                   ["--defocus-radius-px", "2"], ["--corner-sigma-px", "3"],
                                   ["--degrade", "paper", "--paper-blur-px", "3"],
                                   ["--degrade", "paper", "--paper-gaussian-var", "0.05"]])
def test_every_degradation_option_reaches_the_degraded_image(tmp_path, extra):
    """Each lower-layer option changes rgb_degraded against the same run without it (same
    seed, same clean image) and is recorded in the written config."""
    base = ["--target", "icesat", "--pattern", "elliptical", "--frames", "1", "--width", "160", "--height", "120",
            "--workers", "1", "--modalities", "rgb,rgb_degraded"]
    preset = ["--degrade", "paper"] if "paper" in extra else ["--degrade", "physical"]
    assert run_main(*base, *preset, "--out", str(tmp_path / "a")) == 0
    assert run_main(*base, *preset, *extra, "--out", str(tmp_path / "b")) == 0
    a = (tmp_path / "a" / "rgb_degraded" / "000000.png").read_bytes()
    b = (tmp_path / "b" / "rgb_degraded" / "000000.png").read_bytes()
    assert a != b
    assert (tmp_path / "a" / "rgb" / "000000.png").read_bytes() == (tmp_path / "b" / "rgb" / "000000.png").read_bytes()
    cfg = tomllib.loads((tmp_path / "b" / "config.toml").read_text())["degrade"]
    key = extra[-2].lstrip("-").replace("-", "_")
    assert str(cfg[key]) in (extra[-1], str(float(extra[-1])) if extra[-1][0].isdigit() else extra[-1])


def test_roll_turns_the_camera_about_its_boresight(capsys):
    """--roll-deg φ: every frame's R_cam_from_body is the roll-free one turned about the camera
    z axis by φ (either sense; look_at applies it as R_z(roll)·R_cam_from_lvlh), and t_cam_m keeps
    its depth."""
    argv = ["--target", "icesat", "--pattern", "drift", "--frames", "3", "--json"]
    assert run_main(*argv) == 0
    f0 = json.loads(capsys.readouterr().out)["frames"]
    assert run_main(*argv, "--roll-deg", "30") == 0
    f1 = json.loads(capsys.readouterr().out)["frames"]
    for a, b in zip(f0, f1, strict=True):
        Ra = np.array(a["R_cam_from_body"]).reshape(3, 3)
        Rb = np.array(b["R_cam_from_body"]).reshape(3, 3)
        D = Rb @ Ra.T
        np.testing.assert_allclose(D[2], [0, 0, 1], atol=1e-12)
        assert math.degrees(abs(math.atan2(D[1, 0], D[0, 0]))) == pytest.approx(30.0, abs=1e-9)
        np.testing.assert_allclose(b["t_cam_m"][2], a["t_cam_m"][2], rtol=1e-12)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, None], ids=["SIGTERM", "SIGHUP", "Ctrl-C"])
def test_a_failure_while_a_signal_unwinds_the_job_reports_the_signal(signum, capsys):
    """The signal's exception lands wherever the main thread is; code it interrupts can fail in
    turn as it unwinds (``threading``'s "release unlocked lock" once turned a SIGTERM into
    "rendering failed", exit 1, in test_terminated_pool_stops_its_workers_and_removes_its_temporaries).
    Such a failure reports the signal and its status; a failure of its own stays a failure."""
    def run():
        try:
            raise pool.Terminated(signum) if signum is not None else KeyboardInterrupt()
        except KeyboardInterrupt:
            raise RuntimeError("release unlocked lock")

    result, status = cli._guarded(run)
    assert result is None
    name = signal.Signals(signum).name if signum is not None else None
    assert status == 128 + (signum if signum is not None else signal.SIGINT)
    err = capsys.readouterr().err.strip()
    assert err == (f"cli.py: terminated by {name}" if name else "cli.py: interrupted") \
        + "; complete frames are kept, rerun the same command to resume"

    def failing():
        raise RuntimeError("a render's own failure")

    assert cli._guarded(failing) == (None, 1)
    assert "rendering failed (RuntimeError: a render's own failure)" in capsys.readouterr().err
