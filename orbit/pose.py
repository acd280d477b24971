"""Camera pointing, pinhole projection and 6-DoF pose labels.

Camera frame (OpenCV): x right, y down, z forward (boresight), origin at the optical centre.
The camera sits at ``rho_lvlh`` (the relative position of docs/conventions.md, observer minus
target, in LVLH) and looks at the target centre. A pose label maps target-body points into the
camera:

    p_cam = R_cam_from_body · p_body + t_cam,
    R_cam_from_body = R_cam_from_lvlh · R_lvlh_from_body,   t_cam = R_cam_from_lvlh · (0 − ρ).

Rotation conventions (active matrices, Hamilton scalar-first quaternions, z-y-x Euler angles)
are those of :mod:`orbit.rotations`. Pointing and labels: docs/orbit.md, "Camera pointing and
pose labels"; the pinhole: docs/conventions.md, "Camera model".

References
----------
R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., Cambridge
University Press (2004), ch. 6, doi:10.1017/CBO9780511811685.
T. Hodaň et al., "BOP: Benchmark for 6D object pose estimation", ECCV (2018),
doi:10.1007/978-3-030-01249-6_2 (label format: millimetres, row-major ``cam_R_m2c``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import finite_array, finite_scalar
from .rotations import euler_zyx_from_matrix, quat_continuous, quat_from_matrix, rot_z

__all__ = ["look_at", "pose_from_relative", "camera_matrix", "intrinsics_from_focal",
           "project", "PoseLabels", "pose_labels", "blender_from_opencv"]

_PARALLEL_TOL = 1e-6
"""|u_ref × ẑ_c| below which the up reference is taken as parallel to the boresight."""

_BLENDER_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])


def look_at(rho_lvlh, *, up_ref_lvlh=(0.0, 0.0, 1.0), roll_rad=0.0) -> np.ndarray:
    """Camera attitude that points the boresight at the target centre.

    Parameters
    ----------
    rho_lvlh : array_like, shape (3,) or (N, 3)
        Camera position relative to the target, LVLH [m].
    up_ref_lvlh : array_like, shape (3,) or (N, 3), optional
        Up reference u_ref in LVLH; image "up" (−y_cam) is kept as close to it as possible.
        Default +z_LVLH (orbit normal); normalised here [-].
    roll_rad : float or array_like, shape (N,), optional
        Extra rotation about the boresight applied as ``R_z(roll) · R`` [rad].

    Returns
    -------
    R_cam_from_lvlh : ndarray, shape (3, 3) or (N, 3, 3), float64
        Rows ``[x̂_cᵀ; ŷ_cᵀ; ẑ_cᵀ]`` [-].

    Raises
    ------
    ValueError
        If ``|rho_lvlh| = 0`` (camera at the target centre), ``up_ref_lvlh`` is zero, or an
        input is not finite.

    Notes
    -----
    ::

        ẑ_c = −ρ/|ρ|,   ŷ_c = −normalize(u − (u·ẑ_c) ẑ_c),   x̂_c = ŷ_c × ẑ_c

    Where ``|û_ref × ẑ_c| < 1e-6`` (up reference along the boresight) the row falls back to
    u = +y_LVLH, and to +x_LVLH if that is parallel too (possible only when u_ref ∥ y_LVLH).
    The projection is applied twice (re-orthogonalisation), so the result is orthonormal to
    rounding even when u_ref is just outside that tolerance.
    """
    rho = finite_array("rho_lvlh", rho_lvlh, shape_tail=(3,), ndim=(1, 2))
    single = rho.ndim == 1
    rho2 = np.atleast_2d(rho)
    dist = np.linalg.norm(rho2, axis=-1)
    if np.any(dist == 0.0):
        k = int(np.flatnonzero(dist == 0.0)[0])
        where = "" if single else f" at row {k}"
        raise ValueError(f"rho_lvlh must be non-zero (camera at the target centre){where}, "
                         f"got {rho2[k].tolist()}")
    up = finite_array("up_ref_lvlh", up_ref_lvlh, shape_tail=(3,), ndim=(1, 2))
    up_norm = np.linalg.norm(up, axis=-1, keepdims=True)
    if np.any(up_norm == 0.0):
        raise ValueError(f"up_ref_lvlh must be a non-zero 3-vector, got {up.tolist()}")
    if up.ndim == 2 and up.shape[0] not in (1, rho2.shape[0]):
        raise ValueError(f"up_ref_lvlh must have shape (3,) or ({rho2.shape[0]}, 3) like rho_lvlh, "
                         f"got {up.shape}")
    up = np.broadcast_to(up / up_norm, rho2.shape)

    z_c = -rho2 / dist[:, None]
    for fallback in ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)):
        parallel = np.linalg.norm(np.cross(up, z_c), axis=-1) < _PARALLEL_TOL
        up = np.where(parallel[:, None], np.asarray(fallback), up)
    u_perp = up
    for _ in range(2):  # Gram–Schmidt twice: u_ref may be within 1e-6 of the boresight
        u_perp = u_perp - np.sum(u_perp * z_c, axis=-1, keepdims=True) * z_c
    y_c = -u_perp / np.linalg.norm(u_perp, axis=-1, keepdims=True)
    x_c = np.cross(y_c, z_c)
    R = np.stack([x_c, y_c, z_c], axis=-2)

    roll = finite_array("roll_rad", roll_rad, ndim=(0, 1))
    if roll.ndim == 1 and roll.shape[0] not in (1, rho2.shape[0]):
        raise ValueError(f"roll_rad must be a scalar or have shape ({rho2.shape[0]},), "
                         f"got {roll.shape}")
    if np.any(roll != 0.0):
        R = rot_z(roll) @ R
    return R[0] if single else R


def pose_from_relative(rho_lvlh, R_lvlh_from_body, R_cam_from_lvlh):
    """Pose of the target body in the camera frame from the relative geometry.

    Parameters
    ----------
    rho_lvlh : array_like, shape (..., 3)
        Camera position relative to the target, LVLH [m].
    R_lvlh_from_body : array_like, shape (..., 3, 3)
        Target attitude [-].
    R_cam_from_lvlh : array_like, shape (..., 3, 3)
        Camera attitude, e.g. from :func:`look_at` [-].

    Returns
    -------
    R_cam_from_body : ndarray, shape (..., 3, 3), float64
        ``R_cam_from_lvlh · R_lvlh_from_body`` [-].
    t_cam_m : ndarray, shape (..., 3), float64
        Target origin in the camera frame, ``R_cam_from_lvlh · (−ρ)`` [m].

    Notes
    -----
    Leading dimensions broadcast; with them ``p_cam = R_cam_from_body p_body + t_cam_m``.
    """
    rho = finite_array("rho_lvlh", rho_lvlh, shape_tail=(3,))
    R_lb = finite_array("R_lvlh_from_body", R_lvlh_from_body, shape_tail=(3, 3))
    R_cl = finite_array("R_cam_from_lvlh", R_cam_from_lvlh, shape_tail=(3, 3))
    R_cam_from_body = R_cl @ R_lb
    t_cam_m = -(R_cl @ rho[..., None])[..., 0]
    return R_cam_from_body, t_cam_m


def camera_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole intrinsic matrix K (docs/conventions.md, "Camera model").

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels, ``f / p_x`` and ``f / p_y``, > 0 [px].
    cx, cy : float
        Principal point; integer pixel coordinates are pixel centres [px].

    Returns
    -------
    K : ndarray, shape (3, 3), float64
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` [px].
    """
    fx = finite_scalar("fx", fx, positive=True)
    fy = finite_scalar("fy", fy, positive=True)
    cx = finite_scalar("cx", cx)
    cy = finite_scalar("cy", cy)
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def intrinsics_from_focal(focal_length_m: float, pixel_pitch_m, width: int,
                          height: int) -> np.ndarray:
    """Intrinsic matrix of a sensor with a centred principal point.

    Parameters
    ----------
    focal_length_m : float
        Focal length f, > 0 [m].
    pixel_pitch_m : float or array_like, shape (2,)
        Pixel pitch p, or ``(p_x, p_y)``, > 0 [m].
    width, height : int
        Image size W × H, > 0 [px].

    Returns
    -------
    K : ndarray, shape (3, 3), float64
        ``f_x = f/p_x``, ``f_y = f/p_y``, ``c = ((W − 1)/2, (H − 1)/2)`` [px].
    """
    f = finite_scalar("focal_length_m", focal_length_m, positive=True)
    pitch = finite_array("pixel_pitch_m", pixel_pitch_m, ndim=(0, 1))
    if pitch.shape not in ((), (2,)) or not np.all(pitch > 0.0):
        raise ValueError(f"pixel_pitch_m must be a positive scalar or pair, got {pitch.tolist()}")
    px, py = np.broadcast_to(pitch, (2,))
    size = []
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"{name} must be a positive integer [px], got {v!r}")
        size.append(int(v))
    W, H = size
    return camera_matrix(f / px, f / py, 0.5 * (W - 1), 0.5 * (H - 1))


def project(K, p_cam) -> np.ndarray:
    """Pinhole projection of camera-frame points to pixel coordinates.

    Parameters
    ----------
    K : array_like, shape (3, 3)
        Intrinsic matrix with last row ``[0, 0, 1]`` [px].
    p_cam : array_like, shape (..., 3)
        Points in the camera frame (OpenCV: x right, y down, z forward) [m].

    Returns
    -------
    uv : ndarray, shape (..., 2), float64
        ``u = f_x x/z + s y/z + c_x``, ``v = f_y y/z + c_y`` [px]; NaN where z ≤ 0 (not imaged).
    """
    K = finite_array("K", K)
    if K.shape != (3, 3) or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise ValueError("K must be a 3x3 intrinsic matrix with last row [0, 0, 1], "
                         f"got {K.tolist()}")
    p = finite_array("p_cam", p_cam, shape_tail=(3,))
    z = p[..., 2:3]
    front = z > 0.0
    uvw = p @ K[:2].T
    uv = uvw / np.where(front, z, 1.0)
    return np.where(front, uv, np.nan)


@dataclass(frozen=True, slots=True, eq=False)
class PoseLabels:
    """Per-frame 6-DoF pose labels of the target in the camera frame.

    Attributes
    ----------
    R_cam_from_body : ndarray, shape (N, 3, 3), float64
        Rotation body → camera (OpenCV camera axes) [-].
    t_cam_m : ndarray, shape (N, 3), float64
        Target origin in the camera frame [m] (BOP ``cam_t_m2c`` is this × 1000, in mm).
    q_cam_from_body : ndarray, shape (N, 4), float64
        Hamilton scalar-first unit quaternion of ``R_cam_from_body``; q₀ ≥ 0 in the first
        frame, continuous afterwards (q_k · q_{k−1} ≥ 0) [-].
    euler_zyx_rad : ndarray, shape (N, 3), float64
        ``(yaw, pitch, roll)`` z-y-x Euler angles of ``R_cam_from_body`` [rad].

    Notes
    -----
    Arrays are stored read-only. Build with :func:`pose_labels`.
    """

    R_cam_from_body: np.ndarray
    t_cam_m: np.ndarray
    q_cam_from_body: np.ndarray
    euler_zyx_rad: np.ndarray

    def __post_init__(self):
        shapes = {"R_cam_from_body": (3, 3), "t_cam_m": (3,), "q_cam_from_body": (4,),
                  "euler_zyx_rad": (3,)}
        n = None
        for name, tail in shapes.items():
            a = finite_array(name, getattr(self, name), shape_tail=tail, ndim=(1 + len(tail),))
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise ValueError(f"{name} must have {n} rows like R_cam_from_body, "
                                 f"got {a.shape[0]}")
            a = a.copy()
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return self.t_cam_m.shape[0]


def pose_labels(R_cam_from_body, t_cam_m) -> PoseLabels:
    """Pose labels (matrix, translation, continuous quaternion, Euler angles) for a sequence.

    Parameters
    ----------
    R_cam_from_body : array_like, shape (N, 3, 3) or (3, 3)
        Rotations body → camera, in frame order [-].
    t_cam_m : array_like, shape (N, 3) or (3,)
        Target origin in the camera frame [m].

    Returns
    -------
    labels : PoseLabels
        With N rows (N = 1 for a single pose).

    Notes
    -----
    Quaternions by Shepperd's method (:func:`orbit.rotations.quat_from_matrix`) made
    continuous along the sequence (:func:`orbit.rotations.quat_continuous`).
    """
    R = finite_array("R_cam_from_body", R_cam_from_body, shape_tail=(3, 3), ndim=(2, 3))
    t = finite_array("t_cam_m", t_cam_m, shape_tail=(3,), ndim=(1, 2))
    R = R.reshape(-1, 3, 3)
    t = t.reshape(-1, 3)
    if R.shape[0] != t.shape[0]:
        raise ValueError(f"t_cam_m must have {R.shape[0]} rows like R_cam_from_body, "
                         f"got {t.shape[0]}")
    q = quat_continuous(quat_from_matrix(R))
    return PoseLabels(R, t, q, euler_zyx_from_matrix(R))


def blender_from_opencv(R, t):
    """Convert a camera-frame pose from OpenCV axes to Blender camera axes.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Rotation into the OpenCV camera frame (x right, y down, z forward), e.g.
        ``R_cam_from_body`` [-].
    t : array_like, shape (..., 3)
        Translation in the OpenCV camera frame [m].

    Returns
    -------
    R_blender : ndarray, shape (..., 3, 3), float64
        ``diag(1, −1, −1) · R``: into Blender's camera frame (x right, y up, looking
        along −z) [-].
    t_blender : ndarray, shape (..., 3), float64
        ``diag(1, −1, −1) · t`` [m].
    """
    R = finite_array("R", R, shape_tail=(3, 3))
    t = finite_array("t", t, shape_tail=(3,))
    return _BLENDER_FROM_OPENCV @ R, t * np.array([1.0, -1.0, -1.0])
