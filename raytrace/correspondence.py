"""Where each pixel's hit lies on the target, and where it goes in the next frame: the ``coords``
and ``flow`` modalities, both from the geometry pass's hit record.

*Body coordinates.* The geometry pass (:meth:`raytrace.scene.Scene.render_geometry`) reports per
pixel the triangle hit (``face_index``) and a float32 z-depth. The body-frame point is taken
from neither the depth nor Embree's float32 hit: the pixel's ray — origin the optical centre
``o = −Rᵀ t``, direction ``Rᵀ d_cam`` with ``d_cam`` from :meth:`raytrace.camera.Camera.ray_directions_cam`
(z = 1) — is intersected in float64 with the plane of its hit triangle,
``s = n·(v₀ − o) / n·d``, ``p = o + s·d`` (the line–plane intersection,
https://en.wikipedia.org/wiki/Line%E2%80%93plane_intersection), so the point lies on the
triangle's plane and on the pixel's ray to float64 round-off (measured against a brute-force
Möller–Trumbore cast: ≤ 4·10⁻¹⁶ of the range, 1.4·10⁻¹³ m at 560 m), where ``z·d_cam`` from the
stored float32 depth is off along the ray by up to z·2⁻²⁴·|d_cam| (3·10⁻⁵ m at 560 m). ``s`` is
the z-depth of the hit. The ``coords`` file rounds p to float32: ~6·10⁻⁸ of the target-sized
coordinates, whatever the range.

*Flow.* A body point p of frame t lands in the next planned frame at
``uv₁ = camera.project(R₁ p + t₁)``; the flow is ``uv₁ − (u, v)``. It is *valid* where uv₁ lies in
the image (−0.5 ≤ u < W − 0.5, −0.5 ≤ v < H − 0.5) and the next frame's camera sees p: the
segment from p to the next optical centre ``c₁ = −R₁ᵀ t₁`` crosses no triangle of the target —
the next frame's primary ray through p meets nothing before p (but for the last
:attr:`raytrace.scene.Scene.ray_eps_m`), with no neighbouring pixel or depth interpolation
involved (:func:`seen_from`); a point on a triangle seen exactly edge-on is not valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Camera

_CHUNK = 1 << 16  # pixels per batch of the producers: their float64 temporaries stay a few MB

__all__ = ["FrameHits", "PixelHits", "coords_image", "flow_image", "pixel_hits", "seen_from"]


@dataclass(frozen=True, slots=True, eq=False)
class PixelHits:
    """The target pixels of a frame and their hit points.

    Attributes
    ----------
    rows, cols : ndarray, shape (N,), int64
        Pixel coordinates (v, u) of the pixels that hit the target, row-major order.
    face : ndarray, shape (N,), int64
        Global triangle index hit (:attr:`raytrace.scene.GeometryFrame.face_index`).
    p_body_m : ndarray, shape (N, 3), float64
        Body-frame point hit [m]: the pixel's ray intersected with its triangle's plane.
    depth_m : ndarray, shape (N,), float64
        Its z-depth in the camera frame [m].
    normal_body : ndarray, shape (N, 3), float64
        The hit triangle's normal (v₁ − v₀) × (v₂ − v₀), unnormalised, in the body frame [m²].
    shape : tuple
        (H, W) of the image.
    """

    rows: np.ndarray
    cols: np.ndarray
    face: np.ndarray
    p_body_m: np.ndarray
    depth_m: np.ndarray
    normal_body: np.ndarray
    shape: tuple


def _pose(R_cam_from_body, t_cam_m) -> tuple:
    R = np.ascontiguousarray(np.asarray(R_cam_from_body, dtype=np.float64).reshape(3, 3))
    t = np.asarray(t_cam_m, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError("R_cam_from_body and t_cam_m must be finite")
    return R, t


def pixel_hits(vertices, faces, camera: Camera, R_cam_from_body, t_cam_m, face_index, *,
               rect: tuple | None = None) -> PixelHits:
    """The body-frame points of a frame's primary hits (module docstring: ray ∩ triangle plane, float64).

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        The target's vertices in the body frame [m] (:attr:`raytrace.scene.Scene.vertices`).
    faces : array_like, shape (F, 3)
        Triangles as vertex indices (:attr:`raytrace.scene.Scene.faces`).
    camera : Camera
        The camera the frame was rendered with.
    R_cam_from_body : array_like, shape (3, 3)
        Pose of the frame (``p_cam = R p_body + t``) [-].
    t_cam_m : array_like, shape (3,)
        [m].
    face_index : ndarray, shape (H, W), int
        Triangle hit per pixel, −1 on background (:attr:`raytrace.scene.GeometryFrame.face_index`).
    rect : tuple of int, keyword-only, optional
        (u0, v0, u1, v1), end exclusive: a rectangle holding every hit (the frame's
        :attr:`~raytrace.scene.GeometryFrame.cast_rect`), searched instead of the whole image.

    Returns
    -------
    PixelHits
    """
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a raytrace.camera.Camera, got {type(camera).__name__}")
    face_index = np.asarray(face_index)
    if face_index.shape != (camera.height, camera.width):
        raise ValueError(f"face_index must have the camera's shape ({camera.height}, {camera.width}), "
                         f"got {face_index.shape}")
    R, t = _pose(R_cam_from_body, t_cam_m)
    V = np.asarray(vertices, dtype=np.float64)
    Fc = np.asarray(faces, dtype=np.int64)
    ru0, rv0, ru1, rv1 = (0, 0, camera.width, camera.height) if rect is None else (int(r) for r in rect)
    rows, cols = np.nonzero(face_index[rv0:rv1, ru0:ru1] >= 0)
    rows, cols = rows + rv0, cols + ru0
    face = face_index[rows, cols].astype(np.int64)
    if face.size and face.max() >= len(Fc):
        raise ValueError(f"face_index must index the {len(Fc)} faces, got {int(face.max())}")
    n_hits = face.size
    p, depth, normal = np.empty((n_hits, 3)), np.empty(n_hits), np.empty((n_hits, 3))
    if not n_hits:
        return PixelHits(rows, cols, face, p, depth, normal, face_index.shape)
    RT = np.ascontiguousarray(R.T)
    o_body = -_times(t[None, :], RT)[0]  # Rᵀ t: the optical centre in the body frame
    u0, u1 = int(cols.min()), int(cols.max()) + 1
    band = max(1, _CHUNK // (u1 - u0))  # rows per band: the bands' ray directions stay small
    for v0 in range(int(rows[0]), int(rows[-1]) + 1, band):
        lo, hi = np.searchsorted(rows, (v0, v0 + band))  # rows ascend (row-major order)
        if hi == lo:
            continue
        r, c, f = rows[lo:hi], cols[lo:hi], face[lo:hi]
        d_cam = camera.ray_directions_cam(u0, v0, u1, int(r[-1]) + 1)[(r - v0) * (u1 - u0) + (c - u0)]
        d_body = _times(d_cam, RT)  # Rᵀ d for each row
        a = V[Fc[f, 0]]
        n = np.cross(V[Fc[f, 1]] - a, V[Fc[f, 2]] - a)
        w = o_body - a  # from the triangle's first vertex to the optical centre
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -np.einsum("ij,ij->i", n, w) / np.einsum("ij,ij->i", n, d_body)
        p[lo:hi] = a + (w + s[:, None] * d_body)
        depth[lo:hi] = s * d_cam[:, 2]
        normal[lo:hi] = n
    return PixelHits(rows, cols, face, p, depth, normal, face_index.shape)


def _times(p: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``p @ M.T`` for rows ``p`` (N, 3) and a 3 × 3 ``M``, column by column: numpy's matmul hands
    it to BLAS, whose threads, beside numba's still spinning after a parallel kernel, took 0.9 s
    for 1.2 M rows (here 0.1 s)."""
    return np.column_stack([p[:, 0] * M[k, 0] + p[:, 1] * M[k, 1] + p[:, 2] * M[k, 2] for k in range(3)])


def coords_image(hits: PixelHits) -> np.ndarray:
    """The ``coords`` image: body-frame point of each pixel's hit, shape (H, W, 3), float32 [m];
    0 on background."""
    out = np.zeros(hits.shape + (3,), dtype=np.float32)
    out.reshape(-1, 3)[hits.rows * hits.shape[1] + hits.cols] = hits.p_body_m
    return out


def flow_image(scene, camera: Camera, hits: PixelHits, next_pose) -> np.ndarray:
    """The ``flow`` image: (du, dv, valid) of each pixel to the next frame (module docstring),
    shape (H, W, 3), float32.

    Parameters
    ----------
    scene : raytrace.scene.Scene
        The target's scene (its occlusion rays, vertices and :attr:`~raytrace.scene.Scene.ray_eps_m`).
    camera : Camera
        The camera of both frames.
    hits : PixelHits
        This frame's hits (:func:`pixel_hits`).
    next_pose : tuple or None
        (R_cam_from_body, t_cam_m) of the next planned frame; None for the last frame of a
        sequence: every pixel (0, 0, 0).

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        du, dv [px] where the point lies in front of the next frame's camera (0 elsewhere,
        and on background); validity 1 where it lies in the next image and is seen there, else 0.
    """
    out = np.zeros(hits.shape + (3,), dtype=np.float32)
    if next_pose is None or not hits.face.size:
        return out
    R1, t1 = _pose(*next_pose)
    c1 = -_times(t1[None, :], np.ascontiguousarray(R1.T))[0]  # the next optical centre, body frame
    W, H = camera.width, camera.height
    flat = out.reshape(-1, 3)
    for lo in range(0, hits.face.size, _CHUNK):
        sl = slice(lo, lo + _CHUNK)
        p = hits.p_body_m[sl]
        uv1 = camera.project(_times(p, R1) + t1)
        front = np.isfinite(uv1[:, 0])
        f = np.zeros((len(p), 3), dtype=np.float32)
        f[front, 0] = uv1[front, 0] - hits.cols[sl][front]
        f[front, 1] = uv1[front, 1] - hits.rows[sl][front]
        with np.errstate(invalid="ignore"):
            inside = front & (uv1[:, 0] >= -0.5) & (uv1[:, 0] < W - 0.5) & (uv1[:, 1] >= -0.5) & (uv1[:, 1] < H - 0.5)
        idx = np.flatnonzero(inside)
        if idx.size:
            f[idx, 2] = seen_from(scene, p[idx], hits.face[sl][idx], c1, normal_body=hits.normal_body[sl][idx])
        flat[hits.rows[sl] * W + hits.cols[sl]] = f
    return out


def seen_from(scene, p_body_m, face, centre_body_m, *, normal_body=None) -> np.ndarray:
    """Whether an optical centre sees the points ``p_body_m`` on their triangles ``face``: the
    segment from the centre to each point, its end pulled back along it by
    :attr:`raytrace.scene.Scene.ray_eps_m`, meets no triangle of ``scene`` — the centre's own ray
    through the point meets nothing before it; False for a triangle seen exactly edge-on.
    ``normal_body``: the triangles' normals (any length), if known. Shape (N,), bool.

    The segment is cast from its pulled-back end towards the centre (Embree holds float32
    coordinates: there they are target-sized, at the centre range-sized), on the same line, so
    that the test is the centre's primary ray's. With the centre outside the target's convex hull
    the line beyond the centre is outside it too, and the ray need not stop there (Embree's
    any-hit batch, :meth:`raytrace.scene.Scene.occluded`); and a point on a closed component wound
    outwards (:attr:`raytrace.scene.Scene.two_sided` False) whose triangle faces away from the
    centre is hidden by that component itself: no ray is cast for it (about half the points)."""
    face = np.asarray(face, dtype=np.int64)
    p = np.asarray(p_body_m, dtype=np.float64)
    if normal_body is None:
        V, Fc = scene.vertices, scene.faces
        a = V[Fc[face, 0]]
        normal_body = np.cross(V[Fc[face, 1]] - a, V[Fc[face, 2]] - a)
    c = np.asarray(centre_body_m, dtype=np.float64)
    u = c - p  # point → centre
    side = np.einsum("ij,ij->i", normal_body, u)  # > 0: the triangle's front faces the centre
    dist = np.sqrt(np.einsum("ij,ij->i", u, u))
    cast = (side != 0.0) & (dist > scene.ray_eps_m)
    outside = bool(np.all(np.einsum("ij,j->i", scene.hull_vertices - c, _axis_away(scene.hull_vertices, c)) > 0.0))
    if outside:
        cast &= (side > 0.0) | scene.two_sided[scene.component_of_face[face]]
    towards = u[cast] / dist[cast, None]
    origins = p[cast] + scene.ray_eps_m * towards
    if outside:
        blocked = scene.occluded(origins, towards, robust=True)
    else:
        blocked = scene.occluded(origins, c - origins, tfar=1.0, robust=True)
    seen = np.zeros(len(p), dtype=bool)
    seen[cast] = ~blocked
    return seen


def _axis_away(points: np.ndarray, c: np.ndarray) -> np.ndarray:
    """A unit direction from ``c`` towards the points' centroid: when every point lies strictly on
    its side of the plane through ``c`` normal to it, ``c`` is outside their convex hull."""
    d = points.mean(axis=0) - c
    nrm = np.linalg.norm(d)
    return d / nrm if nrm > 0 else np.array([0.0, 0.0, 1.0])


class FrameHits:
    """What the ``coords`` and ``flow`` producers of one frame share (:mod:`raytrace.dataset.modalities`):
    the scene, camera, pose, the geometry pass's frame and the next planned frame's pose (None
    for the last), with the hit points computed once on first use."""

    def __init__(self, scene, camera: Camera, R_cam_from_body, t_cam_m, geometry, next_pose=None):
        self.scene, self.camera, self.geometry, self.next_pose = scene, camera, geometry, next_pose
        self.R, self.t = _pose(R_cam_from_body, t_cam_m)
        self._hits = None

    @property
    def hits(self) -> PixelHits:
        if self._hits is None:
            self._hits = pixel_hits(self.scene.vertices, self.scene.faces, self.camera, self.R, self.t,
                                    self.geometry.face_index, rect=self.geometry.cast_rect)
        return self._hits

    def coords(self) -> np.ndarray:
        """:func:`coords_image` of this frame."""
        return coords_image(self.hits)

    def flow(self) -> np.ndarray:
        """:func:`flow_image` of this frame to the next."""
        return flow_image(self.scene, self.camera, self.hits, self.next_pose)
