"""Slow, obviously correct NumPy oracles shared by the ray-tracing tests."""

import numpy as np


def point_mesh_distance(points, V, F):
    """Brute-force distance from each point to the nearest triangle of (V, F): the distance to
    the plane where the point projects inside the triangle, else to the nearest edge segment."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        dp = np.einsum("fk,fk->f", p - a, n)
        q = p - dp[:, None] * n
        inside = np.ones(len(F), bool)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("fk,fk->f", np.cross(v - u, q - u), n) >= -1e-12
        d = np.where(inside, np.abs(dp), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            e = v - u
            s = np.clip(np.einsum("fk,fk->f", p - u, e) / np.einsum("fk,fk->f", e, e), 0.0, 1.0)
            d = np.minimum(d, np.linalg.norm(p - (u + s[:, None] * e), axis=1))
        out[i] = d.min()
    return out


def png_chunks(path) -> list:
    """The chunk types of a PNG file, in order (PNG spec: 8-byte signature, then length, type, data, CRC)."""
    data, i, out = open(path, "rb").read(), 8, []
    while i < len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        out.append(data[i + 4:i + 8].decode("ascii"))
        i += 12 + n
    return out
