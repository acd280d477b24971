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

from . import _background, _edges, _filter, _gather, _paths, _rows, _surface, environment as env, presets
from ._kernels import centre_rays, ray_origins32
from ._sampling import (AA_SECOND_STREAM, BOX_STREAM, COVERAGE_STREAM, LOBE_PATH_STREAM, SECOND_PASS_STREAM,
                        SUB_GATHER_STREAM)
from ._threads import parallel_chunksize, submit as _submit
from .brdf import split_sum_table
from .camera import Camera
from .lighting import Lighting
from .presets import QUALITIES, Quality, preset_cache_options, quality_preset
from .scene import GeometryFrame, Scene, _check_pose

__all__ = ["QUALITIES", "Quality", "RenderFrame", "quality_preset", "render"]


# the fewest final-gather rays worth casting at an edge sub-sample off its pixel centre's
# surface (render gives such a sub-sample Quality.aa_gather_rays of them, gather_rays / 4 below 32
# rays, at least 2): on the scenes of
# benchmarks/bench_time_error.py at 640×480, 2-ray sub-sample gathers made ``balanced``-8 worse
# than the cache alone (``backlit`` views 14.7–14.9 % with them, 13.0–13.1 % without), 4-ray ones
# made ``balanced``-16 better (median of four views 7.3 → 6.5 %)
_MIN_SUB_GATHER = 4
# the traced path from a final-gather hit: at most _GATHER_BOUNCES one-sample bounces, each
# beyond the first only from hits nearer than _NEAR_SPACINGS cache lattice spacings (in a gap
# the cache is most wrong and the light bounces most); measured on the 12 scenes of
# benchmarks/bench_time_error.py at 1280×960 against 1 bounce: ``balanced``-16 median error
# 3.30 → 3.16 %, -64 2.33 → 2.21 %, for +4 % time (+13 % with every hit continued, same error);
# Tiangong's arm lying on its core module (a white gap): the pixel beside it 12 % too bright
# with 1 bounce, 5 % with 4, 1 % with 8
_GATHER_BOUNCES = 4
_NEAR_SPACINGS = 2.0
# ... and the first bounce (from the final-gather hit itself) only from hits nearer than
# _FIRST_NEAR_SPACINGS spacings (and glossy hits): a farther hit takes the cache's indirect
# light, which the contact rows (raytrace.cache) made right near contacts, so a one-sample
# bounce there added more noise than the bias it removed. Measured on the 12 scenes of
# benchmarks/bench_time_error.py at 1280×960 against every hit continued (median error, bias
# and noise without the reference's noise, two seeds): ``balanced``-8 3.22 → 3.17 %, -16
# 2.23 → 2.20 % (2 spacings: 2.22 %), -64 1.45 → 1.45 %; 35 of the 36 scene-preset errors
# lower or equal (interior bias² up, noise² down more: -16 summed 23.7 → 29.1 and
# 46.5 → 36.4 ×10⁻⁴), with fewer rays (BENCHMARKS.md, "The first bounce only near")
_FIRST_NEAR_SPACINGS = 1.0
# the lobe of a part is sampled (``balanced``) only where its specular albedo is at least this
# fraction of its diffuse one (luminance): white paint's reflection (f0 = 0.04, α = 0.5, 4.5 % of
# its diffuse albedo) costs as many lobe rays as gold's and is then taken from the mirror term
# alone; real materials at 1280×960, ``balanced``-16: Crew Dragon 1.36 → 0.98 s, Cassini 1.39 →
# 1.23 s; error at 640×480 (8 / 16 / 64 rays) Crew Dragon 1.93 / 1.57 / 0.96 → 2.01 / 1.66 / 1.05 %,
# the other three within 0.1 %
LOBE_MIN_SPECULAR = 0.2
# the final gather, the lobe sampling and the edge sub-samples' shadow rays in one kernel each
# that calls Embree from numba (presets.FUSED_GATHER; raytrace._paths, raytrace._embree; the same
# frames); False: the batched code through embreex, the fallback where the wheel has no Embree 4
# (the tests compare the two). The fused kernels hand out blocks of raytrace._paths._BLOCK points
# _FUSED_CHUNK blocks at a time (numba.set_parallel_chunksize: the rays per point vary 8×
# in the second pass; 0, numba's static split, measured 0.95–1.03× on four scenes)
_FUSED_CHUNK = 1


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
    """

    geometry: GeometryFrame
    radiance: np.ndarray
    quality: Quality
    timings_s: dict = field(default_factory=dict)


def _surfaces(scene: Scene, O, D, face) -> dict:
    """The surface points where rays O + t D hit triangles ``face`` of ``scene``: point,
    shading and geometric normals, direction to the viewer, barycentrics, side, part
    (:func:`raytrace._surface.surfaces`; ``O`` a row per ray, or one row for all)."""
    n = len(D)
    out = {k: np.empty((n, 3)) for k in ("P", "NS", "NG", "WO")}
    out["B"] = np.empty((n, 2))
    out["SIDE"] = np.empty(n, dtype=np.int64)
    out["face"] = face
    out["comp"] = scene.component_of_face[face]
    _surface.surfaces(O, D, face, scene.vertices, scene.faces, scene.face_normal, scene.corner_normal, out["P"],
                      out["NS"], out["NG"], out["WO"], out["B"], out["SIDE"])
    return out


class _Sunlight:
    """What the Sun's term and the background need of a frame's lighting: no radiance cache.
    :func:`render` makes one on its own thread and shades the Sun (shadow rays, soft shadows,
    the sub-samples' solar-disc rays) and finds the edges to anti-alias with it while the
    :class:`_Context` (a subclass: these and the cache's solution) is built on a side thread."""

    def __init__(self, scene: Scene, lighting: Lighting, prefiltered_glossy: bool = False):
        self.scene = scene
        self.lighting = lighting
        mats = scene.materials
        self.diff = np.array([m.diffuse for m in mats], dtype=np.float64)
        self.f0 = np.array([m.f0 for m in mats], dtype=np.float64)
        self.alpha = np.array([m.roughness for m in mats], dtype=np.float64)
        self.specular = self.f0.max(axis=1) > 0.0
        # parts whose mirror ray ``balanced``'s mirror term weights by more than 0 (the same
        # expression as raytrace._surface.add_mirror's blend, so t = 1 exactly where False)
        t = np.minimum(np.maximum((self.alpha - _surface.MIRROR_BLEND_A0) / _surface.MIRROR_BLEND_WIDTH, 0.0), 1.0)
        self.mirror_weighted = t < 1.0
        # ``fast`` (no final gather): glossy parts reflect the environment prefiltered by their
        # lobe, and every specular point casts its mirror ray
        self.prefiltered_glossy = prefiltered_glossy
        self.eps = scene.ray_eps_m
        self.p_background, self.tex = _background_params(lighting)

    def sunlight(self, s, *, disc=None, occluder_t=None, robust: bool = False):
        """Sunlight (shadowed) at the points ``s``: radiance (n, 3) and the Sun's visibility
        (n,) in {0, 1}. The shadow ray goes towards the Sun's centre, or, with ``disc`` =
        (pixel, number, n_strata, seed) per point, towards one solar-disc sample per point
        (:func:`raytrace._surface.sun_disc_dirs`), drawn only for the points facing the Sun;
        ``occluder_t``, when given, receives the distance to the occluder of every blocked
        point. ``robust``: through Embree's robust scene (the pixel centres' exact Sun: no ray
        slips through an edge there), else the faster one (:attr:`Scene.direct_fast`). The
        cheap specular term of everything else is :meth:`_Context.add_mirror`'s."""
        n = len(s["P"])
        L = np.zeros((n, 3))
        vis = np.zeros(n)
        light = self.lighting
        e_sun = light.sun_irradiance_at_target_W_m2
        sx, sy, sz = light.sun_dir_body
        if e_sun > 0.0 and n:
            want = np.empty(n, dtype=bool)
            o = np.empty((n, 3), np.float32)  # Embree's precision: rounded once, as before
            _surface.sun_rays(s["P"], s["NS"], s["NG"], sx, sy, sz, self.eps, want, o)
            idx = np.flatnonzero(want)
            direct = None
            if presets.FUSED_GATHER and occluder_t is None:
                direct = self.scene.direct if robust else self.scene.direct_fast
            if len(idx) and direct is not None:
                # the disc samples drawn and the shadow rays cast in one kernel
                pixel, number, n_strata, seed = disc if disc is not None else (idx, idx, 0, 0)
                _paths.sun_visibility(direct.handle, idx, s["P"], s["NG"], float(sx), float(sy), float(sz), self.eps,
                                      np.asarray(pixel, np.int64), np.asarray(number, np.int64), int(n_strata),
                                      int(seed), math.cos(0.5 * light.sun_angular_diameter_rad), vis)
            elif len(idx):
                if disc is None:
                    d = np.broadcast_to(np.float32([sx, sy, sz]), (len(idx), 3))
                else:
                    # (float32: they only steer shadow rays)
                    d = np.empty((len(idx), 3), np.float32)
                    pixel, number, n_strata, seed = disc
                    _surface.sun_disc_dirs(pixel[idx], number[idx], n_strata, seed, sx, sy, sz,
                                           math.cos(0.5 * light.sun_angular_diameter_rad), d)
                if occluder_t is None:
                    blocked = self.scene.occluded(o[idx], d, robust=robust)
                else:
                    h = self.scene.intersect(o[idx], d, robust=robust)
                    blocked = h["geomID"] >= 0
                    occluder_t[idx[blocked]] = h["tfar"][blocked]
                vis[idx[~blocked]] = 1.0
            _surface.shade_sun(s["NS"], s["WO"], s["comp"], self.diff, self.f0, self.alpha, sx, sy, sz, e_sun, vis, L)
        return L, vis

    def mirror_hits(self, s):
        """The mirror rays of the specular points of ``s`` and their closest hits, as
        :meth:`_Context.add_mirror` takes them: (rows, origins, directions, hits), or None where
        no point is specular."""
        spec = self.specular[s["comp"]]
        if not spec.any():
            return None
        n = len(s["P"])
        o = np.empty((n, 3))
        d = np.empty((n, 3))
        _surface.mirror_rays(s["NS"], s["NG"], s["WO"], s["P"], self.eps, spec, o, d)
        idx = np.flatnonzero(spec)
        if self.prefiltered_glossy:
            h = self.scene.intersect(o[idx], d[idx])
        else:
            # ``balanced`` weights the mirror ray by 1 − t (add_mirror): where t = 1 (wide
            # lobes: paint, aluminium) it needs no ray, and a miss stands in for it
            h = {"geomID": np.full(len(idx), -1, np.int32), "primID": np.zeros(len(idx), np.int32),
                 "u": np.zeros(len(idx), np.float32), "v": np.zeros(len(idx), np.float32)}
            cast = np.flatnonzero(self.mirror_weighted[s["comp"][idx]])
            if len(cast):
                hc = self.scene.intersect(o[idx[cast]], d[idx[cast]])
                for key in h:
                    h[key][cast] = hc[key]
        return idx, o[idx], d[idx], h

    def soft_shadows(self, s, vis, occ_t, footprint_m, pix, H, W, n_rays, seed):
        """Replace the point-Sun visibility by the visible fraction of the solar disc (n_rays
        stratified shadow rays) wherever a penumbra can be wider than a quarter pixel: at
        blocked points whose occluder is far enough (penumbra half-width t·tan(θ☉/2) on the
        receiver) and at lit points within that width of them (a max filter in the image).
        Elsewhere the point Sun is exact to within a quarter pixel. Updates ``vis`` and returns
        the rows it changed and what their radiance gains, (rows, ΔL), to add to the points'
        radiance once it holds the rest of their direct light (None when none changed)."""
        light = self.lighting
        half = 0.5 * light.sun_angular_diameter_rad
        e_sun = light.sun_irradiance_at_target_W_m2
        if half <= 0.0 or e_sun <= 0.0 or n_rays <= 1 or not len(pix):
            return None
        blocked = np.isfinite(occ_t)
        w_blocked = np.minimum(occ_t[blocked] * math.tan(half) / footprint_m[blocked], 8.0)
        if not len(w_blocked) or w_blocked.max() <= 0.25:
            return None
        from scipy.ndimage import maximum_filter
        # the max filter runs on the target's bounding box only (pixels are row-major in pix)
        v, u = pix // W, pix % W
        v0, u0 = v.min(), u.min()
        w_px = np.zeros((v.max() - v0 + 1, u.max() - u0 + 1))
        w_px[v[blocked] - v0, u[blocked] - u0] = w_blocked
        reach = math.ceil(w_blocked.max())
        near = maximum_filter(w_px, size=2 * reach + 1, mode="constant")[v - v0, u - u0] > 0.25
        sx, sy, sz = light.sun_dir_body
        NS, NG = s["NS"], s["NG"]  # (no BLAS: see raytrace._kernels.rows_times_matrix)
        facing = ((NS[:, 0] * sx + NS[:, 1] * sy + NS[:, 2] * sz > 0.0)
                  & (NG[:, 0] * sx + NG[:, 1] * sy + NG[:, 2] * sz > 0.0))
        cand = np.flatnonzero(near & facing)
        if not len(cand):
            return None
        d = np.empty((len(cand) * n_rays, 3), np.float32)  # as Embree takes them
        _surface.sun_disc_dirs(np.repeat(pix[cand].astype(np.int64), n_rays), np.tile(np.arange(n_rays), len(cand)),
                               n_rays, seed, sx, sy, sz, math.cos(half), d)
        o = np.repeat(s["P"][cand] + self.eps * s["NG"][cand], n_rays, axis=0)
        v = 1.0 - self.scene.occluded(o, d).reshape(len(cand), n_rays).mean(axis=1)
        full = np.zeros((len(cand), 3))
        _surface.shade_sun(s["NS"][cand], s["WO"][cand], s["comp"][cand], self.diff, self.f0, self.alpha, sx, sy, sz,
                           e_sun, np.ones(len(cand)), full)
        dL = (v - vis[cand])[:, None] * full
        vis[cand] = v
        return cand, dL


class _Context(_Sunlight):
    """Per-frame constants the kernels need: :class:`_Sunlight`'s and the radiance cache's
    solution under the frame's lighting."""

    def __init__(self, scene: Scene, lighting: Lighting, cache_options: dict, prefiltered_glossy: bool = False):
        super().__init__(scene, lighting, prefiltered_glossy)
        self.table = split_sum_table()
        self.p = lighting.packed()[0]
        self.cache = scene.radiance_cache(**cache_options)
        # parts whose specular albedo exceeds their diffuse one (metals, MLI foils): traced
        # paths continue along their lobe, as the cache's transfer does
        self.glossy = self.cache.glossy_comp
        # ``balanced`` samples the lobe of parts whose specular albedo is at least
        # LOBE_MIN_SPECULAR of their diffuse one (luminance); elsewhere the cheap mirror term
        # (:meth:`add_mirror`) stands alone
        lum = np.array([0.2126, 0.7152, 0.0722])
        spec_albedo = self.cache.bounce_albedo - self.diff
        self.lobe_sampled = self.specular & (spec_albedo @ lum >= LOBE_MIN_SPECULAR * (self.diff @ lum))
        # the environment's unoccluded irradiance: the cache's sky term and the final gather's
        # control variate are both its complement over blocked directions
        cells = env.environment_cells(self.p, self.tex)
        self.env_irradiance = env.irradiance_table(self.p, self.tex, cells=cells)
        # ``fast``: the environment prefiltered by each glossy part's lobe for the mirror term's
        # wide lobes, one table per distinct roughness (raytrace._surface.add_mirror)
        levels = np.unique(self.alpha[self.specular & (self.alpha > _surface.GLOSSY_A0)]) if prefiltered_glossy else []
        self.glossy_level = np.searchsorted(levels, self.alpha).clip(0, max(len(levels) - 1, 0))
        self.glossy_env = env.glossy_table(self.p, levels, cells) if len(levels) else np.zeros((1, 2, 2, 3))
        self.cf = self.cache.solve(lighting, env_irradiance=self.env_irradiance)
        self.sun = np.array([*lighting.sun_dir_body, lighting.sun_irradiance_at_target_W_m2])

    def add_mirror(self, s, E_point, L, hits, lbar_out=None):
        """Adds the cheap specular term of everything but the Sun
        (:func:`raytrace._surface.add_mirror`) to ``L`` (n, 3): the mirror rays ``hits`` of
        :meth:`mirror_hits` (None: no specular point) reflecting the cache's light (``E_point``
        the points' cache irradiance); ``lbar_out`` (n, 3), if given, receives the radiance L̄
        the specular term reflects (the control variate of :meth:`lobe`)."""
        if hits is None:
            return
        n = len(s["P"])
        idx, o, d, h = hits
        M = np.zeros((n, 3))
        lbar = np.zeros((n, 3)) if lbar_out is None else lbar_out
        _surface.add_mirror(idx, o, d, h["geomID"], h["primID"], h["u"].astype(np.float64),
                            h["v"].astype(np.float64), s["NS"], s["WO"], s["comp"], E_point, *self._lookup(),
                            self.prefiltered_glossy, self.env_irradiance, self.glossy_env, self.glossy_level, M,
                            lbar)
        L += M

    def lobe(self, s, n_rays: int, pix: np.ndarray, seed: int, lbar: np.ndarray, var: np.ndarray | None = None):
        """Specular reflection of everything but the Sun, sampled over each glossy point's GGX
        lobe with n_rays rays, minus its cheap counterpart (the mirror term of :meth:`add_mirror`,
        which reflected ``lbar``): radiance (n, 3) (0 at points whose part's lobe is not sampled,
        :attr:`lobe_sampled`, where the mirror term is the answer). A lobe ray that
        hits a part sees it as a final-gather ray does: the Sun exact there (a shadow ray) and
        the hit's indirect light traced (:meth:`_bounces`), not the cache's, whose lattice blurs
        the shadows and edges a sharp lobe reflects. ``var`` (n,), if given, receives each
        estimate's luminance variance (:func:`raytrace._gather.lobe_sum`). Where Embree can
        be called from numba, all in one kernel (:func:`raytrace._paths.lobe_traced`)."""
        n = len(s["P"])
        out = np.zeros((n, 3))
        if var is not None:
            var.fill(0.0)
        idx = np.flatnonzero(self.lobe_sampled[s["comp"]])
        if len(idx) == 0:
            return out
        direct = self.scene.direct_fast if presets.FUSED_GATHER else None
        if direct is not None:
            val = np.empty((len(idx), 3))
            v = np.empty(len(idx))
            light = self.lighting
            sx, sy, sz = (float(x) for x in light.sun_dir_body)
            with parallel_chunksize(_FUSED_CHUNK):
                _paths.lobe_traced(direct.handle, idx, s["P"], s["NS"], s["NG"], s["WO"], s["comp"], n_rays, seed,
                                   seed ^ LOBE_PATH_STREAM, np.asarray(pix, dtype=np.int64), self.eps, sx, sy, sz,
                                   light.sun_irradiance_at_target_W_m2 > 0.0, _GATHER_BOUNCES,
                                   np.float32(_NEAR_SPACINGS * self.cache.spacing_m), *self._lookup(), lbar, val, v)
            out[idx] = val
            if var is not None:
                var[idx] = v
            return out
        step = max(1, presets.CHUNK_RAYS // n_rays)
        for a in range(0, len(idx), step):
            part = idx[a:a + step]
            m = len(part) * n_rays
            o = np.empty((m, 3))
            d = np.empty((m, 3))
            w = np.empty((m, 3))
            _gather.lobe_rays(part, s["P"], s["NS"], s["NG"], s["WO"], s["comp"], self.f0, self.alpha, n_rays, seed,
                              pix, self.eps, o, d, w)
            h = self.scene.intersect(o, d)
            val = np.empty((len(part), 3))
            hu, hv = h["u"].astype(np.float64), h["v"].astype(np.float64)
            # the hits' sunlight exact and their indirect light traced, as for the final gather
            # (their own stream of samples: another seed term of the same keys)
            vis = self._bounce_sun(o, d, h)
            keys = np.repeat(pix[part].astype(np.int64), n_rays) * n_rays + np.tile(np.arange(n_rays), len(part))
            e_ind = self._bounces(o, d, h, hu, hv, keys, seed ^ LOBE_PATH_STREAM, _GATHER_BOUNCES)
            v = np.empty(len(part))
            _gather.lobe_sum(n_rays, o, d, w, h["geomID"], h["primID"], hu, hv, *self._lookup(), part, lbar, vis, e_ind,
                             val, v)
            out[part] = val
            if var is not None:
                var[part] = v
        return out

    def cache_E(self, s):
        E = np.empty((len(s["P"]), 3))
        c = self.cache
        _surface.cache_irradiance(self.cf.indirect_W_m2, c.valid, c.face_s, c.lat_start, c.lat_ids, s["face"], s["B"],
                                  s["SIDE"], E)
        return E

    def gather_E(self, s, n_rays: int, pix: np.ndarray, seed: int, var: np.ndarray | None = None,
                 counts: np.ndarray | None = None, hits: np.ndarray | None = None, first: int = 0,
                 path_seed: int | None = None, share: int = 0, rows: np.ndarray | None = None):
        """Final-gather irradiance (n, 3) of the points ``s`` from n_rays rays each, or from
        counts[k] rays at point k (≥ 1; then ``n_rays`` is ignored): in one kernel
        (:meth:`_gather_fused`) where Embree can be called from numba, else in chunks of about
        presets.CHUNK_RAYS rays (every sample is keyed by its pixel, so the result does not depend on
        the chunking); the rays are samples ``first``, ``first`` + 1, … of each pixel's
        sequence of directions (:func:`raytrace._gather.gather_rays`, keyed by ``seed``; with
        ``share`` > 0 ``pix`` holds pixel · share + i for the sub-sample i of a pixel, and the
        sub-samples of a pixel share its sequence: :func:`raytrace._gather.gather_start`), the
        paths traced from their hits keyed by ``path_seed`` (default ``seed``). ``var`` (n,),
        if given, receives each estimate's luminance variance
        (:func:`raytrace._gather.gather_sum`), ``hits`` (n,) how many of its rays hit a part.
        ``rows`` (n,), if given, are the rows of ``s`` the n points are (the rest is per point)."""
        n = len(s["P"]) if rows is None else len(rows)
        if var is None:
            var = np.empty(n)
        if counts is None:
            counts = np.full(n, n_rays, dtype=np.int64)
            kmul = n_rays
        else:
            counts = np.asarray(counts, dtype=np.int64)
            kmul = int(counts.max()) if n else 1
        seeds = (seed, seed if path_seed is None else path_seed)
        direct = self.scene.direct_fast if presets.FUSED_GATHER else None
        if direct is not None:
            rows = np.arange(n, dtype=np.int64) if rows is None else np.asarray(rows, dtype=np.int64)
            return self._gather_fused(direct, s, rows, counts, kmul, first, pix, seeds, var, hits, share)
        if rows is not None:
            s = {k: s[k][rows] for k in ("P", "NS", "NG")}
        end = np.cumsum(counts)
        # chunk boundaries: every presets.CHUNK_RAYS rays (at least one point per chunk). In chunks,
        # the float64 ray, hit and bounce arrays of the final gather and the lobe sampling stay a
        # few MB and are reused by the allocator instead of being mapped fresh (a whole 1280×960
        # gather at 16 rays is 2.6 M rays, ~60 MB per array, and the page faults of writing fresh
        # arrays from parallel kernels cost more than the kernels: bounce2_rays 66 ms fresh against
        # 9 ms on mapped memory, measured on Crew Dragon ``sunlit``)
        chunk = presets.CHUNK_RAYS
        cuts = np.unique(np.searchsorted(end, np.arange(chunk, int(end[-1]) if n else 0, chunk), side="right"))
        bounds = [0, *[int(c) for c in cuts if 0 < c < n], n]
        if len(bounds) == 2:
            return self._gather_chunk(s, counts, kmul, first, pix, seeds, var, hits, share)
        E = np.empty((n, 3))
        for a, b in zip(bounds[:-1], bounds[1:]):
            E[a:b] = self._gather_chunk({k: v[a:b] for k, v in s.items()}, counts[a:b], kmul, first, pix[a:b],
                                        seeds, var[a:b], None if hits is None else hits[a:b], share)
        return E

    def _gather_fused(self, direct, s, rows, counts, kmul: int, first: int, pix: np.ndarray, seeds, var: np.ndarray,
                      hits: np.ndarray | None, share: int = 0):
        """:meth:`gather_E` in one kernel that calls Embree itself
        (:func:`raytrace._paths.gather_traced`; ``direct`` the scene's
        :class:`raytrace._embree.DirectScene`): the same estimate, without the arrays of every
        ray and bounce. The distances that decide where a path continues are float32, as the
        batched code compares them (NumPy casts the threshold to the hits' float32)."""
        n = len(rows)
        start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=start[1:])
        E = np.empty((n, 3))
        h = np.empty(n, dtype=np.int64)
        light = self.lighting
        sx, sy, sz = (float(x) for x in light.sun_dir_body)
        with parallel_chunksize(_FUSED_CHUNK):
            _paths.gather_traced(direct.handle, s["P"], s["NS"], s["NG"], rows, start, first, seeds[0], seeds[1],
                                 pix.astype(np.int64), share, kmul, self.eps, sx, sy, sz,
                                 light.sun_irradiance_at_target_W_m2 > 0.0, _GATHER_BOUNCES,
                                 np.float32(_FIRST_NEAR_SPACINGS * self.cache.spacing_m),
                                 np.float32(_NEAR_SPACINGS * self.cache.spacing_m), *self._lookup(),
                                 self.env_irradiance, presets.GATHER_ALPHA, E, var, h)
        if hits is not None:
            hits[:] = h
        return E

    def _gather_chunk(self, s, counts, kmul: int, first: int, pix: np.ndarray, seeds, var: np.ndarray,
                      hits: np.ndarray | None, share: int = 0):
        n = len(s["P"])
        start = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=start[1:])
        m = int(start[-1])
        o = np.empty((m, 3))
        d = np.empty((m, 3))
        seed, path_seed = seeds
        _gather.gather_rays(s["P"], s["NS"], s["NG"], start, first, seed, pix, share, kmul, self.eps, o, d)
        h = self.scene.intersect(o, d)
        if hits is not None and n:
            hits[:] = np.add.reduceat((h["geomID"] >= 0).astype(np.int64), start[:-1])
        hu, hv = h["u"].astype(np.float64), h["v"].astype(np.float64)
        vis = self._bounce_sun(o, d, h)
        # each ray's key: its pixel × kmul + its number there (kmul > every count: distinct)
        keys = np.repeat(pix.astype(np.int64) * kmul - start[:-1], counts) + np.arange(m, dtype=np.int64)
        e_ind = self._traced_indirect(o, d, h, hu, hv, keys, path_seed)
        E = np.empty((n, 3))
        _gather.gather_sum(start, o, d, s["NG"], h["geomID"], h["primID"], hu, hv, *self._lookup(), vis, e_ind, s["NS"],
                           self.env_irradiance, presets.GATHER_ALPHA, E, var)
        return E

    def _traced_indirect(self, o, d, h, hu, hv, keys, seed):
        """Traced estimate of the indirect irradiance at each gather hit (−1 at misses): a path
        of up to _GATHER_BOUNCES cosine-weighted one-sample bounces from the hit (from hits
        nearer than _FIRST_NEAR_SPACINGS lattice spacings, each further bounce only from hits
        nearer than _NEAR_SPACINGS; glossy hits always; elsewhere the hit's indirect light is
        the cache's), the Sun exact (a shadow
        ray) at every vertex, the cache beyond the last (E ≈ π·L_in at each vertex). Light
        bounced several times within a gap narrower than the cache's lattice is then traced,
        not interpolated: the cache's error there reaches the pixel multiplied once more by
        the gap's albedo-weighted view factor at every traced bounce. At a glossy hit the path
        follows the part's lobe instead and estimates its specular reflection
        (:func:`raytrace._gather.bounce2_rays`): a gold foil facing a lit wall reflects the wall,
        not the average of its surroundings."""
        return self._bounces(o, d, h, hu, hv, keys, seed, _GATHER_BOUNCES,
                             first_near_m=_FIRST_NEAR_SPACINGS * self.cache.spacing_m)

    def _continued(self, h, near_m):
        """Which rays' hits a traced path continues from: those nearer than ``near_m`` (the
        rays' directions unit) and every glossy hit, whose reflection the cache's irradiance
        cannot stand in for."""
        go = h["tfar"] < near_m
        hit = h["geomID"] >= 0
        if self.glossy.any() and hit.any():
            sc = self.scene
            f = sc.face_offset[h["geomID"][hit]] + h["primID"][hit]
            go[hit] |= self.glossy[sc.component_of_face[f]]
        return go

    def _bounces(self, o, d, h, hu, hv, keys, seed, levels, first_near_m=None):
        """:meth:`_traced_indirect` for rays (o, d) with hits h, ``levels`` bounces deep; with
        ``first_near_m``, the first bounce only from hits :meth:`_continued` at that distance
        (the others take the cache's indirect light)."""
        m = len(d)
        e_ind = np.empty((m, 3))
        _rows.hit_or_miss_rows(h["geomID"], e_ind)  # directions below the surface carry nothing
        if levels <= 0 or not (h["geomID"] >= 0).any():
            e_ind.fill(-1.0)
            return e_ind
        want = np.empty(m, dtype=bool)
        o2 = np.empty((m, 3))
        d2 = np.empty((m, 3))
        w2 = np.empty((m, 3))
        sc = self.scene
        _gather.bounce2_rays(o, d, h["tfar"].astype(np.float64), h["geomID"], h["primID"], hu, hv, sc.face_offset,
                             sc.face_normal, sc.corner_normal, sc.component_of_face, self.glossy, self.f0, self.alpha,
                             keys, seed, self.eps, want, o2, d2, w2)
        if first_near_m is not None:
            go = self._continued(h, first_near_m)
            want &= go
            e_ind[(h["geomID"] >= 0) & ~go] = -1.0
        idx = np.flatnonzero(want)
        if len(idx):
            o2c, d2c = np.empty((len(idx), 3)), np.empty((len(idx), 3))
            _rows.take_rows(o2, idx, o2c)
            _rows.take_rows(d2, idx, d2c)
            o2, d2 = o2c, d2c
            h2 = sc.intersect(o2, d2)
            hu2, hv2 = h2["u"].astype(np.float64), h2["v"].astype(np.float64)
            vis2 = self._bounce_sun(o2, d2, h2)
            e2 = np.full((len(idx), 3), -1.0)  # beyond the last traced bounce: the cache
            if levels > 1:
                # continued: hits within _NEAR_SPACINGS lattice spacings (d2 is unit), and every
                # glossy hit
                near = np.flatnonzero(self._continued(h2, _NEAR_SPACINGS * self.cache.spacing_m))
                if len(near):
                    # keys * 4 + 1: the next bounce's samples, distinct per sample and depth
                    e2[near] = self._bounces(o2[near], d2[near], {k: v[near] for k, v in h2.items()}, hu2[near],
                                             hv2[near], keys[idx][near] * 4 + 1, seed, levels - 1)
            L2 = np.empty((len(idx), 3))
            _gather.incoming_rays(o2, d2, h2["geomID"], h2["primID"], hu2, hv2, *self._lookup(), vis2, e2, L2)
            _rows.put_weighted_rows(idx, L2, w2, e_ind)
        return e_ind

    def _bounce_sun(self, o, d, h):
        """The Sun's visibility (0/1) at the hits of rays (o, d) from one shadow ray each; −1 at
        misses (the environment needs none)."""
        light = self.lighting
        if light.sun_irradiance_at_target_W_m2 <= 0.0 or not len(d):
            return np.full(len(d), -1.0)
        vis = np.empty(len(d))
        _rows.hit_or_miss(h["geomID"], vis)
        sx, sy, sz = light.sun_dir_body
        want = np.empty(len(d), dtype=bool)
        so = np.empty((len(d), 3))
        _gather.bounce_sun_rays(o, d, h["tfar"].astype(np.float64), h["geomID"], h["primID"], self.scene.face_offset,
                                self.scene.face_normal, sx, sy, sz, self.eps, want, so)
        idx = np.flatnonzero(want)
        if len(idx):
            blocked = self.scene.occluded(so[idx], np.broadcast_to(np.float32([sx, sy, sz]), (len(idx), 3)))
            vis[idx[~blocked]] = 1.0
        return vis

    def _lookup(self):
        """Arguments of :func:`raytrace._surface.incoming` after the ray."""
        sc, c = self.scene, self.cache
        return (sc.face_offset, sc.face_normal, sc.corner_normal, sc.component_of_face, self.diff, self.f0,
                self.alpha, self.glossy, self.table, self.sun, self.cf.irradiance_W_m2, self.cf.sun_irradiance_W_m2, c.valid,
                c.face_s, c.lat_start, c.lat_ids, self.p, self.tex)

    def add_diffuse(self, s, E, L):
        _surface.add_diffuse(E, s["comp"], self.diff, L)


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
    take nor give), ``guide`` = (normals, depths, fx, fy, cx, cy) of that image: rows (n, 3).

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
    ``inst`` and ``guide`` = (normals, depths, fx, fy, cx, cy): the filtered image and its
    variances (σ_l = 0: geometry only). They are new arrays, or, with ``overwrite``, may be
    ``img`` and ``var`` themselves (one image less in memory)."""
    if not overwrite:
        img, var = img.copy(), var.copy()
    tmp, var_tmp = np.zeros_like(img), np.zeros_like(var)
    var_blur, lum = np.zeros_like(var), np.zeros_like(var)
    normal, depth, fx, fy, cx, cy = guide
    for k in range(passes):
        if sigma_l > 0.0:
            _filter.guide_images(img, var, inst, lum, var_blur)
        _filter.atrous(img, var, var_blur, lum, inst, normal, depth, fx, fy, cx, cy, 1 << k, sigma_l, tmp, var_tmp)
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
           geometry: GeometryFrame | None = None, cache_options: dict | None = None) -> RenderFrame:
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
        _stars(rad, scene, camera, R, t, lighting, timings)
        return RenderFrame(geo, rad, q, timings)

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
    pix = np.flatnonzero(geo.instance.ravel() > 0)
    O = np.empty((len(pix), 3))
    D = np.empty((len(pix), 3))
    centre_rays(pix, W, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, O, D)
    face = geo.face_index.ravel()[pix].astype(np.int64)
    s = _surfaces(scene, O, D, face)
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
        _background.earth_background(geo.instance, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy,
                                     sunl.p_background, sunl.tex, _BACKGROUND_STEP, _BACKGROUND_TOL,
                                     _BACKGROUND_CHORD, earth_px, rad.reshape(H, W, 3))
        _check_finite("background", rad)
    epix = _aa_pixels(q, scene, camera, R, t, o_body, geo, lighting, sunl, s, vis, pix, lit_img, earth_px,
                      earth_drawn)
    traced = None
    if len(epix) and len(epix) <= _aa_chunk_pixels(q.aa_grid):
        traced = _trace_chunk(sunl, scene, camera, R, t, o_body, geo, epix, q.aa_grid, int(seed), q.cov_grid)
    t_early = time.perf_counter() - t0
    t0 = time.perf_counter()
    ctx = pending.result() if pending is not None else \
        _Context(scene, lighting, cache_options, prefiltered_glossy=q.gather_rays == 0)
    timings["cache"] = time.perf_counter() - t0
    t0 = time.perf_counter() - t_direct  # the Sun at the centres counts in "direct"
    lbar = np.zeros((len(pix), 3))
    E = ctx.cache_E(s)
    ctx.add_mirror(s, E, L, mirror, lbar)
    if penumbra is not None:
        cand, dL = penumbra
        L[cand] += dL
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
                 camera.fx, camera.fy, camera.cx - u0, camera.cy - v0)
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
        sub = _supersample(ctx, scene, camera, R, t, o_body, geo, epix, q.aa_grid, int(seed), centre_light,
                           q.aa_gather_rays, centre, q.cov_grid, q.borrow, q.own_at_boundary, contrast, traced)
        del traced
        if n_extra:
            # the highest contrast first, ties in pixel order; then back in pixel order
            sel = np.sort(np.argsort(-contrast, kind="stable")[:n_extra])
            sub2 = _supersample(ctx, scene, camera, R, t, o_body, geo, epix[sel], q.aa_grid,
                                int(seed) ^ AA_SECOND_STREAM, centre_light, q.aa_gather_rays, centre, q.cov_grid,
                                q.borrow, q.own_at_boundary)
            sub[sel] = 0.5 * (sub[sel] + sub2)
        _check_finite("anti-aliasing", sub)
        _rows.put_rows_nonnegative(epix, sub, rad)
    if q.box_grid > 1 and len(pix):
        # every other target pixel: its area mean from box_grid² sub-samples, which take the
        # centres' filtered light interpolated on their surface (none near a boundary casts a gather
        # of its own; one on another surface than its centre's, rare here, does)
        rest = np.setdiff1d(pix, epix, assume_unique=True)
        if len(rest):
            box = _supersample(ctx, scene, camera, R, t, o_body, geo, rest, q.box_grid, int(seed) ^ BOX_STREAM,
                               centre_light, q.aa_gather_rays, centre, borrow=q.borrow)
            _check_finite("area means", box)
            _rows.put_rows_nonnegative(rest, box, rad)
    timings["antialias"] = time.perf_counter() - t0
    rad = rad.reshape(H, W, 3)
    _stars(rad, scene, camera, R, t, lighting, timings)
    return RenderFrame(geo, rad, q, timings)


def _aa_pixels(q: Quality, scene: Scene, camera: Camera, R, t, o_body, geo, lighting: Lighting, sunl: _Sunlight, s,
               vis, pix, lit_img, earth_px, earth_drawn: bool) -> np.ndarray:
    """The pixels :func:`render` anti-aliases (flat indices, ascending): where 4-neighbours
    disagree (:func:`raytrace._edges.edge_pixels`: id, Earth, lit/shadowed, crease, depth
    step), and as the preset asks, where a rod's shadow thinner than a pixel may fall
    (:func:`_thin_shadow_pixels`), where a pixel corner sees another part or Sun than its
    centre (:func:`_corner_edges`) and where a triangle thinner than a pixel lies
    (:func:`raytrace._edges.sliver_pixels`). Needs no radiance cache."""
    H, W = camera.height, camera.width
    if earth_drawn:
        check = np.array([0, 0, W, H])
    else:
        u0, v0, u1, v1 = geo.cast_rect
        check = np.array([max(u0 - 1, 0), max(v0 - 1, 0), min(u1 + 1, W), min(v1 + 1, H)])
    if not (q.aa_grid > 1 and check[2] > check[0] and check[3] > check[1]):
        return np.zeros(0, dtype=np.int64)
    corners = _corner_rays(scene, camera, R, t, o_body, geo) if q.corner_rays else None
    edges = np.zeros((H, W), dtype=bool)
    _edges.edge_pixels(geo.instance, lit_img.reshape(H, W), geo.normal_cam, geo.depth_m, earth_px, check, edges)
    sun_corners = q.sun_corners and lighting.sun_irradiance_at_target_W_m2 > 0.0
    if sun_corners and q.thin_shadows and len(pix):
        thin = _thin_shadow_pixels(scene, s, vis, geo.depth_m.ravel()[pix].astype(np.float64) / camera.fx,
                                   lighting.sun_dir_body)
        edges.ravel()[pix[thin]] = True
    if corners is not None:  # (``fast`` casts none)
        edges |= _corner_edges(scene, geo, corners, lit_img.reshape(H, W) if sun_corners else None,
                               lighting.sun_dir_body, sunl.eps)
    if q.slivers:
        _edges.sliver_pixels(scene.vertices, scene.faces, R, t, camera.fx, camera.fy, camera.cx, camera.cy,
                             1e-6 * scene.scale_m, 1.0, geo.depth_m, edges)
    return np.flatnonzero(edges.ravel())


def _stars(rad, scene: Scene, camera: Camera, R, t, lighting: Lighting, timings: dict) -> None:
    """The stars of ``lighting`` into the background of ``rad`` (H, W, 3), in place."""
    if lighting.stars is None:
        return
    from .stars import add_stars
    t0 = time.perf_counter()
    add_stars(rad, lighting.stars, lighting.R_body_from_eci, scene, camera, R, t, lighting.earth)
    _check_finite("stars", rad)
    timings["stars"] = time.perf_counter() - t0


def _earth_may_be_in_view(camera: Camera, R, lighting: Lighting) -> bool:
    """Earth's disc can overlap the field of view (cone test, conservative)."""
    e_cam = R @ np.asarray(lighting.earth.earth_dir_body)
    half_diag = math.atan(math.hypot(max(camera.cx + 0.5, camera.width - 0.5 - camera.cx) / camera.fx,
                                     max(camera.cy + 0.5, camera.height - 0.5 - camera.cy) / camera.fy))
    angle = math.acos(max(-1.0, min(1.0, float(e_cam[2]))))
    return angle <= half_diag + lighting.earth.angular_radius_rad + 1e-6


def _thin_shadow_pixels(scene: Scene, s, vis, foot, sun_dir) -> np.ndarray:
    """Which of the lit surface points ``s`` (rows of the target pixels; ``foot`` their pixel
    footprints [m]) may hold the shadow of a rod or wire thinner than a pixel, which the centre
    and corner probes can both miss: a conservative shadow map of the triangles that are
    slivers seen from the Sun (:func:`raytrace._edges.shadow_map_of_slivers`, cells of the
    median footprint, slivers narrower than 1.5 cells) and a look-up over each footprint
    (:func:`raytrace._edges.near_shadow_slivers`)."""
    lit = vis >= 0.5
    out = np.zeros(len(vis), dtype=bool)
    if not lit.any():
        return out
    sdir = np.asarray(sun_dir, dtype=np.float64)
    a = np.array([1.0, 0.0, 0.0]) if abs(sdir[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(sdir, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(sdir, e1)
    V = scene.vertices
    pa, pb = V @ e1, V @ e2
    cell = float(np.median(foot[lit]))
    if not (np.isfinite(cell) and cell > 0.0):
        return out
    span = max(pa.max() - pa.min(), pb.max() - pb.min())
    cell = max(cell, span / 2048.0)  # at most 2048² cells (34 MB)
    a0, b0 = pa.min() - cell, pb.min() - cell
    nx = int((pa.max() - a0) / cell) + 2
    ny = int((pb.max() - b0) / cell) + 2
    grid = np.full((ny, nx), -np.inf)
    _edges.shadow_map_of_slivers(V, scene.faces, e1, e2, sdir, a0, b0, cell, 1.5 * cell, grid)
    _edges.near_shadow_slivers(s["P"], s["NS"], s["WO"], lit, foot, e1, e2, sdir, a0, b0, cell, grid, out)
    return out


def _background_params(lighting: Lighting):
    """The environment's parameter vector and texture as the background draws them: Earth
    without the ambient sky (the sky lights the target but is not drawn)."""
    p, tex = lighting.packed()
    p[env.P_AMBIENT] = 0.0
    return p, tex


def _corner_rays(scene: Scene, camera: Camera, R, t, o_body, geo):
    """One ray through every pixel corner of the cast rectangle (:func:`_corner_edges`): the
    rays (float32, body frame) and their closest hits, or None when the rectangle is empty."""
    from ._kernels import make_rays
    u0, v0, u1, v1 = geo.cast_rect
    w, h = u1 - u0 + 1, v1 - v0 + 1
    if u1 <= u0 or v1 <= v0:
        return None
    z0 = 0.0 if geo.camera_inside_hull else scene._near_plane(scene.hull_vertices @ R.T + t)
    o32 = np.empty((h * w, 3), dtype=np.float32)
    d32 = np.empty((h * w, 3), dtype=np.float32)
    make_rays(o_body, np.ascontiguousarray(R.T), camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5, u0, v0, w,
              h, z0, o32, d32)
    return o32, d32, scene.intersect(o32, d32, robust=z0 <= 0.0)


def _corner_edges(scene: Scene, geo, corners, lit=None, sun_dir=None, eps: float = 0.0) -> np.ndarray:
    """Pixels containing geometry their centre ray missed: one extra ray through every pixel
    corner of the cast rectangle (shared by four pixels, so about one ray per pixel; ``corners``
    from :func:`_corner_rays`); a pixel whose corners see another part than its centre holds a
    sub-pixel feature (a mast, a gap between panels, a thin wing seen edge-on) and must be
    supersampled. Features wider than 0.71 px are always caught; thinner ones only where they
    cross a corner."""
    H, W = geo.instance.shape
    u0, v0, u1, v1 = geo.cast_rect
    out = np.zeros((H, W), dtype=bool)
    w, h = u1 - u0 + 1, v1 - v0 + 1
    if corners is None:
        return out
    o32, d32, hc = corners
    corner = (hc["geomID"] + 1).reshape(h, w)
    centre = geo.instance[v0:v1, u0:u1].astype(corner.dtype)
    out[v0:v1, u0:u1] = ((corner[:-1, :-1] != centre) | (corner[:-1, 1:] != centre) | (corner[1:, :-1] != centre)
                         | (corner[1:, 1:] != centre))
    if lit is not None:
        # the Sun at every corner hit: a pixel whose corners and centre disagree holds a
        # shadow edge, or the shadow of a rod thinner than a pixel that its centre missed
        n = h * w
        sx, sy, sz = sun_dir
        want = np.empty(n, dtype=bool)
        so = np.empty((n, 3))
        O = np.ascontiguousarray(o32, dtype=np.float64)
        D = np.ascontiguousarray(d32, dtype=np.float64)
        _gather.bounce_sun_rays(O, D, hc["tfar"].astype(np.float64), hc["geomID"], hc["primID"], scene.face_offset,
                                scene.face_normal, sx, sy, sz, eps, want, so)
        idx = np.flatnonzero(want)
        c_lit = np.zeros(n, dtype=bool)
        if len(idx):
            c_lit[idx] = ~scene.occluded(so[idx], np.broadcast_to(np.float32([sx, sy, sz]), (len(idx), 3)))
        c_lit = c_lit.reshape(h, w)
        lc = lit[v0:v1, u0:u1] & (centre > 0)
        out[v0:v1, u0:u1] |= (centre > 0) & ((c_lit[:-1, :-1] != lc) | (c_lit[:-1, 1:] != lc) | (c_lit[1:, :-1] != lc)
                                             | (c_lit[1:, 1:] != lc))
    return out


def _supersample(ctx: _Context, scene: Scene, camera: Camera, R, t, o_body, geo, epix, n_grid, seed: int,
                 centre_light=None, gather_rays: int = 0, centre_surface=None, cov_grid: int = 0, borrow: bool = False,
                 own_at_boundary: bool = False, contrast_out=None, traced=None):
    """Box-filtered radiance of the listed pixels from n_grid² correlated multi-jittered
    sub-pixel rays (:func:`raytrace._edges.subpixel_rays`). Each sub-sample is shaded like a
    ``fast`` pixel (exact Sun, cache, mirror term); with ``centre_light`` (the centres' filtered
    gathered irradiance and filtered lobe corrections, ``balanced``) a sub-sample on the same surface as its
    pixel centre (same part, normals within 25°, within a pixel footprint of the centre's
    tangent plane: ``centre_surface`` = (row of each pixel, −1 off
    the target, and per row the centre's point, normal and footprint; ``centre_light`` is per row
    too, and needs it)) takes the irradiance of the (up to) four pixel centres around it
    on that surface, interpolated bilinearly at its image position, instead of the cache's
    (and adds their lobe corrections, interpolated the same way),
    so edge pixels carry the same
    indirect light as their neighbours; any other sub-sample (another part, the far side of a
    crease, another rod of a truss) gets its own final gather and lobe samples (the centre's
    light there was wrong, black or twice the truth); with ``borrow`` it first
    tries the filtered irradiance of the nearest neighbouring centre on its own surface. Misses
    see Earth or black space.

    With ``cov_grid`` ≥ 2, coverage and shading are estimated apart (as multisample
    anti-aliasing does): cov_grid² further primary rays, which cost a ray each and no shading,
    give the fraction of the pixel each part (or space) covers; the shaded sub-samples give
    each part's mean radiance. A part the shaded sub-samples missed is shaded at one of its
    coverage rays. The estimate of where the silhouette and the part boundaries run then has
    the noise of cov_grid² + n_grid² samples, not n_grid².

    With ``contrast_out`` (one per pixel), it receives the squared contrast each pixel's shaded
    sub-samples saw (:func:`raytrace._rows.subsample_contrast`).

    The pixels go through in chunks of about presets.CHUNK_RAYS sub-samples (every sample is keyed
    by its pixel and number, so the result does not depend on the chunking): the arrays of
    all of them at once (~600 k rows on Tiangong at 1280×960) were mapped fresh on every
    frame, and their page faults cost more than the shading. Each chunk is traced
    (:func:`_trace_chunk`: rays, hits, the Sun; no radiance cache) and then shaded
    (:func:`_shade_chunk`); ``traced``, if given, is the trace of ``epix`` as one chunk
    (:func:`render` traces it while the context is solved on its side thread)."""
    per = _aa_chunk_pixels(n_grid)
    if len(epix) <= per:
        if traced is None:
            traced = _trace_chunk(ctx, scene, camera, R, t, o_body, geo, epix, n_grid, seed, cov_grid)
        return _shade_chunk(ctx, camera, geo, traced, seed, centre_light, gather_rays, centre_surface, borrow,
                            own_at_boundary, contrast_out)
    def chunk(i):
        tr = _trace_chunk(ctx, scene, camera, R, t, o_body, geo, epix[i:i + per], n_grid, seed, cov_grid)
        return _shade_chunk(ctx, camera, geo, tr, seed, centre_light, gather_rays, centre_surface, borrow,
                            own_at_boundary, None if contrast_out is None else contrast_out[i:i + per])

    starts = range(0, len(epix), per)
    # The chunks two at a time (presets.AA_CHUNKS_ON_TWO_THREADS): a chunk's Python and NumPy
    # steps run on one core, which the other chunk's kernels then use. Each chunk's samples are
    # keyed by pixel, so the same bytes (tests/raytrace/test_shading.py); 12 benchmark scenes,
    # median per-scene time ratio 0.95 for ``balanced``-16 and -64 (BENCHMARKS.md). ``fast``'s
    # anti-aliasing is one chunk on all of them.
    if presets.AA_CHUNKS_ON_TWO_THREADS and numba.get_num_threads() > 1:
        return np.concatenate([f.result() for f in [_submit("aa", 2, chunk, i) for i in starts]])
    return np.concatenate([chunk(i) for i in starts])


def _aa_chunk_pixels(n_grid: int) -> int:
    """Pixels per chunk of :func:`_supersample` (about presets.CHUNK_RAYS sub-samples)."""
    return max(1, presets.CHUNK_RAYS // (n_grid * n_grid))


def _trace_chunk(sunl: _Sunlight, scene: Scene, camera: Camera, R, t, o_body, geo, epix, n_grid, seed: int,
                 cov_grid: int) -> dict:
    """What :func:`_supersample` finds of one chunk of pixels without the radiance cache: the
    sub-pixel rays and their hits, and at the hits the surfaces, the Sun (solar-disc shadow
    rays) and the mirror rays (:func:`_trace_subsamples`); with ``cov_grid`` ≥ 2 the coverage
    rays of the pixels whose sub-samples saw more than one part and the first coverage ray of
    each part no sub-sample saw, traced the same way. :func:`_shade_chunk` finishes it."""
    S = n_grid * n_grid
    W = camera.width
    R_bc = np.ascontiguousarray(R.T)
    z0 = 0.0 if geo.camera_inside_hull else scene._near_plane(scene.hull_vertices @ R.T + t)
    D = np.empty((len(epix) * S, 3))
    _edges.subpixel_rays(epix.astype(np.int64), W, n_grid, seed, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, D)
    h = _intersect_from(scene, o_body, z0, D)
    centre = np.repeat(epix, S)
    number = np.tile(np.arange(S), len(epix))
    tr = {"epix": epix, "S": S, "R_cam": np.ascontiguousarray(R, dtype=np.float64), "mixed": None,
          "sub": _trace_subsamples(sunl, scene, o_body, D, h, centre, number, S, seed)}
    if cov_grid < 2:
        return tr

    def groups(hh):
        g = np.empty(len(hh["geomID"]), dtype=np.int64)
        _edges.ray_groups(hh["geomID"], hh["primID"], scene.face_offset, scene.component_of_face, g)
        return g

    # coverage rays only where the shaded sub-samples saw more than one part (or space):
    # shadow edges and creases within one part need none
    g_s = groups(h).reshape(len(epix), S)
    mixed = np.flatnonzero((g_s != g_s[:, :1]).any(axis=1))
    if not len(mixed):
        return tr
    mpix = epix[mixed]
    C = cov_grid * cov_grid
    Dc = np.empty((len(mpix) * C, 3))
    _edges.subpixel_rays(mpix.astype(np.int64), W, cov_grid, (seed + COVERAGE_STREAM) & 0x7FFFFFFF, R_bc, camera.fx,
                         camera.fy, camera.cx, camera.cy, Dc)
    hc = _intersect_from(scene, o_body, z0, Dc)
    g_c = groups(hc).reshape(len(mpix), C)
    g_m = np.ascontiguousarray(g_s[mixed])
    # parts seen only by coverage rays: shade the first such ray of each
    first_of = np.zeros((len(mpix), C), dtype=bool)
    _edges.coverage_unshaded_first(g_m, g_c, first_of)
    first = np.flatnonzero(first_of.ravel())
    tr.update(mixed=mixed, C=C, g_m=g_m, g_c=g_c, first_of=first_of, first=first)
    if len(first):
        hx = {k: v[first] for k, v in hc.items()}
        tr["cov"] = _trace_subsamples(sunl, scene, o_body, Dc[first], hx, np.repeat(mpix, C)[first], S + first % C,
                                      S + C, seed)
    return tr


def _shade_chunk(ctx: _Context, camera: Camera, geo, tr: dict, seed: int, centre_light, gather_rays: int,
                 centre_surface, borrow: bool, own_at_boundary: bool, contrast_out=None):
    """:func:`_supersample` of one chunk of pixels traced by :func:`_trace_chunk`
    (``contrast_out``: a view of its rows)."""
    epix, S, R_cam = tr["epix"], tr["S"], tr["R_cam"]
    L = _shade_subsamples(ctx, geo, camera, R_cam, tr["sub"], S, seed, centre_light, gather_rays, centre_surface,
                          borrow, own_at_boundary)
    out = np.empty((len(epix), 3))
    _rows.group_means(L, S, out)
    if contrast_out is not None:
        _rows.subsample_contrast(L, S, contrast_out)
    mixed = tr["mixed"]
    if mixed is None:
        return out
    C, first = tr["C"], tr["first"]
    L_c = np.zeros((len(mixed) * C, 3))
    if len(first):
        L_c[first] = _shade_subsamples(ctx, geo, camera, R_cam, tr["cov"], S + C, seed, centre_light, gather_rays,
                                       centre_surface, borrow, own_at_boundary)
    res = np.empty((len(mixed), 3))
    _edges.coverage_combine(tr["g_m"], np.ascontiguousarray(L.reshape(len(epix), S, 3)[mixed]), tr["g_c"],
                            tr["first_of"], L_c.reshape(len(mixed), C, 3), res)
    out[mixed] = res
    return out


def _intersect_from(scene: Scene, o_body, z0: float, D):
    """Closest hits of the rays from the camera centre o_body along D (float64), started at
    the plane z_cam = z0 (:meth:`Scene.intersect`): in the scene the labels are cast in
    (robust) where z0 = 0, the camera inside the target's hull, where it may lie on a face
    (only Embree's robust mode reports that face, at t = 0, as the labels do); else, the rays
    starting in front of the target, in the faster one."""
    o32 = np.empty(D.shape, np.float32)
    d32 = np.empty(D.shape, np.float32)
    ray_origins32(np.asarray(o_body, dtype=np.float64), float(z0), D, o32, d32)
    return scene.intersect(o32, d32, robust=z0 <= 0.0)


def _trace_subsamples(sunl: _Sunlight, scene: Scene, o_body, D, h, centre, number, S, seed) -> dict:
    """What the shading of sub-pixel rays D (hits h) of pixels ``centre`` needs that is not the
    radiance cache (:func:`_shade_subsamples` finishes it): at the hits the surfaces, the Sun
    (one solar-disc shadow ray each) and the mirror rays; along the misses Earth or black space.
    ``number`` (< S) is each ray's index within its pixel (it keys the solar-disc and gather
    samples)."""
    hit = h["geomID"] >= 0
    idx = np.flatnonzero(hit)
    tr = {"n": len(D), "idx": idx, "miss": None}
    if len(idx):
        face = np.empty(len(idx), np.int64)
        Dh = np.empty((len(idx), 3))
        c_idx = np.empty(len(idx), np.int64)  # each hit's pixel
        n_idx = np.empty(len(idx), np.int64)  # and its number there
        _rows.subsample_hits(idx, h["geomID"], h["primID"], scene.face_offset, D, np.asarray(centre, np.int64),
                             np.asarray(number, np.int64), face, Dh, c_idx, n_idx)
        s = _surfaces(scene, np.asarray(o_body, np.float64).reshape(1, 3), Dh, face)  # one origin for all
        disc = None
        if sunl.lighting.sun_angular_diameter_rad > 0.0 and S > 1:
            # one solar-disc sample per sub-sample, stratified over the pixel's S sub-samples in
            # strata permuted per pixel, independent of the sub-samples' cells
            disc = (c_idx, n_idx, S, seed)
        Ls, _ = sunl.sunlight(s, disc=disc)
        tr.update(s=s, Dh=Dh, c_idx=c_idx, n_idx=n_idx, Ls=Ls, mirror=sunl.mirror_hits(s))
    miss = np.flatnonzero(~hit)
    if len(miss) and sunl.lighting.earth is not None:
        Dm = D[miss] / np.linalg.norm(D[miss], axis=1, keepdims=True)
        out = np.empty((len(miss), 3))
        _background.env_along(o_body, np.ascontiguousarray(Dm), sunl.p_background, sunl.tex, out)
        tr["miss"] = (miss, out)
    return tr


def _shade_subsamples(ctx: _Context, geo, camera: Camera, R_cam, tr: dict, S, seed, centre_light, gather_rays,
                      centre_surface, borrow, own_at_boundary=False):
    """Radiance along the sub-pixel rays traced by :func:`_trace_subsamples` (of a camera with
    pose R_cam = R_cam_from_body): the cache's light and the mirror term added to the Sun's,
    and with ``centre_light`` the centres' filtered gathered irradiance in place of the cache's and
    their lobe corrections (or the sub-sample's own gather)."""
    L = np.zeros((tr["n"], 3))
    idx = tr["idx"]
    if len(idx):
        s, Dh, c_idx, n_idx, Ls = tr["s"], tr["Dh"], tr["c_idx"], tr["n_idx"], tr["Ls"]
        E = ctx.cache_E(s)
        lbar = np.zeros((len(idx), 3))
        ctx.add_mirror(s, E, Ls, tr["mirror"], lbar)
        if centre_light is not None:
            row_of_pixel, P_c, N_c, foot = centre_surface
            k = np.empty(len(idx), dtype=np.int64)
            H, W = geo.instance.shape
            _edges.donor_rows(c_idx, W, H, s["comp"], s["P"], s["NS"], row_of_pixel,
                              geo.instance.ravel(), P_c, N_c, foot, borrow, k)
            # on its own pixel centre's surface: the filtered irradiance (centre_light[0], in place
            # of the cache's, which is kept only where no centre's applies) and lobe corrections
            # of the (up to) four centres around it on that surface, interpolated bilinearly,
            # not the centre's alone (a contact shadow or the light of a neighbouring part varies
            # within the pixel)
            own = np.flatnonzero((k >= 0) & (k == row_of_pixel[c_idx]))
            added = np.empty(len(own), dtype=np.bool_)
            _edges.interpolate_rows_into(own, Dh, R_cam, camera.fx, camera.fy, camera.cx, camera.cy, W, H, s["comp"],
                                         s["P"], s["NS"], row_of_pixel, geo.instance.ravel(), P_c, N_c, foot,
                                         centre_light[0], centre_light[1], 4 if own_at_boundary else 1, E, Ls, added)
            k[own] = -2  # done; −1: none
            if own_at_boundary:
                k[own[~added]] = -1  # near its surface's boundary: its own gather below
            _rows.take_add_rows(k, centre_light[0], centre_light[1], E, Ls)  # where k ≥ 0: a neighbouring centre's
            # below _MIN_SUB_GATHER rays an unfiltered gather is noisier than the cache is wrong
            j = np.flatnonzero(k == -1)
            if len(j) and gather_rays >= _MIN_SUB_GATHER:
                keys = c_idx[j] * S + n_idx[j]  # the samples' keys, distinct per sub-sample
                if ctx.lobe_sampled[s["comp"][j]].any():  # the lobe replaces the mirror term
                    sj = {k: s[k][j] for k in ("P", "NS", "NG", "WO", "comp")}
                    Ls[j] += ctx.lobe(sj, gather_rays, keys, seed, lbar[j])
                # the gathers of a pixel's sub-samples: one stratified set of its own sequence
                # (a stream apart from its centre's gather), their paths keyed per sub-sample
                E[j] = ctx.gather_E(s, gather_rays, keys, seed ^ SUB_GATHER_STREAM, path_seed=seed, share=S, rows=j)
        ctx.add_diffuse(s, E, Ls)
        _rows.put_rows(idx, Ls, L)
    if tr["miss"] is not None:
        miss, out = tr["miss"]
        L[miss] = out
    return L
