"""Keypoints of a target: a reproducible set of salient body-frame points, their per-frame pixel
positions and whether each is seen and lit (docs/formats.md, ``model/keypoints.json`` and the
labels' ``keypoints_px`` / ``keypoints_state``).

Default set
    :func:`default_keypoints`: farthest-point sampling (Eldar, Lindenbaum, Porat & Zeevi, "The
    farthest point strategy for progressive image sampling", IEEE Trans. Image Processing 6(9),
    1997) of the target's convex-hull vertices, started from the hull vertex farthest from the
    hull vertices' centroid. Deterministic (no random draw; ties go to the lexicographically
    smallest vertex), so the same mesh gives the same points whatever its vertex order. Eleven
    points by default, as SPEED+ uses for Tango (Park, Märtens, Lecuyer, Izzo & D'Amico,
    "SPEED+: Next-generation dataset for spacecraft pose estimation across domain gap",
    IEEE Aerospace Conference 2022).
User set
    :func:`read_keypoints`: a JSON file in the ``model/keypoints.json`` schema, or a plain list
    of ``[x, y, z]`` in metres (body frame).
States
    :func:`keypoint_states` projects the points with :meth:`raytrace.camera.Camera.project`
    (whatever lens model the camera carries) and casts, in one batch, a ray from the optical
    centre to each point (stopped a tolerance short of it, so that a point on the surface does
    not hide itself) and a ray from each point towards the Sun (started the same tolerance off
    the point): ``outside`` (not in the image −0.5 ≤ u < W − 0.5, −0.5 ≤ v < H − 0.5, or at or
    behind the optical centre), ``occluded`` (the target hides it), ``shadowed`` (the target
    shades it from the Sun, or Earth's shadow leaves less than half the solar disc:
    ``shadow_fraction`` < 0.5) or ``visible``.
"""

from __future__ import annotations

import json
import math

import numpy as np

__all__ = ["DEFAULT_COUNT", "COUNT_RANGE", "MAX_POINTS", "STATES", "default_keypoints", "farthest_point_order",
           "keypoints_document", "read_keypoints", "keypoint_states", "frame_keypoints"]

DEFAULT_COUNT = 11
"""Points of the default set (SPEED+'s count for Tango)."""
COUNT_RANGE = (4, 64)
"""Allowed ``n`` of :func:`default_keypoints`."""
MAX_POINTS = 256
"""Most points a user's keypoint file may hold."""
STATES = ("visible", "shadowed", "occluded", "outside")
"""The per-frame states of a keypoint."""
EARTH_SHADOW_LIMIT = 0.5
"""A point counts as shadowed when the Earth leaves less than this fraction of the solar disc visible."""
TOLERANCE_REL = 1e-4
"""The rays' tolerance at the keypoint, relative to the target's bounding radius."""
_FILE_LIMIT_BYTES = 1 << 20


def farthest_point_order(points, n: int, start: int) -> np.ndarray:
    """Indices of ``n`` points of ``points`` chosen by farthest-point sampling: ``start`` first,
    then each time the point whose distance to the nearest chosen one is largest (the first
    such index on a tie).

    Parameters
    ----------
    points : array_like, shape (m, 3)
    n : int
        How many, 1 … m.
    start : int
        Index of the first point.

    Returns
    -------
    ndarray, shape (n,), int64
    """
    P = np.asarray(points, dtype=np.float64)
    if not 1 <= n <= len(P):
        raise ValueError(f"n must be in [1, {len(P)}] (the number of points), got {n}")
    chosen = [int(start)]
    d = np.linalg.norm(P - P[start], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(P - P[k], axis=1))
    return np.asarray(chosen, dtype=np.int64)


HULL_MAX_POINTS = 100_000
"""Above this many vertices the hull is taken of one vertex per cell of a :data:`GRID_CELLS`³ grid
(qhull took 12 s for the 655 362 vertices of a finely divided sphere, all on its hull)."""
GRID_CELLS = 128


def _grid_representatives(V: np.ndarray, cells: int = GRID_CELLS) -> np.ndarray:
    """One vertex per occupied cell of a ``cells``³ grid over the bounding box: the one farthest
    from the box's centre (ties: the lexicographically smallest), so that the points on the
    hull stay within a cell (1/``cells`` of the box's largest side) of the hull of ``V``."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    cell = max(float((hi - lo).max()), 1e-300) / cells
    key = np.minimum(np.floor((V - lo) / cell), cells - 1).astype(np.int64)
    far = np.linalg.norm(V - 0.5 * (lo + hi), axis=1)
    order = np.lexsort((V[:, 2], V[:, 1], V[:, 0], -far, key[:, 2], key[:, 1], key[:, 0]))
    k = key[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(k[1:] != k[:-1], axis=1)
    return V[order[first]]


def _hull_points(V: np.ndarray) -> np.ndarray:
    """The distinct convex-hull vertices of ``V`` in lexicographic order (of
    :func:`_grid_representatives` beyond :data:`HULL_MAX_POINTS` vertices); every distinct
    vertex when the points are flat or collinear (no 3-D hull)."""
    from scipy.spatial import ConvexHull, QhullError
    V = np.asarray(V, dtype=np.float64)
    if len(V) > HULL_MAX_POINTS:
        V = _grid_representatives(V)
    try:
        V = V[ConvexHull(V).vertices]
    except (QhullError, ValueError):
        pass
    return np.unique(V, axis=0)  # sorted rows: the order is neither the mesh's nor qhull's


def default_keypoints(model, n: int = DEFAULT_COUNT) -> tuple[list, np.ndarray]:
    """The default keypoints of a target: farthest-point sampling of its convex-hull vertices.

    Parameters
    ----------
    model : raytrace.model.TargetModel
        The target (body frame, metres).
    n : int
        Number of points, 4 … 64; fewer when the hull has fewer vertices (a box: 8).

    Returns
    -------
    names : list of str
        ``kp00``, ``kp01``, …
    points_body_m : ndarray, shape (k, 3), float64
        k = min(n, number of hull vertices); the first is the hull vertex farthest from the
        hull vertices' centroid, each next the hull vertex farthest from those before. Meshes
        of more than 100 000 vertices: the hull of one vertex per cell of a 128³ grid (mesh
        vertices within 1/128 of the box's largest side of the hull).
    """
    lo, hi = COUNT_RANGE
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not lo <= n <= hi:
        raise ValueError(f"n must be an integer in [{lo}, {hi}], got {n!r}")
    V = np.concatenate([np.asarray(c.mesh.vertices, dtype=np.float64) for c in model.components])
    H = _hull_points(V)
    start = int(np.argmax(np.linalg.norm(H - H.mean(axis=0), axis=1)))
    P = H[farthest_point_order(H, min(int(n), len(H)), start)]
    return [f"kp{k:02d}" for k in range(len(P))], P


DEFAULT_SOURCE = ("farthest-point sampling of the convex hull vertices, from the one farthest from their centroid "
                  "(raytrace.keypoints.default_keypoints)")


def keypoints_document(names, points_body_m, source: str) -> dict:
    """The ``model/keypoints.json`` document."""
    return {"frame": "body", "unit": "m", "source": str(source), "names": [str(s) for s in names],
            "points_body_m": [[float(v) for v in p] for p in np.asarray(points_body_m, dtype=np.float64)]}


def _points(value, what: str) -> np.ndarray:
    if not isinstance(value, list):
        raise ValueError(f"{what} must be a list of [x, y, z] points in metres, got {type(value).__name__}")
    if not 1 <= len(value) <= MAX_POINTS:
        raise ValueError(f"{what} must hold 1 to {MAX_POINTS} points, got {len(value)}")
    out = np.empty((len(value), 3))
    for k, p in enumerate(value):
        ok = isinstance(p, list) and len(p) == 3 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in p)
        if not ok:
            raise ValueError(f"{what}: point {k} must be [x, y, z], three finite numbers in metres, got {p!r}")
        out[k] = p
    _, first, inverse = np.unique(out, axis=0, return_index=True, return_inverse=True)
    dup = np.flatnonzero(first[inverse.ravel()] != np.arange(len(out)))
    if len(dup):
        k = int(dup[0])
        raise ValueError(f"{what}: point {k} repeats point {int(first[inverse.ravel()[k]])} ({out[k].tolist()})")
    return out


def parse_keypoints(doc, what: str = "keypoints") -> tuple[list, np.ndarray, str | None]:
    """(names, points_body_m, source or None) of a parsed keypoint document: the
    ``model/keypoints.json`` schema or a plain list of ``[x, y, z]`` [m]; ValueError (one line
    starting with ``what``) otherwise."""
    if isinstance(doc, list):
        P = _points(doc, what)
        return [f"kp{k:02d}" for k in range(len(P))], P, None
    if not isinstance(doc, dict):
        raise ValueError(f"{what} must be a JSON object with points_body_m (model/keypoints.json) or a list of "
                         f"[x, y, z] points in metres, got {type(doc).__name__}")
    unknown = sorted(set(doc) - {"frame", "unit", "source", "names", "points_body_m"})
    if unknown:
        raise ValueError(f"{what}: unknown key {unknown[0]!r} (allowed: frame, unit, source, names, points_body_m)")
    if "points_body_m" not in doc:
        raise ValueError(f"{what} lacks points_body_m (a list of [x, y, z] points in metres)")
    if doc.get("frame", "body") != "body":
        raise ValueError(f"{what}: frame must be 'body' (the target's body frame), got {doc['frame']!r}")
    if doc.get("unit", "m") != "m":
        raise ValueError(f"{what}: unit must be 'm' (metres), got {doc['unit']!r}")
    source = doc.get("source")
    if source is not None and not isinstance(source, str):
        raise ValueError(f"{what}: source must be a string, got {type(source).__name__}")
    P = _points(doc["points_body_m"], f"{what}: points_body_m")
    names = doc.get("names")
    if names is None:
        names = [f"kp{k:02d}" for k in range(len(P))]
    if not isinstance(names, list) or len(names) != len(P) or not all(isinstance(s, str) and s.strip() for s in names):
        raise ValueError(f"{what}: names must be a list of {len(P)} non-empty strings, one per point, got {names!r}")
    dup = sorted({s for s in names if names.count(s) > 1})
    if dup:
        raise ValueError(f"{what}: names must be unique, repeated: {dup[0]!r}")
    return list(names), P, source


def read_keypoints(path) -> tuple[list, np.ndarray, str | None]:
    """:func:`parse_keypoints` of a JSON file (at most 1 MiB, UTF-8)."""
    from .files import read_regular_file
    what = str(path)
    data = read_regular_file(path, limit_bytes=_FILE_LIMIT_BYTES, what=what)
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=lambda c: math.nan)
    except ValueError as exc:  # UnicodeDecodeError too
        raise ValueError(f"{what} is not UTF-8 JSON ({str(exc).splitlines()[0]})") from None
    return parse_keypoints(doc, what)


def tolerance_m(scene) -> float:
    """How far short of a keypoint the camera's ray stops, and how far off it the Sun's ray
    starts [m]: 10⁻⁴ of the target's bounding radius, at least twice the scene's offset of
    secondary rays (:attr:`raytrace.scene.Scene.ray_eps_m`, float32 precision far from the
    origin)."""
    return max(TOLERANCE_REL * scene.model.bounding_radius_m, 2.0 * scene.ray_eps_m)


def keypoint_states(scene, camera, R_cam_from_body, t_cam_m, points_body_m, sun_dir_body, *,
                    shadow_fraction: float = 1.0, tol_m: float | None = None) -> tuple[np.ndarray, list]:
    """Pixel positions and states of keypoints in one frame.

    Parameters
    ----------
    scene : raytrace.scene.Scene
    camera : raytrace.camera.Camera
    R_cam_from_body, t_cam_m : array_like, (3, 3) and (3,)
        Pose: p_cam = R_cam_from_body @ p_body + t_cam_m [m].
    points_body_m : array_like, shape (N, 3)
    sun_dir_body : array_like, shape (3,)
        Direction towards the Sun in the body frame (need not be unit).
    shadow_fraction : float
        Fraction of the solar disc the Earth leaves visible at the target; below 0.5 every
        point in view is ``shadowed``.
    tol_m : float, optional
        The rays' tolerance at the point (default :func:`tolerance_m`).

    Returns
    -------
    uv : ndarray, shape (N, 2)
        :meth:`Camera.project` of the points [px]; NaN at or behind the optical centre.
    states : list of str
        One of :data:`STATES` per point.
    """
    R = np.asarray(R_cam_from_body, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t_cam_m, dtype=np.float64).reshape(3)
    P = np.asarray(points_body_m, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
        raise ValueError(f"points_body_m must be an (N, 3) array of finite numbers [m], got shape {P.shape}")
    s = np.asarray(sun_dir_body, dtype=np.float64).reshape(3)
    if not (np.isfinite(s).all() and np.linalg.norm(s) > 0):
        raise ValueError(f"sun_dir_body must be a finite non-zero vector, got {s.tolist()}")
    s = s / np.linalg.norm(s)
    tol = tolerance_m(scene) if tol_m is None else float(tol_m)
    p_cam = P @ R.T + t
    uv = camera.project(p_cam)
    u, v = uv[:, 0], uv[:, 1]
    inside = (p_cam[:, 2] > 0) & np.isfinite(u) & np.isfinite(v) & (u >= -0.5) & (u < camera.width - 0.5) \
        & (v >= -0.5) & (v < camera.height - 0.5)
    states = ["outside"] * len(P)
    idx = np.flatnonzero(inside)
    if len(idx):
        centre = -R.T @ t  # the optical centre in the body frame
        seg = P[idx] - centre
        dist = np.linalg.norm(seg, axis=1)
        n = len(idx)
        origins = np.concatenate([np.broadcast_to(centre, (n, 3)), P[idx] + tol * s])
        directions = np.concatenate([seg / dist[:, None], np.broadcast_to(s, (n, 3))])
        tfar = np.concatenate([np.maximum(dist - tol, 0.0), np.full(n, np.inf)])
        hit = scene.occluded(origins, directions, tfar=tfar)
        earth_dark = not shadow_fraction >= EARTH_SHADOW_LIMIT
        for j, k in enumerate(idx):
            states[k] = "occluded" if hit[j] else "shadowed" if (hit[n + j] or earth_dark) else "visible"
    return uv, states


def frame_keypoints(scene, camera, R_cam_from_body, t_cam_m, points_body_m, light: dict) -> dict:
    """The label fields of a frame's keypoints: ``keypoints_px`` ([u, v], or None at or behind
    the optical centre) and ``keypoints_state``; ``light`` is the plan's frame light
    (``sun_dir_body``, ``shadow_fraction``)."""
    uv, states = keypoint_states(scene, camera, R_cam_from_body, t_cam_m, points_body_m, light["sun_dir_body"],
                                 shadow_fraction=light["shadow_fraction"])
    px = [None if not np.all(np.isfinite(p)) else [float(p[0]), float(p[1])] for p in uv]
    return {"keypoints_px": px, "keypoints_state": states}
