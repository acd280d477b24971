"""Previews (raytrace.preview, ``cli.py preview``): an off-screen PNG of the requested size, and a
scene drawn from exactly the states, poses and lights the renderer uses, checked against
independent answers (the main job's labels.json, the camera's field of view, the Sun from
orbit.sun in LVLH axes, Earth straight down −x in LVLH)."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cli
from raytrace import files as F
from raytrace import preview
from raytrace.camera import Camera

ROOT = Path(__file__).resolve().parents[1]
OPTS = ["--target", "icesat", "--pattern", "drift", "--frames", "20", "--seed", "3", "--arg-lat-deg", "90"]  # some frames in shadow


def plan_for(argv: list) -> dict:
    args = cli.build_parser().parse_args(argv)
    cfg, given = cli.resolve_config(args)
    return cli.plan_sequence(cfg, given)


@pytest.fixture(scope="module")
def scene():
    plan = plan_for(OPTS + ["--attitude-ypr-deg", "90,0,0"])
    track = cli.preview_track(plan)
    pl = preview.build_plotter(track, size=(640, 400), frusta_every=3)
    yield plan, track, pl
    pl.close()


def headless_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    env["PYTHONPATH"] = str(ROOT)
    return env


def run_cli(*argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "cli.py"), *argv], capture_output=True, text=True, cwd=ROOT,
                          env=headless_env(), timeout=300, check=False)


def test_preview_command_writes_a_png_of_the_requested_size_without_a_display(tmp_path):
    out = tmp_path / "sub" / "p.png"
    r = run_cli("preview", *OPTS, "--size", "640x400", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # no VTK warnings: the EGL window is chosen up front
    assert "preview 640x400 in" in r.stdout and str(out) in r.stdout
    img = F.read_image(str(out))
    assert img.shape[:2] == (400, 640)
    rgb = img[..., :3].reshape(-1, 3)
    assert len(np.unique(rgb, axis=0)) > 100  # a drawing, not a blank window
    assert np.mean(np.all(rgb == 255, axis=1)) > 0.3  # on a white background


def test_all_patterns_are_drawn_side_by_side(tmp_path):
    out = tmp_path / "all.png"
    r = run_cli("preview", "--target", "icesat", "--all-patterns", "--frames", "12", "--size", "1200x500",
                "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert [ln.split(":")[0] for ln in r.stdout.splitlines()[:4]] == [f"icesat {p}" for p in cli.PATTERNS]
    assert F.read_image(str(out)).shape[:2] == (500, 1200)


def test_drawn_trajectory_is_the_rendered_sequence(tmp_path, monkeypatch):
    """The main job's labels.json and the preview, from the same options, hold the same states."""
    seq = tmp_path / "seq"
    small = ["--width", "32", "--height", "24", "--modalities", "mask", "--workers", "1", "--quiet"]
    assert cli.main(OPTS + small + ["--out", str(seq)]) == 0
    labels = json.loads((seq / "labels.json").read_text())
    r_rendered = np.array([f["r_lvlh"] for f in labels])

    seen = {}
    real = preview.write_preview

    def capture(tracks, path, **kw):
        seen["tracks"] = tracks
        return real(tracks, path, **kw)

    monkeypatch.setattr(preview, "write_preview", capture)
    assert cli.main(["preview", *OPTS, "--width", "32", "--height", "24", "--size", "320x200",
                     "--out", str(tmp_path / "p.png")]) == 0
    (track,) = seen["tracks"]
    pl = preview.build_plotter(track, size=(320, 200))
    try:
        drawn = np.asarray(pl.renderers[0].actors["trajectory"].mapper.dataset.points)
        np.testing.assert_array_equal(drawn, r_rendered)  # the very same floats, every frame
        flat = np.asarray(pl.renderers[1].actors["trajectory"].mapper.dataset.points)
        np.testing.assert_array_equal(flat[:, :2], r_rendered[:, :2])
        assert np.all(flat[:, 2] == 0.0)
        t = pl.renderers[0].actors["trajectory"].mapper.dataset.point_data["t [s]"]
        np.testing.assert_array_equal(t, [f["t_s"] for f in labels])
        hidden = np.asarray(pl.renderers[0].actors["not_visible"].mapper.dataset.points)
        np.testing.assert_array_equal(hidden, r_rendered[[not f["visible"] for f in labels]])
    finally:
        pl.close()


def test_frusta_start_at_the_camera_point_at_the_target_and_open_by_the_fov(scene):
    plan, _track, pl = scene
    c = plan["camera"]
    fov_x = math.radians(Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy).fov_deg[0])
    r = np.array([f["r_lvlh"] for f in plan["result"]["frames"]])
    apexes = []
    for name in ("frusta", "frusta_not_visible"):
        if name not in pl.renderers[0].actors:
            continue
        pts = np.asarray(pl.renderers[0].actors[name].mapper.dataset.points).reshape(-1, 5, 3)
        for p in pts:
            apex, corners = p[0], p[1:]
            apexes.append(apex)
            # the far rectangle is centred on the line of sight to the target (the LVLH origin)
            np.testing.assert_allclose(corners.mean(axis=0), 0.7 * apex, atol=1e-9 * np.linalg.norm(apex))
            half_width = 0.5 * np.linalg.norm(corners[1] - corners[0])  # top-left to top-right
            half = math.atan2(half_width, np.linalg.norm(corners.mean(axis=0) - apex))
            assert 2 * half == pytest.approx(fov_x, rel=1e-9)
    assert sorted(map(tuple, apexes)) == sorted(map(tuple, r[::3]))


def test_sun_earth_and_target_are_in_lvlh_axes(scene):
    plan, track, pl = scene
    from orbit.reference import ReferenceOrbit
    from orbit.sun import sun_position_eci
    res = plan["result"]
    ro = res["reference_orbit"]
    ref = ReferenceOrbit(altitude_m=ro["altitude_m"], inclination_rad=ro["inclination_rad"], raan_rad=ro["raan_rad"],
                         arg_lat_rad=ro["arg_lat_rad"], epoch_utc=ro["epoch_utc"])
    t0 = np.array([res["t_s"][0]])
    r_tgt, _ = ref.target_state_eci(t0)
    s = sun_position_eci(ref.unix_s(t0))[0] - r_tgt[0]
    sun_lvlh = ref.R_eci_from_lvlh(t0)[0].T @ (s / np.linalg.norm(s))
    np.testing.assert_allclose(track.sun_dir_lvlh, sun_lvlh, atol=1e-9)
    np.testing.assert_allclose(track.earth_dir_lvlh, [-1.0, 0.0, 0.0], atol=1e-12)  # LVLH x points away from Earth
    # yaw 90 deg about z (lvlh-fixed): body x -> LVLH y, body y -> LVLH -x, true scale kept
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    body = np.vstack([c.mesh.vertices for c in plan["model"].components])
    np.testing.assert_allclose(track.vertices_lvlh_m, body @ Rz.T, atol=1e-9)
    assert np.linalg.norm(track.vertices_lvlh_m, axis=1).max() == pytest.approx(plan["model"].bounding_radius_m)
    axes = pl.renderers[0].cube_axes_actor
    assert (axes.GetXTitle(), axes.GetYTitle(), axes.GetZTitle()) == preview.AXIS_TITLES
    assert "icesat drift" in pl.renderers[0].actors["title"].GetText(2)
    for name in ("target", "start", "end", "sun", "earth"):
        assert name in pl.renderers[0].actors


def test_frustum_lines_of_a_known_camera():
    # camera at (0, 0, -10) looking along +z (identity axes), 4x2 px, fx = fy = 2 px, centred
    K = np.array([[2.0, 0.0, 1.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])
    pts, seg = preview.frustum_lines([0, 0, -10], np.eye(3), K, 4, 2, 4.0)
    np.testing.assert_allclose(pts, [[0, 0, -10], [-4, -2, -6], [4, -2, -6], [4, 2, -6], [-4, 2, -6]])
    assert seg.shape == (8, 2) and set(seg.ravel()) == set(range(5))
    with pytest.raises(ValueError, match="depth_m"):
        preview.frustum_lines([0, 0, -10], np.eye(3), K, 4, 2, 0.0)


def test_track_validation_names_the_parameter(scene):
    _, track, _ = scene
    good = {f: getattr(track, f) for f in track.__slots__}
    for field, bad, text in (("r_lvlh_m", np.zeros((3, 2)), "r_lvlh_m must have shape (n, 3)"),
                             ("t_s", track.t_s[::-1], "t_s must be non-decreasing"),
                             ("R_lvlh_from_cam", 2 * track.R_lvlh_from_cam, "R_lvlh_from_cam must hold rotation"),
                             ("sun_dir_lvlh", [1.0, 1.0, 0.0], "sun_dir_lvlh must be a unit vector"),
                             ("faces", track.faces + len(track.vertices_lvlh_m), "faces must index"),
                             ("width", 0, "width must be an integer >= 1")):
        with pytest.raises(ValueError, match=text.replace("(", r"\(").replace(")", r"\)")):
            preview.PreviewTrack(**{**good, field: bad})
    with pytest.raises(ValueError, match="size must be"):
        preview.build_plotter(track, size=(10, 10))
    with pytest.raises(ValueError, match="frusta_every"):
        preview.build_plotter(track, frusta_every=0)


@pytest.mark.parametrize("argv, text", [
    (["--interactive"], "argument --interactive: no display"),
    (["--size", "12x5"], "argument --size: must be WIDTHxHEIGHT"),
    (["--all-patterns", "--amplitude-m", "20", "--kappa", "0.1"], "argument --all-patterns"),
    (["--target", "hubble"], "argument --target: must be one of"),
])
def test_preview_errors_are_one_line_and_write_nothing(tmp_path, capsys, monkeypatch, argv, text):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "p.png"
    try:
        code = cli.main(["preview", *argv, "--out", str(out)])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and text in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("name, text", [("afolder", "--out: {} is a folder"), ("noext", "--out must be a .png file name"),
                                        ("p.PNG", "--out must be a .png file name")])
def test_preview_out_is_a_png_file_name(tmp_path, capsys, name, text):
    """--out naming a folder or a file without .png had the PNG written beside it as NAME.png (and reported
    the path given); both are refused, one line, nothing written."""
    (tmp_path / "afolder").mkdir()
    out = tmp_path / name
    assert cli.main(["preview", "--frames", "4", "--size", "320x200", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert text.format(out) in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afolder"] and not any((tmp_path / "afolder").iterdir())


def test_html_needs_the_exporter(tmp_path, capsys):
    if preview.html_export_available():
        assert cli.main(["preview", *OPTS, "--size", "320x200", "--out", str(tmp_path / "p.png"),
                         "--html", str(tmp_path / "p.html")]) == 0
        assert (tmp_path / "p.html").stat().st_size > 0
    else:
        assert cli.main(["preview", *OPTS, "--out", str(tmp_path / "p.png"), "--html", str(tmp_path / "p.html")]) == 2
        assert "pip install trame-pyvista nest_asyncio2" in capsys.readouterr().err
        assert not (tmp_path / "p.png").exists()


def test_default_frusta_stride():
    assert preview.default_frusta_every(48) == 4
    assert preview.default_frusta_every(1) == 1
    with pytest.raises(ValueError, match="n_frames"):
        preview.default_frusta_every(0)


def test_preview_module_does_not_import_orbit():
    code = ("import sys; import raytrace.preview; "
            "assert not any(m == 'orbit' or m.startswith('orbit.') for m in sys.modules), 'orbit imported'")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, env=headless_env(), timeout=60)


def test_start_and_end_markers_have_the_colour_bar_s_colours_at_their_times(scene):
    """The legend's start and end markers agree with the trajectory's colour bar: each has the
    colour the bar's lookup table gives the first and the last frame's time."""
    _plan, track, pl = scene
    for ren in pl.renderers:
        actors = ren.actors
        if "trajectory" not in actors:
            continue
        lut = actors["trajectory"].mapper.lookup_table
        for name, t in (("start", track.t_s[0]), ("end", track.t_s[-1])):
            want = np.array(lut.map_value(float(t))[:3])
            got = np.array(actors[name].prop.color.float_rgb)
            np.testing.assert_allclose(got, want, atol=1.5 / 255, err_msg=name)
