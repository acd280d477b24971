"""The command line: orbit-only output (--dry-run, --json), JSON contract, one-line errors, render-scene.

The rendering main job is tested in tests/test_pipeline.py."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import cli
from raytrace.dataset import pool
from orbit import cw
from orbit.patterns import parameters

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    return subprocess.run([sys.executable, str(ROOT / "cli.py"), *args], check=False, capture_output=True, text=True,
                          cwd=ROOT, timeout=120)


def test_dry_run_prints_states_and_flags():
    r = run("--target", "cassini", "--pattern", "spiral", "--frames", "12", "--dry-run")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    rows = [ln for ln in lines if not ln.startswith("#") and not ln.startswith("frame")]
    assert len(rows) == 12
    assert "pattern spiral" in lines[0]
    assert any(ln.startswith("frame") and "los" in ln and "shadow" in ln for ln in lines)
    assert r.stderr == ""


def test_json_states_follow_cw_dynamics_and_pattern():
    r = run("--target", "spacedragon", "--pattern", "drip-drop", "--frames", "25", "--seed", "5", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    n = doc["n"]
    assert n == pytest.approx(math.sqrt(3.986004418e14 / (6378137.0 + 400e3) ** 3), rel=1e-14)
    s0 = np.array(doc["s0_lvlh"])
    t = np.array(doc["t_s"])
    states = np.array([f["r_lvlh"] + f["v_lvlh"] for f in doc["frames"]])
    # independent oracle: integrate the CW ODE numerically from the printed initial state
    A = cw.system_matrix(n)
    sol = solve_ivp(lambda _t, s: A @ s, (0, t[-1]), s0, method="DOP853", t_eval=t, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(states, sol.y.T, rtol=1e-8, atol=1e-8)
    assert parameters(s0, n).pattern == "drip-drop" == doc["pattern_parameters"]["pattern"]
    lo, hi = doc["range_band_m"]
    ranges = np.linalg.norm(states[:, :3], axis=1)
    assert np.all((ranges >= lo) & (ranges <= hi))
    for f in doc["frames"]:
        R = np.array(f["R_cam_from_body"]).reshape(3, 3)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        # the camera looks at the target: the target origin is on the boresight at the range
        np.testing.assert_allclose(f["t_cam_m"], [0, 0, f["range_m"]], atol=1e-9)
        assert f["visible"] == (f["line_of_sight"] and f["sun_clear"] and f["shadow_fraction"] > 0)
        # the boresight points at the target, so the Sun direction in the camera frame makes the
        # Sun angle with +z_cam; the Earth direction is recomputed in LVLH, without the ECI chain
        assert np.linalg.norm(f["sun_dir_cam"]) == pytest.approx(1.0, abs=1e-12)
        assert math.degrees(math.acos(f["sun_dir_cam"][2])) == pytest.approx(f["sun_angle_deg"], abs=1e-7)
        r_cam_lvlh = np.array(f["r_lvlh"]) + [6378137.0 + 400e3, 0, 0]  # camera from Earth's centre
        R_cam_from_lvlh = R  # LVLH-fixed target: body axes = LVLH axes
        expected = R_cam_from_lvlh @ (-r_cam_lvlh / np.linalg.norm(r_cam_lvlh))
        np.testing.assert_allclose(f["earth_dir_cam"], expected, atol=1e-12)


def test_same_seed_same_bytes_different_seed_differs():
    a = run("--pattern", "drift", "--frames", "5", "--seed", "9", "--json")
    b = run("--pattern", "drift", "--frames", "5", "--seed", "9", "--json")
    c = run("--pattern", "drift", "--frames", "5", "--seed", "10", "--json")
    assert a.returncode == b.returncode == c.returncode == 0
    assert a.stdout == b.stdout and a.stdout != c.stdout


@pytest.mark.parametrize("args, names", [
    (["--target", "hubble"], ["--target", "tiangong", "spacedragon", "icesat", "cassini"]),
    (["--pattern", "circle"], ["--pattern", "elliptical", "spiral", "drip-drop", "drift"]),
    (["--frames", "0"], ["--frames", "[1, 1000000]"]),
    (["--frames", "ten"], ["--frames"]),
    (["--seed", "-1"], ["--seed"]),
    (["--altitude-km", "nan"], ["--altitude-km", "100"]),
    (["--altitude-km", "-400"], ["--altitude-km"]),
    (["--altitude-km", "50"], ["--altitude-km"]),
    (["--inclination-deg", "200"], ["--inclination-deg", "180"]),
    (["--window-s", "0"], ["--window-s"]),
    (["--window-s", "inf"], ["--window-s"]),
    (["--epoch", "yesterday"], ["--epoch", "ISO 8601"]),
    (["--bogus"], ["--bogus"]),
    (["--star-limit-mag", "12"], ["--star-limit-mag", "9"]),
    (["--star-catalogue", "no_such_stars.csv"], ["--star-catalogue", "no_such_stars.csv"]),
])
def test_bad_input_one_line_nonzero_exit(args, names):
    r = run(*args)
    assert r.returncode == 2
    assert r.stdout == ""
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1, err
    for name in names:
        assert name in err


def test_impossible_window_is_a_clear_error():
    r = run("--pattern", "drift", "--window-s", "1000000", "--frames", "3")
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1
    assert "window_s" in r.stderr


# --------------------------------------------------------------------------- render-scene
def _tiny_scene(tmp_path, **over):
    import trimesh

    from orbit.pose import look_at
    (tmp_path / "parts").mkdir(exist_ok=True)
    trimesh.creation.box((1.0, 1.0, 1.0)).export(tmp_path / "parts" / "bus.ply")
    rho = np.array([2.0, -8.0, 3.0])
    R = look_at(rho)
    scene = {"meshes": [{"path": "parts/bus.ply", "albedo": [0.6, 0.6, 0.6]}],
             "camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                        "R_cam_from_body": R.ravel().tolist(), "t_cam_m": (-R @ rho).tolist()},
             "sun": {"sun_dir_body": [0.6, -0.48, 0.64], "sun_irradiance_W_m2": 1361.0},
             "ambient_radiance_W_m2_sr": 1.0, "quality": "fast"}
    scene.update(over)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    return path


def test_render_scene_reports_a_signal_whose_unwinding_failed(tmp_path, monkeypatch, capsys):
    """A SIGTERM's exception can make the code it lands in fail as it unwinds (threading's
    "release unlocked lock"): render-scene reports the signal, exit 143, and writes nothing;
    a failure of its own stays "rendering ... failed", exit 1."""
    import signal

    import raytrace.shade

    def interrupted(*a, **k):
        try:
            raise pool.Terminated(signal.SIGTERM)
        except KeyboardInterrupt:
            raise RuntimeError("release unlocked lock")

    path = _tiny_scene(tmp_path)
    out = tmp_path / "out"
    monkeypatch.setattr(raytrace.shade, "render", interrupted)
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "cli.py: terminated by SIGTERM; nothing half-written is left"
    assert not out.exists()

    def failing(*a, **k):
        raise RuntimeError("a render's own failure")

    monkeypatch.setattr(raytrace.shade, "render", failing)
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 1
    assert "failed (RuntimeError: a render's own failure); nothing was written" in capsys.readouterr().err
    assert not out.exists()


def test_render_scene_writes_a_frame(tmp_path):
    import OpenImageIO as oiio
    path = _tiny_scene(tmp_path)
    out = tmp_path / "out"
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 0
    for rel in ("rgb/000000.png", "mask/000000.png", "depth/000000.exr", "normal/000000.exr", "hdr/000000.exr",
                "frame.json"):
        assert (out / rel).is_file(), rel
    mask = oiio.ImageBuf(str(out / "mask/000000.png")).get_pixels(oiio.UINT16)[..., 0]
    depth = oiio.ImageBuf(str(out / "depth/000000.exr")).get_pixels(oiio.FLOAT)[..., 0]
    hdr = oiio.ImageBuf(str(out / "hdr/000000.exr")).get_pixels(oiio.FLOAT)
    assert mask.shape == (48, 64) and np.any(mask == 1)
    assert np.array_equal(mask > 0, np.isfinite(depth))  # labels agree with pixels
    assert np.all(hdr[mask > 0].sum(-1) > 0)
    assert not [p for p in out.iterdir() if p.name.startswith(".partial")]


@pytest.mark.parametrize("over,match", [
    ({"quality": "ultra"}, "quality must be one of"),
    ({"sun": {"sun_dir_body": [0, 0, float("nan")]}}, "sun_dir_body"),
    ({"camera": {"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "width": 0, "height": 4,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 5]}}, "width"),
    ({"meshes": [{"path": "missing.ply", "albedo": 0.5}]}, "missing.ply"),
    ({"meshes": [{"path": "parts/bus.ply", "material": "unobtainium"}]}, "material must be one of"),
    ({"extra": 1}, "unknown keys"),
    ({"stars": {"limit_mag": 6.0}}, "stars.R_body_from_eci is required"),
    ({"stars": {"R_body_from_eci": [1, 0, 0, 0, 1, 0, 0, 0, 1], "limit_mag": 20}}, "limit magnitude"),
    ({"stars": {"R_body_from_eci": [1, 0, 0, 0, 1, 0, 0, 0, -1]}}, "stars.R_body_from_eci must be a rotation matrix"),
    ({"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": [1, 0, 0, 0, 1, 0, 0, 0, -1], "t_cam_m": [0, 0, 5]}},
     "camera.R_cam_from_body must be a rotation matrix"),
    ({"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": [1.01, 0, 0, 0, 1, 0, 0, 0, 1], "t_cam_m": [0, 0, 5]}},
     "camera.R_cam_from_body must be a rotation matrix (orthonormal to 0.001"),
    ({"stars": {"R_body_from_eci": [1, 0, 0, 0, 1, 0, 0, 0, 1], "catalogue": "none.csv"}}, "none.csv"),
    ({"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48, "fov": 30,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 5]}}, "camera: unknown keys ['fov']"),
    ({"sun": {"sun_dir_body": [0, 0, 1], "angular_diameter_deg": None}}, "sun.angular_diameter_deg"),
    ({"sun": {"sun_dir_body": [0, 0, 1], "angular_diameter_deg": 200}}, "sun.angular_diameter_deg"),
    ({"sun": {"sun_dir_body": [0, 0, 1], "sun_irradiance_W_m2": "1361"}}, "sun_irradiance_W_m2 must be a number"),
    ({"sun": {"sun_dir_body": [0, 0, 1], "sun_irradiance_W_m2": 1e300}}, "sun_irradiance_W_m2 must be a finite"),
    ({"sun": {"sun_dir_body": "up"}}, "sun_dir_body must be a unit 3-vector"),
    ({"ambient_radiance_W_m2_sr": True}, "ambient_radiance_W_m2_sr must be a number"),
    ({"version": 2}, "version must be 1"),
    # numbers must be JSON numbers: not text or truth values that float() would also take
    ({"camera": {"K": [["120", 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 5]}}, "camera.K must be 9 numbers"),
    ({"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": ["0", "0", "5"]}},
     "camera.t_cam_m must be 3 numbers"),
    ({"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": [True, 0, 0, 0, 1, 0, 0, 0, 1], "t_cam_m": [0, 0, 5]}},
     "camera.R_cam_from_body must be 9 numbers"),
    ({"sun": {"sun_dir_body": [False, False, True]}}, "sun_dir_body must be a unit 3-vector of numbers"),
    ({"meshes": [{"path": "parts/bus.ply", "albedo": True}]}, "meshes[0].albedo must be 1 or 3 numbers"),
    ({"meshes": [{"path": "parts/bus.ply", "albedo": ["0.5", 0.5, 0.5]}]}, "meshes[0].albedo must be 1 or 3 numbers"),
    ({"meshes": [{"path": "parts/bus.ply", "albedo": [0.5, 0.5]}]}, "meshes[0].albedo must be 1 or 3 numbers"),
    ({"earth": {"earth_dir_body": [0, 0, -1], "earth_distance_m": 6.8e6, "texture": [[1, 2], [3]]}},
     "earth.texture must be one of uniform, procedural"),
    # a focal length no lens has (it overflowed the culling's arithmetic)
    ({"camera": {"K": [[1e300, 0, 31.5], [0, 1e300, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 5]}}, "fx must be a number in (0, 1e+09]"),
    ({"camera": {"K": [[120.0, 0, 1e12], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                 "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [0, 0, 5]}}, "cx must be a number in"),
])
def test_render_scene_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, over, match):
    path = _tiny_scene(tmp_path, **over)
    out = tmp_path / "out"
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1
    assert not out.exists()


def test_render_scene_takes_a_rotation_rounded_in_print(tmp_path):
    """A pose printed to 4 decimals (|R Rᵀ − I| ~ 1e-4) is a pose, not an error: the frame is
    rendered with the nearest rotation, which frame.json gives; an exact one is kept as is."""
    from raytrace.scenefile import load_scene_file
    path = _tiny_scene(tmp_path)
    exact = load_scene_file(str(path)).R_cam_from_body
    data = json.loads(path.read_text())
    assert np.array_equal(exact.ravel(), data["camera"]["R_cam_from_body"])  # kept bit for bit
    data["camera"]["R_cam_from_body"] = [round(v, 4) for v in data["camera"]["R_cam_from_body"]]
    assert np.abs(np.reshape(data["camera"]["R_cam_from_body"], (3, 3)) @ np.reshape(
        data["camera"]["R_cam_from_body"], (3, 3)).T - np.eye(3)).max() > 1e-6  # the old bound refused it
    path.write_text(json.dumps(data))
    out = tmp_path / "out"
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 0
    R = np.reshape(json.loads((out / "frame.json").read_text())["R_cam_from_body"], (3, 3))
    assert np.abs(R @ R.T - np.eye(3)).max() < 1e-12 and np.linalg.det(R) > 0
    assert np.abs(R - exact).max() < 2e-4  # the pose that was rounded


def test_render_scene_warns_when_shadow_fraction_contradicts_the_earth(tmp_path, capsys):
    """Sun straight behind Earth: the scene's Earth hides all of the solar disc (ν = 0), so a
    shadow_fraction of 1 gets a one-line warning (the render keeps the file's ν); so does the
    Sun's centre on Earth's limb, which hides half of its disc (a limb ~70° across is straight
    at the Sun's 0.27°); the Sun beside Earth: ν = 1, no warning."""
    from raytrace.scenefile import load_scene_file
    d, r = 6.778e6, 6.378137e6
    b = math.asin(r / d)  # Earth's angular radius seen from the target
    cases = [((0.0, 0.0, -1.0), 0.0, True), ((math.sin(b), 0.0, -math.cos(b)), 0.5, True),
             ((1.0, 0.0, 0.0), 1.0, False)]
    for sun, nu, warns in cases:
        path = _tiny_scene(tmp_path, sun={"sun_dir_body": list(sun)},
                           earth={"earth_dir_body": [0.0, 0.0, -1.0], "earth_distance_m": d})
        assert cli.geometric_shadow_fraction(load_scene_file(path).lighting) == pytest.approx(nu, abs=0.01)
        out = tmp_path / f"out{nu}"
        assert cli.main(["render-scene", str(path), "--out", str(out)]) == 0
        info = json.loads((out / "frame.json").read_text())
        assert info["shadow_fraction"] == 1.0 and info["geometric_shadow_fraction"] == pytest.approx(nu, abs=0.01)
        err = capsys.readouterr().err
        assert ("warning: sun.shadow_fraction is 1" in err) == warns and err.count("\n") == int(warns)


def test_render_scene_warns_when_no_pixel_sees_the_target(tmp_path, capsys):
    """The camera turned away from the target (the box behind it): a valid scene, rendered, with
    a one-line warning and an empty mask; facing it: no warning."""
    from orbit.pose import look_at
    rho = np.array([2.0, -8.0, 3.0])
    R = look_at(-rho)  # looking away from the origin, which is now behind the camera
    for name, over, warns in (("away", {"camera": {"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]],
                                                   "width": 64, "height": 48, "R_cam_from_body": R.ravel().tolist(),
                                                   "t_cam_m": (-R @ rho).tolist()}}, True),
                              ("facing", {}, False)):
        out = tmp_path / name
        assert cli.main(["render-scene", str(_tiny_scene(tmp_path, **over)), "--out", str(out)]) == 0
        counts = json.loads((out / "frame.json").read_text())["pixel_counts"]
        assert (sum(counts[1:]) == 0) == warns  # index 0: the background
        err = capsys.readouterr().err
        assert ("warning: no pixel sees the target" in err) == warns and err.count("\n") == int(warns)


def test_render_scene_checks_out_before_rendering(tmp_path, capsys, monkeypatch):
    """--out that is a file fails at once, one line, exit 2, before any rendering."""
    import raytrace.shade
    monkeypatch.setattr(raytrace.shade, "render", lambda *a, **k: pytest.fail("rendered before checking --out"))
    path = _tiny_scene(tmp_path)
    (tmp_path / "taken").write_text("x")
    assert cli.main(["render-scene", str(path), "--out", str(tmp_path / "taken")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not a folder" in err and err.count("\n") == 1


def test_render_scene_overwrites_only_its_own_earlier_frame(tmp_path, capsys):
    """A folder holding a sequence, other modality files, or frame 000000's files without a frame.json is
    refused before the render and left byte for byte; a new folder, one with unrelated files only, and the
    command's own earlier output are written."""
    def snapshot(d):
        return {p.relative_to(d).as_posix(): p.read_bytes() for p in d.rglob("*") if p.is_file()}
    path = _tiny_scene(tmp_path)
    own = tmp_path / "own"
    assert cli.main(["render-scene", str(path), "--out", str(own)]) == 0
    assert cli.main(["render-scene", str(path), "--out", str(own), "--seed", "3"]) == 0  # over its own frame
    for name, make in (("sequence", lambda d: (d / "scenario.json").write_text("{}")),
                       ("other frames", lambda d: ((d / "rgb").mkdir(), (d / "rgb" / "000001.png").write_bytes(b"x"))),
                       ("no frame.json", lambda d: ((d / "mask").mkdir(), (d / "mask" / "000000.png").write_bytes(b"x")))):
        out = tmp_path / name.replace(" ", "_")
        out.mkdir()
        make(out)
        before = snapshot(out)
        capsys.readouterr()
        assert cli.main(["render-scene", str(path), "--out", str(out)]) == 2, name
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--out" in err and "render-scene did not write" in err, (name, err)
        assert snapshot(out) == before, name
    side = tmp_path / "notes"
    side.mkdir()
    (side / "README.txt").write_text("mine")
    assert cli.main(["render-scene", str(path), "--out", str(side)]) == 0
    assert (side / "README.txt").read_text() == "mine" and (side / "hdr" / "000000.exr").is_file()


def test_render_scene_warns_of_a_mesh_with_non_finite_vertices(tmp_path, capsys, nan_box_obj):
    """The scene's mesh loses the faces that touch its NaN vertex and the command says so in one line."""
    path = _tiny_scene(tmp_path)
    n_bad = nan_box_obj(tmp_path / "parts" / "bus.obj")
    scene = json.loads(path.read_text())
    scene["meshes"][0]["path"] = "parts/bus.obj"
    path.write_text(json.dumps(scene))
    assert cli.main(["render-scene", str(path), "--out", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"warning: meshes[0]: bus.obj: {n_bad} of 12 triangles touch" in err, err


def test_render_scene_file_not_utf8_or_empty_out_is_one_line(tmp_path, capsys):
    path = tmp_path / "scene.json"
    path.write_bytes(b"\xff\xfe\x00\x80")
    assert cli.main(["render-scene", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "scene file:" in err and str(path) in err and "UTF-8" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:  # an argparse error, as a command line user sees it
        cli.main(["render-scene", str(_tiny_scene(tmp_path)), "--out", ""])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --out: must name a folder" in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_render_scene_refuses_an_out_folder_that_cannot_be_made_before_rendering(tmp_path, capsys, monkeypatch):
    """/proc takes no new folders, though os.access may say it does (as root): refused in one
    line before any rendering."""
    import raytrace.shade
    monkeypatch.setattr(raytrace.shade, "render", lambda *a, **k: pytest.fail("rendered before checking --out"))
    assert cli.main(["render-scene", str(_tiny_scene(tmp_path)), "--out", "/proc/orbitsynth-out"]) == 2
    err = capsys.readouterr().err
    assert "--out: cannot create /proc/orbitsynth-out" in err and err.count("\n") == 1


def test_render_scene_moves_nothing_when_one_file_cannot_be_placed(tmp_path, capsys):
    """A file where an output folder must go (``hdr``): the render fails in one line, and none of
    the other files has been moved into --out (all or nothing)."""
    path = _tiny_scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "hdr").write_text("in the way")
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == ["hdr"]


def test_render_scene_unexpected_failure_is_one_line(tmp_path, capsys, monkeypatch):
    """Whatever fails inside the renderer: one line naming the scene, exit 1, nothing written."""
    import raytrace.shade

    def boom(*a, **k):
        raise RuntimeError("something\nunforeseen")
    monkeypatch.setattr(raytrace.shade, "render", boom)
    path = _tiny_scene(tmp_path)
    assert cli.main(["render-scene", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "RuntimeError: something unforeseen" in err and str(path) in err
    assert not (tmp_path / "out").exists()


def test_epoch_whose_sequence_runs_past_the_almanac_names_epoch():
    r = run("--pattern", "elliptical", "--frames", "2", "--epoch", "2050-12-31T23:59:00Z", "--dry-run")
    assert r.returncode == 2 and r.stdout == ""
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and "--epoch" in err and "2051-01-01" in err, err


def test_render_scene_mesh_far_from_its_origin_renders_as_if_centred(tmp_path):
    """A 1 m sphere authored 5 km from its file's origin (a CAD export in mm): the scene file is
    moved to the mesh's centre for float32 ray tracing, so the image is the one of the same
    sphere at the origin (no self-shadowing speckles), and frame.json keeps the file's pose."""
    import OpenImageIO as oiio
    import trimesh
    hdr = {}
    for off in (0.0, 5000.0):
        mesh = trimesh.creation.icosphere(4, radius=1000.0)
        mesh.vertices += [off * 1000.0, 0.0, 0.0]
        mesh.export(tmp_path / f"ball{int(off)}.obj")  # text: PLY would round 5e6 mm to float32
        path = _tiny_scene(tmp_path, meshes=[{"path": f"ball{int(off)}.obj", "unit_scale_m": 0.001, "albedo": 0.6}],
                           camera={"K": [[120.0, 0, 31.5], [0, 120.0, 23.5], [0, 0, 1]], "width": 64, "height": 48,
                                   "R_cam_from_body": np.eye(3).ravel().tolist(), "t_cam_m": [-off, 0.0, 5.0]},
                           sun={"sun_dir_body": [0.4, -0.3, -0.866]}, ambient_radiance_W_m2_sr=0.0)
        out = tmp_path / f"out{int(off)}"
        assert cli.main(["render-scene", str(path), "--out", str(out)]) == 0
        hdr[off] = oiio.ImageBuf(str(out / "hdr/000000.exr")).get_pixels(oiio.FLOAT)
        info = json.loads((out / "frame.json").read_text())
        assert info["t_cam_m"] == pytest.approx([-off, 0.0, 5.0]) and info["body_offset_m"] == pytest.approx([off, 0, 0])
    lit = hdr[0.0].sum(-1) > 0
    assert lit.sum() > 200
    assert np.allclose(hdr[5000.0], hdr[0.0], rtol=1e-3, atol=1e-3)


def test_render_scene_stars_in_the_background_only(tmp_path):
    """A catalogue star straight along the optical axis but behind the box is hidden; one
    beside the box lands in its pixel, off the mask; the scene file round-trips."""
    import OpenImageIO as oiio

    from raytrace.scenefile import load_scene_file, scene_to_dict
    path = _tiny_scene(tmp_path)
    spec = load_scene_file(path)
    R = spec.R_cam_from_body
    d_axis = R.T @ np.array([0.0, 0.0, 1.0])  # body = inertial here (identity attitude)
    d_side = R.T @ np.array([20.2 / 120.0, 3.2 / 120.0, 1.0])
    d_side /= np.linalg.norm(d_side)
    rows = ["ra_deg,dec_deg,v_mag"]
    for d in (d_axis, d_side):
        rows.append(f"{math.degrees(math.atan2(d[1], d[0])):.9f},{math.degrees(math.asin(d[2])):.9f},-3.0")
    (tmp_path / "cat.csv").write_text("\n".join(rows) + "\n")
    assert cli.main(["render-scene", str(path), "--out", str(tmp_path / "plain")]) == 0
    path = _tiny_scene(tmp_path, stars={"R_body_from_eci": np.eye(3).ravel().tolist(), "catalogue": "cat.csv"})
    out = tmp_path / "out"
    assert cli.main(["render-scene", str(path), "--out", str(out)]) == 0
    hdr = oiio.ImageBuf(str(out / "hdr/000000.exr")).get_pixels(oiio.FLOAT)
    plain = oiio.ImageBuf(str(tmp_path / "plain/hdr/000000.exr")).get_pixels(oiio.FLOAT)
    mask = oiio.ImageBuf(str(out / "mask/000000.png")).get_pixels(oiio.UINT16)[..., 0]
    changed = np.argwhere((hdr != plain).any(-1))
    assert changed.tolist() == [[27, 52]]  # (23.5 + 3.2, 31.5 + 20.2) rounded
    assert mask[27, 52] == 0 and mask[24, 32] > 0  # the axis star is behind the box
    spec = load_scene_file(path)
    again = scene_to_dict(spec.camera, spec.R_cam_from_body, spec.t_cam_m, spec.lighting, [])
    assert again["stars"]["catalogue"] == str(tmp_path / "cat.csv")


def test_a_fresh_numba_cache_is_detected_and_filled_by_the_precompile_step(tmp_path):
    """jit.kernels_not_compiled in a process whose numba cache directory is empty: every group
    a ``reference`` frame calls; after raytrace._precompile compiled the kernel standing for
    the main job's group into that directory, the preset's group only; after its own, none. In
    the serial builds, which the main job's pool workers call (and compile in half the time);
    the parallel build of a probe is another cache entry (test_threaded_kernels.py)."""
    code = ("import cli, sys; from raytrace import _precompile as P; from raytrace.dataset import jit; "
            "a = jit.kernels_not_compiled('reference', serial=True); "
            "bad = P._compile_share([(n, P.group_signatures(['fast', 'reference'])[n][1]) for n in [P.probe('fast')]], "
            "serial=True); "
            "b = jit.kernels_not_compiled('reference', serial=True); "
            "c = jit.kernels_not_compiled('reference', serial=False); "
            "bad += P._compile_share([(n, P.group_signatures(['fast', 'reference'])[n][1]) "
            "for n in [P.probe('reference')]], serial=True); "
            "print(','.join(a), bad, ','.join(b), ','.join(c), "
            "','.join(jit.kernels_not_compiled('reference', serial=True)) or '-')")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300,
                       check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["fast,reference", "[]", "reference", "fast,reference", "-"]


def test_keypoints_option_labels_and_sequence_identity(tmp_path, capsys):
    """--keypoints: the file's points land in model/keypoints.json; each frame's keypoints_px is
    OpenCV's projection with the frame's pose and camera.json's K; no point is visible or
    shadowed by the target while Earth's shadow holds the frame; other points are another
    sequence (refused), the same points resume; a bad file is one line and writes nothing."""
    import hashlib

    import cv2
    from tests.cli_helpers import run_main
    pts = [[0.5, -3.8, 0.0], [-0.4, 3.8, 0.0], [1.1, 0.6, -0.6], [0.0, 0.0, 0.97], [-2.0, -0.5, 0.4]]
    kp = tmp_path / "kp.json"
    kp.write_text(json.dumps({"names": ["tip-y", "tip+y", "st", "top", "shade"], "points_body_m": pts}))
    small = ["--target", "icesat", "--frames", "8", "--width", "96", "--height", "72", "--focal-length-mm", "0.3",
             "--modalities", "mask,depth", "--arg-lat-deg", "90", "--workers", "1", "--quiet"]
    seq = tmp_path / "seq"
    assert run_main(*small, "--keypoints", kp, "--out", seq) == 0
    doc = json.loads((seq / "model/keypoints.json").read_text())
    assert doc["names"] == ["tip-y", "tip+y", "st", "top", "shade"] and doc["points_body_m"] == pts
    assert doc["frame"] == "body" and doc["unit"] == "m" and doc["source"] == "file kp.json"
    K = np.array(json.loads((seq / "camera.json").read_text())["K"])
    labels = json.loads((seq / "labels.json").read_text())
    seen_dark = set()
    for lab in labels:
        R = np.array(lab["R_cam_from_body"]).reshape(3, 3)
        ref, _ = cv2.projectPoints(np.array(pts), cv2.Rodrigues(R)[0], np.array(lab["t_cam_m"]), K, np.zeros(5))
        np.testing.assert_allclose(np.array(lab["keypoints_px"], dtype=float), ref.reshape(-1, 2), atol=1e-6)
        assert len(lab["keypoints_state"]) == 5 and set(lab["keypoints_state"]) <= {"visible", "shadowed", "occluded",
                                                                                       "outside"}
        if lab["shadow_fraction"] < 0.5:
            seen_dark.update(lab["keypoints_state"])
    assert "visible" not in seen_dark and "shadowed" in seen_dark  # the phase ends in Earth's shadow
    digest = hashlib.sha256((seq / "model/keypoints.json").read_bytes()).hexdigest()
    assert json.loads((seq / "manifest.json").read_text())["files"]["model/keypoints.json"] == digest
    # the same points (same file) resume; other points at the same path are another sequence
    capsys.readouterr()
    assert run_main(*small, "--keypoints", kp, "--out", seq) == 0
    pts[0][0] = 0.6
    kp.write_text(json.dumps(pts))
    before = sorted(p.name for p in seq.rglob("*"))
    assert run_main(*small, "--keypoints", kp, "--out", seq) == 2
    assert "holds another sequence" in capsys.readouterr().err
    assert sorted(p.name for p in seq.rglob("*")) == before
    # a bad file: one line naming the option, nothing written
    kp.write_text("[[0, 0, NaN]]")
    assert run_main(*small, "--keypoints", kp, "--out", tmp_path / "bad") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("cli.py: error: argument --keypoints: ") and "point 0 must be" in err and "\n" not in err
    assert not (tmp_path / "bad").exists()


def test_a_config_files_keypoints_go_with_its_model(tmp_path, capsys):
    """A [sequence] keypoints file belongs to the file's model: read (as an absolute path) with it,
    dropped when a --target or --mesh flag chooses another model; the dataset command refuses it."""
    from tests.cli_helpers import run_main
    conf = tmp_path / "c.toml"
    conf.write_text('[sequence]\ntarget = "icesat"\nkeypoints = "kp.json"\n')
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--config", str(conf)]))
    assert cfg["sequence"]["keypoints"] == os.path.abspath("kp.json") and "keypoints" in given
    cfg, given = cli.resolve_config(cli.build_parser().parse_args(["--config", str(conf), "--target", "cassini"]))
    assert cfg["sequence"]["keypoints"] is None and "keypoints" not in given
    assert run_main("dataset", "--config", conf, "--frames", "2", "--out", tmp_path / "ds") == 2
    err = capsys.readouterr().err.strip()
    assert err == "cli.py: error: --config: [sequence] keypoints is not used by the dataset command (built-in targets only)"
    assert not (tmp_path / "ds").exists()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("flag", ["--dry-run", "--json"])
def test_a_plan_that_cannot_be_written_is_a_one_line_error(flag):
    """Standard output on a full disk: one line naming it, status 1, no traceback."""
    with open("/dev/full", "w") as full:
        r = subprocess.run([sys.executable, str(ROOT / "cli.py"), "--target", "cassini", flag], stdout=full,
                           stderr=subprocess.PIPE, text=True, cwd=ROOT, timeout=120, check=False)
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == ["cli.py: error: cannot write the plan to standard output "
                                             "(No space left on device)"]


def test_a_reader_that_leaves_early_is_not_an_error():
    """`cli.py --json | head -1`: the command ends with status 0 and nothing on standard error,
    its output up to where the reader left as it would be whole."""
    whole = run("--target", "cassini", "--json", "--frames", "2000")  # 3.4 MB: more than a pipe holds
    p = subprocess.Popen([sys.executable, str(ROOT / "cli.py"), "--target", "cassini", "--json", "--frames", "2000"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    first = p.stdout.readline()
    p.stdout.close()  # the reader leaves
    err = p.stderr.read()
    assert p.wait(timeout=120) == 0 and err == b""
    assert whole.returncode == 0 and first.decode() == whole.stdout.splitlines(keepends=True)[0]
