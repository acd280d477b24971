"""One Embree scene per target and the geometry pass: exact depth, normals and ids per pixel.

:class:`Scene` owns a target's Embree BVH (one geometry per component, so ``geomID`` →
component), built lazily once and reused for every frame; it is dropped when the object is
pickled so scenes can be sent to worker processes. :meth:`Scene.render_geometry` casts one
primary ray per pixel centre — only inside the projection of the target's convex hull — and
returns every geometric AOV from the same hit record (:class:`GeometryFrame`).

Precision: Embree sees float32 body-frame coordinates, with every ray origin
advanced to just in front of the target so that they stay target-sized at any range; every
hit is then re-intersected in float64 with the triangle Embree reported from the true
optical centre, so depth is exact to float64 round-off rather than float32. Rays are
unnormalised with z = 1 in the camera frame, so the hit parameter is the z-depth. Embree
runs in robust (watertight) mode: no ray slips between triangles sharing an edge.
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import _kernels, presets
from ._threads import available_cores, parallel_chunksize
from .camera import Camera, distort_normalised, radial_limit
from .model import TargetModel

__all__ = ["GeometryFrame", "Scene", "default_threads"]

_RAYS_PER_CHUNK = 1 << 14  # rays per Embree call: small enough to balance threads, large enough to amortise
_ROWS_PER_TASK = 4  # image rows per task of cast_and_refine's parallel loop
_CULL_GROUPS = 64  # at most this many bounding polytopes cull the geometry pass's rays (_part_hulls)
_CULL_PARTS = True  # cast only inside the parts' polytopes' images (False: the whole rectangle)
_MIN_CHUNK = 2048  # fewest rays per Embree call of a batch on the thread pool
_POOL: ThreadPoolExecutor | None = None


def default_threads() -> int:
    """Threads for the geometry pass: the CPUs this process may use."""
    return available_cores()


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=default_threads(), thread_name_prefix="raytrace")
    return _POOL


_KDOP_DIRECTIONS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                             if (i, j, k) != (0, 0, 0)], dtype=np.float64)
_KDOP_DIRECTIONS /= np.linalg.norm(_KDOP_DIRECTIONS, axis=1, keepdims=True)


def _bounding_vertices(V: np.ndarray, max_vertices: int = 2048, max_points: int = 100_000) -> np.ndarray:
    """Vertices of a convex polytope that contains every point of ``V``, projected every
    frame to find the pixels worth casting: the convex hull when ``V`` has at most
    ``max_points`` points and the hull at most ``max_vertices`` vertices; else (or for flat
    point sets) a 26-DOP padded by 1e-6 of the size (the intersection of the 26 half-spaces
    n·x ≤ max n·V), which is looser but has a few dozen vertices."""
    from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError
    if len(V) <= max_points:
        try:
            hull = ConvexHull(V)
            if len(hull.vertices) <= max_vertices:
                return np.ascontiguousarray(V[hull.vertices], dtype=np.float64)
        except QhullError:
            pass  # flat or degenerate: the padded 26-DOP is full-dimensional
    size = max(float(np.ptp(V, axis=0).max()), 1e-9)
    h = (V @ _KDOP_DIRECTIONS.T).max(axis=0) + 1e-6 * size
    halfspaces = np.hstack([_KDOP_DIRECTIONS, -h[:, None]])
    inside = HalfspaceIntersection(halfspaces, V.mean(axis=0))
    return np.ascontiguousarray(inside.intersections, dtype=np.float64)


def _part_hulls(V: np.ndarray, vertex_offset, max_groups: int = _CULL_GROUPS) -> tuple[np.ndarray, np.ndarray]:
    """The bounding polytopes the geometry pass culls its rays with (:func:`_bounding_vertices`
    of each part, or of runs of consecutive parts when there are more than ``max_groups``):
    their vertices stacked, (m, 3) float64, and each polytope's first row, (G + 1,) int64. The
    target's one hull leaves most of a rectangle around rods and panels empty: on the 12 scenes
    of ``benchmarks/bench_time_error.py`` at 1280 × 960 the rays cast are 0.11–0.60 of the
    rectangle's pixels, whose hits are 0.09–0.59 of them (Cassini's boom and antennas: 0.11–0.14
    cast); its geometry pass took 0.63–0.77× the time (BENCHMARKS.md, "Rays only where a part
    may be")."""
    n_parts = len(vertex_offset) - 1
    bounds = np.unique(np.round(np.linspace(0, n_parts, min(n_parts, max_groups) + 1)).astype(np.int64))
    hulls = [_bounding_vertices(V[vertex_offset[a]:vertex_offset[b]]) for a, b in zip(bounds[:-1], bounds[1:])
             if vertex_offset[b] > vertex_offset[a]]
    ptr = np.cumsum([0] + [len(h) for h in hulls]).astype(np.int64)
    P = np.ascontiguousarray(np.concatenate(hulls) if hulls else np.empty((0, 3)), dtype=np.float64)
    return P, ptr


def closed_outward(mesh) -> bool:
    """Whether a trimesh mesh is closed and every connected body of it is wound outwards: it is
    watertight, its winding is consistent, and each body's signed volume (the divergence
    theorem, Σ v0 · (v1 × v2) / 6 over its faces) is positive. Only then can the radiance
    cache keep the front side of its faces alone; a mesh written with the opposite winding
    convention (clockwise, or one body inside out) is closed but seen from its faces' back."""
    if len(mesh.faces) == 0 or not (mesh.is_watertight and mesh.is_winding_consistent):
        return False
    import trimesh
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    T = np.asarray(mesh.vertices, dtype=np.float64)[mesh.faces]
    six_v = np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2]))
    return bool(np.all(np.bincount(labels, weights=six_v) > 0.0))


def _check_pose(R_cam_from_body, t_cam_m) -> tuple[np.ndarray, np.ndarray]:
    R = np.asarray(R_cam_from_body, dtype=np.float64)
    t = np.asarray(t_cam_m, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"R_cam_from_body must have shape (3, 3), got {R.shape}")
    if t.shape != (3,):
        raise ValueError(f"t_cam_m must have shape (3,), got {t.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError("R_cam_from_body and t_cam_m must be finite")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("R_cam_from_body must be a rotation matrix (orthonormal, det +1) to 1e-6")
    return R, t


@dataclass(frozen=True, slots=True, eq=False)
class GeometryFrame:
    """Geometric AOVs of one frame, all from the same primary hits (pixel centres).

    Attributes
    ----------
    depth_m : ndarray, shape (H, W), float32
        Z-depth along the optical axis [m]; ``inf`` where nothing is hit.
    normal_cam : ndarray, shape (H, W, 3), float32
        Unit shading normal in the camera frame, facing the camera; 0 on background.
    normal_geom_cam : ndarray, shape (H, W, 3), float32, or None
        Unit geometric (flat triangle) normal in the camera frame, facing the camera (when
        requested).
    instance : ndarray, shape (H, W), uint16
        Component id, k + 1 for component k of the target; 0 is background.
    face_index : ndarray, shape (H, W), int32
        Global triangle index hit (components concatenated in order); −1 on background.
    ray_distance_m : ndarray, shape (H, W), float32, or None
        Distance from the optical centre along the ray [m] (when requested).
    cast_rect : tuple of int
        (u0, v0, u1, v1): the pixel rectangle rays were cast in (end exclusive).
    n_components : int
        Number of components of the target.
    camera_inside_hull : bool
        The optical centre lies inside (or on) the target's convex hull, or the hull straddles
        the camera's z = 0 plane: culling was off (not when the target is wholly behind).
    semantic_lut : ndarray, shape (n_components + 1,), uint8
        Semantic class id of each instance id (0 → 0, background).
    visible_fraction : float
        Fraction of the target's silhouette (as the same pinhole would see it on an
        unbounded sensor) that falls inside the image [-]: 1 when the whole target is in
        frame, 0 when it is out of view (also wholly behind the camera); NaN when the
        camera is inside the target's convex hull or the hull straddles the camera's z = 0
        plane (the silhouette is unbounded there). The part outside the image is counted on a
        coarser grid when it is large (see :meth:`Scene.render_geometry`).
    """

    depth_m: np.ndarray
    normal_cam: np.ndarray
    normal_geom_cam: np.ndarray | None
    instance: np.ndarray
    face_index: np.ndarray
    ray_distance_m: np.ndarray | None
    cast_rect: tuple
    n_components: int
    camera_inside_hull: bool
    semantic_lut: np.ndarray
    visible_fraction: float

    @property
    def semantic(self) -> np.ndarray:
        """Semantic class id per pixel (raytrace.model.SEMANTIC_CLASSES index + 1), shape (H, W), uint8."""
        return self.semantic_lut[self.instance]

    @property
    def mask(self) -> np.ndarray:
        """Binary target mask, shape (H, W), bool."""
        return self.instance > 0

    @property
    def pixel_counts(self) -> np.ndarray:
        """Visible pixels per id, shape (n_components + 1,), int64 (index 0 = background)."""
        return np.bincount(self.instance.ravel(), minlength=self.n_components + 1)

    @property
    def bbox_xyxy(self) -> tuple | None:
        """(u_min, v_min, u_max, v_max) of the mask, inclusive pixel indices; None if empty."""
        rows = np.flatnonzero(self.mask.any(axis=1))
        if rows.size == 0:
            return None
        cols = np.flatnonzero(self.mask.any(axis=0))
        return int(cols[0]), int(rows[0]), int(cols[-1]), int(rows[-1])

    @property
    def bbox_xywh(self) -> tuple | None:
        """BOP-style [x, y, width, height] of the mask [px]; None if empty."""
        b = self.bbox_xyxy
        return None if b is None else (b[0], b[1], b[2] - b[0] + 1, b[3] - b[1] + 1)


class Scene:
    """A target's Embree scene plus the float64 geometry needed to refine its hits.

    Parameters
    ----------
    model : TargetModel
        The target, in its body frame [m].
    """

    def __init__(self, model: TargetModel):
        if not isinstance(model, TargetModel):
            raise ValueError(f"model must be a raytrace.model.TargetModel, got {type(model).__name__}")
        self.model = model
        verts, faces, offsets, creases, comp_of_face = [], [], [0], [], []
        base = 0
        for k, comp in enumerate(model.components):
            v = np.asarray(comp.mesh.vertices, dtype=np.float64)
            f = np.asarray(comp.mesh.faces, dtype=np.int64)
            verts.append(v)
            faces.append(f + base)
            base += len(v)
            offsets.append(offsets[-1] + len(f))
            creases.append(comp.crease_angle_rad)
            comp_of_face.append(np.full(len(f), k, dtype=np.int64))
        self.vertices = np.ascontiguousarray(np.concatenate(verts))
        self.faces = np.ascontiguousarray(np.concatenate(faces))
        if len(self.vertices) >= 2**31:
            raise ValueError(f"model {model.name}: at most 2**31 - 1 vertices, got {len(self.vertices)}")
        self.face_offset = np.asarray(offsets, dtype=np.int64)
        self.vertex_offset = np.cumsum([0] + [len(v) for v in verts])
        self.component_of_face = np.concatenate(comp_of_face)
        self.face_normal, self.corner_normal = self._normals(self.component_of_face, np.asarray(creases))
        self.hull_vertices = _bounding_vertices(self.vertices)
        self.part_hulls = _part_hulls(self.vertices, self.vertex_offset)
        self.scale_m = float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))
        # offset of secondary rays' origins from the surface [m]: 2·10⁻⁵ of the target's size,
        # or, for a mesh far from its origin, ~16–32 float32 ulps of its largest coordinate
        # (Embree holds vertices and ray origins in float32: a 1 m sphere 5 km from the
        # origin, ulp 0.5 mm, cast shadow acne over its lit side with the size-based 20 µm)
        far = float(np.abs(self.vertices).max()) if len(self.vertices) else 0.0
        self.ray_eps_m = max(2e-5 * max(self.scale_m, 1e-3), 2.0**-19 * far)
        if far > 1e3 * max(self.scale_m, 1e-3):
            warnings.warn(f"model {model.name}: its vertices lie up to {far:.4g} m from the body origin, "
                          f"{far / max(self.scale_m, 1e-3):.3g}x its size: float32 ray tracing loses precision "
                          "there; recentre the mesh (raytrace.meshio.load_mesh(..., recentre='bbox'))",
                          RuntimeWarning, stacklevel=2)
        self.semantic_lut = np.array([0] + [c.semantic_id for c in model.components], dtype=np.uint8)
        self._embree = None
        self._direct = None
        self._direct_fast = None
        self._caches = {}  # radiance caches by their options (sorted items)

    # ------------------------------------------------------------------ build
    def _normals(self, comp_of_face: np.ndarray, creases: np.ndarray):
        V, F = self.vertices, self.faces
        tri = V[F]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(cross, axis=1)
        if np.any(norm <= 0.0):
            bad = int(np.flatnonzero(norm <= 0.0)[0])
            k = int(comp_of_face[bad])
            raise ValueError(f"component {self.model.components[k].name} has a zero-area triangle "
                             f"(face {bad - self.face_offset[k]}); repair the mesh (raytrace.meshio) first")
        face_normal = cross / norm[:, None]
        # corner angles
        angles = np.empty((len(F), 3))
        for k in range(3):
            a = tri[:, (k + 1) % 3] - tri[:, k]
            b = tri[:, (k + 2) % 3] - tri[:, k]
            angles[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
        # weld identical positions within a component (smoothing never crosses components)
        key = np.column_stack([V, np.repeat(np.arange(len(self.face_offset) - 1), np.diff(self.vertex_offset))])
        _, weld = np.unique(key, axis=0, return_inverse=True)
        weld = weld.ravel().astype(np.int64)
        self.vertex_weld = weld  # welded vertex id of each vertex (same position, same component)
        corners = weld[F].ravel()
        order = np.argsort(corners, kind="stable")
        ptr = np.zeros(weld.max() + 2, dtype=np.int64)
        np.add.at(ptr, corners + 1, 1)
        ptr = np.cumsum(ptr)
        cos_crease = np.cos(creases)[comp_of_face]  # each face smooths with its component's angle
        corner = _kernels.corner_normals(V, F, face_normal, angles, ptr, order.astype(np.int64), weld, cos_crease)
        for k, comp in enumerate(self.model.components):  # authored normals replace the crease rule's
            if comp.corner_normals is not None:
                lo, hi = self.face_offset[k], self.face_offset[k + 1]
                ok = np.all(np.isfinite(comp.corner_normals), axis=2)
                corner[lo:hi][ok] = comp.corner_normals[ok]
        # float32 normals: 1e-7 rad is plenty, and half the memory traffic per hit
        return (np.ascontiguousarray(face_normal, dtype=np.float32), np.ascontiguousarray(corner, dtype=np.float32))

    @property
    def embree(self):
        """The Embree scene, built on first use (one TriangleMesh per component)."""
        if self._embree is None:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
            scene = rtcore_scene.EmbreeScene(robust=True)  # watertight: no leaks at shared edges and vertices
            vo = self.vertex_offset
            for k, comp in enumerate(self.model.components):
                v = np.ascontiguousarray(self.vertices[vo[k]:vo[k + 1]], dtype=np.float32)
                f = np.ascontiguousarray(self.faces[self.face_offset[k]:self.face_offset[k + 1]] - vo[k],
                                         dtype=np.int32)
                TriangleMesh(scene, v, f)
            self._embree = scene
        return self._embree

    @property
    def direct(self):
        """The same scene for kernels that call Embree themselves
        (:class:`raytrace._embree.DirectScene`), built on first use; None where the embreex
        wheel has no Embree 4 library to call."""
        if self._direct is None:
            from . import _embree
            self._direct = _embree.DirectScene(self.vertices, self.faces, self.vertex_offset, self.face_offset) \
                if _embree.available() else False
        return self._direct or None

    @property
    def direct_fast(self):
        """:attr:`direct` built without Embree's robust flag (its faster traversal and
        intersection arithmetic), for the rays that shade a preset's frame, where a ray that
        slips through the edge two triangles share (measured: once in 24 M rays cast at and
        from inside closed meshes) is one Monte Carlo sample in millions; the labels, the
        pixel centres' Sun, the radiance cache and the reference keep the robust scene
        (:data:`raytrace.presets.FAST_TRAVERSAL`).
        :attr:`direct` itself where that switch is off; None where :attr:`direct` is."""
        # The rays a preset's frame casts to shade it (sub-samples' Sun, soft shadows, final gathers and
        # their paths, glossy lobes and mirror rays, anti-aliasing sub-samples, coverage and corner rays,
        # stars) go through Embree built without its robust flag (Scene.direct_fast). The robust one
        # (Scene.direct) casts the geometry pass (the labels), the pixel centres' exact Sun, camera rays
        # that may start on a face (the camera inside the target's hull), the radiance cache's rays and
        # the reference path tracer's: only the robust mode reports a face a ray starts on (t = 0), which
        # the labels and the cache's contact rows count on. Measured (BENCHMARKS.md, "Embree's robust flag
        # where it matters only"): one frame on both cores 0.924× / 0.891× / 0.911× the time for
        # ``fast`` / ``balanced``-8 / -16 (median of the 12 scenes' ratios, side by side), the same
        # errors; sub-pixel primary rays 0.69–0.84× (Cassini's 11 m boom triangles gain most); of 2 M
        # rays from random surface points of each target, 3 or fewer found no hit where the robust
        # scene found one, ~1 % another triangle at the same distance (coincident faces, shared edges),
        # and the hit distances' error along the normal stayed below 0.005 of the rays' offset
        # ray_eps_m. presets.FAST_TRAVERSAL False: every ray robust.
        if not presets.FAST_TRAVERSAL or self.direct is None:
            return self.direct
        if self._direct_fast is None:
            from . import _embree
            self._direct_fast = _embree.DirectScene(self.vertices, self.faces, self.vertex_offset, self.face_offset,
                                                    robust=False)
        return self._direct_fast

    @property
    def materials(self) -> tuple:
        """BRDF of each component (:func:`raytrace.materials.material_of`), made once (a
        frame's shading asks for them; made anew they took 2 ms a frame on ICESat)."""
        if not hasattr(self, "_materials"):
            from .materials import material_of
            self._materials = tuple(material_of(c) for c in self.model.components)
        return self._materials

    procedural_materials = True
    """Whether the presets with a procedural material (gold/silver MLI's crinkle, the solar
    cells' grid: :mod:`raytrace.surfaces`) use it; False shades them uniform (set before the
    first frame)."""

    @property
    def material_tables(self) -> tuple:
        """(mat_par, face_uv, atlas, varying): the per-hit materials' tables
        (:func:`raytrace.surfaces.material_tables`), made once."""
        key = bool(self.procedural_materials)
        if getattr(self, "_material_tables_key", None) != key:
            from .surfaces import material_tables
            self._material_tables = material_tables(self.model.components, self.faces, self.vertices,
                                                    self.face_offset, procedural=key)
            self._material_tables_key = key
        return self._material_tables

    @property
    def two_sided(self) -> np.ndarray:
        """Per component: False when its mesh is a closed shell wound outwards (only the
        outside can be seen and lit: :func:`closed_outward`), True otherwise (open, or closed
        but wound inwards or inconsistently: either side may face the light), shape
        (n_components,), bool."""
        if not hasattr(self, "_two_sided"):
            self._two_sided = np.array([not closed_outward(c.mesh) for c in self.model.components])
        return self._two_sided

    def radiance_cache(self, **options):
        """The body-space radiance cache of this scene (:class:`raytrace.cache.RadianceCache`)
        with ``options``, built on first use and kept with the others (the ``fast`` and
        ``balanced`` presets can ask for different lattice spacings,
        :func:`raytrace.presets.preset_cache_options`)."""
        from .cache import RadianceCache
        key = tuple(sorted(options.items()))
        if key not in self._caches:
            self._caches[key] = RadianceCache(self, **options)
        return self._caches[key]

    def adopt_radiance_cache(self, cache, **options) -> None:
        """Use ``cache`` (built for this scene with ``options``, e.g. in another process and
        pickled with it) as :meth:`radiance_cache`'s with those options."""
        if cache.scene is not self:
            raise ValueError("the radiance cache was built for another scene")
        self._caches[tuple(sorted(options.items()))] = cache

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_embree"] = None
        state["_direct"] = None
        state["_direct_fast"] = None
        state["_caches"] = {}
        state.pop("_material_tables", None)  # rebuilt on first use (per-face, MBs on big meshes)
        state.pop("_material_tables_key", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)

    # ------------------------------------------------------------------ batched rays
    def _run(self, origins, directions, tfar, query, output):
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        n = len(o)
        far = None if tfar is None else np.ascontiguousarray(np.broadcast_to(tfar, (n,)), dtype=np.float32)
        scene = self.embree
        # at least 4 chunks per thread: a batch of 76 k rays in 65 k + 11 k chunks ran 1.1× faster
        # on 2 threads than on one, in 8 balanced chunks 1.9× (Cassini edge sub-pixel rays)
        chunk = max(_MIN_CHUNK, min(4 * _RAYS_PER_CHUNK, -(-n // (4 * default_threads()))))
        spans = [(a, min(a + chunk, n)) for a in range(0, n, chunk)]

        def run(span):
            a, b = span
            kw = {} if far is None else {"dists": far[a:b].copy()}
            return scene.run(o[a:b], d[a:b], query=query, output=output, **kw)

        if len(spans) <= 1:
            parts = [run(s) for s in spans]
        else:
            parts = list(_pool().map(run, spans))
        return parts

    def _direct_rays(self, origins, directions, tfar, robust: bool = True):
        """(direct scene, O, D) for the kernels of raytrace._embree when they can take this
        batch (Embree 4 loaded, no ``tfar``, a non-empty batch of (n, 3) rows), else None: the
        robust scene (:attr:`direct`), or with ``robust`` False :attr:`direct_fast`. The
        rows become float32, as :meth:`_run` makes them for embreex."""
        if tfar is not None or not presets.DIRECT_BATCHES:
            return None
        O = np.asarray(origins)
        D = np.asarray(directions)
        if O.ndim != 2 or O.shape[1:] != (3,) or D.shape != O.shape or not len(O):
            return None
        direct = self.direct if robust else self.direct_fast
        if direct is None:
            return None
        return direct, np.ascontiguousarray(O, dtype=np.float32), np.ascontiguousarray(D, dtype=np.float32)

    def intersect(self, origins, directions, *, tfar=None, robust: bool = False) -> dict:
        """Closest hits of a batch of rays (float32 body frame; directions need not be unit):
        Embree's ``geomID``, ``primID``, ``u``, ``v``, ``tfar`` arrays (geomID −1 on a miss;
        ``tfar`` in units of the direction's length). Where Embree 4 can be called from numba
        (:mod:`raytrace._embree`) and no ``tfar`` is given, the rays go through
        :func:`raytrace._embree.intersect_batch` on numba's threads (on batches of 0.5–5.8 M
        sub-pixel rays of the 12 benchmark scenes 0.85–1.07× embreex's time, median 0.91,
        ``benchmarks/bench_embree_paths.py``), in :attr:`direct_fast` (the rays of shading),
        or with ``robust`` in :attr:`direct` (embreex's arrays bit for bit); else through
        embreex (robust) in chunks on the thread pool."""
        fast = self._direct_rays(origins, directions, tfar, robust)
        if fast is not None:
            from . import _embree
            direct, O, D = fast
            n = len(O)
            out = {"geomID": np.empty(n, np.int32), "primID": np.empty(n, np.int32), "u": np.empty(n, np.float32),
                   "v": np.empty(n, np.float32), "tfar": np.empty(n, np.float32)}
            _embree.intersect_batch(direct.handle, O, D, out["geomID"], out["primID"], out["u"], out["v"],
                                    out["tfar"])
            return out
        parts = self._run(origins, directions, tfar, "INTERSECT", 1)
        if not parts:
            return {"geomID": np.empty(0, np.int32), "primID": np.empty(0, np.int32),
                    "u": np.empty(0, np.float32), "v": np.empty(0, np.float32), "tfar": np.empty(0, np.float32)}
        return {k: np.concatenate([p[k] for p in parts]) for k in ("geomID", "primID", "u", "v", "tfar")}

    def occluded(self, origins, directions, *, tfar=None, robust: bool = False) -> np.ndarray:
        """True where a ray hits anything before ``tfar`` (default: infinity), shape (n,); without
        ``tfar`` through raytrace._embree where it can (as :meth:`intersect`, ``robust`` too)."""
        fast = self._direct_rays(origins, directions, tfar, robust)
        if fast is not None:
            from . import _embree
            direct, O, D = fast
            out = np.empty(len(O), dtype=bool)
            _embree.occluded_batch(direct.handle, O, D, out)
            return out
        parts = self._run(origins, directions, tfar, "OCCLUDED", None)
        if not parts:
            return np.zeros(0, dtype=bool)
        return np.concatenate(parts) >= 0

    # ------------------------------------------------------------------ culling
    def projected_rect(self, camera: Camera, R_cam_from_body, t_cam_m) -> tuple | None:
        """Unclipped pixel rectangle (u0, v0, u1, v1), end exclusive, holding every pixel centre
        the target can cover; None when part of the target is at or behind the optical centre
        and part in front of it (its projection is unbounded); (0, 0, 0, 0) when all of it is
        behind the camera.

        The convex hull of the mesh contains the target; when all hull vertices lie in front
        of the camera, the projected target lies inside the convex hull of the projected
        vertices, so the rectangle (padded by one pixel) contains it.
        """
        R, t = _check_pose(R_cam_from_body, t_cam_m)
        return self._projected_rect(camera, self.hull_vertices @ R.T + t)

    def _projected_rect(self, camera: Camera, p_hull_cam: np.ndarray) -> tuple | None:
        p = p_hull_cam
        behind = p[:, 2] <= 1e-9 * max(self.scale_m, 1.0)
        if np.all(behind):
            return (0, 0, 0, 0)  # nothing in front of the camera: nothing to see
        if np.any(behind):
            return None
        if camera.distorted:
            # the target's rays lie in the box of its hull's normalised points; a pixel sees it
            # only if its undistorted ray does
            x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
            return camera.pixel_rect_of_box(float(x.min()), float(x.max()), float(y.min()), float(y.max()))
        u = camera.fx * p[:, 0] / p[:, 2] + camera.cx
        v = camera.fy * p[:, 1] / p[:, 2] + camera.cy
        return (math.floor(u.min()) - 1, math.floor(v.min()) - 1, math.ceil(u.max()) + 2, math.ceil(v.max()) + 2)

    def _near_plane(self, p_hull_cam: np.ndarray) -> float:
        """z of a plane just in front of the target, where rays start (0 if it straddles the camera)."""
        return max(0.0, float(p_hull_cam[:, 2].min()) - 1e-3 * max(self.scale_m, 1.0))

    def cast_rect(self, camera: Camera, R_cam_from_body, t_cam_m) -> tuple[tuple, bool]:
        """Pixel rectangle to cast (the projected rectangle clipped to the image), and whether
        culling was off because the camera is inside the target's convex hull."""
        full = self.projected_rect(camera, R_cam_from_body, t_cam_m)
        return self._clip(camera, full)

    @staticmethod
    def _clip(camera: Camera, full: tuple | None) -> tuple[tuple, bool]:
        if full is None:
            return (0, 0, camera.width, camera.height), True
        u0, v0 = max(0, full[0]), max(0, full[1])
        u1, v1 = min(camera.width, full[2]), min(camera.height, full[3])
        if u1 <= u0 or v1 <= v0:
            return (0, 0, 0, 0), False
        return (int(u0), int(v0), int(u1), int(v1)), False

    def _pixels_outside_image(self, camera: Camera, R, t, full: tuple, max_rays: int,
                              z0: float | None = None) -> float:
        """Silhouette pixels of the target outside the image, within the unclipped projected
        rectangle ``full``: the strips above, below, left and right of the image are cast
        (hit or miss only) on the image's pixel grid, subsampled by an integer stride when
        they hold more than ``max_rays`` pixels (then an estimate: hits · stride²)."""
        U0, V0, U1, V1 = full
        W, H = camera.width, camera.height
        va, vb = max(V0, 0), min(V1, H)
        strips = [(U0, V0, U1, min(V1, 0)), (U0, max(V0, H), U1, V1),      # above, below
                  (U0, va, min(U1, 0), vb), (max(U0, W), va, U1, vb)]      # left, right
        strips = [s for s in strips if s[2] > s[0] and s[3] > s[1]]
        area = sum((s[2] - s[0]) * (s[3] - s[1]) for s in strips)
        if area == 0:
            return 0.0
        stride = max(1, math.ceil(math.sqrt(area / max_rays)))
        R_body_from_cam = np.ascontiguousarray(R.T)
        o_body = -R_body_from_cam @ t
        if z0 is None:
            z0 = self._near_plane(self.hull_vertices @ R.T + t)
        hits = 0
        for u0, v0, u1, v1 in strips:
            # pixel centres u0 + k·stride (…), cast through a camera whose pixels are stride wide
            w = (u1 - u0 + stride - 1) // stride
            h = (v1 - v0 + stride - 1) // stride
            o32 = np.empty((w * h, 3), dtype=np.float32)
            d32 = np.empty((w * h, 3), dtype=np.float32)
            _kernels.make_rays(o_body, R_body_from_cam, camera.fx / stride, camera.fy / stride,
                               (camera.cx - u0) / stride, (camera.cy - v0) / stride, *camera.lens_arrays(), 0, 0,
                               w, h, z0, o32, d32)  # (a pinhole: distorted cameras take _distorted_fraction)
            hits += int(np.count_nonzero(self.embree.run(o32, d32) >= 0))
        return float(hits) * stride * stride

    def _distorted_fraction(self, camera: Camera, R, t, p_hull_cam: np.ndarray, max_rays: int) -> float:
        """Visible fraction of the target through a distorted camera: its silhouette is
        measured in the undistorted image plane, on the pinhole pixel grid of the same K over
        the box of the hull's normalised points (subsampled by an integer stride when it
        holds more than ``max_rays`` points); a hit counts as in view where its distorted
        point lies in the image (−0.5 ≤ u < W − 0.5, −0.5 ≤ v < H − 0.5) within the distortion's
        invertible radius. An estimate when strided."""
        x = p_hull_cam[:, 0] / p_hull_cam[:, 2]
        y = p_hull_cam[:, 1] / p_hull_cam[:, 2]
        U0, U1 = math.floor(camera.fx * x.min() + camera.cx) - 1, math.ceil(camera.fx * x.max() + camera.cx) + 2
        V0, V1 = math.floor(camera.fy * y.min() + camera.cy) - 1, math.ceil(camera.fy * y.max() + camera.cy) + 2
        stride = max(1, math.ceil(math.sqrt((U1 - U0) * (V1 - V0) / max_rays)))
        uu, vv = np.meshgrid(np.arange(U0, U1, stride, dtype=np.float64), np.arange(V0, V1, stride, dtype=np.float64))
        xs, ys = (uu.ravel() - camera.cx) / camera.fx, (vv.ravel() - camera.cy) / camera.fy
        d = np.column_stack([xs, ys, np.ones(len(xs))]) @ R  # R_body_from_cam (x, y, 1), per row
        o_body = -R.T @ t
        z0 = self._near_plane(p_hull_cam)
        hit = self.embree.run((o_body + z0 * d).astype(np.float32), d.astype(np.float32)) >= 0
        if not hit.any():
            return 0.0
        xs, ys = xs[hit], ys[hit]
        xd, yd = distort_normalised(xs, ys, camera.dist_coeffs)
        u, v = camera.fx * xd + camera.cx, camera.fy * yd + camera.cy
        seen = (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5) & \
            (np.hypot(xs, ys) <= radial_limit(camera.dist_coeffs))
        return float(np.count_nonzero(seen)) / len(xs)

    # ------------------------------------------------------------------ render
    def render_geometry(self, camera: Camera, R_cam_from_body, t_cam_m, *, cull: bool = True,
                        ray_distance: bool = False, geometric_normal: bool = False,
                        threads: int | None = None, visible_fraction: bool = True) -> GeometryFrame:
        """Cast primary rays and return depth, normals and ids for one pose.

        Parameters
        ----------
        camera : Camera
            Intrinsics and image size.
        R_cam_from_body : array_like, shape (3, 3)
            Target attitude in the camera frame (``p_cam = R p_body + t``) [-].
        t_cam_m : array_like, shape (3,)
            Target origin in the camera frame [m].
        cull : bool, keyword-only
            Cast only inside the projected convex hull (True, default) or every pixel.
            Both give identical images.
        ray_distance : bool, keyword-only
            Also return the distance along each ray.
        geometric_normal : bool, keyword-only
            Also return the flat (triangle) normal.
        threads : int, keyword-only, optional
            Threads for ray casting. Default: numba's thread count of the calling thread
            (rays, Embree and refinement in one kernel, :func:`raytrace._kernels.cast_and_refine`),
            or every CPU of the process (:func:`default_threads`) where the embreex wheel has no
            Embree 4 to call; given, the rays go through ``embreex`` in row chunks: 1 in the
            calling thread, more on that many threads of a pool. The result does not depend on
            it.
        visible_fraction : bool, keyword-only
            Compute :attr:`GeometryFrame.visible_fraction`. Free when the target is wholly in
            frame; when it crosses the border, the part of its silhouette outside the image is
            counted with hit-only rays on the same pixel grid (a coarser one when that would
            take more than 1/4 of the image's rays: then the fraction is an estimate, good to a
            few per cent for a target mostly outside the image).

        Returns
        -------
        GeometryFrame
        """
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a raytrace.camera.Camera, got {type(camera).__name__}")
        R, t = _check_pose(R_cam_from_body, t_cam_m)
        H, W = camera.height, camera.width
        p_hull = self.hull_vertices @ R.T + t  # projected once per frame
        full = self._projected_rect(camera, p_hull)
        rect, inside = self._clip(camera, full)
        if not cull:
            rect = (0, 0, W, H)
        depth = np.full((H, W), np.inf, dtype=np.float32)
        dist = np.full((H, W), np.inf, dtype=np.float32) if ray_distance else np.empty((1, 1), np.float32)
        n_shade = np.zeros((H, W, 3), dtype=np.float32)
        n_geom = np.zeros((H, W, 3), dtype=np.float32) if geometric_normal else np.empty((1, 1, 3), np.float32)
        inst = np.zeros((H, W), dtype=np.uint16)
        face = np.full((H, W), -1, dtype=np.int32)

        u0, v0, u1, v1 = rect
        w = u1 - u0
        if w > 0 and v1 > v0:
            R_body_from_cam = np.ascontiguousarray(R.T)
            o_body = -R_body_from_cam @ t
            # start rays just in front of the target (its nearest hull vertex) unless inside it
            z0 = 0.0 if inside else self._near_plane(p_hull)
            fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
            lens, table = camera.lens_arrays()
            direct = self.direct if presets.CAST_IN_ONE_KERNEL and threads is None else None
            if direct is not None:
                # rays, Embree and refinement in one kernel on numba's threads (the calling
                # thread's count), rows handed out a few at a time: the hits crowd into part of
                # the rectangle. The same AOVs as the chunks below, bit for bit.
                cast = np.empty((0, 0), np.uint8)
                # (the parts' polytopes cull a pinhole's rays: under distortion the image of a
                # convex polytope is no convex polygon, and the whole rectangle is cast)
                if cull and not inside and _CULL_PARTS and not camera.distorted:
                    # within the rectangle only the pixels in the image of some part's bounding
                    # polytope: the same hits, 0.11–0.60 of the rays on the benchmark scenes
                    P, ptr = self.part_hulls
                    cast = np.empty((v1 - v0, w), np.uint8)
                    _kernels.cull_mask(P @ R.T + t, ptr, fx, fy, cx, cy, u0, v0, w, v1 - v0,
                                       1e-9 * max(self.scale_m, 1.0), cast)
                with parallel_chunksize(_ROWS_PER_TASK):
                    _kernels.cast_and_refine(direct.handle, o_body, R_body_from_cam, R, fx, fy, cx, cy, lens, table,
                                             u0, v0, w,
                                             v1 - v0, z0, self.vertices, self.faces, self.face_offset,
                                             self.face_normal, self.corner_normal, depth, dist, n_shade, n_geom,
                                             inst, face, ray_distance, geometric_normal, cast)
            else:  # row chunks through embreex, on a thread pool
                scene = self.embree

                def chunk(va: int, h: int) -> None:  # rows [va, va + h): disjoint outputs per chunk
                    o32 = np.empty((h * w, 3), dtype=np.float32)
                    d32 = np.empty((h * w, 3), dtype=np.float32)
                    _kernels.make_rays(o_body, R_body_from_cam, fx, fy, cx, cy, lens, table, u0, va, w, h, z0, o32, d32)
                    hits = scene.run(o32, d32, query="INTERSECT", output=1)
                    _kernels.refine_hits(o_body, R_body_from_cam, R, fx, fy, cx, cy, lens, table, u0, va, w, h, z0,
                                         hits["geomID"], hits["primID"], hits["tfar"], self.vertices, self.faces,
                                         self.face_offset, self.face_normal, self.corner_normal,
                                         depth, dist, n_shade, n_geom, inst, face, ray_distance, geometric_normal)

                rows = max(1, _RAYS_PER_CHUNK // w)
                starts = range(v0, v1, rows)
                if threads is None:
                    threads = default_threads()
                if threads == 1 or len(starts) == 1:
                    for va in starts:
                        chunk(va, min(rows, v1 - va))
                else:
                    futures = [_pool().submit(chunk, va, min(rows, v1 - va)) for va in starts]
                    for f in futures:
                        f.result()
        fraction = math.nan
        if visible_fraction:
            seen = int(np.count_nonzero(inst))
            if full is None:
                fraction = math.nan
            elif rect[2] <= rect[0] or rect[3] <= rect[1]:
                fraction = 0.0  # the projection misses the image
            elif full[0] >= 0 and full[1] >= 0 and full[2] <= W and full[3] <= H:
                fraction = 1.0 if seen else 0.0  # wholly inside the image (or hidden: nothing to see)
            elif camera.distorted:
                fraction = self._distorted_fraction(camera, R, t, p_hull, max(1024, W * H // 4)) if seen else 0.0
            else:
                total = seen + self._pixels_outside_image(camera, R, t, full, max_rays=max(1024, W * H // 4),
                                                          z0=self._near_plane(p_hull))
                fraction = 0.0 if total == 0 else min(1.0, seen / total)
        return GeometryFrame(depth_m=depth, normal_cam=n_shade, normal_geom_cam=n_geom if geometric_normal else None,
                             instance=inst,
                             face_index=face, ray_distance_m=dist if ray_distance else None,
                             cast_rect=rect, n_components=len(self.model.components),
                             camera_inside_hull=inside, semantic_lut=self.semantic_lut,
                             visible_fraction=fraction)
