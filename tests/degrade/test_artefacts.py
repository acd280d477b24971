"""Flight-camera artefacts (degrade.artefacts) and the signal_e / saturation outputs, each against
an answer computed here from its definition: the cos⁴ law, binomial and normal sampling bounds,
charge bookkeeping, the pinhole projection of the Sun, a third-party JPEG decoder and the
camera equation."""

import io
import itertools
import math

import numpy as np
import OpenImageIO as oiio
import pytest
from PIL import Image

from degrade.artefacts import (
    ARTEFACTS_OFF,
    ArtefactConfig,
    bloom,
    camera_maps,
    jpeg_bytes,
    jpeg_roundtrip,
    relative_illumination,
    stray_light,
)
from degrade.chain import DegradeConfig, OpticsConfig, degrade, simulate_frame
from degrade.encode import srgb_encode
from degrade.exposure import physical_exposure
from degrade.sensor import SensorConfig, demosaic
from raytrace.camera import Camera
from raytrace.dataset.camera_options import CAMERA_OPTIONS
from tests.cli_helpers import run_main

F_M, P_M = 4e-3, 3.45e-6
QUIET = SensorConfig(shot_noise=False, read_noise_e=0.0, quantise=False, demosaic=None)


def _config(sensor=QUIET, **art) -> DegradeConfig:
    base = {"vignetting": False, "prnu_sigma": 0.0, "dsnu_sigma_e": 0.0, "hot_pixel_fraction": 0.0, "blooming": False,
            "stray_light": False}
    base.update(art)
    return DegradeConfig(optics=OpticsConfig(focal_length_m=F_M, pixel_pitch_m=P_M, aperture_m=None), sensor=sensor,
                         encoding="linear", artefacts=ArtefactConfig(**base))


# --------------------------------------------------------------------------- vignetting


def test_vignetting_of_a_flat_field_is_the_cosine_fourth_law():
    h, w = 48, 64
    f_m, p_m = 1e-3, 10e-6  # a wide field, so the fall-off is large: corners at 22°
    rows, cols = np.mgrid[0:h, 0:w]
    theta = np.arctan(np.hypot(cols - (w - 1) / 2, rows - (h - 1) / 2) * p_m / f_m)
    expected = np.cos(theta) ** 4
    assert expected.min() < 0.8
    np.testing.assert_allclose(relative_illumination(h, w, focal_length_m=f_m, pixel_pitch_m=p_m), expected, rtol=1e-6)
    # through the chain: the electrons of a flat field are QE·Φ_max·level·cos⁴θ
    c = _config(vignetting=True)
    c = DegradeConfig(optics=OpticsConfig(focal_length_m=f_m, pixel_pitch_m=p_m, aperture_m=None), sensor=QUIET,
                      encoding="linear", artefacts=c.artefacts)
    out = simulate_frame(np.full((h, w), 0.5, np.float32), c, rng=0)
    np.testing.assert_allclose(out.signal_e, 0.5 * QUIET.full_well_e * expected, rtol=1e-5)
    # the mechanical term: 1 − α·ρ, α lost at the corners
    mech = relative_illumination(h, w, focal_length_m=f_m, pixel_pitch_m=p_m, mechanical=0.3)
    rho = np.hypot(cols - (w - 1) / 2, rows - (h - 1) / 2) / math.hypot((w - 1) / 2, (h - 1) / 2)
    np.testing.assert_allclose(mech, expected * (1 - 0.3 * rho), rtol=1e-6)


# --------------------------------------------------------------------------- PRNU, DSNU, hot pixels


def test_prnu_and_dsnu_maps_have_their_sigma_and_belong_to_the_camera_seed():
    shape = (120, 160)
    n = shape[0] * shape[1]
    art = ArtefactConfig(prnu_sigma=0.01, dsnu_sigma_e=3.0)
    maps = camera_maps(shape, art, 7)
    # sample std of n normal values: relative standard error 1/sqrt(2(n − 1)); 5 of them
    tol = 5 / math.sqrt(2 * (n - 1))
    assert abs(np.std(maps.gain, ddof=1) / 0.01 - 1) < tol
    assert abs(np.std(maps.offset_e, ddof=1) / 3.0 - 1) < tol
    assert abs(np.mean(maps.gain) - 1) < 5 * 0.01 / math.sqrt(n)
    again, other = camera_maps(shape, art, 7), camera_maps(shape, art, 8)
    assert np.array_equal(maps.gain, again.gain) and np.array_equal(maps.offset_e, again.offset_e)
    assert not np.array_equal(maps.gain, other.gain) and not np.array_equal(maps.offset_e, other.offset_e)
    # two frames of one camera (different frame streams, noise off): the same fixed pattern
    cfg = _config(prnu_sigma=0.01, dsnu_sigma_e=3.0)
    flat = np.full(shape, 0.4, np.float32)
    a = simulate_frame(flat, cfg, rng=1, camera_seed=7).signal_e
    b = simulate_frame(flat, cfg, rng=2, camera_seed=7).signal_e
    c = simulate_frame(flat, cfg, rng=1, camera_seed=8).signal_e
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # PRNU leaves a flat field's mean signal: mean of n gains within 5 standard errors of 1
    mean_e = 0.4 * QUIET.full_well_e
    prnu_only = simulate_frame(flat, _config(prnu_sigma=0.01), rng=1, camera_seed=7).signal_e
    assert abs(prnu_only.mean() / mean_e - 1) < 5 * 0.01 / math.sqrt(n)
    assert abs(np.std(prnu_only / mean_e, ddof=1) / 0.01 - 1) < tol


def test_hot_pixel_count_is_the_fraction_of_the_photosites_within_binomial_bounds():
    shape, fraction, mean_e_s = (200, 300), 1e-3, 2e4
    n = shape[0] * shape[1]
    maps = camera_maps(shape, ArtefactConfig(hot_pixel_fraction=fraction, hot_pixel_dark_e_per_s=mean_e_s), 3)
    hot = maps.hot_dark_e_per_s[maps.hot_dark_e_per_s > 0]
    sd = math.sqrt(n * fraction * (1 - fraction))
    assert abs(hot.size - n * fraction) < 5 * sd
    assert abs(hot.mean() / mean_e_s - 1) < 5 / math.sqrt(hot.size)  # exponential: sd = mean
    # their dark signal in the chain: D_hot·t on top of the photo-signal (noise off)
    sensor = SensorConfig(shot_noise=False, read_noise_e=0.0, quantise=False, demosaic=None, exposure_s=0.01)
    cfg = _config(sensor, hot_pixel_fraction=fraction, hot_pixel_dark_e_per_s=mean_e_s)
    out = simulate_frame(np.zeros(shape, np.float32), cfg, rng=0, camera_seed=3).signal_e
    expected = np.minimum(maps.hot_dark_e_per_s.astype(np.float64) * 0.01, sensor.full_well_e)
    np.testing.assert_allclose(out, expected, rtol=1e-6, atol=1e-3)


# --------------------------------------------------------------------------- blooming and smear


def test_blooming_conserves_charge_spills_along_the_column_and_stops_at_full_wells():
    fw = 1000.0
    e = np.zeros((40, 6))
    e[20, 2] = fw + 3.5 * fw  # 3.5 wells of excess: 1.75 up, 1.75 down
    out = bloom(e, fw)
    col = np.zeros(40)
    col[19:22] = fw  # the source and one full neighbour each way ...
    col[18] = col[22] = 0.75 * fw  # ... and the last 0.75 well of each half
    np.testing.assert_allclose(out[:, 2], col)
    assert np.count_nonzero(out[:, [0, 1, 3, 4, 5]]) == 0
    # random scene with room to spare: every column keeps its charge, no photosite above FW
    rng = np.random.default_rng(5)
    e = rng.uniform(0, 0.3 * fw, (64, 48))
    spots = rng.random(e.shape) < 0.01
    spots[:8] = spots[-8:] = False  # away from the ends, where charge would leave
    e[spots] = 3 * fw
    e[30:34, 10:14] = 4 * fw
    out = bloom(e, fw)
    assert out.max() <= fw
    np.testing.assert_allclose(out.sum(axis=0), e.sum(axis=0), rtol=1e-12)
    changed = out != e
    assert np.array_equal(changed.any(axis=0), (e > fw).any(axis=0))  # only columns with excess change
    # charge beyond the array's ends leaves it: a full column keeps H·FW
    e = np.full((10, 1), fw)
    e[0, 0] = 5 * fw
    assert np.allclose(bloom(e, fw), fw)


def test_blooming_with_an_anti_blooming_drain_spills_only_its_share():
    fw = 1000.0
    e = np.zeros((40, 3))
    e[20, 1] = fw + 3.5 * fw
    half = np.zeros(40)
    half[20] = fw
    half[19] = half[21] = 0.875 * fw  # half of 3.5 wells spills: 0.875 each way, the rest drained
    np.testing.assert_allclose(bloom(e, fw, spill=0.5)[:, 1], half)
    assert np.array_equal(bloom(e, fw, spill=0.0), np.minimum(e, fw))  # no spill: a plain clip


def test_blooming_runs_that_join_spill_their_common_excess_symmetrically():
    fw = 1000.0
    e = np.zeros((40, 1))
    e[10, 0] = e[13, 0] = fw + 4 * fw  # two runs 2 rows apart, 4 wells of excess each
    # round 1: rows 8, 9 and 14, 15 fill; the gap 11-12 gets 4 wells for 2 of room and joins
    # rows 8-15 into one run with 2 wells of excess; round 2: rows 7 and 16 fill
    expected = np.zeros(40)
    expected[7:17] = fw
    np.testing.assert_allclose(bloom(e, fw)[:, 0], expected, rtol=0, atol=1e-9)
    # many fragmented runs: conserved per column, bounded, symmetric under flipping the column
    rng = np.random.default_rng(11)
    e = rng.uniform(0, 1.05 * fw, (80, 60))  # 5 % of the photosites just over the well: runs 1-2 long
    e[rng.random(e.shape) < 0.03] = 6 * fw
    e[:10] = e[-10:] = 0.0  # room at both ends: nothing leaves
    out = bloom(e, fw)
    assert out.max() <= fw
    np.testing.assert_allclose(out.sum(axis=0), e.sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(bloom(e[::-1], fw)[::-1], out, rtol=0, atol=1e-9)


def test_smear_adds_the_fraction_of_the_column_mean():
    e = np.zeros((10, 3))
    e[2, 1] = 1000.0
    from degrade.artefacts import smear
    out = smear(e, 0.05)
    np.testing.assert_allclose(out[:, 1], e[:, 1] + 0.05 * 100.0)
    assert np.all(out[:, [0, 2]] == 0)


# --------------------------------------------------------------------------- stray light and ghost


def _sun(theta_deg: float, phi_deg: float = 30.0) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def test_stray_light_is_zero_behind_and_far_off_axis_and_rises_toward_the_field_edge():
    h, w = 60, 80
    kw = {"focal_length_m": F_M, "pixel_pitch_m": 20e-6, "aperture_m": 1e-3}
    art = ArtefactConfig(ghost_reflectance=0.0)
    assert stray_light(h, w, [0.1, 0.2, -1.0], config=art, **kw) is None  # behind the camera
    assert stray_light(h, w, _sun(61.0), config=art, **kw) is None  # beyond the 60° exclusion
    edge_deg = math.degrees(math.atan(math.hypot(w / 2, h / 2) * 20e-6 / F_M))
    angles = np.linspace(59.5, edge_deg + 0.1, 12)
    means = [stray_light(h, w, _sun(a), config=art, **kw).astype(np.float64).mean() for a in angles]
    assert all(b > a for a, b in itertools.pairwise(means)) and means[0] > 0
    np.testing.assert_allclose(means[-1], art.pst_edge * 1361.0 * (edge_deg / (edge_deg + 0.1)) ** 3, rtol=1e-6)  # float32
    glare = stray_light(h, w, _sun(50.0, 0.0), config=art, **kw)
    assert glare[:, -1].mean() > glare[:, 0].mean()  # brighter on the Sun's side (+x)


def test_ghost_is_centred_at_the_mirrored_pinhole_position_and_holds_its_power():
    h, w, p_m = 120, 160, 20e-6
    cam = Camera.from_focal(F_M, p_m, w, h)
    art = ArtefactConfig(pst_edge=0.0, ghost_radius_px=6.0, ghost_magnification=-0.5)
    sun = _sun(32.0, 20.0)
    u, v = cam.project(sun[None, :])[0]
    centre = np.array([cam.cx, cam.cy])
    expected = centre - 0.5 * (np.array([u, v]) - centre)
    assert not (0 <= u < w and 0 <= v < h)  # the Sun is outside the field, its ghost inside
    e = stray_light(h, w, sun, focal_length_m=F_M, pixel_pitch_m=p_m, aperture_m=1e-3, config=art)
    rows, cols = np.nonzero(e)
    np.testing.assert_allclose([np.average(cols, weights=e[rows, cols]), np.average(rows, weights=e[rows, cols])],
                               expected, atol=0.35)
    power = 0.005 ** 2 * 1361.0 * sun[2] * math.pi * 1e-3 ** 2 / 4
    np.testing.assert_allclose(e.astype(np.float64).sum() * p_m * p_m, power, rtol=1e-6)  # float32 irradiance


def test_glare_in_electrons_is_the_pst_times_the_solar_photons_and_follows_the_visible_sun():
    h, w, t_s, qe, lam = 48, 64, 1e-3, 0.6, 530e-9
    sensor = SensorConfig(quantum_efficiency=qe, shot_noise=False, read_noise_e=0.0, quantise=False, demosaic=None,
                          exposure_s=t_s)
    cfg = _config(sensor, stray_light=True, glare_gradient=0.0, ghost_reflectance=0.0)
    sun = _sun(45.0)
    full = simulate_frame(np.zeros((h, w), np.float32), cfg, rng=0, sun_dir_cam=sun).signal_e
    half = simulate_frame(np.zeros((h, w), np.float32), cfg, rng=0, sun_dir_cam=sun, sun_fraction=0.5).signal_e
    theta_edge = math.atan(math.hypot(w / 2, h / 2) * P_M / F_M)
    pst = 1e-4 * (theta_edge / math.radians(45.0)) ** 3
    photons = pst * 1361.0 * P_M**2 * t_s * lam / (6.62607015e-34 * 299792458.0)
    np.testing.assert_allclose(full, qe * photons, rtol=1e-5)
    np.testing.assert_allclose(half, 0.5 * qe * photons, rtol=1e-5)


# --------------------------------------------------------------------------- JPEG


def test_jpeg_decodes_with_pillow_and_loses_less_at_higher_quality():
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:48, 0:64]
    img = np.stack([(x * 4) % 256, (y * 5) % 256, (x + y) * 2 % 256], axis=-1).astype(np.float64)
    img = np.clip(img + rng.normal(0, 8, img.shape), 0, 255).astype(np.uint8)
    err = {}
    for q in (20, 95):
        decoded = np.asarray(Image.open(io.BytesIO(jpeg_bytes(img, q))).convert("RGB"))
        ours = jpeg_roundtrip(img, q)
        assert decoded.shape == img.shape and ours.shape == img.shape
        assert np.abs(decoded.astype(int) - ours).max() <= 2  # two decoders of one file
        assert not np.array_equal(ours, img)
        err[q] = np.abs(ours.astype(int) - img).mean()
    assert err[95] < err[20]


# --------------------------------------------------------------------------- signal_e and saturation


def test_signal_e_without_noise_and_artefacts_is_qe_times_the_camera_equation_photons():
    h, w, n_f, t_s, qe, fw, lam = 24, 32, 4.0, 2e-3, 0.6, 10000.0, 530e-9
    radiance = np.random.default_rng(1).uniform(0.0, 8.0, (h, w, 3)).astype(np.float32)
    signal = physical_exposure(radiance, f_number=n_f, exposure_s=t_s, pixel_pitch_m=P_M, quantum_efficiency=qe,
                               full_well_e=fw, wavelengths_m=(lam,) * 3)
    sensor = SensorConfig(quantum_efficiency=qe, full_well_e=fw, shot_noise=False, read_noise_e=0.0, quantise=False)
    cfg = DegradeConfig(optics=OpticsConfig(focal_length_m=F_M, pixel_pitch_m=P_M, aperture_m=None), sensor=sensor,
                        encoding="linear", artefacts=ARTEFACTS_OFF)
    out = simulate_frame(signal, cfg, rng=0)
    h_j_s, c_m_s = 6.62607015e-34, 299792458.0  # SI 2019, exact
    photons = math.pi * radiance.astype(np.float64) / (4 * n_f**2) * P_M**2 * t_s * lam / (h_j_s * c_m_s)
    mosaic = np.empty((h, w))
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = photons[0::2, 0::2, 0], photons[0::2, 1::2, 1]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = photons[1::2, 0::2, 1], photons[1::2, 1::2, 2]
    expected = np.minimum(qe * mosaic, fw)
    assert 0 < (expected >= fw).mean() < 0.9  # some photosites saturate
    assert out.signal_e.shape == (h, w) and out.signal_e.dtype == np.float32
    np.testing.assert_allclose(out.signal_e, expected, rtol=2e-6)
    assert np.array_equal(out.saturation, out.signal_e >= fw)


def test_artefacts_off_draw_the_same_noise_as_the_chain_without_them():
    """Below the full well the two paths are one model: same streams, same bits."""
    img = np.random.default_rng(2).uniform(0.0, 0.6, (48, 64, 3)).astype(np.float32)
    old = degrade(img, DegradeConfig(), rng=9)
    new = simulate_frame(img, DegradeConfig(artefacts=ARTEFACTS_OFF), rng=9)
    assert np.array_equal(old, new.image)


def test_option_defaults_are_the_artefact_config_defaults():
    by_key = {o.key: o.default for o in CAMERA_OPTIONS}
    d = ArtefactConfig()
    field = {"hot_pixel_dark_e_s": "hot_pixel_dark_e_per_s"}
    for key, value in by_key.items():
        if key != "camera_seed":
            assert getattr(d, field.get(key, key)) == value, key


def test_every_value_an_option_takes_the_artefact_config_takes():
    """A value the command line lets through must not fail later, in a worker, mid-sequence."""
    import argparse
    import re
    field = {"hot_pixel_dark_e_s": "hot_pixel_dark_e_per_s"}
    checked = 0
    for o in CAMERA_OPTIONS:
        if o.key == "camera_seed" or getattr(o.parse, "toml", None) not in ("a number", "an integer"):
            continue
        checked += 1
        with pytest.raises(argparse.ArgumentTypeError) as exc:
            o.parse("nan")
        lo_b, lo, hi = re.search(r"([\[(])(-?[\d.e+]+), (-?[\d.e+]+)\]", str(exc.value)).groups()
        lo, hi = float(lo), float(hi)
        values = [hi, 0.5 * (lo + hi)] + ([lo] if lo_b == "[" else [lo + 1e-9 * (hi - lo)])
        for v in values:
            v = int(v) if o.parse.toml == "an integer" else v
            parsed = o.parse(str(v))
            ArtefactConfig(**{field.get(o.key, o.key): parsed})
    assert checked == 15


def test_bad_parameters_are_one_line_value_errors():
    for kwargs, name in (({"prnu_sigma": 0.5}, "prnu_sigma"), ({"jpeg_quality": 101}, "jpeg_quality"),
                         ({"sun_exclusion_deg": 0.0}, "sun_exclusion_deg"), ({"blooming": "yes"}, "blooming")):
        with pytest.raises(ValueError, match=name) as exc:
            ArtefactConfig(**kwargs)
        assert "\n" not in str(exc.value)


# --------------------------------------------------------------------------- the main job


SMALL = ["--target", "cassini", "--pattern", "spiral", "--frames", "1", "--width", "96", "--height", "64",
         "--quiet", "--workers", "1"]


CAMERA = ["--modalities", "rgb_degraded,signal_e,saturation", "--degrade", "physical", "--exposure-us", "3000"]


@pytest.fixture(scope="module")
def base_sequence(tmp_path_factory):
    seq = tmp_path_factory.mktemp("camera") / "seq"
    assert run_main(*SMALL, *CAMERA, "--out", seq) == 0
    return seq


def test_main_job_writes_signal_e_and_saturation_consistent_with_rgb_degraded(base_sequence):
    seq = base_sequence
    sig = oiio.ImageBuf(str(seq / "signal_e" / "000000.exr")).get_pixels(oiio.FLOAT)
    sat = oiio.ImageBuf(str(seq / "saturation" / "000000.png")).get_pixels(oiio.UINT8)
    rgb = oiio.ImageBuf(str(seq / "rgb_degraded" / "000000.png")).get_pixels(oiio.UINT8)
    sig, sat = sig.reshape(64, 96), sat.reshape(64, 96)
    fw, max_dn = 10000.0, 4095
    assert set(np.unique(sat)) == {0, 255} and np.array_equal(sat == 255, sig >= fw)
    # the ADC and demosaic of these electrons give rgb_degraded exactly: saturated photosites at the top DN
    dn = np.clip(np.rint(sig.astype(np.float64) / (fw / max_dn)), 0, max_dn)
    assert np.all(dn[sat == 255] == max_dn)
    rgb_again = srgb_encode(np.clip(demosaic((dn / max_dn).astype(np.float32)), 0, 1), bits=8)
    assert np.array_equal(np.rint(rgb_again * 255).astype(np.uint8), rgb)


@pytest.mark.parametrize("extra", [["--vignetting", "false"], ["--blooming", "false"], ["--jpeg-quality", "50"],
                                   ["--camera-seed", "5"]])
def test_each_artefact_option_reaches_the_degraded_image(base_sequence, tmp_path, extra):
    import tomllib
    seq = tmp_path / "seq"
    assert run_main(*SMALL, *CAMERA, *extra, "--out", seq) == 0
    assert (seq / "rgb_degraded/000000.png").read_bytes() != (base_sequence / "rgb_degraded/000000.png").read_bytes()
    cfg = tomllib.loads((seq / "config.toml").read_text())["degrade"]
    assert str(cfg[extra[0][2:].replace("-", "_")]).lower() == extra[1]


@pytest.mark.parametrize("args, flag", [
    (["--prnu-sigma", "0.5"], "--prnu-sigma"),
    (["--jpeg-quality", "101"], "--jpeg-quality"),
    (["--sun-exclusion-deg", "0"], "--sun-exclusion-deg"),
    (["--blooming", "maybe"], "--blooming"),
    (["--modalities", "saturation", "--degrade", "paper"], "--modalities"),
    (["--modalities", "signal_e", "--degrade", "none"], "--modalities"),
])
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, args, flag):
    assert run_main(*SMALL, *args, "--out", tmp_path / "x") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"cli.py: error: argument {flag}") and not (tmp_path / "x").exists()
