"""--distortion on the command line: the sequence folder's images are cast through the lens
(camera.json's distCoeffs), bad coefficients are one line naming the flag with nothing
written, and the BOP export refuses a distorted sequence."""

import json

import cv2
import numpy as np
import pytest

from raytrace.camera import Camera
from raytrace.export import export_bop
from raytrace.files import read_image
from raytrace.scene import Scene
from raytrace.targets import load_target
from tests.cli_helpers import run_main

DIST = [-0.25, 0.08, 0.002, -0.001, 0.0]
SMALL = ["--target", "icesat", "--pattern", "spiral", "--frames", "1", "--width", "160", "--height", "120",
         "--focal-length-mm", "1", "--workers", "1", "--quiet"]


@pytest.fixture(scope="module")
def distorted(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist") / "seq"
    assert run_main(*SMALL, "--distortion", ",".join(map(str, DIST)), "--modalities", "rgb,mask,depth",
                    "--star-limit-mag", "7", "--out", out) == 0  # (stars: their projection through the lens too)
    return out


def test_mask_and_depth_are_the_lens_camera_of_camera_json(distorted):
    cam_doc = json.loads((distorted / "camera.json").read_text())
    assert cam_doc["distCoeffs"] == DIST
    assert "distortion = [-0.25, 0.08, 0.002, -0.001, 0.0]" in (distorted / "config.toml").read_text()
    K = np.array(cam_doc["K"])
    cam = Camera(cam_doc["width"], cam_doc["height"], K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                 dist_coeffs=cam_doc["distCoeffs"])
    pin = Camera(cam_doc["width"], cam_doc["height"], K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    rec = json.loads((distorted / "labels.json").read_text())[0]
    R = np.array(rec["R_cam_from_body"]).reshape(3, 3)
    t = np.array(rec["t_cam_m"])
    mask = cv2.imread(str(distorted / rec["files"]["mask"]), cv2.IMREAD_UNCHANGED)
    scene = Scene(load_target("icesat"))
    g_lens = scene.render_geometry(cam, R, t)
    g_pin = scene.render_geometry(pin, R, t)
    assert (g_lens.instance > 0).sum() > 500
    np.testing.assert_array_equal(mask, g_lens.instance)
    depth = read_image(str(distorted / rec["files"]["depth"]))
    depth = depth[..., 0] if depth.ndim == 3 else depth
    hit = g_lens.instance > 0
    np.testing.assert_array_equal(depth[hit], g_lens.depth_m[hit])
    # the lens moved the target by a fraction of a pixel here (it sits at the image centre):
    # the pinhole's depths differ at most of its pixels
    both = hit & (g_pin.instance > 0)
    assert (depth[both] != g_pin.depth_m[both]).mean() > 0.5


@pytest.mark.parametrize("value, words", [
    ("-0.25,0.08,0.002", ["--distortion", "5 comma-separated"]),
    ("-3,0,0,0,0", ["--distortion", "fold the image"]),
])
def test_bad_distortion_is_one_line_and_writes_nothing(tmp_path, capsys, value, words):
    out = tmp_path / "seq"
    assert run_main(*SMALL, "--distortion", value, "--out", out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("cli.py: error: argument --distortion"), err
    for w in words:
        assert w in err
    assert not out.exists()


def test_bop_export_refuses_a_distorted_sequence(distorted, tmp_path):
    with pytest.raises(ValueError, match=r"^BOP has no lens distortion: camera.json distCoeffs"):
        export_bop(distorted, tmp_path / "bop")
    assert not (tmp_path / "bop").exists()
