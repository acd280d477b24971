"""The lighting context of a frame (:func:`raytrace.shade.render`): :class:`_Sunlight`, what the
Sun's term and the background need (no radiance cache), and :class:`_Context`, that and the
radiance cache's solution under the frame's lighting, with the methods that drive the shading
kernels: sunlight and soft shadows, mirror rays and the mirror term, the final gather (fused or
batched, the paths traced from its hits), the glossy-lobe sampling and the cache's irradiance.
"""

from __future__ import annotations

import math

import numpy as np

from . import _gather, _paths, _rows, _surface, environment as env, presets
from ._sampling import LOBE_PATH_STREAM
from ._threads import parallel_chunksize
from .brdf import split_sum_table
from .lighting import Lighting
from .scene import Scene
from .surfaces import point_materials


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


def _surfaces(scene: Scene, O, D, face, px_rad: float = 0.0) -> dict:
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
    point_materials(scene, out, O, px_rad)
    return out


class _Sunlight:
    """What the Sun's term and the background need of a frame's lighting: no radiance cache.
    :func:`raytrace.shade.render` makes one on its own thread and shades the Sun (shadow rays, soft shadows,
    the sub-samples' solar-disc rays) and finds the edges to anti-alias with it while the
    :class:`_Context` (a subclass: these and the cache's solution) is built on a side thread."""

    def __init__(self, scene: Scene, lighting: Lighting, prefiltered_glossy: bool = False):
        self.scene = scene
        self.lighting = lighting
        self.sun = lighting.sun_record()  # the Sun as the kernels take it (raytrace._lights)
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
        self.mat_par, self.face_uv, self.atlas, self.varying = scene.material_tables
        self.px_rad = 0.0  # the angle a pixel spans, where the frame's camera sets it (procedural materials)

    def _mats(self, s):
        """(comp, diff, f0, alpha, rows) as the kernels index the materials of the points ``s``:
        the components' rows, or where the points carry their own (:func:`point_materials`)
        the components' rows followed by one row per point, point k at row n_comp + k (rows:
        how many component rows come first)."""
        if "m_diff" not in s:
            return s["comp"], self.diff, self.f0, self.alpha, 0
        cached = getattr(self, "_mats_of", None)
        if cached is not None and cached[0] is s["m_diff"]:  # the same points as last time
            return cached[1]
        C = len(self.diff)
        out = (C + np.arange(len(s["m_alpha"]), dtype=np.int64), np.concatenate([self.diff, s["m_diff"]]),
               np.concatenate([self.f0, s["m_f0"]]), np.concatenate([self.alpha, s["m_alpha"]]), C)
        self._mats_of = (s["m_diff"], out)
        return out

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
            _surface.sun_rays(s["P"], s["NS"], s["NG"], self.sun, self.eps, want, o)
            idx = np.flatnonzero(want)
            direct = None
            if presets.FUSED_GATHER and occluder_t is None:
                direct = self.scene.direct if robust else self.scene.direct_fast
            if len(idx) and direct is not None:
                # the disc samples drawn and the shadow rays cast in one kernel
                pixel, number, n_strata, seed = disc if disc is not None else (idx, idx, 0, 0)
                _paths.sun_visibility(direct.handle, idx, s["P"], s["NG"], self.sun, self.eps,
                                      np.asarray(pixel, np.int64), np.asarray(number, np.int64), int(n_strata),
                                      int(seed), vis)
            elif len(idx):
                if disc is None:
                    d = np.broadcast_to(np.float32([sx, sy, sz]), (len(idx), 3))
                else:
                    # (float32: they only steer shadow rays)
                    d = np.empty((len(idx), 3), np.float32)
                    pixel, number, n_strata, seed = disc
                    _surface.sun_disc_dirs(pixel[idx], number[idx], n_strata, seed, self.sun, d)
                if occluder_t is None:
                    blocked = self.scene.occluded(o[idx], d, robust=robust)
                else:
                    h = self.scene.intersect(o[idx], d, robust=robust)
                    blocked = h["geomID"] >= 0
                    occluder_t[idx[blocked]] = h["tfar"][blocked]
                vis[idx[~blocked]] = 1.0
            kc, kd, kf, ka, _ = self._mats(s)
            _surface.shade_sun(s["NS"], s["WO"], kc, kd, kf, ka, self.sun, vis, L)
        return L, vis

    def mirror_hits(self, s):
        """The mirror rays of the specular points of ``s`` and their closest hits, as
        :meth:`_Context.add_mirror` takes them: (rows, origins, directions, hits), or None where
        no point is specular. Where the glossy term is prefiltered (``fast``: every specular point
        casts its mirror ray) the rays are gathered and rounded to float32 by a kernel
        (:func:`raytrace._rows.take_ray_rows`, not NumPy's fancy indexing: the same arrays)."""
        if "m_f0" in s:
            f0 = s["m_f0"]
            spec = np.maximum(np.maximum(f0[:, 0], f0[:, 1]), f0[:, 2]) > 0.0  # f0.max(axis=1) > 0, faster
        else:
            spec = self.specular[s["comp"]]
        if not spec.any():
            return None
        n = len(s["P"])
        o = np.empty((n, 3))
        d = np.empty((n, 3))
        _surface.mirror_rays(s["NS"], s["NG"], s["WO"], s["P"], self.eps, spec, o, d)
        idx = np.flatnonzero(spec)
        if self.prefiltered_glossy:
            m = len(idx)
            oi, di = np.empty((m, 3)), np.empty((m, 3))
            o32, d32 = np.empty((m, 3), np.float32), np.empty((m, 3), np.float32)
            _rows.take_ray_rows(idx, o, d, oi, di, o32, d32)
            return idx, oi, di, self.scene.intersect(o32, d32)
        # ``balanced`` weights the mirror ray by 1 − t (add_mirror): where t = 1 (wide
        # lobes: paint, aluminium) it needs no ray, and a miss stands in for it
        h = {"geomID": np.full(len(idx), -1, np.int32), "primID": np.zeros(len(idx), np.int32),
             "u": np.zeros(len(idx), np.float32), "v": np.zeros(len(idx), np.float32)}
        if "m_alpha" in s:  # as mirror_weighted, per point
            cast = np.flatnonzero(s["m_alpha"][idx] < _surface.MIRROR_BLEND_A0 + _surface.MIRROR_BLEND_WIDTH)
        else:
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
                               n_rays, seed, self.sun, d)
        o = np.repeat(s["P"][cand] + self.eps * s["NG"][cand], n_rays, axis=0)
        v = 1.0 - self.scene.occluded(o, d).reshape(len(cand), n_rays).mean(axis=1)
        full = np.zeros((len(cand), 3))
        kc, kd, kf, ka, _ = self._mats(s)
        _surface.shade_sun(s["NS"][cand], s["WO"][cand], kc[cand], kd, kf, ka, self.sun, np.ones(len(cand)), full)
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
        kc, level = self._mats(s)[0], self.glossy_level
        if "m_alpha" in s:
            level = np.concatenate([level, level[s["comp"]]])
        _surface.add_mirror(idx, o, d, h["geomID"], h["primID"], h["u"].astype(np.float64),
                            h["v"].astype(np.float64), s["NS"], s["WO"], kc, E_point, *self._lookup(s),
                            self.prefiltered_glossy, self.env_irradiance, self.glossy_env, level, M,
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
            kc = self._mats(s)[0]
            with parallel_chunksize(_FUSED_CHUNK):
                _paths.lobe_traced(direct.handle, idx, s["P"], s["NS"], s["NG"], s["WO"], kc, n_rays, seed,
                                   seed ^ LOBE_PATH_STREAM, np.asarray(pix, dtype=np.int64), self.eps, _GATHER_BOUNCES,
                                   np.float32(_NEAR_SPACINGS * self.cache.spacing_m), *self._lookup(s), lbar, val, v)
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
            kc, _, kf, ka, _ = self._mats(s)
            _gather.lobe_rays(part, s["P"], s["NS"], s["NG"], s["WO"], kc, kf, ka, n_rays, seed, pix, self.eps, o, d, w)
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
        with parallel_chunksize(_FUSED_CHUNK):
            _paths.gather_traced(direct.handle, s["P"], s["NS"], s["NG"], rows, start, first, seeds[0], seeds[1],
                                 pix.astype(np.int64), share, kmul, self.eps, _GATHER_BOUNCES,
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
                                self.scene.face_normal, self.sun, self.eps, want, so)
        idx = np.flatnonzero(want)
        if len(idx):
            blocked = self.scene.occluded(so[idx], np.broadcast_to(np.float32([sx, sy, sz]), (len(idx), 3)))
            vis[idx[~blocked]] = 1.0
        return vis

    def _lookup(self, s=None):
        """Arguments of :func:`raytrace._surface.incoming` after the ray; with points ``s``
        that carry their own materials, the material rows of :meth:`_mats`."""
        sc, c = self.scene, self.cache
        _, diff, f0, alpha, C = self._mats(s) if s is not None else (None, self.diff, self.f0, self.alpha, 0)
        glossy = self.glossy if not C else np.concatenate([self.glossy, self.glossy[s["comp"]]])
        return (sc.face_offset, sc.face_normal, sc.corner_normal, sc.component_of_face, diff, f0,
                alpha, glossy, self.table, self.sun, self.cf.irradiance_W_m2, self.cf.sun_irradiance_W_m2, c.valid,
                c.face_s, c.lat_start, c.lat_ids, self.p, self.tex, self.mat_par, self.face_uv, self.atlas)

    def add_diffuse(self, s, E, L):
        kc, kd, _, _, _ = self._mats(s)
        _surface.add_diffuse(E, kc, kd, L)


def _background_params(lighting: Lighting):
    """The environment's parameter vector and texture as the background draws them: Earth
    without the ambient sky (the sky lights the target but is not drawn)."""
    p, tex = lighting.packed()
    p[env.P_AMBIENT] = 0.0
    return p, tex
