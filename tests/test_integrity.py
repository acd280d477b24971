"""Nothing silently mixed or lost: one run owns a sequence folder (an OS lock), a dataset is
declared complete only when every file matches its record, a refused or failed run leaves the
folder as it found it (or without half-written frames), input files are read only if they are
regular files of sane size, and bounded planning (tumble, motion blur, memory).

Small frames (64×48, one worker) keep the module quick."""

import errno
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from raytrace import files as F
from raytrace.dataset import options as opt
from raytrace.dataset import pool
from tests.cli_helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
TINY = ["--target", "tiangong", "--frames", "2", "--width", "64", "--height", "48", "--workers", "1", "--quiet"]




def tree(folder: Path) -> dict:
    """Relative path → bytes (None for a folder) of everything under ``folder``, hidden included."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


def cli_proc(*argv, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "cli.py"), *map(str, argv)], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def one_error_line(err: str, *words) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], (w, err)


# --------------------------------------------------------------------------- one owner per folder
def test_a_folder_locked_by_another_run_is_refused_before_anything_is_written(tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    other = F.FolderLock(str(seq), shared=False)  # another run holds the folder
    other.acquire()
    try:
        before = tree(seq)
        assert run_main(*TINY, "--out", seq) == 2
        one_error_line(capsys.readouterr().err, "--out", "in use by another run")
        assert tree(seq) == before
        # a shard is refused too while a whole run holds it
        assert run_main(*TINY, "--shard", "1/2", "--out", seq) == 2
        assert tree(seq) == before
    finally:
        other.release()
    assert run_main(*TINY, "--out", seq) == 0
    assert not (seq / F.LOCK_NAME).exists()  # released with the run, and its file removed
    assert (seq / "manifest.json").is_file()


def test_shards_of_one_sequence_share_the_folder_and_a_whole_run_is_refused_meanwhile(tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    shard = F.FolderLock(str(seq), shared=True)  # shard 2/2 of the same sequence, running
    shard.acquire()
    try:
        assert run_main(*TINY, "--shard", "1/2", "--out", seq) == 0
        assert "1 of 2 frames present" in capsys.readouterr().out
        assert run_main(*TINY, "--out", seq) == 2
        one_error_line(capsys.readouterr().err, "in use by another run")
        assert (seq / F.LOCK_NAME).exists()  # the other shard still holds it: not removed from under it
    finally:
        shard.release()
    assert run_main(*TINY, "--shard", "2/2", "--out", seq) == 0
    assert "labels.json and manifest.json written" in capsys.readouterr().out
    assert not (seq / F.LOCK_NAME).exists()


def test_lock_file_deleted_by_its_holder_cannot_let_two_runs_in(tmp_path):
    """A process that opened the lock file before its holder deleted it must lock the new file,
    not the deleted one (else it and a third process would both hold 'the' lock)."""
    a = F.FolderLock(str(tmp_path), shared=False)
    a.acquire()
    fd = os.open(tmp_path / F.LOCK_NAME, os.O_RDWR)  # a late opener of the same file
    a.release(remove=True)
    c = F.FolderLock(str(tmp_path), shared=False)
    c.acquire()  # creates and holds a new lock file
    b = F.FolderLock(str(tmp_path), shared=False)
    with pytest.raises(F.FolderLockBusy):
        b.acquire()
    os.close(fd)
    c.release(remove=True)


def test_two_different_runs_started_at_once_never_both_succeed(tmp_path):
    """The race: two runs with different options into one new folder at the same time.
    Exactly one may own it; the folder then holds that run's sequence only."""
    for attempt in range(2):
        seq = tmp_path / f"X{attempt}"
        procs = [cli_proc(*TINY, "--roll-deg", roll, "--out", seq) for roll in ("0", "90")]
        outs = [p.communicate(timeout=300) for p in procs]
        codes = [p.returncode for p in procs]
        assert sorted(codes) == [0, 2], (codes, outs)
        loser = outs[codes.index(2)][1]
        assert "in use by another run" in loser or "holds another sequence" in loser, loser
        roll = ("0", "90")[codes.index(0)]
        scen = json.loads((seq / "scenario.json").read_text())
        assert scen["config"]["camera"]["roll_deg"] == float(roll)
        assert run_main(*TINY, "--roll-deg", roll, "--out", seq) == 0  # the files are that sequence's


# --------------------------------------------------------------------------- shards and the manifest
def test_a_shard_never_declares_complete_a_dataset_with_a_corrupt_frame(tmp_path, capsys):
    opts = ["--target", "icesat", "--frames", "12", "--width", "64", "--height", "48", "--workers", "1", "--quiet"]
    full = tmp_path / "full"
    assert run_main(*opts, "--out", full) == 0
    seq = tmp_path / "copy"
    shutil.copytree(full, seq)
    (seq / "labels.json").unlink()
    (seq / "manifest.json").unlink()
    os.truncate(seq / "rgb" / "000003.png", 100)  # frame 3 belongs to shard 2/2
    capsys.readouterr()
    assert run_main(*opts, "--shard", "1/2", "--out", seq) == 0
    out = capsys.readouterr().out
    assert not (seq / "manifest.json").exists() and not (seq / "labels.json").exists()
    assert "frame 3 does not match its manifest record (rgb/000003.png)" in out
    # its own shard renders it again, and the manifest then agrees with every file
    assert run_main(*opts, "--shard", "2/2", "--out", seq) == 0
    manifest = json.loads((seq / "manifest.json").read_text())
    for rel, digest in manifest["files"].items():
        assert F.sha256_file(str(seq / rel)) == digest, rel
    assert (seq / "rgb" / "000003.png").read_bytes() == (full / "rgb" / "000003.png").read_bytes()


def test_an_incomplete_sequence_keeps_no_manifest_that_disagrees_with_its_files(tmp_path):
    opts = ["--target", "icesat", "--frames", "4", "--width", "64", "--height", "48", "--workers", "1", "--quiet"]
    seq = tmp_path / "seq"
    assert run_main(*opts, "--out", seq) == 0
    os.truncate(seq / "mask" / "000001.png", 10)  # frame 1: shard 2/2's
    assert run_main(*opts, "--shard", "1/2", "--out", seq) == 0
    assert not (seq / "manifest.json").exists()


# --------------------------------------------------------------------------- foreign or broken folders
def test_random_bytes_as_scenario_json_name_the_folder_as_foreign(tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "scenario.json").write_bytes(np.random.default_rng(1).bytes(4096))
    before = tree(seq)
    for _ in range(2):  # and so on every rerun: a usage error, not "rendering failed ... rerun"
        assert run_main(*TINY, "--out", seq) == 2
        one_error_line(capsys.readouterr().err, str(seq), "not a sequence of this tool")
    assert tree(seq) == before


@pytest.mark.parametrize("content", ['{"format": "something else"}', "[1, 2]"])
def test_a_json_scenario_of_another_tool_is_foreign(tmp_path, capsys, content):
    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "scenario.json").write_text(content)
    assert run_main(*TINY, "--out", seq) == 2
    one_error_line(capsys.readouterr().err, "not a sequence of this tool")


def test_scenario_json_that_is_a_folder_is_refused_and_nothing_is_left(tmp_path, capsys):
    seq = tmp_path / "seq"
    (seq / "scenario.json").mkdir(parents=True)
    before = tree(seq)
    assert run_main(*TINY, "--out", seq) == 2
    one_error_line(capsys.readouterr().err, "not a sequence of this tool", "a folder")
    assert tree(seq) == before  # no camera.json, config.toml, model/ or empty folders


def test_a_non_empty_folder_of_other_files_is_refused(tmp_path, capsys):
    seq = tmp_path / "mine"
    seq.mkdir()
    (seq / "notes.txt").write_text("my notes\n")
    (seq / "rgb").mkdir()
    (seq / "rgb" / "holiday.png").write_bytes(b"not ours")
    before = tree(seq)
    assert run_main(*TINY, "--out", seq) == 2
    one_error_line(capsys.readouterr().err, "not empty", "notes.txt")
    assert tree(seq) == before
    empty = tmp_path / "empty"
    empty.mkdir()
    assert run_main(*TINY, "--out", empty) == 0  # an empty folder is fine


@pytest.mark.parametrize("new", [True, False], ids=["new folder", "existing empty folder"])
def test_a_disk_full_while_preparing_leaves_the_folder_as_found(tmp_path, capsys, monkeypatch, new):
    seq = tmp_path / "a" / "seq"
    if not new:
        seq.mkdir(parents=True)
    real = F.atomic_write_bytes

    def full(path, data):
        if path.endswith("config.toml"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(F, "atomic_write_bytes", full)
    assert run_main(*TINY, "--out", seq) == 2
    one_error_line(capsys.readouterr().err, "No space left on device")
    if new:
        assert not (tmp_path / "a").exists()
    else:
        assert tree(seq) == {}


def test_a_disk_full_while_rendering_removes_the_files_of_incomplete_frames(tmp_path, capsys, monkeypatch):
    opts = ["--target", "icesat", "--frames", "4", "--width", "64", "--height", "48", "--workers", "1", "--quiet"]
    seq = tmp_path / "seq"
    real = F.write_frame_record

    def full(seq_dir, frame, record):
        if frame == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        real(seq_dir, frame, record)

    monkeypatch.setattr(F, "write_frame_record", full)
    assert run_main(*opts, "--out", seq) == 1
    assert "No space left on device" in capsys.readouterr().err
    names = sorted(p.name for p in seq.rglob("*.png")) + sorted(p.name for p in seq.rglob("*.exr"))
    assert not any(n.startswith(("000002", "000003")) for n in names), names  # frame 2 (and unrendered 3)
    assert any(n.startswith("000001") for n in names)  # complete frames are kept
    assert not list(seq.rglob(".*.tmp*"))
    monkeypatch.setattr(F, "write_frame_record", real)
    assert run_main(*opts, "--out", seq) == 0  # and the rerun completes it


# --------------------------------------------------------------------------- input files
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_config_that_is_a_device_a_fifo_or_too_large_is_one_line(tmp_path):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (opt.CONFIG_LIMIT_BYTES + 10) + "\n")
    for path, words in (("/dev/zero", ["regular file", "character device"]), (fifo, ["regular file", "FIFO"]),
                        (big, ["at most 1 MiB"])):
        if str(path).startswith("/dev") and not os.path.exists(path):
            continue
        p = cli_proc("--config", path, "--dry-run")
        out, err = p.communicate(timeout=60)  # a FIFO without a writer must not hang the run
        assert p.returncode == 2, err
        one_error_line(err, "--config", *words)


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_mesh_star_catalogue_and_scene_file_must_be_regular_files(tmp_path, capsys):
    for name in ("zero.obj", "zero.csv", "zero.json"):
        (tmp_path / name).symlink_to("/dev/zero")
    assert run_main("--mesh", tmp_path / "zero.obj", "--dry-run") == 2
    one_error_line(capsys.readouterr().err, "--mesh", "regular file")
    assert run_main("--star-catalogue", tmp_path / "zero.csv", "--dry-run") == 2
    one_error_line(capsys.readouterr().err, "--star-catalogue", "regular file")
    assert run_main("render-scene", tmp_path / "zero.json", "--out", tmp_path / "o") == 2
    one_error_line(capsys.readouterr().err, "scene file", "regular file")
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- temporary scenes
def test_every_kind_of_run_removes_the_scene_folder_a_killed_run_left(tmp_path, monkeypatch):
    """The pool's scene folder of a run killed with SIGKILL goes with the next run, even one
    that starts no pool (--workers 1, --dry-run); a live process's folder stays."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    pid = int(dead.stdout)
    for argv in (["--dry-run", "--frames", "2"], [*TINY, "--out", tmp_path / "seq"]):
        stale = tmp_path / f"{pool._SCENES_FOLDER}{F._HOST}.{pid}-abcdefgh"
        stale.mkdir()
        (stale / "scene0.pickle").write_bytes(b"x" * 1000)
        live = tmp_path / f"{pool._SCENES_FOLDER}{F._HOST}.{os.getpid()}-live"
        live.mkdir(exist_ok=True)
        assert run_main(*argv) == 0
        assert not stale.exists()
        assert live.exists()


# --------------------------------------------------------------------------- bounded planning
def test_tumble_planning_at_high_rates_is_bounded():
    """A torque-free tumble at 10 rev/s about each axis over the default spiral's 2777 s window
    (28 000 turns): planning returns in seconds, not minutes."""
    p = cli_proc("--attitude", "tumble", "--inertia-kg-m2", "1,2,3", "--omega0-deg-s", "3600,3600,3600", "--dry-run")
    t0 = time.monotonic()
    try:
        out, err = p.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        pytest.fail("tumble planning ran for more than 90 s")
    assert p.returncode == 0, err
    assert time.monotonic() - t0 < 90


def _blur(capsys, exposure_us: float, *extra) -> list:
    assert run_main("--target", "cassini", "--frames", "3", "--attitude", "spin", "--motion-blur", "auto",
                    "--exposure-us", exposure_us, "--json", *extra) == 0
    return json.loads(capsys.readouterr().out)


def test_auto_motion_blur_grows_with_the_exposure_of_a_fast_spin(capsys):
    """3600 deg/s: a quarter, half, three quarters, one and two turns in the exposure. The blur
    never shrinks as the exposure grows (comparing end poses gave 188 / 124 / 0 px at 1/2, 3/4
    and 1 turn) and the label says what was applied and how long the swept path is."""
    exposures = [25_000, 50_000, 75_000, 100_000, 200_000]
    docs = [_blur(capsys, e, "--spin-rate-deg-s", "3600") for e in exposures]
    L = np.array([[f["motion_blur_px"] for f in d["frames"]] for d in docs])
    path = np.array([[f["motion_path_px"] for f in d["frames"]] for d in docs])
    assert np.all(L[3] > 10.0), L  # a full turn blurs
    assert np.all(np.diff(L, axis=0) >= 0.0), L
    assert np.all(np.diff(path, axis=0) > 0), path  # the swept path keeps growing
    assert np.all(L <= path + 1e-9)  # a straight blur is never longer than the path it stands for
    assert "motion_blur" in docs[0] or all("motion_blur_bounded" in f for f in docs[0]["frames"])


def test_auto_motion_blur_of_a_half_turn_about_the_line_of_sight_matches_the_arcs(capsys):
    """A spin about the line of sight moves every hull vertex on a circle about the principal
    point, of radius r_k = f ρ_k / z_k. In half a turn centred on the frame time a vertex sweeps
    the half circle centred on its frame-time position (angle φ_k); uniform in time on it, its
    position has variance r_k²/2 along the tangent there and r_k² (1/2 − 4/π²) along the radius.
    The blur is a segment along the principal axis v of the mean of these covariances, of
    length min(√(12 λ), E): λ their mean variance along v, E the RMS of the half circles'
    extents along v. An answer from the frame's pose and the geometry of circles alone."""
    from scipy.spatial import ConvexHull

    from raytrace.targets import load_target
    doc = _blur(capsys, 20, "--spin-rate-deg-s", "0")
    axis_lvlh = np.array(doc["frames"][0]["r_lvlh"])  # target → camera at t = 0, where body axes = LVLH axes
    axis = ",".join(f"{v:.17g}" for v in axis_lvlh / np.linalg.norm(axis_lvlh))
    f = _blur(capsys, 50_000, "--spin-rate-deg-s", "3600", "--spin-axis", axis)["frames"][0]
    R = np.array(f["R_cam_from_body"]).reshape(3, 3)
    model = load_target("cassini")
    pts = np.concatenate([np.asarray(c.mesh.vertices) for c in model.components])
    p = pts[ConvexHull(pts).vertices] @ R.T + np.array(f["t_cam_m"])
    focal_px = 4e-3 / 3.45e-6
    u = focal_px * p[:, :2] / p[:, 2:3]  # image position about the principal point [px]
    r = np.linalg.norm(u, axis=1)
    rad = u / r[:, None]
    tan = np.stack([-rad[:, 1], rad[:, 0]], axis=1)
    cov = np.mean(r[:, None, None] ** 2 * (0.5 * tan[:, :, None] * tan[:, None, :]
                                          + (0.5 - 4.0 / math.pi**2) * rad[:, :, None] * rad[:, None, :]), axis=0)
    lam, vecs = np.linalg.eigh(cov)
    v = vecs[:, -1]
    phi = np.arctan2(u[:, 1], u[:, 0])
    theta = phi[:, None] + np.linspace(-0.5 * math.pi, 0.5 * math.pi, 20001)[None, :]
    along = r[:, None] * (np.cos(theta) * v[0] + np.sin(theta) * v[1])
    extent = np.sqrt(np.mean((along.max(axis=1) - along.min(axis=1)) ** 2))
    expected = min(math.sqrt(12.0 * lam[-1]), extent)
    assert f["motion_blur_px"] == pytest.approx(expected, rel=0.005)
    angle = math.degrees(math.atan2(-v[1], v[0]))  # counter-clockwise from +column, rows down
    assert (f["motion_angle_deg"] - angle + 90.0) % 180.0 == pytest.approx(90.0, abs=0.5)


# --------------------------------------------------------------------------- unchecked combinations
def test_offset_above_half_the_adc_range_is_refused(capsys):
    assert run_main("--offset-dn", "65535", "--bit-depth", "8", "--dry-run") == 2
    one_error_line(capsys.readouterr().err, "--offset-dn", "--bit-depth 8")
    assert run_main("--offset-dn", "64", "--bit-depth", "8", "--dry-run") == 0


def test_a_tiny_but_non_zero_spin_axis_is_a_direction(capsys):
    assert run_main("--attitude", "spin", "--spin-axis", "1e-200,0,0", "--spin-rate-deg-s", "1", "--json",
                    "--frames", "2") == 0
    capsys.readouterr()
    assert run_main("--attitude", "spin", "--spin-axis", "0,0,0", "--dry-run") == 2
    err = capsys.readouterr().err
    one_error_line(err, "--spin-axis")
    assert "spin_axis_body" not in err


@pytest.mark.parametrize("out", [" ", "  \t", "a\nb"])
def test_a_blank_or_control_character_out_is_refused(tmp_path, capsys, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    assert run_main(*TINY, "--out", out) == 2
    one_error_line(capsys.readouterr().err, "--out")
    assert list(tmp_path.iterdir()) == []


def test_a_frame_too_large_for_memory_is_refused_up_front(tmp_path, capsys):
    t0 = time.monotonic()
    assert run_main("--width", "65535", "--height", "65535", "--frames", "1", "--out", tmp_path / "huge") == 2
    one_error_line(capsys.readouterr().err, "--width/--height", "GiB")
    assert not (tmp_path / "huge").exists()
    assert time.monotonic() - t0 < 30


def test_workers_are_lowered_to_what_memory_holds(monkeypatch, capsys):
    from raytrace.camera import Camera
    cam = Camera.from_focal(4e-3, 3.45e-6, 1280, 960)
    need = pool.WORKER_BASE_BYTES + pool.FRAME_BYTES_PER_PIXEL * 1280 * 960
    monkeypatch.setattr(pool, "memory_bytes", lambda: (64 * need, 2.5 * need))
    assert pool.fit_workers([cam], 8) == 2
    assert "2 workers instead of 8" in capsys.readouterr().err
    assert pool.fit_workers([cam], 2) == 2
