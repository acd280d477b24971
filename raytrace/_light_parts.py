"""The frame's linear radiance split by where the light comes from (``render(..., parts=True)``,
the ``light`` modality): four parts whose sum is the radiance image.

``sun``
    Sunlight reflected once, from the lit surface point to the camera (diffuse and the Sun's
    specular highlight, after shadow rays and the solar disc's penumbra).
``earth``
    Earth's light reflected once by the target (the environment term of Earth alone: Earth's
    unoccluded irradiance minus what the target's own parts hide of it), and Earth's disc
    seen directly behind the target.
``sky``
    The ambient sky's light reflected once by the target (likewise), and the stars drawn in
    the background.
``inter``
    Light that reached the point after at least one reflection on the target itself, from
    any source (inter-reflections, the glossy parts' reflections of the others and of the
    environment).

How. The renderer's estimators (the radiance cache's solve, the final gather and its
filter, the glossy lobe, the anti-aliasing's box over sub-samples) are not run once per
source: that would multiply their cost. Instead each pixel centre's light is split where the
parts are known apart, and the final pixel value is shared out in those proportions, so the
parts sum to the ``hdr`` radiance to float32 rounding whatever the estimators did:

1. At each target pixel centre the Sun's term is exact and separate (its shadow ray and
   penumbra, :meth:`raytrace._context._Sunlight.sunlight`); everything else at the centre
   (the cache's or the final gather's diffuse light, the mirror and lobe terms) is the
   remainder.
2. The remainder is split in the proportions of the radiance cache's indirect irradiance at
   the point: the direct environment term of Earth alone and of the sky alone
   (:meth:`raytrace.cache.RadianceCache.direct_environment`, linear in the environment, so
   they sum to the full environment's), and the rest of the cache's indirect light
   (inter-reflection), all interpolated at the point with the same weights.
3. A pixel's final value is divided in the proportions of its centre's parts (per colour
   channel). Where the renderer anti-aliased the pixel (its value is a mean over sub-pixel
   rays, across a silhouette, a part edge or a shadow edge) the proportions are those of the
   sum of the parts at the 3 × 3 pixel centres around it (Earth's disc behind a background
   centre counted as ``earth``); ``reference`` (every pixel a jittered area mean, from the path
   tracer) uses its centres' parts as ``fast`` shades them, the 3 × 3 sum where the 3 × 3
   centres disagree on the part or the Sun's visibility.

What is exact and what is not. The parts always sum to the pixel (float32 rounding; measured
≤ 2 × 10⁻⁷ relative). The ``sun`` part is the Sun's exact term at every pixel that is not
anti-aliased (a lit Lambertian plate: ρ/π·E·cos θ to 10⁻⁵; in a geometric shadow 0). The split
of the rest follows the cache's proportions, not those of the final gather or the lobe (which
are not computed per source); on an open face both are the environment's light alone and
agree, in a crevice the gather's share of inter-reflection may differ from the cache's. The
sky's term comes from a coarser irradiance table than the frame's (Earth's is the rest of the
full environment's): a light that is off shows up at < 0.2 % of one that is on. Checked by
superposition (``tests/raytrace/test_light_parts.py``; a frame is linear in its lights): on
two plates under Sun, Earth and sky, ``fast``, each part against the same part of the frame
lit by that light alone, median per-pixel difference 0 (sun), 3 × 10⁻⁴ (earth), 0 (sky),
10⁻⁵ (inter against the sum of the three frames'); ``balanced``-8, whose gather is noisy, the
means within 2 %. Anti-aliased pixels are approximate (a silhouette's pixel is shared out as
its neighbourhood's centres, not as its sub-samples saw it). A pixel whose proportions are
all zero (no light reached any centre around it, yet a sub-sample found some) goes to
``sun``, the one light that changes within a pixel without the centres seeing it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHANNELS", "PARTS"]

PARTS = ("earth", "inter", "sky", "sun")
"""The parts, in their order in the image: the order of their names, which is how OpenEXR
stores layers (its channel list is sorted by name), so a file reads back in this order."""
EARTH, INTER, SKY, SUN = range(4)
CHANNELS = tuple(f"{p}.{c}" for p in PARTS for c in "RGB")
"""The image's 12 channel names (OpenEXR layers ``earth``, ``inter``, ``sky``, ``sun``)."""


def environment_terms(ctx, s):
    """The direct environment terms of Earth alone and of the sky alone
    (:meth:`raytrace.cache.RadianceCache.direct_environment`) on the radiance cache's rows
    that the points ``s`` read, under the frame's lighting: (D_earth, D_sky, has_earth,
    has_sky); an absent light's term is a placeholder. With both, the sky's comes from a
    coarser irradiance table (0.6 ms instead of 6) and Earth's is the full environment's (the
    frame's own table) minus it: only their proportions are used, and the two sum to the full
    environment's term exactly."""
    from . import _light_kernels, environment as env
    light, cache = ctx.lighting, ctx.cache
    has_earth = light.earth is not None
    has_sky = light.ambient_radiance_W_m2_sr > 0.0
    none = np.zeros((1, 3))
    if not (has_earth or has_sky):
        return none, none, False, False
    mark = np.zeros(len(cache.valid), dtype=bool)
    _light_kernels.mark_rows(cache.valid, cache.face_s, cache.lat_start, cache.lat_ids, s["face"], s["B"], s["SIDE"],
                             mark)
    rows = np.flatnonzero(mark)
    p, tex = light.packed()
    envs = [(p, tex, ctx.env_irradiance)]
    if has_earth and has_sky:
        ps = p.copy()
        ps[env.P_ESUN] = 0.0  # the sky alone: Earth's disc unlit, still hiding the sky behind it
        envs.append((ps, tex, env.irradiance_table(ps, tex, 25, 48, 32, 64)))
    D = cache.direct_environment(envs, rows)
    if not has_sky:
        return D[0], none, True, False
    if not has_earth:
        return none, D[0], False, True
    D_earth = D[0]
    D_earth[rows] -= D[1][rows]
    return D_earth, D[1], True, True


def centre_parts(ctx, s, E_ind, L_sun, L_total) -> np.ndarray:
    """The parts (n, 4, 3) float32 (:data:`PARTS`) of the pixel centres' radiance ``L_total`` (n, 3) at
    the points ``s``, whose Sun term is ``L_sun`` (n, 3) and whose cache irradiance (indirect)
    is ``E_ind`` (n, 3): the rest split in the cache's proportions (module notes, step 2;
    :func:`raytrace._light_kernels.centre_parts`)."""
    from . import _light_kernels
    D_earth, D_sky, has_earth, has_sky = environment_terms(ctx, s)
    c = ctx.cache
    out = np.empty((len(L_total), 4, 3), dtype=np.float32)  # proportions: float32 is plenty, and half the memory
    _light_kernels.centre_parts(D_earth, D_sky, has_earth, has_sky, c.valid, c.face_s, c.lat_start, c.lat_ids,
                                s["face"], s["B"], s["SIDE"], E_ind, L_sun, L_total, out)
    return out


def mixed_pixels(instance: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """Flat indices of the pixels whose 3 × 3 neighbourhood disagrees on the part (or space) or
    on the Sun's visibility at the centres (``lit`` (H, W) bool)."""
    from scipy.ndimage import maximum_filter, minimum_filter
    inst = instance.astype(np.int64)
    lit8 = lit.astype(np.int8)
    mixed = (maximum_filter(inst, size=3, mode="nearest") != minimum_filter(inst, size=3, mode="nearest")) | \
            (maximum_filter(lit8, size=3, mode="nearest") != minimum_filter(lit8, size=3, mode="nearest"))
    return np.flatnonzero(mixed)


def assemble(rad: np.ndarray, pix: np.ndarray, parts: np.ndarray, background: np.ndarray | None,
             mixed: np.ndarray) -> np.ndarray:
    """The parts image (H, W, 12) float32 (:data:`CHANNELS`) of the radiance ``rad`` (H, W, 3):
    target pixel centres ``pix`` (flat) with parts ``parts`` (n, 4, 3) of their centre's
    light, ``mixed`` (flat) the pixels shared out by their 3 × 3 centres' parts,
    ``background`` (len(mixed), 3) Earth's disc drawn behind the mixed pixels' centres before
    they were anti-aliased (None: no Earth drawn; elsewhere in the background ``rad`` is
    Earth's disc). Every other pixel is background: ``earth``
    (:func:`raytrace._light_kernels.assemble`)."""
    from . import _light_kernels
    H, W, _ = rad.shape
    row_of_pixel = np.full(H * W, -1, dtype=np.int32)
    row_of_pixel[pix] = np.arange(len(pix), dtype=np.int32)
    is_mixed = np.zeros(H * W, dtype=bool)
    is_mixed[mixed] = True
    mixed = np.asarray(mixed, dtype=np.int64)
    off = row_of_pixel[mixed] < 0  # mixed pixels whose centre is background: −2 − their index in ``mixed``
    row_of_pixel[mixed[off]] = -2 - np.flatnonzero(off).astype(np.int32)
    bg = np.zeros((1, 3), np.float32) if background is None else np.ascontiguousarray(background, np.float32)
    out = np.zeros((H * W, 12), dtype=np.float32)  # black space is left as it is
    _light_kernels.assemble(rad.reshape(H * W, 3), row_of_pixel, is_mixed, np.ascontiguousarray(parts), bg,
                            background is not None, H, W, out)
    return out.reshape(H, W, 12)


def fast_centre_parts(scene, camera, R, t, lighting, geo, cache_options: dict, sun_rays: int, seed: int):
    """The pixel centres' parts as ``fast`` shades them (for ``reference``, whose path tracer
    keeps no per-source sums): (target pixels (flat), parts (n, 4, 3), the Sun's visibility (n,))."""
    from ._context import _Context, _surfaces
    from ._kernels import centre_rays
    H, W = camera.height, camera.width
    R_bc = np.ascontiguousarray(R.T)
    o_body = -R_bc @ t
    pix = np.flatnonzero(geo.instance.ravel() > 0)
    O = np.empty((len(pix), 3))
    D = np.empty((len(pix), 3))
    centre_rays(pix, W, o_body, R_bc, camera.fx, camera.fy, camera.cx, camera.cy, *camera.lens_arrays(), O, D)
    s = _surfaces(scene, O, D, geo.face_index.ravel()[pix].astype(np.int64), 1.0 / camera.fx)
    ctx = _Context(scene, lighting, cache_options, prefiltered_glossy=True)
    soft = sun_rays > 1 and lighting.sun_angular_diameter_rad > 0.0
    occ_t = np.full(len(pix), np.inf) if soft else None
    L, vis = ctx.sunlight(s, occluder_t=occ_t, robust=True)
    penumbra = None
    if soft and len(pix):
        footprint_m = geo.depth_m.ravel()[pix].astype(np.float64) / camera.fx
        penumbra = ctx.soft_shadows(s, vis, occ_t, footprint_m, pix, H, W, sun_rays, seed)
    L_sun = L.copy()
    E = ctx.cache_E(s)
    ctx.add_mirror(s, E, L, ctx.mirror_hits(s))
    if penumbra is not None:
        cand, dL = penumbra
        L[cand] += dL
        L_sun[cand] += dL
    ctx.add_diffuse(s, E, L)
    return pix, centre_parts(ctx, s, E, L_sun, L), vis
