"""Anti-aliasing of a frame (:func:`raytrace.shade.render`): the pixels to anti-alias (edges,
corner rays, thin shadows, slivers) and their box-filtered radiance from correlated
multi-jittered sub-pixel rays, traced and then shaded in chunks, with coverage rays where a pixel
holds more than one part.
"""

from __future__ import annotations

import numba
import numpy as np

from . import _background, _edges, _gather, _rows, presets
from ._context import _Context, _Sunlight, _surfaces
from ._kernels import ray_origins32
from ._lights import SUN_X, SUN_Y, SUN_Z
from ._sampling import COVERAGE_STREAM, SUB_GATHER_STREAM
from ._threads import submit as _submit
from .camera import Camera
from .lighting import Lighting
from .presets import Quality
from .scene import Scene


# the fewest final-gather rays worth casting at an edge sub-sample off its pixel centre's
# surface (render gives such a sub-sample Quality.aa_gather_rays of them, gather_rays / 4 below 32
# rays, at least 2): on the scenes of
# benchmarks/bench_time_error.py at 640×480, 2-ray sub-sample gathers made ``balanced``-8 worse
# than the cache alone (``backlit`` views 14.7–14.9 % with them, 13.0–13.1 % without), 4-ray ones
# made ``balanced``-16 better (median of four views 7.3 → 6.5 %)
_MIN_SUB_GATHER = 4


def _aa_pixels(q: Quality, scene: Scene, camera: Camera, R, t, o_body, geo, lighting: Lighting, sunl: _Sunlight, s,
               vis, pix, lit_img, earth_px, earth_drawn: bool) -> np.ndarray:
    """The pixels :func:`raytrace.shade.render` anti-aliases (flat indices, ascending): where 4-neighbours
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
                               sunl.sun, sunl.eps)
    if q.slivers:
        _edges.sliver_pixels(scene.vertices, scene.faces, R, t, camera.fx, camera.fy, camera.cx, camera.cy,
                             camera.lens_arrays()[0],
                             1e-6 * scene.scale_m, 1.0, geo.depth_m, edges)
    return np.flatnonzero(edges.ravel())


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
    make_rays(o_body, np.ascontiguousarray(R.T), camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5,
              *camera.lens_arrays(), u0, v0, w, h, z0, o32, d32)
    return o32, d32, scene.intersect(o32, d32, robust=z0 <= 0.0)


def _corner_edges(scene: Scene, geo, corners, lit=None, sun=None, eps: float = 0.0) -> np.ndarray:
    """Pixels containing geometry their centre ray missed: one extra ray through every pixel
    corner of the cast rectangle (shared by four pixels, so about one ray per pixel; ``corners``
    from :func:`_corner_rays`); a pixel whose corners see another part than its centre holds a
    sub-pixel feature (a mast, a gap between panels, a thin wing seen edge-on) and must be
    supersampled. Features wider than 0.71 px are always caught; thinner ones only where they
    cross a corner. With ``lit`` (the centres' sunlit mask) and ``sun`` (the Sun record,
    :mod:`raytrace._lights`), also pixels whose corners and centre disagree on the Sun."""
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
        sx, sy, sz = sun[SUN_X], sun[SUN_Y], sun[SUN_Z]
        want = np.empty(n, dtype=bool)
        so = np.empty((n, 3))
        O = np.ascontiguousarray(o32, dtype=np.float64)
        D = np.ascontiguousarray(d32, dtype=np.float64)
        _gather.bounce_sun_rays(O, D, hc["tfar"].astype(np.float64), hc["geomID"], hc["primID"], scene.face_offset,
                                scene.face_normal, sun, eps, want, so)
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
    (:func:`raytrace.shade.render` traces it while the context is solved on its side thread)."""
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
    _edges.subpixel_rays(epix.astype(np.int64), W, n_grid, seed, R_bc, camera.fx, camera.fy, camera.cx, camera.cy,
                         *camera.lens_arrays(), D)
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
                         camera.fy, camera.cx, camera.cy, *camera.lens_arrays(), Dc)
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
        # one origin for all; the procedural materials filtered over a pixel's footprint, as at
        # the centres (and the path tracer's jittered rays): the same material in every ray
        s = _surfaces(scene, np.asarray(o_body, np.float64).reshape(1, 3), Dh, face, sunl.px_rad)
        disc = None
        if sunl.lighting.sun_angular_diameter_rad > 0.0 and S > 1:
            # one solar-disc sample per sub-sample, stratified over the pixel's S sub-samples in
            # strata permuted per pixel, independent of the sub-samples' cells
            disc = (c_idx, n_idx, S, seed)
        Ls, _ = sunl.sunlight(s, disc=disc)
        tr.update(s=s, Dh=Dh, c_idx=c_idx, n_idx=n_idx, Ls=Ls, mirror=sunl.mirror_hits(s))
    miss = np.flatnonzero(~hit)
    if len(miss) and sunl.lighting.earth is not None:
        Dm = np.empty((len(miss), 3))
        _rows.unit_rows(D, miss, Dm)
        out = np.empty((len(miss), 3))
        _background.env_along(o_body, Dm, sunl.p_background, sunl.tex, out)
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
            _edges.interpolate_rows_into(own, Dh, R_cam, camera.fx, camera.fy, camera.cx, camera.cy,
                                         camera.lens_arrays()[0], W, H, s["comp"],
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
                    sj = {k: s[k][j] for k in ("P", "NS", "NG", "WO", "comp", "m_diff", "m_f0", "m_alpha") if k in s}
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
