"""Previews of a sequence before it is rendered: pyvista scenes from plain arrays, off-screen.

A preview shows, for one or more sequences (one column each):

* top, in 3-D and at true scale in LVLH axes (x radial, y along-track, z orbit normal): the
  target mesh at the start frame's attitude, the observer trajectory as a tube coloured by
  time with its start and end marked, camera frusta every k frames pointing at the target,
  the Sun and Earth directions at the start frame as arrows from the target, and the frames
  whose visibility flags fail as red spheres (their frusta red too);
* bottom, the in-plane x–y projection like the classic relative-motion plots: along-track y
  to the right, radial x up (seen from −z, the orbit normal pointing into the page).

This module only draws what it is given — it knows nothing of orbits (the pipeline in
``cli.py`` turns a planned sequence into :class:`PreviewTrack` records, from the very states
the renderer uses). Nothing here needs a display: :func:`use_offscreen_backend` selects VTK's
EGL window (Mesa's software renderer on a headless Linux box) when there is no X or Wayland
display.
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from dataclasses import dataclass

import numpy as np

__all__ = [
    "AXIS_TITLES",
    "HTML_EXPORT_PACKAGES",
    "PreviewTrack",
    "build_plotter",
    "default_frusta_every",
    "frustum_lines",
    "has_display",
    "html_export_available",
    "use_offscreen_backend",
    "write_preview",
]

AXIS_TITLES = ("x radial [m]", "y along-track [m]", "z orbit normal [m]")
"""LVLH axis titles: origin at the target, x away from Earth, y along-track, z orbit normal."""

_TRAJ_CMAP = "viridis"
_HIDDEN_RGB = (0.85, 0.1, 0.1)
_FRUSTUM_RGB = (0.25, 0.25, 0.25)
_SUN_RGB = (1.0, 0.6, 0.0)
_EARTH_RGB = (0.1, 0.35, 0.9)
_ARROW_FRACTION = 0.4
"""Sun and Earth arrow length as a fraction of the scene size."""


def _array(name: str, value, shape: tuple, dtype=np.float64) -> np.ndarray:
    """``value`` as an array of ``shape`` (-1 = any length), finite if floating."""
    try:
        a = np.array(value, dtype=dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of shape {shape}, got {type(value).__name__}") from None
    if a.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, a.shape)):
        want = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {int(np.count_nonzero(~np.isfinite(a)))} NaN/inf value(s)")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, slots=True, eq=False)
class PreviewTrack:
    """One sequence to draw, as plain arrays in LVLH (origin at the target).

    Attributes
    ----------
    title : str
        Panel title (``"cassini spiral"``).
    r_lvlh_m : ndarray, shape (n, 3), float64
        Observer (camera) position per frame, the states the renderer uses [m].
    t_s : ndarray, shape (n,), float64
        Frame times, non-decreasing [s].
    visible : ndarray, shape (n,), bool
        Visibility flag per frame (false frames are highlighted).
    R_lvlh_from_cam : ndarray, shape (n, 3, 3), float64
        Camera axes in LVLH per frame (columns x right, y down, z boresight) [-].
    K : ndarray, shape (3, 3), float64
        Camera intrinsics [px].
    width, height : int
        Image size [px].
    vertices_lvlh_m : ndarray, shape (v, 3), float64
        Target mesh vertices in LVLH at the start frame's attitude [m].
    faces : ndarray, shape (f, 3), int64
        Triangles (indices into ``vertices_lvlh_m``).
    face_ids : ndarray, shape (f,), int64
        Instance id (component index + 1) per triangle, for colouring.
    sun_dir_lvlh : ndarray, shape (3,), float64
        Unit vector from the target to the Sun at the start frame [-].
    earth_dir_lvlh : ndarray, shape (3,), float64
        Unit vector from the target to the Earth's centre at the start frame [-].
    """

    title: str
    r_lvlh_m: np.ndarray
    t_s: np.ndarray
    visible: np.ndarray
    R_lvlh_from_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int
    vertices_lvlh_m: np.ndarray
    faces: np.ndarray
    face_ids: np.ndarray
    sun_dir_lvlh: np.ndarray
    earth_dir_lvlh: np.ndarray

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "title", str(self.title))
        r = _array("r_lvlh_m", self.r_lvlh_m, (-1, 3))
        n = r.shape[0]
        if n < 1:
            raise ValueError("r_lvlh_m must hold at least one frame, got 0")
        if np.any(np.linalg.norm(r, axis=1) == 0.0):
            raise ValueError("r_lvlh_m must not be at the target centre (|r| = 0)")
        set_(self, "r_lvlh_m", r)
        t = _array("t_s", self.t_s, (n,))
        if np.any(np.diff(t) < 0):
            raise ValueError("t_s must be non-decreasing")
        set_(self, "t_s", t)
        set_(self, "visible", _array("visible", self.visible, (n,), dtype=bool))
        R = _array("R_lvlh_from_cam", self.R_lvlh_from_cam, (n, 3, 3))
        if not np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9):
            raise ValueError("R_lvlh_from_cam must hold rotation matrices (orthonormal)")
        set_(self, "R_lvlh_from_cam", R)
        set_(self, "K", _array("K", self.K, (3, 3)))
        for name in ("width", "height"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
            set_(self, name, int(v))
        v = _array("vertices_lvlh_m", self.vertices_lvlh_m, (-1, 3))
        f = _array("faces", self.faces, (-1, 3), dtype=np.int64)
        if f.size and (f.min() < 0 or f.max() >= v.shape[0]):
            raise ValueError(f"faces must index vertices_lvlh_m (0..{v.shape[0] - 1}), "
                             f"got indices {f.min()}..{f.max()}")
        set_(self, "vertices_lvlh_m", v)
        set_(self, "faces", f)
        set_(self, "face_ids", _array("face_ids", self.face_ids, (f.shape[0],), dtype=np.int64))
        for name in ("sun_dir_lvlh", "earth_dir_lvlh"):
            d = _array(name, getattr(self, name), (3,))
            if abs(np.linalg.norm(d) - 1.0) > 1e-6:
                raise ValueError(f"{name} must be a unit vector, got norm {np.linalg.norm(d):.6g}")
            set_(self, name, d)

    @property
    def n_frames(self) -> int:
        return int(self.r_lvlh_m.shape[0])


# --------------------------------------------------------------------------- backend
def has_display() -> bool:
    """Whether windows can be opened: always on Windows and macOS, on other systems when
    ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set."""
    if sys.platform in ("win32", "darwin"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def use_offscreen_backend() -> None:
    """Choose VTK's EGL render window where no display exists (before the first window).

    VTK ≥ 9.4 wheels try X first and fall back to EGL, then OSMesa, printing a warning on
    the way; naming EGL (``VTK_DEFAULT_OPENGL_WINDOW``) skips the X attempt. A value the
    user already set is kept.
    """
    if not has_display():
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


HTML_EXPORT_PACKAGES = ("trame-pyvista", "nest_asyncio2")
"""What pyvista's HTML export needs (pyvista ≥ 0.49: the trame plotter component, which starts
its server through nest_asyncio2)."""


def html_export_available() -> bool:
    """Whether pyvista's HTML exporter and what it needs (:data:`HTML_EXPORT_PACKAGES`) are installed."""
    return all(importlib.util.find_spec(p.replace("-", "_")) is not None for p in HTML_EXPORT_PACKAGES)


# --------------------------------------------------------------------------- geometry
def default_frusta_every(n_frames: int, *, target: int = 12) -> int:
    """Stride k giving about ``target`` frusta over ``n_frames`` frames."""
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    return max(1, math.ceil(n_frames / target))


def frustum_lines(apex_m, R_lvlh_from_cam, K, width: int, height: int, depth_m: float) -> tuple:
    """The edges of one camera's view pyramid, cut at z-depth ``depth_m``.

    Parameters
    ----------
    apex_m : array_like, shape (3,)
        Camera centre in LVLH [m].
    R_lvlh_from_cam : array_like, shape (3, 3)
        Camera axes in LVLH (columns x right, y down, z boresight) [-].
    K : array_like, shape (3, 3)
        Intrinsics [px].
    width, height : int
        Image size [px]; the pyramid passes through the outer pixel corners.
    depth_m : float
        Depth of the far rectangle along the boresight [m].

    Returns
    -------
    points : ndarray, shape (5, 3), float64
        Apex, then the corners top-left, top-right, bottom-right, bottom-left (image order) [m].
    segments : ndarray, shape (8, 2), int64
        Point-index pairs: four apex-to-corner edges and the far rectangle.
    """
    if not (math.isfinite(depth_m) and depth_m > 0.0):
        raise ValueError(f"depth_m must be a finite number > 0, got {depth_m!r}")
    apex = np.asarray(apex_m, dtype=np.float64).reshape(3)
    R = np.asarray(R_lvlh_from_cam, dtype=np.float64).reshape(3, 3)
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    u = np.array([-0.5, width - 0.5, width - 0.5, -0.5])
    v = np.array([-0.5, -0.5, height - 0.5, height - 0.5])
    corners_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(4)], axis=1) * depth_m
    points = np.vstack([apex, apex + corners_cam @ R.T])
    segments = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]], dtype=np.int64)
    return points, segments


def _frusta_polydata(pv, track: PreviewTrack, frames) -> object:
    pts, lines = [], []
    for i in frames:
        depth = 0.3 * float(np.linalg.norm(track.r_lvlh_m[i]))
        p, seg = frustum_lines(track.r_lvlh_m[i], track.R_lvlh_from_cam[i], track.K, track.width, track.height, depth)
        base = 5 * len(pts)
        pts.append(p)
        lines.extend(np.hstack([np.full((8, 1), 2), seg + base]).ravel())
    poly = pv.PolyData(np.vstack(pts))
    poly.lines = np.asarray(lines, dtype=np.int64)
    return poly


def _polyline(pv, points: np.ndarray, t_s: np.ndarray):
    poly = pv.PolyData(np.asarray(points, dtype=np.float64))
    n = points.shape[0]
    poly.lines = np.concatenate([[n], np.arange(n)]).astype(np.int64)
    poly.point_data["t [s]"] = np.asarray(t_s, dtype=np.float64)
    return poly


# --------------------------------------------------------------------------- drawing
def _draw_3d(pl, pv, track: PreviewTrack, k: int, scale_m: float, title_size: int, clim: tuple) -> None:
    target = pv.PolyData.from_regular_faces(track.vertices_lvlh_m, track.faces)
    target.cell_data["instance id"] = track.face_ids
    pl.add_mesh(target, scalars="instance id", cmap="tab20", show_scalar_bar=False, name="target",
                smooth_shading=False)
    _draw_common(pl, pv, track, k, scale_m, clim, flat=False)
    pl.show_bounds(bounds=_bounds(track, scale_m, flat=False), grid="back", location="outer",
                   xtitle=AXIS_TITLES[0], ytitle=AXIS_TITLES[1], ztitle=AXIS_TITLES[2], font_size=10,
                   color="black", n_xlabels=4, n_ylabels=4, n_zlabels=3, fmt="%.0f")
    pl.add_axes(xlabel="x", ylabel="y", zlabel="z", color="black", line_width=2, viewport=(0.0, 0.0, 0.15, 0.25))
    n_vis = int(np.count_nonzero(track.visible))
    pl.add_text(f"{track.title}: {track.n_frames} frames, {n_vis} visible, "
                f"{track.t_s[-1] - track.t_s[0]:.0f} s (LVLH, true scale)", font_size=title_size, color="black",
                name="title")
    pl.camera_position = "iso"
    pl.camera.azimuth = 180.0  # look from +x, +y, +z side down towards the target
    pl.reset_camera()
    pl.camera.zoom(1.25)


def _draw_xy(pl, pv, track: PreviewTrack, k: int, scale_m: float, title_size: int, clim: tuple) -> None:
    flat = track.vertices_lvlh_m * np.array([1.0, 1.0, 0.0])
    target = pv.PolyData.from_regular_faces(flat, track.faces)
    target.cell_data["instance id"] = track.face_ids
    pl.add_mesh(target, scalars="instance id", cmap="tab20", show_scalar_bar=False, name="target",
                lighting=False)
    _draw_common(pl, pv, track, k, scale_m, clim, flat=True)
    pl.show_bounds(bounds=_bounds(track, scale_m, flat=True), grid="front", location="outer",
                   xtitle=AXIS_TITLES[0], ytitle=AXIS_TITLES[1], ztitle=" ", font_size=10, color="black",
                   show_zaxis=False, show_zlabels=False, n_xlabels=5, n_ylabels=5, fmt="%.0f")
    pl.add_text(f"{track.title}: in-plane x-y projection (y along-track right, x radial up)",
                font_size=title_size, color="black", name="title")
    pl.enable_parallel_projection()
    c = np.zeros(3)
    pl.camera_position = [(c[0], c[1], -10.0 * scale_m), tuple(c), (1.0, 0.0, 0.0)]
    pl.reset_camera()
    pl.camera.zoom(0.95)


def time_colour(t_s: float, clim: tuple) -> tuple:
    """The trajectory's colour (RGB in [0, 1]) at time ``t_s`` [s] on its colour bar ``clim``
    = (t_min, t_max) [s]."""
    from matplotlib import colormaps
    lo, hi = float(clim[0]), float(clim[1])
    frac = 0.0 if hi <= lo else min(max((float(t_s) - lo) / (hi - lo), 0.0), 1.0)
    return tuple(float(c) for c in colormaps[_TRAJ_CMAP](frac)[:3])


def _draw_common(pl, pv, track: PreviewTrack, k: int, scale_m: float, clim: tuple, *, flat: bool) -> None:
    r = track.r_lvlh_m * (np.array([1.0, 1.0, 0.0]) if flat else np.ones(3))
    line = _polyline(pv, r, track.t_s)
    pl.add_mesh(line, scalars="t [s]", cmap=_TRAJ_CMAP, clim=clim, line_width=6, render_lines_as_tubes=True,
                name="trajectory", scalar_bar_args={"title": "t [s]", "color": "black", "vertical": True,
                                                    "position_x": 0.9, "position_y": 0.25, "height": 0.5,
                                                    "width": 0.05, "fmt": "%.0f"})
    marker_r = 0.025 * scale_m
    # the markers take the colour bar's colours at their times, so the legend and the bar agree
    start_rgb, end_rgb = time_colour(track.t_s[0], clim), time_colour(track.t_s[-1], clim)
    pl.add_mesh(pv.Sphere(radius=marker_r, center=r[0]), color=start_rgb, name="start", label="start")
    pl.add_mesh(pv.Cube(center=r[-1], x_length=1.6 * marker_r, y_length=1.6 * marker_r, z_length=1.6 * marker_r),
                color=end_rgb, name="end", label="end")
    hidden = np.flatnonzero(~track.visible)
    if hidden.size:
        pl.add_mesh(pv.PolyData(r[hidden]), color=_HIDDEN_RGB, point_size=11, render_points_as_spheres=True,
                    name="not_visible", label="not visible")
    frames = np.arange(0, track.n_frames, k)
    if not flat:
        for name, sel, rgb in (("frusta", frames[track.visible[frames]], _FRUSTUM_RGB),
                               ("frusta_not_visible", frames[~track.visible[frames]], _HIDDEN_RGB)):
            if sel.size:
                pl.add_mesh(_frusta_polydata(pv, track, sel), color=rgb, line_width=1.5, name=name)
    else:  # boresights in the plane
        seg = np.stack([r[frames], r[frames] * 0.7], axis=1).reshape(-1, 3)
        pl.add_mesh(pv.line_segments_from_points(seg), color=_FRUSTUM_RGB, line_width=1.5, name="frusta")
    arrow_len = _ARROW_FRACTION * scale_m
    r_target = _target_radius(track)
    for (name, rgb), d in zip((("sun", _SUN_RGB), ("earth", _EARTH_RGB)), _arrow_dirs(track, flat)):
        if d is None:  # perpendicular to the projection plane
            continue
        start = d * 1.1 * r_target  # from the target's edge, so the arrows do not hide it
        pl.add_mesh(pv.Arrow(start=start, direction=d, scale=arrow_len, tip_length=0.15, tip_radius=0.04,
                             shaft_radius=0.015), color=rgb, name=name, label=f"{name.capitalize()} (start frame)")
        pl.add_point_labels(np.array([start + d * arrow_len * 1.08]), [name.capitalize()], font_size=12,
                            text_color=rgb, shape=None, show_points=False, always_visible=True, name=f"{name}_label")
    if not flat:
        pl.add_legend(bcolor="white", border=True, size=(0.16, 0.2), loc="lower right", face="circle")


def _arrow_dirs(track: PreviewTrack, flat: bool) -> list:
    """Sun and Earth arrow directions as drawn (projected to z = 0 when ``flat``; None when
    a direction is perpendicular to the plane)."""
    out = []
    for d in (track.sun_dir_lvlh, track.earth_dir_lvlh):
        d = d * np.array([1.0, 1.0, 0.0]) if flat else d
        norm = float(np.linalg.norm(d))
        out.append(None if norm < 1e-6 else d / norm)
    return out


def _target_radius(track: PreviewTrack) -> float:
    v = track.vertices_lvlh_m
    return float(np.max(np.linalg.norm(v, axis=1))) if v.size else 0.0


def _scale_m(track: PreviewTrack) -> float:
    """Size of the scene: the largest extent of the trajectory and the target [m]."""
    extent = float(np.max(np.ptp(np.vstack([track.r_lvlh_m, np.zeros((1, 3))]), axis=0)))
    return max(extent, 2.0 * _target_radius(track), 1e-3)


def _bounds(track: PreviewTrack, scale_m: float, *, flat: bool) -> list:
    """Axis box around trajectory, target and arrows; the thin axis padded to 1/4 of the scene."""
    pts = np.vstack([track.r_lvlh_m, track.vertices_lvlh_m if track.vertices_lvlh_m.size else np.zeros((1, 3)),
                     [np.zeros(3)]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    for d in _arrow_dirs(track, flat):  # the arrow tips
        tip = d * (1.1 * _target_radius(track) + _ARROW_FRACTION * scale_m)
        lo, hi = np.minimum(lo, tip), np.maximum(hi, tip)
    for ax in range(3):
        if hi[ax] - lo[ax] < 0.25 * scale_m:
            mid = 0.5 * (hi[ax] + lo[ax])
            lo[ax], hi[ax] = mid - 0.125 * scale_m, mid + 0.125 * scale_m
    if flat:
        lo[2] = hi[2] = 0.0
    return [lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]]


def build_plotter(tracks, *, size=(1600, 1000), frusta_every: int | None = None, off_screen: bool = True):
    """A pyvista Plotter with one column per track: 3-D scene on top, x–y projection below.

    Parameters
    ----------
    tracks : PreviewTrack or sequence of PreviewTrack
        Sequences to draw side by side.
    size : tuple of 2 int
        Window (and screenshot) size, width × height [px].
    frusta_every : int or None
        Draw a camera frustum every k frames (frames 0, k, 2k, …); None: about 12 per track.
    off_screen : bool
        Render without a window (no display needed).

    Returns
    -------
    pyvista.Plotter
        Subplot (0, j) holds the 3-D scene of track j, (1, j) its projection. Actors are
        named: ``trajectory`` (a polyline through exactly ``r_lvlh_m``; projected with z = 0
        below), ``start``, ``end``, ``not_visible``, ``frusta``, ``frusta_not_visible``,
        ``sun``, ``earth``, ``target``.
    """
    if isinstance(tracks, PreviewTrack):
        tracks = [tracks]
    tracks = list(tracks)
    if not tracks or not all(isinstance(t, PreviewTrack) for t in tracks):
        raise ValueError("tracks must be one or more PreviewTrack records")
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be two integers (width, height), got {size!r}") from None
    if not (64 <= w <= 16384 and 64 <= h <= 16384):
        raise ValueError(f"size must be within 64..16384 px per side, got {w}x{h}")
    if frusta_every is not None and not (isinstance(frusta_every, (int, np.integer)) and frusta_every >= 1):
        raise ValueError(f"frusta_every must be an integer >= 1 or None, got {frusta_every!r}")
    if off_screen:
        use_offscreen_backend()
    import pyvista as pv

    pl = pv.Plotter(shape=(2, len(tracks)), window_size=(w, h), off_screen=off_screen, border=True,
                    row_weights=(1.6, 1.0))
    pl.set_background("white")
    title_size = 9 if len(tracks) > 1 else 11
    t_all = np.concatenate([t.t_s for t in tracks])
    clim = (float(t_all.min()), float(max(t_all.max(), t_all.min() + 1e-9)))  # one time bar for all columns
    for j, track in enumerate(tracks):
        k = frusta_every or default_frusta_every(track.n_frames)
        scale = _scale_m(track)
        pl.subplot(0, j)
        _draw_3d(pl, pv, track, k, scale, title_size, clim)
        pl.subplot(1, j)
        _draw_xy(pl, pv, track, k, scale, title_size, clim)
    return pl


def write_preview(tracks, path: str, *, size=(1600, 1000), frusta_every: int | None = None,
                  html_path: str | None = None) -> str:
    """Render :func:`build_plotter` off-screen to a PNG of exactly ``size`` (and optionally an
    interactive HTML scene); returns ``path``.

    Raises
    ------
    ValueError
        Bad arguments; ``html_path`` given but pyvista's exporter is not installed.
    RuntimeError
        The HTML export failed (the PNG is written by then).
    """
    if html_path is not None and not html_export_available():
        raise ValueError(f"html_path needs pyvista's HTML exporter: pip install {' '.join(HTML_EXPORT_PACKAGES)}")
    pl = build_plotter(tracks, size=size, frusta_every=frusta_every, off_screen=True)
    try:
        pl.screenshot(path, window_size=tuple(int(v) for v in size), return_img=False)
        if html_path is not None:
            try:
                pl.trame.export_html(html_path)
            except Exception as exc:  # a third-party exporter: whatever it raises, report it in one line
                raise RuntimeError(f"HTML export to {html_path} failed ({type(exc).__name__}: "
                                   f"{' '.join(str(exc).split())})") from exc
    finally:
        pl.close()
    return path


def model_track(title: str, model, camera, r_lvlh_m, t_s, visible, R_lvlh_from_cam, R_cam_from_body,
                light0: dict) -> PreviewTrack:
    """The :class:`PreviewTrack` of a sequence of ``model`` seen by ``camera``: the observer
    positions ``r_lvlh_m`` (n, 3) [m] at times ``t_s`` with their ``visible`` flags, the camera
    axes ``R_lvlh_from_cam`` (n, 3, 3) and the renderer's poses ``R_cam_from_body`` (n, 3, 3);
    the target is drawn at the start frame's attitude ``R_lvlh_from_body = R_lvlh_from_cam @
    R_cam_from_body``, with the Sun and Earth directions of the start frame's ``light0``
    (``sun_dir_body``, ``earth_dir_body``)."""
    R_lvlh_from_cam = np.asarray(R_lvlh_from_cam, dtype=np.float64)
    R_lvlh_from_body0 = R_lvlh_from_cam[0] @ np.asarray(R_cam_from_body, dtype=np.float64)[0]
    verts, faces, ids, base = [], [], [], 0
    for k, comp in enumerate(model.components):
        v = np.asarray(comp.mesh.vertices, dtype=np.float64)
        f = np.asarray(comp.mesh.faces, dtype=np.int64)
        verts.append(v @ R_lvlh_from_body0.T)
        faces.append(f + base)
        ids.append(np.full(len(f), k + 1, dtype=np.int64))
        base += len(v)
    sun = R_lvlh_from_body0 @ np.asarray(light0["sun_dir_body"])
    earth = R_lvlh_from_body0 @ np.asarray(light0["earth_dir_body"])
    return PreviewTrack(title=title, r_lvlh_m=np.asarray(r_lvlh_m, dtype=np.float64), t_s=np.asarray(t_s),
                        visible=np.asarray(visible, dtype=bool), R_lvlh_from_cam=R_lvlh_from_cam, K=camera.K,
                        width=camera.width, height=camera.height, vertices_lvlh_m=np.vstack(verts),
                        faces=np.vstack(faces), face_ids=np.concatenate(ids),
                        sun_dir_lvlh=sun / np.linalg.norm(sun), earth_dir_lvlh=earth / np.linalg.norm(earth))


def check_outputs(out: str | None, html: str | None, interactive: bool) -> None:
    """Refuse, before any work, a preview's outputs that cannot be written as asked: ``out``
    (``--out``, a .png) or ``html`` (``--html``, a .html) naming a folder or another extension
    (the file would be written elsewhere, name + extension), ``interactive`` without a display,
    ``html`` without pyvista's exporter. Raises :class:`raytrace.dataset.UsageError`."""
    from .dataset import UsageError
    for option, path, ext in (("--out", out, ".png"), ("--html", html, ".html")):
        if path is not None and os.path.isdir(path):
            raise UsageError(f"{option}: {path} is a folder; give the file's name (e.g. "
                             f"{os.path.join(path, 'preview' + ext)})")
        if path is not None and not str(path).endswith(ext):
            raise UsageError(f"{option} must be a {ext} file name, got {path!r}")
    if interactive and not has_display():
        raise UsageError("argument --interactive: no display (DISPLAY and WAYLAND_DISPLAY are unset); "
                         "drop --interactive to write the PNG off-screen")
    if html is not None and not html_export_available():
        raise UsageError("argument --html: pyvista's HTML exporter is not installed "
                         f"(pip install {' '.join(HTML_EXPORT_PACKAGES)})")


def write_preview_files(tracks, out: str, *, size, frusta_every=None, html_path: str | None = None) -> None:
    """:func:`write_preview` into ``out`` (and ``html_path``), their folders created; failures as
    one-line :class:`raytrace.dataset.UsageError` naming the option."""
    from .dataset import UsageError
    for path in (out, html_path):
        if path is not None and os.path.dirname(os.path.abspath(path)):
            try:
                os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            except OSError as exc:
                raise UsageError(f"--out: cannot create the folder of {path} ({exc.strerror or exc})") from None
    try:
        write_preview(tracks, out, size=size, frusta_every=frusta_every, html_path=html_path)
    except OSError as exc:
        raise UsageError(f"--out: cannot write {out} ({exc.strerror or exc})") from None
    except RuntimeError as exc:
        raise UsageError(f"argument --html: {exc}; the PNG {out} is written") from None
