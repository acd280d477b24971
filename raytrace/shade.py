"""Shading: linear radiance images of a target lit by the Sun, Earth and an ambient sky.

:func:`render` returns a :class:`RenderFrame`: the geometric AOVs of the geometry pass (exact,
per pixel centre) and a linear float32 radiance image [W/(m²·sr)] at three qualities:

``fast``
    Direct sunlight with one shadow ray per lit pixel towards the Sun's centre, and where a
    penumbra can be wider than a quarter pixel (a distant occluder: the shadow of a thin
    mast 20 m away has no umbra at all) the visible fraction of the 0.53° solar disc from 4
    stratified shadow rays (16–64 for ``balanced``); the Sun's specular
    highlight exact; sky, Earth and inter-reflected light from the body-space radiance cache
    (:mod:`raytrace.cache`), interpolated at the pixel's surface point; the specular
    reflection of the environment prefiltered by the part's GGX lobe (the split-sum
    approximation, :func:`raytrace.environment.glossy_table`), corrected by what the parts add
    or hide, and of the other parts along the mirror direction (one ray), weighted by the
    lobe's directional albedo (:func:`raytrace._surface.add_mirror`); anti-aliasing with 3×3
    correlated multi-jittered sub-pixel rays (an unbiased box filter; Kensler 2013) only where
    neighbouring pixels disagree (silhouette, part, shadow and crease edges) or that a wire
    thinner than a pixel crosses (:attr:`Quality.slivers`); where those sub-samples see more than one
    part (or space), 3×3 more primary rays, unshaded, measure how much of the pixel each part
    covers, and the shaded sub-samples give each part's radiance (coverage and shading
    estimated apart, as multisample anti-aliasing does).
``balanced``
    As ``fast``, but the diffuse indirect light at each pixel is a final gather: N
    cosine-weighted rays from the pixel's own surface point (exact occlusion; Earth and sky
    enter as a control variate, their unoccluded irradiance on the point's plane minus the
    environment along each blocked ray, so escaping rays add no noise; where a ray hits
    another part, that part's sunlight is exact (a shadow ray) and its own indirect light a
    traced path (one cosine ray per bounce, exact Sun where each lands, up to 4 bounces where
    they stay within 2 cache lattice spacings — a gap —, the cache beyond)). The gathered
    irradiance is filtered by an edge-avoiding à-trous filter guided by the exact id, normal
    and depth AOVs and by the gathers' own noise (a step between two pixels larger than their
    gathers' spread — a contact shadow, a gap — is kept), so the filter removes noise, not
    detail; the cache's value at the pixel is not used for it (filtering the difference gather −
    cache instead would pass the kinks of the cache's piecewise-linear lattice into the
    frame). Glossy parts also sample their GGX lobe with N rays, minus the
    radiance their cheap mirror term reflects (a control variate of known mean, the split-sum
    albedo), filtered with the same weights. Gather and lobe directions are correlated
    multi-jittered per pixel. Edge pixels get 4×4 (N ≤ 8), 6×6 (N < 32) or 8×8 multi-jittered
    shaded sub-pixel rays, plus 8×8 to 10×10 coverage rays where they are mixed (and pixels
    whose corners disagree with the centre on the Sun's visibility, or that a sliver of a
    triangle — a wire thinner than a pixel — crosses in front of the centre's surface, are edge
    pixels too); a sub-sample on its pixel centre's
    surface is shaded like ``fast`` but with the filtered gathered irradiance of the pixel
    centres around it on that surface, interpolated bilinearly at its position, in place of
    the cache's (and their filtered lobe corrections); one on another surface takes the
    filtered irradiance of the nearest neighbouring centre on its surface (N ≤ 16) or gets its own
    N/4-ray gather (N > 16, or no such neighbour and N = 16; below that the cache alone,
    which is less noisy; N/8 rays from N = 32, where sub-samples near their surface's boundary
    gather their own too and the 8×8 grid has more of them). From N = 12 the cache's lattice
    is 1.5× as fine as ``fast``'s (:func:`raytrace.presets.preset_cache_options`; the scene
    keeps both caches).
``reference``
    Unbiased path tracing (:mod:`raytrace.pathtrace`): every sample jittered over the pixel
    (box filter), the solar disc sampled for soft shadows, BRDF-sampled bounces with Russian
    roulette. It converges to the full solution and is the yardstick for the other two.

Depth, normals and ids are never supersampled: they stay exact at the pixel centre. Each
preset's settings, and the measurements that chose them, are in :mod:`raytrace.presets`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from . import _antialias, _background, _filter, _gather, _light_parts, _rows, presets
from ._context import _Context, _Sunlight, _surfaces
from ._kernels import centre_rays
from ._sampling import AA_SECOND_STREAM, BOX_STREAM, SECOND_PASS_STREAM
from ._threads import submit as _submit
from .camera import Camera
from .lighting import Lighting
from .presets import QUALITIES, Quality, preset_cache_options, quality_preset
from .scene import GeometryFrame, Scene, _check_pose

__all__ = ["QUALITIES", "Quality", "RenderFrame", "quality_preset", "render"]


# the local-linear residual filter (_filter_residual): coordinates in units of 8 pixels, and a
# ridge of 0.01 px² on the plane's covariance
_LL_UNIT = 8.0
_LL_RIDGE_PX2 = 0.01


@dataclass(frozen=True, slots=True, eq=False)
class RenderFrame:
    """One rendered frame.

    Attributes
    ----------
    geometry : GeometryFrame
        Exact per-pixel-centre AOVs (depth, normals, ids, mask).
    radiance : ndarray, shape (H, W, 3), float32
        Linear RGB radiance reaching the camera through each pixel, box-filtered over the
        pixel where anti-aliased, and elsewhere too with :attr:`raytrace.presets.Quality.box_grid`
        [W/(m²·sr)].
    quality : Quality
    timings_s : dict
        Seconds per stage, wall clock. ``cache`` is the wait for the frame's lighting context
        after the geometry pass and the work that needs no radiance cache (the pixel centres'
        sunlight, the pixels to anti-alias and, when they are one chunk, their sub-samples'
        rays and sunlight): the context is built on a side thread meanwhile
        (:data:`raytrace.presets.CONTEXT_ON_SIDE_THREAD`), so its own time is inside the other stages.
        ``antialias`` includes the area means of the other pixels (``Quality.box_grid``).
        ``light_parts`` (with ``parts``): the split by source, all its steps (the rest of the
        frame's time is as without it).
    light_parts : ndarray, shape (H, W, 12), float32, or None
        With ``render(..., parts=True)``: :attr:`radiance` split by where the light comes from,
        ``earth``, ``inter``, ``sky``, ``sun`` (RGB each, :data:`raytrace._light_parts.CHANNELS`);
        the four sum to :attr:`radiance` (:mod:`raytrace._light_parts`). None otherwise.
    """

    geometry: GeometryFrame
    radiance: np.ndarray
    quality: Quality
    timings_s: dict = field(default_factory=dict)
    light_parts: np.ndarray | None = None


# the two-pass final gather (Quality.pilot_rays): the paths traced from the second pass's hits
# take the frame's seed XOR SECOND_PASS_STREAM (raytrace._sampling; its directions continue the
# pilot's sequences); a pixel gets at most _MAX_RAYS_FACTOR × gather_rays rays; the pilot's per-ray
# variance is averaged over the other pixels of the same part within _NOISE_RADIUS; a ray that
# hits a part costs 1 + _HIT_COST rays that escape (its shadow ray, its cache look-up, its
# traced bounces); and every pixel keeps a share _EVEN_SHARE × the mean σ of the allocation
# weight however quiet its neighbours looked (measured on the 12 scenes at 1280×960,
# ``balanced``-16: _HIT_COST 0 took the frame 1.12–1.40× the one pass's time, since the rays
# moved to crevices where they hit and bounce; 3: 1.05–1.09×, 6: 1.00–1.08× for 2.04 / 2.09 %;
# _EVEN_SHARE 0.5 took ICESat ``backlit`` 2.49 → 2.33 %, the others within ±0.1 %)
_MAX_RAYS_FACTOR = 8
_NOISE_RADIUS = 2
_HIT_COST = 3.0
_EVEN_SHARE = 0.5


def _gather_two_pass(ctx: _Context, s, n_rays: int, n_pilot: int, pix: np.ndarray, seed: int, var: np.ndarray,
                     inst: np.ndarray, at, rays_out: np.ndarray | None = None, filter_passes: int = 0) -> np.ndarray:
    """Final-gather irradiance (n, 3) of the target pixels (rows of ``s``; pixel k at
    (at[0][k], at[1][k]) in the box whose ids are ``inst``) in two passes: ``n_pilot`` rays at
    every pixel, then as many more as the pilot's measured noise calls for, at the cost of
    n_rays rays at every pixel in all. For a fixed cost Σ c_k n_k the summed variance
    Σ σ_k²/n_k of the pixels' estimates is least at n_k ∝ σ_k/√c_k (Neyman allocation with
    costs; :func:`raytrace._gather.allocate_rays`), and the gather's noise is very uneven: in
    the 12 scenes of the benchmark the noisiest 20 % of target pixels hold 69–100 % of it (in
    crevices, beside bright parts, where Earth is partly blocked), while the rays from an open,
    evenly lit face return the control variate exactly.

    σ_k is the pilot's per-ray standard deviation averaged (σ²) over the *other* pixels of the
    same part within _NOISE_RADIUS: a pixel's own pilot rays do not steer its second pass, so
    its estimate, the mean of all its rays, stays unbiased (with its own variance in the
    average, a pixel whose pilot happened to see a bright part got more rays and so gave that
    luck less weight: ICESat ``backlit`` 10 % too dark in places, interior bias² 1.2 → 2.7
    ×10⁻⁴). c_k = 1 + _HIT_COST × the same average of its pilot rays' hit fraction. Each pixel
    gets at least n_pilot and at most _MAX_RAYS_FACTOR × n_rays rays in all.

    What the frame keeps of a pixel's noise is what the residual filter leaves of it
    (``filter_passes`` à-trous passes, :func:`_filter_residual`), and the filter averages a
    pixel in a part's interior over many neighbours but one along a part's border (a rod lying
    on a module, a panel's edge) over few: so the allocation minimises Σ Q_k σ_k²/n_k, the
    filtered variances, with n_k ∝ √Q_k σ_k/√c_k, where Q_k is the variance the filter's passes
    leave of unit noise at pixel k counting neighbours on its own part only
    (:func:`raytrace._filter.filter_variance`; 0 passes: Q = 1, the plain Neyman allocation).
    Q depends on the ids alone, not on any ray, so the estimate stays unbiased. Measured on the
    12 scenes of ``benchmarks/bench_time_error.py`` at 1280×960 (``benchmarks/bench_bias_noise.py``,
    the same seeds both ways): at 8 rays the median error stays 2.85 % and the noisiest scenes
    gain (``backlit``: Tiangong 7.79 → 7.56 %, ICESat 3.88 → 3.65 %, Cassini 8.81 → 7.84 %);
    with the local-linear filter at 8 rays as well (:func:`raytrace.presets._filter_linear`) every scene's error
    is within 0.03 % of the old or lower, median 2.85 → 2.68 %; at 16 rays 1.95 → 1.94 %
    (Cassini ``backlit`` 5.79 → 5.46 %); at 64 rays (one pass) 1.33 → 1.32 %, no scene moved by
    more than 0.05 %. The frame's rays in all are the same budget. The second pass
    continues each pixel's sequence of directions from sample n_pilot, so both passes
    together are as evenly stratified as one (:func:`raytrace._gather.gather_rays`).
    ``var`` (n,) receives each estimate's luminance variance, ``rays_out`` (n,), if given, its
    number of rays."""
    hits = np.empty(len(pix), dtype=np.int64)
    E = ctx.gather_E(s, n_pilot, pix, seed, var, hits=hits)
    img = np.zeros(inst.shape)
    img[at] = var * n_pilot  # per ray
    sig2 = np.zeros(inst.shape)
    _filter.same_part_mean(img, inst, _NOISE_RADIUS, sig2)
    img[at] = hits / n_pilot
    hit_frac = np.zeros(inst.shape)
    _filter.same_part_mean(img, inst, _NOISE_RADIUS, hit_frac)
    cost = 1.0 + _HIT_COST * hit_frac[at]
    total = np.empty(len(pix), dtype=np.int64)
    sg = np.sqrt(sig2[at])
    sg += _EVEN_SHARE * sg.mean()
    if filter_passes > 0:
        q = np.empty(inst.shape)
        _filter.filter_variance(inst, filter_passes, q)
        sg *= np.sqrt(q[at])
    _gather.allocate_rays(sg, cost, n_pilot, _MAX_RAYS_FACTOR * n_rays, n_rays * cost.sum(), total)
    if rays_out is not None:
        rays_out[:] = total
    more = np.flatnonzero(total > n_pilot)
    if len(more):
        extra = total[more] - n_pilot
        var2 = np.empty(len(more))
        # the same sequences of directions, continued (their pilot rays left strata for these
        # to fill), and paths of their own from the hits
        E2 = ctx.gather_E(s, 0, pix[more], seed, var2, counts=extra, first=n_pilot,
                          path_seed=seed ^ SECOND_PASS_STREAM, rows=more)
        w = n_pilot / total[more]
        E[more] = w[:, None] * E[more] + (1.0 - w)[:, None] * E2
        var[more] = w * w * var[more] + (1.0 - w) ** 2 * var2
    return E


def _filter_residual(rows, var, inst, at, guide, passes: int, sigma_l: float, linear: float = 0.0) -> np.ndarray:
    """The per-pixel rows (n, 3) of a gathered estimate (``balanced``'s gathered irradiance,
    or its lobe's difference from the mirror term), with their luminance variances
    ``var`` (n,), filtered by ``passes`` à-trous passes (:func:`raytrace._filter.atrous`) on
    the image of ids ``inst`` (pixel k at (at[0][k], at[1][k]); pixels whose id is 0 neither
    take nor give), ``guide`` = (normals, depths, fx, fy, cx, cy, lens, table) of that image: rows (n, 3).

    With ``linear`` = β > 0 each pixel takes, instead of the filter's weighted mean, the value
    at its own position of the weighted least-squares plane (in image coordinates) through its
    neighbours, with the same weights (the cascade's effective kernel), the plane's slope scaled
    by β: a local-linear kernel estimate (e.g. Fan & Gijbels 1996, *Local Polynomial Modelling*,
    ch. 3). The weighted mean is biased wherever the residual has a gradient and the kernel is
    not centred on the pixel — along a part's edge, where the kernel is one-sided, and that is
    where contact shadows and light from the neighbouring part make the gradients; the
    local-linear estimate has no such first-order bias. The plane comes from the same passes:
    the filter is linear in its channels for given weights, so filtering y, y·u, y·v, u, v, u²,
    u·v and v² together gives the weighted moments of the regression."""
    linear_fit = linear > 0.0 and passes > 0
    # image coordinates in units of _LL_UNIT pixels (moments of order 2 stay well scaled); a
    # small ridge on the plane's covariance keeps a kernel one pixel wide (a thin strip)
    # solvable, its slope across the strip then ≈ 0
    av, au = at[0].astype(np.int64), at[1].astype(np.int64)
    img = np.zeros((*inst.shape, 14 if linear_fit else 3))
    var_img = np.zeros(inst.shape)
    _filter.residual_image(rows, var, av, au, _LL_UNIT, img, var_img)
    img, _ = _atrous_passes(img, var_img, inst, guide, passes, sigma_l, overwrite=True)
    out = np.empty((len(av), 3))
    _filter.residual_rows(img, av, au, _LL_UNIT, _LL_RIDGE_PX2 / (_LL_UNIT * _LL_UNIT), linear, out)
    return out


def _atrous_passes(img, var, inst, guide, passes: int, sigma_l: float, overwrite: bool = False):
    """``passes`` à-trous passes (:func:`raytrace._filter.atrous`, pass k with holes of 2^k
    pixels) over the image ``img`` (H, W, C) with per-pixel variances ``var`` (H, W), ids
    ``inst`` and ``guide`` = (normals, depths, fx, fy, cx, cy, lens, table): the filtered image and its
    variances (σ_l = 0: geometry only). They are new arrays, or, with ``overwrite``, may be
    ``img`` and ``var`` themselves (one image less in memory)."""
    if not overwrite:
        img, var = img.copy(), var.copy()
    tmp, var_tmp = np.zeros_like(img), np.zeros_like(var)
    var_blur, lum = np.zeros_like(var), np.zeros_like(var)
    normal, depth, fx, fy, cx, cy, lens, table = guide
    for k in range(passes):
        if sigma_l > 0.0:
            _filter.guide_images(img, var, inst, lum, var_blur)
        _filter.atrous(img, var, var_blur, lum, inst, normal, depth, fx, fy, cx, cy, lens, table, 1 << k, sigma_l, tmp,
                       var_tmp)
        img, tmp = tmp, img
        var, var_tmp = var_tmp, var
    return img, var


def _check_finite(stage: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        raise FloatingPointError(f"non-finite radiance after {stage}: please report this scene")


# Earth behind the target (raytrace._background.earth_background): the procedural texture's
# albedo on the corners of 4 × 4 pixel cells, interpolated in cells that span less than 1e-3
# of Earth's radius (6.4 km; the texture's finest octave is ~60 km) and match their centre's
# albedo to 0.2 %; elsewhere (near the limb) per pixel. 16 frames of the main job (Cassini,
# spiral), against every pixel evaluated: largest error 0.081 % of a pixel's radiance, the
# kernel 0.26–0.47× the time where Earth fills the view (122–176 → 41–72 ms;
# benchmarks/bench_background.py; since then the cells' test once per cell and the per-pixel hit
# test on unnormalised rays: 24–30 → 13–21 ms on one thread where Earth fills a 1280×960 view,
# the same bytes). _BACKGROUND_STEP = 1: per pixel everywhere.
_BACKGROUND_STEP = 4
_BACKGROUND_TOL = 2e-3
_BACKGROUND_CHORD = 1e-3


def render(scene: Scene, camera: Camera, R_cam_from_body, t_cam_m, lighting: Lighting, *,
           quality: str = "balanced", samples: int | None = None, seed: int = 0,
           geometry: GeometryFrame | None = None, cache_options: dict | None = None,
           parts: bool = False) -> RenderFrame:
    """Render one frame: geometric AOVs and linear radiance.

    Parameters
    ----------
    scene : Scene
    camera : Camera
    R_cam_from_body : array_like, shape (3, 3)
        ``p_cam = R p_body + t`` [-].
    t_cam_m : array_like, shape (3,)
        Target origin in the camera frame [m].
    lighting : Lighting
        Sun, Earth and sky in the body frame.
    quality : {"fast", "balanced", "reference"}, keyword-only
    samples : int, optional, keyword-only
        Overrides the preset's sample count (:func:`raytrace.presets.quality_preset`).
    seed : int, keyword-only
        Seed of the frame's sample pattern: the same seed gives the same image bit for bit.
    geometry : GeometryFrame, optional, keyword-only
        The geometry pass of this pose, if already cast.
    cache_options : dict, optional, keyword-only
        Options of the radiance cache (:class:`raytrace.cache.RadianceCache`); without
        ``spacing_m``, the preset's lattice spacing (:func:`raytrace.presets.preset_cache_options`).
    parts : bool, keyword-only
        Also split the radiance into its Sun, Earth, sky and inter-reflected parts
        (:attr:`RenderFrame.light_parts`, :mod:`raytrace._light_parts`). Without it nothing of
        that is computed and the frame is the same, bit for bit.

    Returns
    -------
    RenderFrame
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a raytrace.scene.Scene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a raytrace.camera.Camera, got {type(camera).__name__}")
    if not isinstance(lighting, Lighting):
        raise ValueError(f"lighting must be a raytrace.lighting.Lighting, got {type(lighting).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**31:
        raise ValueError(f"seed must be an integer in [0, 2**31), got {seed!r}")
    if not isinstance(parts, (bool, np.bool_)):
        raise ValueError(f"parts must be True or False, got {parts!r}")
    q = quality_preset(quality, samples)
    R, t = _check_pose(R_cam_from_body, t_cam_m)
    cache_options = preset_cache_options(q, scene.scale_m, cache_options)
    timings = {}
    pending = None
    # The frame's context (:class:`_Context`: the radiance cache's solve, the environment's
    # tables) does not depend on the camera, so it is built on a side thread while the geometry
    # pass runs (presets.CONTEXT_ON_SIDE_THREAD): the cache's Gauss–Seidel sweeps run on one core,
    # and the geometry pass's chunks fill the other. The same frames bit for bit
    # (tests/raytrace/test_shading.py); 12 benchmark scenes, median per-scene time ratio to
    # building it in line 0.95–0.97 for ``fast``, 0.98 for ``balanced``-16 (BENCHMARKS.md, "The
    # context on a side thread"). What needs no cache is done before the frame waits for it
    # (:class:`_Sunlight`: the centres' sunlight and mirror rays, the pixels to anti-alias and
    # their sub-samples' rays, hits and sunlight when they are one chunk): ``fast`` then waits
    # ~0 ms instead of 0–33 ms; one frame on both cores 0.91–0.96× the time (median per scene;
    # ``balanced``-8 0.97–1.01×), the two versions' renders interleaved
    # (benchmarks/bench_interleaved.py; BENCHMARKS.md, "`fast` waits for nothing"). False: one
    # after the other.
    if presets.CONTEXT_ON_SIDE_THREAD and q.name != "reference" and numba.get_num_threads() > 1:
        # what both threads use and the scene builds on first use, built here, once
        scene.embree, scene.direct, scene.direct_fast, scene.radiance_cache(**cache_options)
        pending = _submit("context", 1, _Context, scene, lighting, cache_options, q.gather_rays == 0)
    t0 = time.perf_counter()
    geo = geometry if geometry is not None else scene.render_geometry(camera, R, t)
    timings["geometry"] = time.perf_counter() - t0
    if q.name == "reference":
        from .pathtrace import render_reference
        t0 = time.perf_counter()
        rad = render_reference(scene, camera, R, t, lighting, geo, spp=q.spp, seed=int(seed))
        timings["path_trace"] = time.perf_counter() - t0
        _check_finite("path tracing", rad)
        rad = rad.astype(np.float32)
        light_parts = None
        if parts:
            t0 = time.perf_counter()
            fast_options = preset_cache_options(quality_preset("fast"), scene.scale_m, cache_options)
            pix, centre, vis = _light_parts.fast_centre_parts(scene, camera, R, t, lighting, geo, fast_options,
                                                              quality_preset("balanced").sun_rays, int(seed))
            lit = np.zeros(geo.instance.size, dtype=bool)
            lit[pix] = vis >= 0.5
            mixed = _light_parts.mixed_pixels(geo.instance, lit.reshape(geo.instance.shape))
            light_parts = _light_parts.assemble(rad, pix, centre, None, mixed)
            timings["light_parts"] = time.perf_counter() - t0
        _stars(rad, scene, camera, R, t, lighting, timings, light_parts)
        return RenderFrame(geo, rad, q, timings, light_parts)

    H, W = camera.height, camera.width
    R_bc = np.ascontiguousarray(R.T)
    o_body = -R_bc @ t
    rad = np.zeros((H * W, 3), dtype=np.float32)
    lit_img = np.zeros(H * W, dtype=bool)

    # ---- what needs the geometry and the lighting but not the radiance cache, found while the
    # context may still be solving it on its side thread (its Gauss–Seidel sweeps hold one core;
    # these fill the other): the pixel centres' surfaces and sunlight (shadow rays, soft
    # shadows) and their mirror rays
    t0 = time.perf_counter()
    sunl = _Sunlight(scene, lighting, prefiltered_glossy=q.gather_rays == 0)
    sunl.px_rad = 1.0 / camera.fx
    pix = np.flatnonzero(geo.instance.ravel() > 0)
    O = np.empty((len(pix), 3))
    D = np.empty((len(pix), 3))
    centre_rays(pix, W, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, *camera.lens_arrays(), O, D)
    face = geo.face_index.ravel()[pix].astype(np.int64)
    s = _surfaces(scene, O, D, face, sunl.px_rad)
    soft = q.sun_rays > 1 and lighting.sun_angular_diameter_rad > 0.0
    occ_t = np.full(len(pix), np.inf) if soft else None  # occluder distances cost a closest-hit query
    L, vis = sunl.sunlight(s, occluder_t=occ_t, robust=True)
    penumbra = None
    if soft:
        footprint_m = geo.depth_m.ravel()[pix].astype(np.float64) / camera.fx
        penumbra = sunl.soft_shadows(s, vis, occ_t, footprint_m, pix, H, W, q.sun_rays, int(seed))
    mirror = sunl.mirror_hits(s)
    lit_img[pix] = vis >= 0.5
    t_direct = time.perf_counter() - t0
    # ---- and for anti-aliasing: Earth behind the target, the pixels to anti-alias and, when
    # they are one chunk, their sub-samples' rays, surfaces and sunlight
    t0 = time.perf_counter()
    earth_px = np.zeros((H, W), dtype=bool)
    earth_drawn = lighting.earth is not None and _earth_may_be_in_view(camera, R, lighting)
    if earth_drawn:
        sunl.p_background[_background.env.P_PIX_RAD] = 1.0 / camera.fx  # the detail a pixel resolves
        _background.earth_background(geo.instance, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy,
                                     *camera.lens_arrays(),
                                     sunl.p_background, sunl.tex, _BACKGROUND_STEP, _BACKGROUND_TOL,
                                     _BACKGROUND_CHORD, earth_px, rad.reshape(H, W, 3))
        _check_finite("background", rad)
    epix = _antialias._aa_pixels(q, scene, camera, R, t, o_body, geo, lighting, sunl, s, vis, pix, lit_img, earth_px,
                                 earth_drawn)
    # Earth's disc behind the pixels anti-aliasing will overwrite, for the light parts
    t_parts = time.perf_counter()
    background = rad[epix] if parts and earth_drawn else None
    t_parts = time.perf_counter() - t_parts
    traced = None
    if len(epix) and len(epix) <= _antialias._aa_chunk_pixels(q.aa_grid):
        traced = _antialias._trace_chunk(sunl, scene, camera, R, t, o_body, geo, epix, q.aa_grid, int(seed),
                                         q.cov_grid)
    t_early = time.perf_counter() - t0
    t0 = time.perf_counter()
    ctx = pending.result() if pending is not None else \
        _Context(scene, lighting, cache_options, prefiltered_glossy=q.gather_rays == 0)
    ctx.px_rad = sunl.px_rad
    timings["cache"] = time.perf_counter() - t0
    t0 = time.perf_counter() - t_direct  # the Sun at the centres counts in "direct"
    lbar = np.zeros((len(pix), 3))
    E = E_cache = ctx.cache_E(s)
    L_sun = L.copy() if parts else None  # the Sun's term alone (its penumbra added below)
    ctx.add_mirror(s, E, L, mirror, lbar)
    if penumbra is not None:
        cand, dL = penumbra
        L[cand] += dL
        if parts:
            L_sun[cand] += dL
    timings["direct"] = time.perf_counter() - t0
    _check_finite("direct light", L)
    t0 = time.perf_counter()
    centre_light = None
    if q.gather_rays > 0 and len(pix):
        # final gather and glossy lobe sampling. The gathered irradiance itself is filtered, not
        # its difference from the cache's: the cache is piecewise linear on its lattice, with
        # kinks that the truth has not, and filtering the difference blurs the truth's detail
        # minus the cache's, which puts the kinks' blur into the frame (BENCHMARKS.md, "The
        # gather filtered, not its difference from the cache"). The lobe's difference from its
        # mirror-term counterpart (a control variate of known mean) is filtered as before
        pix64 = pix.astype(np.int64)
        # the target's bounding box, on which the gather's noise is averaged and its residual
        # filtered
        pv, pu = pix // W, pix % W
        v0, u0 = int(pv.min()), int(pu.min())
        box = (slice(v0, int(pv.max()) + 1), slice(u0, int(pu.max()) + 1))
        inst = np.ascontiguousarray(geo.instance[box])
        at = (pv - v0, pu - u0)
        var = np.empty(len(pix))
        if q.pilot_rays > 0:
            G = _gather_two_pass(ctx, s, q.gather_rays, q.pilot_rays, pix64, int(seed), var, inst, at,
                                 filter_passes=q.filter_passes)
        else:
            G = ctx.gather_E(s, q.gather_rays, pix64, int(seed), var)
        var_s = np.empty(len(pix))
        dS = ctx.lobe(s, q.gather_rays, pix64, int(seed), lbar, var_s)
        # each filtered on the target's bounding box with weights from the geometry and, from 8
        # rays, its own noise: the specular residual apart from the diffuse one, on specular
        # pixels only (its steps are reflected edges and shadows, not the diffuse light's)
        guide = (geo.normal_cam[box].astype(np.float64),
                 np.where(np.isfinite(geo.depth_m[box]), geo.depth_m[box], 0.0).astype(np.float64),
                 camera.fx, camera.fy, camera.cx - u0, camera.cy - v0, *camera.lens_arrays())
        rows_E = _filter_residual(G, var, inst, at, guide, q.filter_passes, q.filter_sigma_l, q.filter_linear)
        spec_px = ctx.lobe_sampled[s["comp"]]
        if spec_px.any():
            inst_s = np.zeros_like(inst)
            inst_s[at[0][spec_px], at[1][spec_px]] = inst[at[0][spec_px], at[1][spec_px]]
            rows_S = _filter_residual(dS, var_s, inst_s, at, guide, q.filter_passes, q.filter_sigma_l)
        else:
            rows_S = np.zeros((len(pix), 3))
        # per target pixel (row k of s for pixel pix[k]): the filtered gathered irradiance and
        # the filtered specular correction
        centre_light = (rows_E, rows_S)
        E = rows_E
        L += rows_S
    ctx.add_diffuse(s, E, L)
    _check_finite("indirect light", L)
    centre_parts = None
    if parts:
        t_parts -= time.perf_counter()
        centre_parts = _light_parts.centre_parts(ctx, s, E_cache, L_sun, L)
        t_parts += time.perf_counter()
    # the specular corrections (lobe − mirror term) and the local-linear filter's planes may
    # overshoot below zero; radiance is never negative
    _rows.put_rows_nonnegative(pix, L, rad)
    timings["indirect"] = time.perf_counter() - t0

    # ---- anti-aliasing where neighbours disagree (Earth behind the target is drawn above)
    t0 = time.perf_counter() - t_early  # Earth, the edges and their trace count in "antialias"
    centre = None
    if centre_light is not None and (len(epix) or q.box_grid > 1):
        # the centre's surface (point, normal, footprint; row k of s for pixel pix[k]):
        # a sub-sample shares its pixel's filtered light only on that same surface
        row_of_pixel = np.full(H * W, -1, dtype=np.int32)
        row_of_pixel[pix] = np.arange(len(pix), dtype=np.int32)
        centre = (row_of_pixel, s["P"], s["NS"], geo.depth_m.ravel()[pix].astype(np.float64) / camera.fx)
    if len(epix):
        n_extra = int(q.aa_extra * len(epix))
        contrast = np.empty(len(epix)) if n_extra else None
        sub = _antialias._supersample(ctx, scene, camera, R, t, o_body, geo, epix, q.aa_grid, int(seed), centre_light,
                                      q.aa_gather_rays, centre, q.cov_grid, q.borrow, q.own_at_boundary, contrast,
                                      traced)
        del traced
        if n_extra:
            # the highest contrast first, ties in pixel order; then back in pixel order
            sel = np.sort(np.argsort(-contrast, kind="stable")[:n_extra])
            sub2 = _antialias._supersample(ctx, scene, camera, R, t, o_body, geo, epix[sel], q.aa_grid,
                                           int(seed) ^ AA_SECOND_STREAM, centre_light, q.aa_gather_rays, centre,
                                           q.cov_grid, q.borrow, q.own_at_boundary)
            sub[sel] = 0.5 * (sub[sel] + sub2)
        _check_finite("anti-aliasing", sub)
        _rows.put_rows_nonnegative(epix, sub, rad)
    if q.box_grid > 1 and len(pix):
        # every other target pixel: its area mean from box_grid² sub-samples, which take the
        # centres' filtered light interpolated on their surface (none near a boundary casts a gather
        # of its own; one on another surface than its centre's, rare here, does)
        rest = np.setdiff1d(pix, epix, assume_unique=True)
        if len(rest):
            box = _antialias._supersample(ctx, scene, camera, R, t, o_body, geo, rest, q.box_grid,
                                          int(seed) ^ BOX_STREAM, centre_light, q.aa_gather_rays, centre,
                                          borrow=q.borrow)
            _check_finite("area means", box)
            _rows.put_rows_nonnegative(rest, box, rad)
    timings["antialias"] = time.perf_counter() - t0
    rad = rad.reshape(H, W, 3)
    light_parts = None
    if parts:
        t0 = time.perf_counter()
        light_parts = _light_parts.assemble(rad, pix, centre_parts, background, epix)
        timings["light_parts"] = time.perf_counter() - t0 + t_parts
    _stars(rad, scene, camera, R, t, lighting, timings, light_parts)
    return RenderFrame(geo, rad, q, timings, light_parts)


def _stars(rad, scene: Scene, camera: Camera, R, t, lighting: Lighting, timings: dict,
           light_parts: np.ndarray | None = None) -> None:
    """The stars of ``lighting`` into the background of ``rad`` (H, W, 3), in place, and
    into the ``sky`` part of ``light_parts`` (H, W, 12), if given."""
    if lighting.stars is None:
        return
    from .stars import add_stars
    t0 = time.perf_counter()
    before = rad.copy() if light_parts is not None else None
    add_stars(rad, lighting.stars, lighting.R_body_from_eci, scene, camera, R, t, lighting.earth)
    _check_finite("stars", rad)
    if light_parts is not None:
        changed = np.any(rad != before, axis=2)
        sky = 3 * _light_parts.SKY
        light_parts[changed, sky:sky + 3] += rad[changed] - before[changed]
    timings["stars"] = time.perf_counter() - t0


def _earth_may_be_in_view(camera: Camera, R, lighting: Lighting) -> bool:
    """Earth's disc can overlap the field of view (cone test, conservative)."""
    e_cam = R @ np.asarray(lighting.earth.earth_dir_body)
    if camera.distorted:  # the widest undistorted ray through the image's border
        W, H = camera.width, camera.height
        s = np.linspace(0.0, 1.0, 65)
        xy = camera.undistort(np.column_stack([np.concatenate([W * s - 0.5, W * s - 0.5, np.full(65, -0.5),
                                                               np.full(65, W - 0.5)]),
                                               np.concatenate([np.full(65, -0.5), np.full(65, H - 0.5),
                                                               H * s - 0.5, H * s - 0.5])]))
        half_diag = math.atan(float(np.hypot(xy[:, 0], xy[:, 1]).max())) + 1e-3
    else:
        half_diag = math.atan(math.hypot(max(camera.cx + 0.5, camera.width - 0.5 - camera.cx) / camera.fx,
                                         max(camera.cy + 0.5, camera.height - 0.5 - camera.cy) / camera.fy))
    angle = math.acos(max(-1.0, min(1.0, float(e_cam[2]))))
    return angle <= half_diag + lighting.earth.drawn_angular_radius_rad + 1e-6


