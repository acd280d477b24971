"""The first run, as a newcomer meets it: a lit target in every default frame, the eclipse one
option away and explained in the labels, README commands that work as written, a --help that
lists what is allowed, no silent abbreviations, and small commands that do what they say."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cli
from orbit.patterns import PATTERNS
from raytrace import files as F
from raytrace.dataset import jit, pool
from raytrace.targets import BUILTIN_TARGETS
from tests.cli_helpers import run_main

ROOT = Path(__file__).resolve().parents[1]




def json_doc(capsys, *argv) -> dict:
    assert run_main(*argv, "--json") == 0
    return json.loads(capsys.readouterr().out)


# --------------------------------------------------------------------------- no black frames by default
@pytest.mark.parametrize("pattern", PATTERNS)
def test_every_default_frame_shows_the_target_lit_and_in_view(capsys, pattern):
    for target in ("cassini", "tiangong"):
        doc = json_doc(capsys, "--target", target, "--pattern", pattern)
        frames = doc["frames"]
        assert len(frames) == cli.DEFAULT_FRAMES
        dark = [(f["frame"], f["shadow"], f["not_visible_because"]) for f in frames
                if not f["visible"] or f["shadow"] != "sunlit"]
        assert not dark, (target, pattern, dark)
        assert "arg_lat_deg" in doc["reference_orbit"]["chosen"]


def test_the_eclipse_is_one_option_away_and_labelled(capsys):
    doc = json_doc(capsys, "--target", "cassini", "--pattern", "spiral", "--arg-lat-deg", "180")
    assert doc["reference_orbit"]["chosen"] == []
    shadowed = [f for f in doc["frames"] if f["shadow"] == "umbra"]
    assert len(shadowed) >= 10
    for f in doc["frames"]:
        assert f["visible"] == (not f["not_visible_because"])
        assert ("earth_shadow" in f["not_visible_because"]) == (f["shadow_fraction"] == 0.0)


def test_a_frame_in_shadow_keeps_the_geometric_box_of_its_mask_and_says_why(tmp_path):
    """In Earth's shadow the RGB is dark, but mask and bbox are the target's silhouette (geometry,
    not light); the label says why the frame is not visible. bbox is [x, y, w, h] with w and h
    inclusive: the mask's columns x .. x + w − 1 (read back from the mask PNG)."""
    seq = tmp_path / "seq"
    argv = ["--target", "icesat", "--pattern", "spiral", "--frames", "6", "--width", "96", "--height", "72",
            "--arg-lat-deg", "180", "--workers", "1", "--quiet", "--out", seq]
    assert run_main(*argv) == 0
    labels = json.loads((seq / "labels.json").read_text())
    dark = [f for f in labels if not f["visible"]]
    assert dark, "the eclipse case must hold frames in shadow"
    for f in labels:
        mask = F.read_image(str(seq / f["files"]["mask"]))
        ys, xs = np.nonzero(mask)
        if xs.size == 0:
            assert f["bbox"] is None
            continue
        assert f["bbox"] == [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]
    def target_mean(f):
        rgb = F.read_image(str(seq / f["files"]["rgb"])).astype(float)
        mask = F.read_image(str(seq / f["files"]["mask"]))
        return rgb[mask > 0].mean() if mask.any() else None

    lit = [m for f in labels if f["visible"] and (m := target_mean(f)) is not None]
    umbra = [f for f in dark if f["shadow"] == "umbra" and target_mean(f) is not None]
    assert lit and umbra
    for f in dark:
        assert f["not_visible_because"], f
    for f in umbra:  # the box is the silhouette's while the pixels are dark: geometry, not light
        assert f["not_visible_because"] == ["earth_shadow"] and f["bbox"] is not None
        assert target_mean(f) < 0.2 * np.mean(lit)


# --------------------------------------------------------------------------- README as written
def _quick_start_commands() -> list:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```bash\n(.*?)\n```", section, flags=re.S)


def test_quick_start_is_two_commands_that_leave_the_venv_active():
    cmds = _quick_start_commands()
    assert len(cmds) == 2, cmds
    for cmd in cmds:
        assert "\n" not in cmd.strip()
        assert re.search(r"(^|&& )(\.|source) \.venv/bin/activate &&", cmd), cmd  # later `python cli.py` works
    assert "cli.py --target cassini --pattern spiral" in cmds[0]
    assert cmds[1].rstrip().endswith("python -m pytest")
    ci = (ROOT / ".ci" / "run").read_text()
    assert cmds[1].strip() in ci  # CI runs the same test command


# --------------------------------------------------------------------------- --help and commands
def _help(*command) -> str:
    r = subprocess.run([sys.executable, str(ROOT / "cli.py"), *command, "--help"], capture_output=True, text=True,
                       cwd=ROOT, timeout=60, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    return r.stdout


def _option_entries(text: str) -> dict:
    """Option → its help entry (the lines from the flag to the next flag)."""
    entries, current = {}, None
    for line in text.split("\n", 1)[1].splitlines():
        m = re.match(r"^  (--[a-zA-Z0-9-]+)", line)
        if m:
            current = m.group(1)
            entries[current] = line
        elif current and line.startswith("    "):
            entries[current] += " " + line.strip()
        else:
            current = None
    return entries


CHOICES = {"--target": BUILTIN_TARGETS, "--pattern": PATTERNS, "--attitude": cli.ATTITUDE_MODES,
           "--quality": cli.QUALITIES, "--exposure": cli.EXPOSURE_MODES, "--earth-texture": cli.EARTH_TEXTURES,
           "--degrade": cli.DEGRADE_PRESETS, "--paper-group": cli.PAPER_GROUP_NAMES, "--demosaic": ("MHC", "linear"),
           "--motion-blur": ("fixed", "auto"), "--modalities": cli.MODALITIES, "--targets": BUILTIN_TARGETS,
           "--mode": ("paper", "physical", "both"), "--patterns": PATTERNS}


@pytest.mark.parametrize("command", [[], ["dataset"], ["ablation"], ["render-scene"], ["preview"], ["snapshots"]],
                         ids=["main", "dataset", "ablation", "render-scene", "preview", "snapshots"])
def test_help_lists_every_choice_and_each_default_once(command):
    entries = _option_entries(_help(*command))
    assert entries
    switches = {"--patterns"} if command == ["dataset"] else set()  # dataset --patterns: all four, no value
    for flag, entry in entries.items():
        assert entry.count("(default") <= 1, entry
        if flag in CHOICES and flag not in switches:
            for value in CHOICES[flag]:
                assert value in entry, (flag, value, entry)


def test_abbreviated_flags_are_refused(capsys):
    assert run_main("--frame", "3", "--dry-run") == 2
    assert "--frame" in capsys.readouterr().err
    assert run_main("dataset", "--target", "icesat") == 2  # not --targets


def test_an_unknown_command_suggests_the_nearest(capsys):
    assert run_main("datset") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'dataset'" in err and "unknown command" in err
    assert run_main("zzz") == 2
    assert "commands:" in capsys.readouterr().err


def test_one_spelling_for_the_list_of_targets():
    for command in ("dataset", "ablation", "snapshots"):
        entries = _option_entries(_help(command))
        assert "--targets" in entries and "--target" not in entries, command


def test_dataset_table_follows_the_order_of_targets(tmp_path, capsys):
    argv = ["dataset", "--targets", "icesat,tiangong", "--frames", "1", "--width", "32", "--height", "24",
            "--workers", "1", "--quiet", "--out", tmp_path / "ds"]
    assert run_main(*argv) == 0
    rows = [ln.split()[0] for ln in capsys.readouterr().out.splitlines()[1:3]]
    assert rows == ["icesat_spiral", "tiangong_spiral"]


def test_ablation_with_one_target_prints_each_row_once(capsys):
    argv = ["ablation", "--targets", "icesat", "--frames", "1", "--width", "32", "--height", "24",
            "--focal-length-mm", "0.2", "--workers", "1", "--quiet", "--mode", "paper"]
    assert run_main(*argv) == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| paper")]
    assert len(rows) == len(set(rows)) == 4, rows
    assert all("| icesat |" in r for r in rows)


# --------------------------------------------------------------------------- meshes in the wrong unit
def test_a_mesh_whose_size_suggests_millimetres_gets_a_warning_naming_the_flag(tmp_path, capsys):
    import trimesh
    path = tmp_path / "cube_mm.stl"
    trimesh.creation.box((1000.0, 1000.0, 1000.0)).export(path)  # a 1 m cube drawn in millimetres
    assert run_main("--mesh", path, "--dry-run", "--frames", "2") == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--mesh-unit-m 0.001" in err and "1732 m across" in err
    assert run_main("--mesh", path, "--mesh-unit-m", "0.001", "--dry-run", "--frames", "2") == 0
    assert capsys.readouterr().err == ""


# --------------------------------------------------------------------------- the compile step
def test_the_first_run_compile_shows_a_progress_bar_to_its_end(monkeypatch, capsys):
    """The first run's compile says what it does and how long it should take, then draws a bar
    that the compiling processes advance (here a stand-in that reports three steps) to 100 %."""
    from raytrace import _precompile
    calls = []

    def fake_precompile(processes, groups, progress=None, serial=False):
        total = sum(c for c, _ in _precompile.group_signatures(groups).values())
        for done in (0.25 * total, 0.5 * total, total):
            progress(done, total)
        calls.append((processes, tuple(groups), serial))
        return []

    monkeypatch.setattr(_precompile, "precompile", fake_precompile)
    jit.compile_kernels(["fast"], quiet=False)
    err = capsys.readouterr().err
    assert calls and calls[0][1] == ("fast",)
    assert "compiling the ray-tracing kernels (fast)" in err and "about" in err
    frames = [f for f in err.replace("\r", "\n").splitlines() if f.startswith("compiling:")]
    assert frames and "100%" in frames[-1], err
    jit.compile_kernels(["fast"], quiet=True)  # --quiet: nothing
    assert capsys.readouterr().err == ""
    assert [c[2] for c in calls] == [False, False]
    jit.compile_kernels(["fast"], quiet=True, serial=True)
    assert calls[-1][2] is True


def test_the_compile_is_of_the_builds_the_frames_will_call(tmp_path, monkeypatch):
    """A pool whose workers run one numba thread each calls the kernels' serial builds
    (raytrace._jit.ThreadedKernel), so the first run compiles those; one worker rendering in
    this process on several threads calls the parallel builds."""
    asked = []
    monkeypatch.setattr(jit, "kernels_not_compiled", lambda quality="fast", serial=False: ["fast"])
    monkeypatch.setattr(jit, "compile_kernels", lambda groups, quiet, serial=False: asked.append(serial))
    small = ["--target", "icesat", "--frames", "4", "--width", "64", "--height", "48", "--modalities", "mask"]
    assert run_main(*small, "--workers", "2", "--out", tmp_path / "w2") == 0
    assert run_main(*small, "--workers", "1", "--out", tmp_path / "w1") == 0
    import numba
    per_worker = max(1, min(pool.default_workers() // 2, numba.config.NUMBA_NUM_THREADS))
    assert asked == [per_worker == 1, numba.config.NUMBA_NUM_THREADS == 1]
    assert pool.frame_threads(2, 4) == per_worker
    assert pool.frame_threads(4, 1) == pool.frame_threads(1, 9) == numba.config.NUMBA_NUM_THREADS


def test_the_compile_is_of_the_preset_the_configuration_asks_for(tmp_path, monkeypatch):
    """The kernels compiled first are those of the sequence's preset, whether a flag or the
    ``--config`` file sets it (the file's ``balanced`` once compiled only the ``fast`` group)."""
    asked = []
    monkeypatch.setattr(jit, "kernels_not_compiled",
                        lambda quality="fast", serial=False: asked.append(quality) or [])
    conf = tmp_path / "c.toml"
    conf.write_text('[render]\nquality = "balanced"\n')
    small = ["--target", "icesat", "--frames", "1", "--width", "64", "--height", "48", "--modalities", "mask",
             "--workers", "1"]
    assert run_main(*small, "--config", conf, "--out", tmp_path / "a") == 0
    assert run_main(*small, "--quality", "reference", "--out", tmp_path / "b") == 0
    assert asked == ["balanced", "reference"]
