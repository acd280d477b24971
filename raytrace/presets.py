"""Quality presets of :func:`raytrace.shade.render`: what each setting does, and the
measurements on the scenes of ``benchmarks/bench_time_error.py`` that chose its value.

:func:`quality_preset` returns the :class:`Quality` of ``fast``, ``balanced`` (with a sample
count: its gather rays per pixel, from which the anti-aliasing grid, the residual filter and
the ray allocation follow) or ``reference`` (samples per pixel of the path tracer). The
renderer that reads them, and what each stage does, is :mod:`raytrace.shade`.

The section *switches* at the end holds the module-level switches of the renderer, the scene's
ray casting and the radiance cache (one path or another, chunk sizes, two weights), read at call
time, so that the tests can toggle them here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["QUALITIES", "Quality", "preset_cache_options", "quality_preset"]

QUALITIES = ("fast", "balanced", "reference")


@dataclass(frozen=True, slots=True)
class Quality:
    """Settings of a quality preset (see module notes).

    Attributes
    ----------
    name : str
    gather_rays : int
        Final-gather rays per pixel (0: the cache alone) [-].
    filter_passes : int
        À-trous passes on the gathered irradiance (pass k has holes of 2^k pixels; the
        measurements below that chose the passes, σ_l and β were made when it filtered the
        gathered irradiance's difference from the cache) [-].
    filter_sigma_l : float
        Edge stopping on the gathered light itself: a neighbour's weight falls as exp(−z/σ_l), z the
        z-score of the two pixels' difference from their gathers' own variances
        (:func:`raytrace._filter.atrous`); 0: geometry only [-].
    aa_grid : int
        Edge pixels get aa_grid² stratified sub-pixel rays [-].
    spp : int
        Samples per pixel of the path tracer (``reference``) [-].
    sun_rays : int
        Shadow rays over the solar disc where a penumbra can be wider than a quarter pixel
        (1: a point Sun everywhere) [-].
    cov_grid : int
        Edge pixels whose shaded sub-samples saw more than one part (or space) also get
        cov_grid² unshaded primary rays, in a pattern of their own, that measure how much of
        the pixel each part covers (0 or 1: the shaded sub-samples alone) [-].
    borrow : bool
        An edge sub-sample off its pixel centre's surface takes the filtered gather
        correction of the nearest neighbouring centre on its own surface (3 × 3 pixels), and
        casts its own gather only where there is none; else it always casts its own.
    sun_corners : bool
        Pixels whose corners (the corner rays that find sub-pixel geometry) and centre
        disagree on the Sun's visibility are anti-aliased too: one more shadow ray per pixel
        corner finds shadow edges, and shadows of rods thinner than a pixel, that no pixel
        centre saw (12 scenes at 1280×960: ``balanced``-16 median error 3.16 → 3.12 % for
        +2 % time; ``fast`` 6.97 → 6.87 % for +5 %, not worth it there).
    slivers : bool
        Pixels where the projection of a triangle is a sliver (narrower than a pixel) in
        front of the pixel centre's surface are anti-aliased too: a wire or rod
        thinner than a pixel, which pixel centres and corners can miss along most of its
        length (12 scenes at 1280×960: ``balanced``-8 median error 3.99 → 3.96 %, -16 3.12 →
        3.08 %, for +4 % time; it matters most in sequences, where a missed wire flickers).
        On in ``fast`` too: without it a wire of 0.3 px left 4 of 140 image columns empty
        (``tests/raytrace/test_thin_wire.py``) and Tiangong's solar wings seen edge-on
        vanished from one frame of a 160×120 sequence to the next; on the 12 scenes, median
        error 5.32 → 5.30 % (no scene worse; Cassini ``earth`` 6.47 → 6.35 %) for a median
        per-scene time ratio of 1.039 (0.975–1.208, Cassini's trusses the most; 1.057 in a
        second run, after the kernel stopped allocating per triangle: the machine's noise).
    corner_rays : bool
        One more ray through every pixel corner of the cast rectangle (about one per pixel):
        a pixel whose corners see another part than its centre holds sub-pixel geometry and
        is anti-aliased (:func:`raytrace._antialias._corner_edges`). Off in ``fast``, where :attr:`slivers` finds
        the same pixels but 0–8 per frame (12 scenes at 1280×960: 0–8 pixels of the frames
        differ, the errors are the same to 0.01 %) for 12–37 ms less per frame on one core;
        ``balanced`` needs them for :attr:`sun_corners`.
    thin_shadows : bool
        Lit pixels near the shadow of a rod or wire thinner than a pixel, which pixel centres
        and corners can both miss, are anti-aliased too: a conservative shadow map of the
        triangles that are slivers seen from the Sun, looked up over each pixel's footprint
        (:func:`raytrace._antialias._thin_shadow_pixels`; needs ``sun_corners``).
    own_at_boundary : bool
        An edge sub-sample on its pixel centre's surface takes the centres' filtered light
        interpolated (:func:`raytrace._edges.interpolate_rows_into`) only where all four
        centres around it lie on that surface; nearer than a pixel to where the surface meets
        another part, folds (a crease) or ends, it casts its own final gather
        (:attr:`aa_gather_rays` rays), since the light there is extrapolated from centres
        farther from the contact: a rod lying on a module left a line along the contact too bright, the
        light's steep fall towards the contact missed (:func:`_own_at_boundary`).
    filter_linear : float
        β > 0: the residual filter returns the local-linear estimate (the weighted plane through
        the kernel's neighbours at the pixel, its slope scaled by β) instead of the weighted
        mean, which is biased where the kernel is one-sided, along part edges
        (:func:`raytrace.shade._filter_residual`); 0: the weighted mean [-].
    pilot_rays : int
        > 0: the final gather runs in two passes, ``pilot_rays`` rays at every pixel, then the
        rest of the frame's gather_rays × pixels rays (a ray that hits counted as several that
        escape) shared out by the noise the first pass measured among each pixel's neighbours
        on the same part, weighted by how much of a pixel's noise the residual filter keeps
        (more along a part's border, where it has fewer neighbours to average with;
        :func:`raytrace.shade._gather_two_pass`); 0: gather_rays rays at every pixel [-].
    aa_extra : float
        Fraction of the anti-aliased pixels that get a second, independent aa_grid² pattern
        of shaded sub-samples (and coverage rays), their radiance the mean of both: those
        whose first pattern saw the largest contrast (the range of its sub-samples' R + G + B,
        :func:`raytrace._rows.subsample_contrast`) — a truss, a silhouette against a bright
        part, a penumbra, where the sub-samples' noise sits (:func:`_balanced_aa_extra`) [-].
    box_grid : int
        ≥ 2: every target pixel that is not anti-aliased gets box_grid² stratified sub-pixel
        rays too (:func:`raytrace._antialias._supersample`), shaded like the edge sub-samples on
        their pixel centre's surface (exact Sun with a solar-disc sample each, the cache, the
        centres' filtered light interpolated; a gather of its own only where a
        sub-sample lands on another surface than its centre's, which the anti-aliasing's tests
        leave rare), and takes their mean: the pixel's area mean, which a camera's pixel and the reference's box filter
        integrate, instead of its centre's value (0: the centre's). They differ where the
        radiance curves within a pixel: the outer rim of a penumbra, the sky and Earth light
        falling off towards a contact, a rim seen at a grazing angle (:func:`_box_grid`).
    aa_gather_rays : int
        Rays of the final gather an edge sub-sample casts of its own (off its pixel centre's
        surface, or near that surface's boundary with :attr:`own_at_boundary`;
        :func:`_balanced_aa_gather`); below ``raytrace._antialias._MIN_SUB_GATHER`` none, the cache
        alone [-].
    cache_divisions : int
        > 0: the radiance cache's lattice spacing is the target's bounding-box diagonal divided
        by this (:func:`preset_cache_options`); 0: the cache's default, 1/60 of it
        (:class:`raytrace.cache.RadianceCache`; ``balanced`` from 12 rays: :func:`_cache_divisions`) [-].
    """

    name: str
    gather_rays: int = 0
    filter_passes: int = 0
    aa_grid: int = 2
    spp: int = 0
    sun_rays: int = 1
    cov_grid: int = 0
    borrow: bool = False
    sun_corners: bool = False
    corner_rays: bool = True
    slivers: bool = False
    filter_sigma_l: float = 0.0
    thin_shadows: bool = False
    filter_linear: float = 0.0
    own_at_boundary: bool = False
    pilot_rays: int = 0
    aa_extra: float = 0.0
    cache_divisions: int = 0
    aa_gather_rays: int = 0
    box_grid: int = 0


# coverage grids of edge pixels (Quality.cov_grid), chosen on the scenes of
# benchmarks/bench_time_error.py at 640×480: on Tiangong's and Cassini's six, coverage 6² cut
# ``fast``'s median error 9.2 → 8.1 % for +20 ms per frame, and 8² ``balanced``-8's error on
# Tiangong ``sunlit`` 7.3 → 5.4 %. With multi-jittered sub-pixel
# samples (subpixel_rays) ``fast`` needs fewer coverage rays: on the 12 scenes at 1280×960,
# 4² instead of 6² took the median error 6.29 → 6.38 % (5²: 6.32 %) for 0.91× the time (two
# runs of all 12 scenes, the settings alternated per scene, min of 5: median ratios 0.908 and
# 1/1.09; ``fast``'s error is the cache's bias, edge noise² 77 → 87 of 700 ×10⁻⁴ summed).
# 3² (as many as the shaded sub-samples, in their own pattern) then took it 6.39 → 6.46 % for
# ~0.94× the time, and ``balanced``, whose edge error is the shaded sub-samples' noise, not the
# coverage's, needs no more coverage rays than shaded ones below 32 gather rays
# (_balanced_cov)
COV_FAST = 3
COV_BAL = 8


def _balanced_aa(samples: int) -> int:
    """Side of the shaded sub-pixel grid at ``balanced`` edge pixels for N gather rays. Their
    noise is most of ``balanced``'s error at low N, and it falls with more shaded sub-samples,
    not with more coverage rays or longer sub-sample gathers (640×480, Tiangong and Cassini,
    N = 16: 8×8 instead of 4×4 shaded took Cassini ``earth`` 6.1 → 3.6 %; 16×16 coverage
    instead of 8×8, 6.1 → 6.1 %; 4× the sub-sample gather rays, 6.1 → 5.9 %). Chosen on the
    12 scenes at 1280×960 for the time-error trade: the grid 3/4/6/8 (N ≤ 8/32/128/more) gave
    N = 8: 0.254 s, 5.03 % and N = 16: 0.387 s, 3.73 %; 4/6/6/8 gives 0.283 s, 4.37 % and
    0.481 s, 3.23 %, below the old curve at those times; 6/8 cost more than it gained
    (N = 8: 0.353 s, 4.03 %) and so did 8×8 at N = 64 (1.04 s, 2.35 % → 1.34 s, 2.13 %).
    From N = 32, where edge sub-samples near a boundary cast their own gathers
    (:func:`_own_at_boundary`), 8×8 with gathers of N / 8 rays (:func:`_balanced_aa_gather`) and a
    second pattern at 20 % of the pixels (:func:`_balanced_aa_extra`) instead of 6×6, N / 4 and
    10 % (an AVX-512 machine; ``benchmarks/bench_bias_noise.py``, median error and time, each
    setting in its own run): N = 32 1.39 % in 0.607 s → 1.23 % in 0.733 s,
    N = 64 1.22 % in 0.941 s → 1.02 % in 1.031 s, N = 256 0.89 % in 4.09 s → 0.86 % in 3.02 s:
    below the curve of more gather rays (error ∝ t^−0.2 from 32 to 256 rays). At N = 64, step by
    step: 8×8 with N / 8-ray gathers 1.08 % in 0.951 s; with N / 16 rays 1.16 % in 0.801 s; 6×6
    with N / 8 rays 1.28 % in 0.710 s, 5×5 with N / 4 rays 1.42 % in 0.762 s, 7×7 with N / 8
    1.17 % in 0.836 s, 9×9 with N / 16 1.09 % in 0.970 s; the edge pixels' noise is the
    sub-samples' count more than their gathers'. At N = 12, 7×7 instead of 6×6 gave 1.89 % in 0.315 s against
    1.95 % in 0.279 s, above the curve there (t^−0.73)."""
    return 4 if samples <= 8 else (6 if samples < 32 else 8)


def _balanced_aa_gather(samples: int) -> int:
    """Rays of an edge sub-sample's own final gather (:attr:`Quality.aa_gather_rays`) for N
    gather rays per pixel: N / 4 (at least 2; below _MIN_SUB_GATHER the sub-sample takes the
    cache alone) below N = 32, N / 8 from N = 32, where the 8×8 grid (:func:`_balanced_aa`) has
    1.8× the sub-samples of 6×6 and most sub-samples near a part's boundary gather their own
    (:func:`_own_at_boundary`): the measurements are :func:`_balanced_aa`'s. The gathers of a
    pixel's sub-samples are consecutive blocks of one Owen-scrambled Sobol sequence of the
    pixel (:func:`raytrace._gather.gather_start`), so together they are one stratified set
    (a net of 64 × 8 rays at N = 64) rather than 64 independent ones (the 12 scenes at
    1280×960, the same rays: N = 32 1.23 → 1.19 %, N = 64 1.02 → 1.00 %; there, 8×8 sub-samples
    with N / 16 rays gave 1.06 % and 10×10 with N / 16 0.97 % for 1.04× the time, better on the
    sunlit and Earth-lit views and worse on the backlit ones, and not kept)."""
    return max(2, samples // 4) if samples < 32 else samples // 8


def _balanced_cov(samples: int) -> int:
    """Coverage grid (:attr:`Quality.cov_grid`) of ``balanced`` with N gather rays: the shaded
    grid's side (_balanced_aa) for N ≤ 16, else the larger of COV_BAL and that side + 2.
    Measured on the 12 scenes of ``benchmarks/bench_time_error.py`` at 1280×960 (median error of
    one render, bias and noise estimated without the reference's noise; time: min of 2, one
    run): N = 8 (4² shaded) coverage 8² 3.26 %, 0.329 s; 6² 3.29 %, 0.295 s; 4² 3.35 %, 0.275 s;
    N = 16 (6² shaded) 8² 2.27 %, 0.481 s; 6² 2.30 %, 0.438 s; 4² 2.35 %, 0.430 s; none 2.38 %,
    0.406 s. Along the curve of more gather rays the error falls as t^−0.6 to t^−0.95 (8 → 16
    rays, in the side-by-side runs and in these), so each of these steps down (error ~t^−0.15)
    buys more time than its error would cost there. At N = 64, 6² took the error
    1.52 → 1.56 % for a few % of the time, and stays at 8². With the 8×8 shaded grid from N = 32
    (:func:`_balanced_aa`) it is 10²: at N = 64 (N / 8-ray sub-sample gathers, 10 % second
    patterns) 1.08 % in 0.951 s with 8², 1.06 % in 0.957 s with 10²."""
    aa = _balanced_aa(samples)
    return aa if samples <= 16 else max(COV_BAL, aa + 2)


def _balanced_aa_extra(samples: int) -> float:
    """:attr:`Quality.aa_extra` of ``balanced`` with N gather rays: 10 % of the anti-aliased
    pixels, at every N. Most of ``balanced``'s edge noise sits in few of them (a truss, a
    penumbra, a crevice): in 16-ray frames of Cassini ``sunlit``, Tiangong ``earth`` and ICESat
    ``earth`` the noisiest 10 % hold 51–55 % of the frame's noise². The pixels are picked by
    the contrast their first pattern saw (:func:`raytrace._rows.subsample_contrast`): the
    top 10 % by contrast hold 36–41 % of the noise², the top 10 % by the half-split estimate
    (the two checkerboard halves' means apart, an unbiased but one-degree-of-freedom estimate
    of the pixel mean's variance) 23–30 % (20 %: 53–61 % against 32–50 %).
    Measured on the 12 scenes of ``benchmarks/bench_time_error.py`` at 1280×960 (median
    error of one render, bias and noise estimated without the reference's noise; time: min of
    2 per scene, median ratio over the scenes, one run): against none, with the half-split
    estimate, N = 8 3.07 → 2.89 % for 1.02× the time, N = 16 2.04 → 1.96 % for 1.08×, N = 64
    1.42 → 1.35 % for 1.11×, every scene's error lower at every N; picked by contrast instead,
    2.89 → 2.85 %, 1.96 → 1.95 %, 1.35 → 1.33 % at the same time (summed edge noise² 88.6 →
    85.4, 40.7 → 39.7, 13.8 → 12.9 ×10⁻⁴). 20 % of the pixels instead of 10 % (N = 8: 2.78 %,
    N = 16: 1.91 %, 1.10× the time) is on the curve of more gather rays, not below it
    (t^−0.73 between 8 and 16 rays in the side-by-side Cycles run, BENCHMARKS.md). There,
    against none: 1.06 / 1.07 / 1.10 / 1.10× the time for 0.961 / 0.971 / 0.938 / 0.944× the
    error at 8 / 16 / 64 / 256 rays (half-split) — on the curve at 8 and 16 rays, below it at
    64 and 256 (t^−0.2 there); and the pixels that flicker most in a sequence get half the
    noise variance. From N = 32, with the 8×8 grid (:func:`_balanced_aa`), 20 %: at N = 64 with
    N / 8-ray sub-sample gathers, 10 % gave 1.08 % in 0.951 s, none 1.15 % in 0.919 s, 20 %
    1.03 % in 1.006 s (an AVX-512 machine, each in its own run of
    ``benchmarks/bench_bias_noise.py``). Tried there and not kept: the extra patterns shared out by
    contrast (k patterns at a pixel ∝ its sub-samples' range, up to 4 or 8, as many in all as
    10 %), 1.08 % in 0.97 s — the contrast ranks the noisiest pixels but does not measure their
    noise."""
    return 0.1 if samples < 32 else 0.2


def _filter_passes(samples: int) -> int:
    """À-trous passes on the gathered residual of ``balanced`` with N rays: 3 (N ≤ 4), 2
    (N ≤ 16), 1. Chosen with the residual-guided filter (σ_l = FILTER_SIGMA_L) on the 12 scenes
    of ``benchmarks/bench_time_error.py`` at 1280×960 (median error, bias and noise estimated
    without the reference's noise): N = 8: 3 passes 3.71 %, 2 3.70 %; N = 16: 2 passes 2.74 %, 1
    2.81 %; N = 32: 2 passes 2.34 %, 1 2.23 %; N = 64: 2 passes 2.07 %, 1 1.95 %; N = 256: 2
    passes 1.55 %, 1 1.44 %. With the
    geometry-only filter the best were N = 8: 2 passes 3.85 %, N = 16: 1 pass 2.82 %, N = 64:
    1 pass 2.14 %, N = 256: 0 passes 1.71 % (a pass removed noise but blurred the residual's
    real steps: at N = 64 the unfiltered bias was 0.6 % on Cassini ``sunlit``, 1.1 % filtered)."""
    return 3 if samples <= 4 else (2 if samples <= 16 else 1)


# σ_l of the residual-guided filter (Quality.filter_sigma_l): on the 12 scenes at 1280×960,
# ``balanced``-64 median error 2.14 % geometry-only, 1.95 % with σ_l = 3, 1.95 % with 4, 1.97 %
# with 6 (SVGF uses 4 on a one-sided score, √v of the centre only; that darkened the image,
# interior means up to 0.5 % low at N = 16, and was worse at N = 16: 2.89 % against 2.81 %)
FILTER_SIGMA_L = 4.0


def _filter_sigma_l(samples: int) -> float:
    """σ_l of the residual-guided filter for N gather rays (:attr:`Quality.filter_sigma_l`):
    FILTER_SIGMA_L from 8 rays up, but 3 for 8 < N ≤ 16 (where the filter is local-linear,
    :func:`_filter_linear`; at 8 rays, local-linear too, 3 left Tiangong, ICESat and Cassini
    ``backlit`` 2–3 % noisier than 4 did, the other six of those nine scenes within ±0.02 %);
    below, a pixel's own variance from N terms is too rough a
    guide (N = 4, 3 passes, median error on the 12 scenes: 4.29 % geometry-only, 4.36 %
    guided; with one ray there is no variance at all), so the filter is geometry-only."""
    if samples < 8:
        return 0.0
    return 3.0 if _filter_linear(samples) > 0.0 and samples > 8 else FILTER_SIGMA_L


def _filter_linear(samples: int) -> float:
    """β of the local-linear residual filter for N gather rays (:attr:`Quality.filter_linear`):
    0.7 for 8 ≤ N ≤ 16 (two passes; σ_l = 4 at 8 rays, 3 above), else 0 (the weighted mean).
    At 8 rays it came in with the filter-aware ray allocation of :func:`raytrace.shade._gather_two_pass`, which
    puts more rays where the plane's one-sided fit is noisy: median error 2.85 → 2.68 %, the
    part-boundary bias² of Tiangong ``sunlit`` 3.17 → 2.00 ×10⁻⁴ (noise² 2.08 → 2.06; rods
    lying on modules). Measured before that allocation, on the 12
    scenes of ``benchmarks/bench_time_error.py`` at 1280×960 (median error, bias and noise
    estimated without the reference's noise, ``benchmarks/bench_bias_noise.py``): N = 16
    2.76 → 2.54 % with a ridge of 0.1 px² (bias² over the 12 scenes −32 %, noise² +27 %;
    σ_l = 4, β = 1: 2.59 %; three passes: 2.63 %), 2.50 % with the ridge of 0.01 px² and the
    interpolated sub-sample corrections; N = 8 3.68 → 3.66 %, N = 64 (one pass) 1.94 → 1.93 %:
    there the noise the plane adds eats what it takes from the bias, and it is not used."""
    return 0.7 if 8 <= samples <= 16 else 0.0


def _borrow(samples: int) -> bool:
    """Whether ``balanced`` edge sub-samples off their centre's surface borrow a neighbour's
    filtered light (:attr:`Quality.borrow`). Measured on the 12 scenes of
    ``benchmarks/bench_time_error.py`` at 1280×960 (median error, bias estimated without the
    reference's noise): N = 8 (no sub-sample gathers, the cache alone there): 4.39 → 4.22 %;
    N = 16 (4-ray gathers): 3.20 → 3.30 % for 90–100 ms less per frame (of ~470); N = 64
    (16-ray gathers): 2.33 → 2.46 % (all with a one-bounce gather path and the earlier filter
    passes; with 4-bounce paths and one pass, N = 16: 2.74 → 2.82 %). Below 32 rays the
    corrections are filtered over several pixels anyway, so the neighbour's is about as near
    the truth as the pixel's own."""
    return samples <= 16


def _own_at_boundary(samples: int) -> bool:
    """Whether ``balanced`` with N gather rays gives edge sub-samples near their surface's
    boundary their own gather (:attr:`Quality.own_at_boundary`): from N = 32 (8-ray
    sub-sample gathers). Measured on the 12 scenes of ``benchmarks/bench_time_error.py`` at
    1280×960 (median error of one render, bias and noise estimated without the reference's
    noise, ``benchmarks/bench_bias_noise.py``; time: the two versions alternated, 2 rounds,
    min of 2): N = 64 1.75 → 1.52 % (summed edge bias² 13.0 → 4.9 ×10⁻⁴, noise unchanged)
    for 1.60× the time; N = 256 1.35 → 1.06 % for ~2.6×, a bias the gather rays of the
    interpolating version cannot remove; N = 32 (six of the scenes) 1.91 → 1.66 % for 1.54×.
    That is at least as good as more gather rays buy in the same time. At N = 16 (4-ray
    sub-sample gathers; six scenes) 2.20 → 2.00 % for 1.4× the time, no better than more
    rays, so it stays off there. 4-ray gathers at N = 64 were too noisy (1.65 %); every edge
    sub-sample gathering its own (not only those near a boundary), 1.39 % for 2.3×."""
    return samples >= 32


def _pilot_rays(samples: int) -> int:
    """Rays per pixel of the final gather's first pass (:attr:`Quality.pilot_rays`) for N gather
    rays: max(4, N / 2) from N = 8 (the rest of the frame's rays follow the noise that pass
    measured, :func:`raytrace.shade._gather_two_pass`), else 0 (one pass). Measured on the 12 scenes of
    ``benchmarks/bench_time_error.py`` at 1280×960 (median error, bias and noise without the
    reference's noise, ``benchmarks/bench_bias_noise.py``; one pass against two):
    N = 8 3.19 → 3.07 %, N = 16 2.22 → 2.04 %, N = 64 1.46 → 1.42 % (summed noise² ×10⁻⁴ at
    N = 16: edge 70.8 → 44.7, interior 35.5 → 20.2), for 1.08× / 1.05× the time at N = 8 / 16
    (median of per-scene ratios, the two alternated, min of 3). A pilot of N / 4 rays left too
    few where its neighbours had looked quiet: ICESat ``backlit`` at N = 16 2.68 % (one pass)
    → 3.20 % (N / 4) against 2.49 % (N / 2); Tiangong ``backlit`` 7.43 → 6.53 / 6.14 %."""
    return max(4, samples // 2) if samples >= 8 else 0


def _cache_divisions(samples: int) -> int:
    """:attr:`Quality.cache_divisions` of ``balanced`` with N gather rays: 90 from N = 12 (a
    lattice 1.5× as fine as the default's), else 0 (the default, 1/60 of the diagonal; ``fast``
    keeps it too, whose frame waits on the cache's solve). Measured on the 12 scenes of
    ``benchmarks/bench_time_error.py`` at 1280×960 (``benchmarks/bench_bias_noise.py``, median
    error; time: ``benchmarks/bench_interleaved.py``, median of the per-scene ratios; the cache
    solved on its side thread while the frame casts what needs no cache), 1/60 → 1/90 → 1/120:
    N = 16 1.94 → 1.81 → 1.73 % for 1.043× / 1.071× the time; N = 8 2.68 → 2.57 → 2.49 % for
    1.054× / 1.093×. Along the curve of more rays (error ∝ t^−0.73) the 16-ray steps would cost
    1.10× / 1.17×, so both are below it there; at 8 rays they are on it. The one-off build of the
    four targets' caches takes 1.6–2.2× as long at 1/90 (1/120: 2.0–3.3×; 1.5–4.7 s and
    2.8–6.5 s against 1.0–2.2 s, each after a first build had compiled the kernels), so the
    default ``balanced``-8 (``render-scene``'s) keeps the default lattice (BENCHMARKS.md, "A finer
    radiance cache for `balanced`"). At N = 12 (an AVX-512 machine, 2026-12-04):
    2.11 → 1.95 % (ten scenes lower, ICESat ``sunlit`` and ``backlit`` +0.01 / +0.04 %) for
    1.053× the time (0.996–1.082 by scene), where the curve from 12 to 16 rays (2.09 → 1.84 % for
    0.292 → 0.348 s, t^−0.73) would ask 1.12× for that error: below it, and 12 rays then reach
    2 % (BENCHMARKS.md, "Twelve rays")."""
    return 90 if samples >= 12 else 0


def _box_grid(samples: int) -> int:
    """Side of the sub-pixel grid of ``balanced``'s pixels that are not anti-aliased
    (:attr:`Quality.box_grid`) for N gather rays: 3 from N = 32, else 0 (each pixel its centre).

    The reference path tracer, like a camera, averages each pixel's area; a pixel shaded at its
    centre differs where the radiance curves within it. At N = 64, much of the median scenes'
    interior bias² sat one pixel inside the edges: on Tiangong ``earth`` (×10⁻⁴) 0.19 of 0.37 at
    1–2 px from an edge, 0.08 at 2–3 px, 0.002 beyond 10 px (0.14 of 0.21 even unfiltered,
    so not the residual filter's). Measured on the 12 scenes of ``benchmarks/bench_time_error.py``
    at 1280×960 (``benchmarks/bench_bias_noise.py``, median error; time: the settings alternated
    per scene, fastest of 3, median of the per-scene ratios):

    * N = 64: 1.00 → 0.95 % (all 12 scenes lower: ICESat ``sunlit`` 0.49 → 0.48 % …
      Tiangong ``backlit`` 3.17 → 2.82 %, ICESat ``earth`` 0.99 → 0.84 %; interior noise falls
      too) for 1.052× the time; only the pixels 1 px from the anti-aliased ones: 0.97 % for
      1.017×, within 2 px: 0.96 % for 1.037×; along the curve of more gather rays (error ∝
      t^−0.48 from 32 to 64 rays) 1.052× buys 0.976×.
    * N = 32: 1.19 → 1.10 % for 1.085× (2 × 2: 1.14 %).
    * N = 16 / 12 / 8: 1.82 → 1.77 %, 1.95 → 1.89 %, 2.68 → 2.63 %; at 12 rays for 1.20× the
      time (2 × 2: 1.92 % for 1.10×), where the curve (t^−0.73) buys 0.88× the error: not there.
    * With the sub-samples' own gathers near a boundary, as the edge pixels have them: noisier
      (N = 64, 3 × 3 on the 1 px ring: 0.98 % against 0.97 % without).

    Not the residual: box-averaging only the filtered correction's bilinear interpolant (weights
    1/8, 3/4, 1/8 per axis) raised Tiangong ``earth``'s interior bias² 0.37 → 0.48, and adding
    ΔL/24 of the pixel centres' radiance (the area mean of a quadratic) took it to 0.35 only
    (with 3 × 3: 0.25): what curves is below the centres' spacing — a penumbra's rim, the light
    falling off into a contact."""
    return 3 if samples >= 32 else 0


def preset_cache_options(q: Quality, scale_m: float, options: dict | None = None) -> dict:
    """The options of the radiance cache a frame of preset ``q`` uses, for a target whose
    bounding-box diagonal is ``scale_m`` [m]: ``options`` (the caller's, which win), with the
    preset's lattice spacing where it sets one (:attr:`Quality.cache_divisions`)."""
    out = dict(options or {})
    if q.cache_divisions > 0 and "spacing_m" not in out:
        out["spacing_m"] = float(scale_m) / q.cache_divisions
    return out


_PRESETS = {
    "fast": Quality("fast", gather_rays=0, filter_passes=0, aa_grid=3, sun_rays=4, cov_grid=COV_FAST, slivers=True,
                    corner_rays=False),
    "balanced": Quality("balanced", gather_rays=8, filter_passes=_filter_passes(8), aa_grid=_balanced_aa(8),
                        sun_rays=16, cov_grid=_balanced_cov(8), borrow=_borrow(8), sun_corners=True,
                        slivers=True, filter_sigma_l=_filter_sigma_l(8), thin_shadows=True,
                        filter_linear=_filter_linear(8), pilot_rays=_pilot_rays(8),
                        aa_extra=_balanced_aa_extra(8), aa_gather_rays=_balanced_aa_gather(8)),
    "reference": Quality("reference", spp=1024),
}


def quality_preset(name: str, samples: int | None = None) -> Quality:
    """The preset ``name`` (one of :data:`QUALITIES`); ``samples`` overrides its main sample
    count: gather rays per pixel for ``balanced`` (fewer filter passes as it grows), samples
    per pixel for ``reference``, sub-pixel grid side for ``fast``."""
    if name not in _PRESETS:
        raise ValueError(f"quality must be one of {', '.join(QUALITIES)}; got {name!r}")
    q = _PRESETS[name]
    if samples is None:
        return q
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or not 1 <= samples <= 1 << 20:
        raise ValueError(f"samples must be an integer in [1, 1048576], got {samples!r}")
    samples = int(samples)
    if name == "balanced":
        passes = _filter_passes(samples)
        aa = _balanced_aa(samples)
        return Quality(name, gather_rays=samples, filter_passes=passes, aa_grid=aa, sun_rays=max(16, min(samples, 64)),
                       cov_grid=_balanced_cov(samples), borrow=_borrow(samples), sun_corners=True,
                       slivers=True, filter_sigma_l=_filter_sigma_l(samples), thin_shadows=True,
                       filter_linear=_filter_linear(samples), own_at_boundary=_own_at_boundary(samples),
                       pilot_rays=_pilot_rays(samples), aa_extra=_balanced_aa_extra(samples),
                       cache_divisions=_cache_divisions(samples), aa_gather_rays=_balanced_aa_gather(samples),
                       box_grid=_box_grid(samples))
    if name == "reference":
        return Quality(name, spp=samples)
    aa = max(1, min(samples, 16))
    return replace(q, aa_grid=aa, cov_grid=COV_FAST if aa <= COV_FAST else 0)


# ---- switches
# Module-level switches of the renderer and the radiance cache, in one place: most choose between
# two code paths that give the same bytes (the tests toggle them here, monkeypatch.setattr on this
# module, and compare the paths), some are sizes or weights the tests vary. The code reads them at
# call time as ``presets.NAME``; the measurements that chose them are beside the code they switch.

# shade.render: the frame's lighting context built on a side thread while the geometry pass runs
CONTEXT_ON_SIDE_THREAD = True
# _antialias._supersample: the anti-aliasing's chunks run two at a time on a side pool
AA_CHUNKS_ON_TWO_THREADS = True
# rays per chunk of the final gather and the lobe sampling, and sub-samples per anti-aliasing chunk
CHUNK_RAYS = 1 << 18
# the final gather, lobe and sub-samples' shadow rays in fused kernels calling Embree from numba
FUSED_GATHER = True
# weight of the environment control variate in the final gather (_gather.gather_sum)
GATHER_ALPHA = 1.0
# Scene.intersect / occluded through raytrace._embree's kernels where Embree 4 is loaded
DIRECT_BATCHES = True
# the rays that shade a preset's frame through Embree without its robust flag (Scene.direct_fast)
FAST_TRAVERSAL = True
# the geometry pass through _kernels.cast_and_refine (one kernel) where Embree 4 is callable
CAST_IN_ONE_KERNEL = True
# rays per chunk of the radiance cache's rays (RadianceCache._cast)
CAST_CHUNK_RAYS = 1 << 18
# RadianceCache._cast runs its chunks of rays two at a time on a side pool
CAST_CHUNKS_ON_TWO_THREADS = True
# the contact rows' W_ss and W_sb summed by each chunk of cache rays as it is cast
ASSEMBLE_CONTACT_PER_CHUNK = True
# over-relaxation ω of the cache solve's Gauss–Seidel sweeps (RadianceCache.solve; 1: none)
SOR_OMEGA = 1.2
