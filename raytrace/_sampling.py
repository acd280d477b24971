"""Random numbers of the renderer and the radiance cache: integer hashes, Kensler's hash
permutation, correlated multi-jittered patterns, the Owen-scrambled Sobol sequence, and the
table of random streams that keep one sample pattern of a pixel apart from another.

Every sample is a pure function of integer keys (a pixel, a sub-sample's or a ray's number, a
cache row) and a seed, so a frame does not depend on how its work is chunked or threaded.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import inline, jit


@jit
def _hash32(i, k):
    """A 32-bit hash of the integers (i, k)."""
    h = (i * 0x9E3779B1 + k * 0x85EBCA77 + 0x27D4EB2F) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return h


@jit
def _hash01(i, k):
    """A number in [0, 1) from a hash of the integers (i, k) (24 bits)."""
    return (_hash32(i, k) & 0xFFFFFF) / 16777216.0


@jit
def permute(i, n, p):
    """Element i of a pseudo-random permutation of 0 … n − 1 chosen by the 32-bit key p,
    without storing it: Kensler's hash permutation (2013, "Correlated Multi-Jittered
    Sampling", Pixar TM 13-01, §3), invertible operations on the bits below the next power of
    two, cycle-walked until the result falls below n, then rotated by p."""
    M = 0xFFFFFFFF
    w = n - 1
    w |= w >> 1
    w |= w >> 2
    w |= w >> 4
    w |= w >> 8
    w |= w >> 16
    p &= M
    while True:
        i ^= p
        i = (i * 0xE170893D) & M
        i ^= p >> 16
        i ^= (i & w) >> 4
        i ^= p >> 8
        i = (i * 0x0929EB3F) & M
        i ^= p >> 23
        i ^= (i & w) >> 1
        i = (i * (1 | (p >> 27))) & M
        i = (i * 0x6935FA69) & M
        i ^= (i & w) >> 11
        i = (i * 0x74DCB303) & M
        i ^= (i & w) >> 2
        i = (i * 0x9E501CC3) & M
        i ^= (i & w) >> 2
        i = (i * 0xC860A3DF) & M
        i &= w
        i ^= i >> 5
        if i < n:
            break
    return (i + p) % n


@jit
def _strata(n):
    """Columns of an exact gx × (n / gx) stratification of n samples (the largest divisor of
    n not above √n): every stratum gets exactly one sample, so none is left out."""
    g = int(math.sqrt(n))
    while n % g:
        g -= 1
    return g


@inline
def _shuffle(perm, key, stream):
    """perm[:] = a permutation of 0 … len − 1 from a hash of (key, stream) (Fisher–Yates)."""
    n = perm.shape[0]
    for i in range(n):
        perm[i] = i
    for i in range(n - 1, 0, -1):
        r = min(int(_hash01(key * 64 + i, stream) * (i + 1)), i)
        perm[i], perm[r] = perm[r], perm[i]


@inline
def _cmj_perms(gx, gy, key, stream):
    """The two permutations of a correlated multi-jittered pattern (:func:`_cmj_point`): of
    the gx columns and of the gy rows, from hashes of (key, stream) and (key, stream + 1)."""
    perm_x = np.empty(gx, np.int64)
    perm_y = np.empty(gy, np.int64)
    _shuffle(perm_x, key, stream)
    _shuffle(perm_y, key, stream + 1)
    return perm_x, perm_y


@inline
def _cmj_point(j, gx, gy, perm_x, perm_y, jx, jy):
    """Point j (< gx·gy) of a correlated multi-jittered pattern on [0, 1)² (Kensler 2013,
    "Correlated Multi-Jittered Sampling", Pixar TM 13-01): cell (j mod gx, j div gx) of the
    gx × gy grid, and within it the fine column perm_y[row] and fine row perm_x[column], so the
    gx·gy points also fall one in each of the gx·gy fine columns and rows (n-rooks); (jx, jy)
    ∈ [0, 1)² the jitter within the fine cell."""
    i = j % gx
    r = j // gx
    return (i + (perm_y[r] + jx) / gy) / gx, (r + (perm_x[i] + jy) / gx) / gy


@jit
def _reverse_bits32(x):
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return ((x >> 16) | (x << 16)) & 0xFFFFFFFF


@jit
def _laine_karras32(x, seed):
    """The Laine–Karras permutation of the 32-bit integer x, keyed by ``seed``: every bit
    flipped by a hash of the bits below it (Burley 2020, "Practical Hash-based Owen
    Scrambling", JCGT 9(4), §3)."""
    M = 0xFFFFFFFF
    x = (x + seed) & M
    x ^= (x * 0x6C50B47C) & M
    x ^= (x * 0xB82F1E52) & M
    x ^= (x * 0xC7AFE638) & M
    x ^= (x * 0x8D22F6E6) & M
    return x


@jit
def _owen_scramble32(x, seed):
    """Nested uniform (Owen) scrambling of the 32-bit fraction x, keyed by ``seed``: Burley's
    hash-based form (2020, §3–4): bits reversed, the Laine–Karras permutation (each bit flipped
    by a hash of the bits before it), reversed back."""
    return _reverse_bits32(_laine_karras32(_reverse_bits32(x), seed))


def _sobol2_byte_tables():
    """The second dimension of the Sobol sequence as four 256-entry tables, one per byte of
    the index: entry b of table k is the XOR of the direction numbers of the set bits of b
    (bits 8k … 8k + 7 of the index). Direction numbers m_k = 2·m_{k−1} XOR m_{k−1} (m_1 = 1;
    primitive polynomial x + 1), i.e. the Pascal matrix mod 2 (Joe & Kuo's table:
    0x80000000, 0xC0000000, 0xA0000000, 0xF0000000, …)."""
    v = []
    m = 1
    for bit in range(32):
        v.append(m << (31 - bit))
        m = (m << 1) ^ m
    t = np.zeros((4, 256), np.int64)
    for k in range(4):
        for b in range(256):
            acc = 0
            for i in range(8):
                if b >> i & 1:
                    acc ^= v[8 * k + i]
            t[k, b] = acc
    return t


_SOBOL2_BYTES = _sobol2_byte_tables()


@jit
def _sobol2_y(i):
    """Point i (< 2³²) of the Sobol sequence's second dimension as a 32-bit fraction: four
    table look-ups (:func:`_sobol2_byte_tables`). With the first dimension, the van der
    Corput radical inverse (i's bits reversed), a (0, 2)-sequence: every aligned block of 2^m
    points is a (0, m, 2)-net."""
    t = _SOBOL2_BYTES
    return t[0, i & 255] ^ t[1, (i >> 8) & 255] ^ t[2, (i >> 16) & 255] ^ t[3, (i >> 24) & 255]


@jit
def _owen_sobol2_keyed(i, h_index, h_x, h_y):
    """Sample i of the Owen-scrambled, index-shuffled 2-D Sobol sequence with the scrambling
    keys already hashed (:func:`owen_sobol2`). The first dimension is the radical inverse of
    the shuffled index j, and its scramble reverses the bits back: reverse(LK(j)) without the
    two reversals in between."""
    j = _owen_scramble32(i, h_index)
    x = _reverse_bits32(_laine_karras32(j, h_x))
    y = _owen_scramble32(_sobol2_y(j), h_y)
    return x / 4294967296.0, y / 4294967296.0


@jit
def owen_sobol2(i, key, stream):
    """Sample i (≥ 0) of an Owen-scrambled, index-shuffled 2-D Sobol sequence on [0, 1)²,
    keyed by (key, stream) (Burley 2020, §5): the index scrambled too, so that every prefix of
    2^m samples is still a (0, m, 2)-net (one point in each of the 2^m cells of every
    2^a × 2^(m−a) grid) and a prefix of any length is well spread; a sequence continued from
    sample n fills in the strata the first n left."""
    return _owen_sobol2_keyed(i, _hash32(key, stream), _hash32(key, stream + 1), _hash32(key, stream + 2))


# ---- random streams
# A second sample pattern of the same keys (pixel, sub-sample, ray number) is drawn with the
# frame's seed XORed with one of these constants (the coverage rays: added), so that it does not
# repeat the first. Within the kernels, a pattern's dimensions are streams of the hashes' second
# argument: 4s + 21 … 23 the solar disc (_surface.disc_direction), 2s + 15 … 17 the gather's
# directions (_gather.gather_rays), 4s + 31, 4s + 32 a traced bounce (_gather.bounce2_rays),
# 2s + 11 … 14 the sub-pixel rays (_edges.subpixel_rays), 2s + 23, 2s + 24 the lobe's
# permutations (_gather.lobe_rays), s the seed a stream is drawn with.

# the paths traced from lobe-ray hits, apart from the final gather's (_context._Context.lobe)
LOBE_PATH_STREAM = 0x2545F491
# the directions of an edge sub-sample's own final gather (_antialias._shade_subsamples)
SUB_GATHER_STREAM = 0x2545F491
# The two share a value: a frame draws both with s' = seed ^ 0x2545F491, one sub-sample too (its
# own lobe and gather). They never draw the same stream: the sub-sample's gather directions hash
# the key pixel·1009 + s' with the streams 2s' + 15 … 17 (gather_rays, _paths.gather_traced), the
# lobe's paths the keys pixel·N + r (then 4·key + 1 per bounce) with 4s' + 31, 4s' + 32
# (bounce2_rays, _paths._bounce_draw); the streams meet only at s' = 2³¹ − 8 or 2³¹ − 7, two seeds
# in 2³¹. Where a hash input of one equals one of the other for the same pixel, it is the hash's
# linear input (key·A + stream·B) meeting by chance: on 1280×960 frames of 150 seeds, as often
# with a separate value for either stream. Kept one value: the same bytes.
# the second sub-pixel pattern of the noisiest anti-aliased pixels (Quality.aa_extra)
AA_SECOND_STREAM = 0x1B873593
# the sub-pixel rays of the pixels that are not anti-aliased (Quality.box_grid)
BOX_STREAM = 0x68E31DA4
# the paths traced from the second pass's hits of the two-pass final gather (shade._gather_two_pass)
SECOND_PASS_STREAM = 0x5BD1E995
# added to the seed (mod 2³¹) for the coverage rays of mixed edge pixels (_antialias._trace_chunk)
COVERAGE_STREAM = 0x3C6EF372
