"""``balanced``'s diffuse indirect light at a pixel is its filtered final gather, not the
radiance cache's value there plus a filtered correction: on a Lambertian part the cache's
values at the pixels must not reach the frame. The cache is piecewise linear on a lattice of points, with kinks
the true light has not; had the filter worked on the difference (gather − cache), its blur
of the kinks would stay in the image (on the 12 benchmark scenes that was most of the
interior bias, BENCHMARKS.md "The gather filtered, not its difference from the cache").

The test gives the cache a ±50 % checker at the pixel scale (2 px period on the plates) and
asks the interior of both plates, where nothing is anti-aliased, to come out bit for bit as
without it; ``fast``, which shades with the cache alone, must show the checker (the control:
the perturbation does reach the pixels' cache values)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from raytrace import _context
from raytrace.lighting import Lighting
from raytrace.shade import render

from .test_shading import CAM, _plates, _pose

RHO = np.array([4.0, -0.3, 1.2])  # the camera, as in the form-factor test: ~2 cm per pixel on B
PERIOD_M = 0.04


def _checker_cache(monkeypatch, amplitude: float) -> None:
    """Multiply the cache's irradiance at every shaded point by 1 ± amplitude, a checker of
    PERIOD_M in the body frame's y and z (plate B lies in x = 0, plate A in z = 0)."""
    plain = _context._Context.cache_E

    def cache_E(self, s):
        E = plain(self, s)
        P = s["P"]
        c = np.sign(np.sin(2 * np.pi * P[:, 1] / PERIOD_M) * np.sin(2 * np.pi * (P[:, 2] + P[:, 0]) / PERIOD_M))
        return E * (1.0 + amplitude * c)[:, None]

    monkeypatch.setattr(_context._Context, "cache_E", cache_E)


def _frames(monkeypatch, quality, samples):
    scene = _plates(1.0, 0.1)
    R, t = _pose(RHO)
    light = Lighting(sun_dir_body=(0, 0, 1), sun_irradiance_W_m2=1000.0)  # A lit, B edge-on
    plain = render(scene, CAM, R, t, light, quality=quality, samples=samples, seed=3)
    with monkeypatch.context() as m:
        _checker_cache(m, 0.5)
        checkered = render(scene, CAM, R, t, light, quality=quality, samples=samples, seed=3)
    inst = plain.geometry.instance
    inner = binary_erosion(inst == 1, iterations=4) | binary_erosion(inst == 2, iterations=4)
    return plain.radiance[inner], checkered.radiance[inner], inner.sum()


@pytest.mark.parametrize("samples", [8, 16, 32])
def test_the_caches_values_at_the_pixels_do_not_reach_the_frame(monkeypatch, samples):
    # 8 and 16 rays: two local-linear passes, sub-samples borrowing a neighbour's; 32: one
    # pass, every interior pixel the mean of 3×3 sub-samples interpolating the centres
    plain, checkered, n = _frames(monkeypatch, "balanced", samples)
    assert n > 2000
    assert np.array_equal(plain, checkered), np.abs(plain - checkered).max()


def test_control_fast_shades_with_the_cache_and_shows_the_checker(monkeypatch):
    plain, checkered, _ = _frames(monkeypatch, "fast", None)
    # on B (dark, lit only by A's bounce) the whole indirect light is the cache's: ±50 %;
    # on A the Sun dominates and the cache's part is small, but not nothing
    rel = np.abs(checkered[:, 0] / np.maximum(plain[:, 0], 1e-12) - 1.0)
    assert np.percentile(rel, 90) > 0.2, np.percentile(rel, [10, 50, 90])
