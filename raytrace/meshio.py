"""Load a user's mesh file (glTF/GLB, OBJ, PLY, STL, OFF, …) as a :class:`TargetModel`.

:func:`load_mesh` reads any format trimesh reads, keeps the file's parts as components,
validates and repairs each part, and returns the model with a :class:`MeshReport` that
states what was removed and why.

Conventions
-----------
Units
    ``unit_scale_m`` (metres per file unit) is required and never guessed: OBJ, PLY and STL
    carry no units, and glTF files that claim metres often are not. Use 1 for metre files,
    0.001 for millimetre files, 0.01 for centimetre files.
Body frame
    The file's model frame scaled to metres: axes and origin as authored (docs/conventions.md,
    "Body frame"). ``recentre="bbox"`` or ``"centroid"`` moves the origin to the centre of
    the bounding box or to the area-weighted surface centroid, for files whose origin is far
    from the object. The offset that was subtracted is kept in
    ``model.metadata["origin_offset_m"]``: ``p_body = unit_scale_m * p_file - offset``.
    Nothing sets a centre of mass: the components have ``mass_kg = 0``.
Parts
    A glTF scene gives one component per scene-graph node instance, with the node's world
    transform baked into the vertices; an OBJ gives one per object (``o``) and material
    (``usemtl``) pair; a single-mesh file (PLY, STL, OFF) gives one component. Names are the node names sanitised
    to ``lower_case`` and made unique with ``_2``, ``_3``, … suffixes.
Materials and semantic classes
    In this order: an entry in ``material_map`` / ``semantic_map`` (keyed by component name,
    node name, geometry name or file material name); then a heuristic on the names (material:
    file material name first, then the part name; semantic class: part name first); then
    ``default_material`` / ``"other"``.
Repair, per part, in this order (each removed face is counted once, in the first class it
falls in)
    1. *non-finite*: faces that touch a vertex with NaN/inf coordinates, or coordinates
       beyond the float32 range after scaling, are removed.
    2. Vertices at identical positions are welded (within the part only; never across parts).
    3. *degenerate*: faces with a repeated vertex index or an area of at most
       :data:`DEGENERATE_AREA_M2` after scaling are removed. Faces whose area falls to that
       level once the vertices are rounded to float32 (as Embree sees them, after
       recentring) also count here.
    4. *duplicate*: faces whose sorted vertex triple already occurred (whatever the
       winding) are removed; the first one is kept.
    5. Unreferenced vertices are dropped. A part left without faces is dropped.
    Winding is never changed (the renderer turns normals towards the camera); parts whose
    winding is inconsistent are counted. Holes are not filled.
Shading normals
    Where a part has the file's own vertex normals (glTF ``NORMAL``, OBJ ``vn``) they are the
    shading normals at its face corners (``authored_normals=True``, the default), rotated with
    the node, normalised, and turned to the side of each face's winding; zero, non-finite or
    inconsistent ones, and parts without normals, get the crease rule: the angle-weighted mean
    of the normals of the faces around the vertex within ``crease_angle_deg`` (default 30°;
    0 = flat facets, 180 = smooth everywhere) of the face's own.
Errors
    A missing, unreadable, unsupported or corrupt file, or one with nothing renderable left
    after repair, raises :class:`ValueError` with one line that names the file.
"""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from .model import MATERIALS, SEMANTIC_CLASSES, Component, TargetModel
from .surfaces import file_texture_names, surface_from_visual

__all__ = [
    "DEFAULT_CREASE_ANGLE_DEG",
    "DEGENERATE_AREA_M2",
    "RECENTRE_MODES",
    "check_crease_angle_deg",
    "MeshReport",
    "PartReport",
    "component_summary",
    "load_mesh",
]

DEGENERATE_AREA_M2 = 1e-12
"""Faces with an area at or below this, after scaling to metres, are degenerate [m²]."""

DEFAULT_CREASE_ANGLE_DEG = 30.0
"""Default crease angle of user meshes [deg] (as :data:`raytrace.model.DEFAULT_CREASE_ANGLE_RAD`)."""


def check_crease_angle_deg(value, what: str = "crease_angle_deg") -> float:
    """``value`` as a float in [0, 180] [deg], else ValueError with one line naming ``what``."""
    if (not isinstance(value, numbers.Real) or isinstance(value, bool) or not math.isfinite(value)
            or not 0.0 <= value <= 180.0):
        raise ValueError(f"{what} must be a number of degrees in [0, 180] (0 flat, 180 smooth), got {value!r}")
    return float(value)


RECENTRE_MODES = ("none", "bbox", "centroid")
"""Allowed values of ``recentre``: keep the authored origin, bounding-box centre, surface centroid."""

_F32_MAX = float(np.finfo(np.float32).max)

# Name heuristics: (result, alternatives); an alternative "a+b" needs a word starting with
# "a" and a word starting with "b". Words are the letter runs of the name, camelCase split.
_MATERIAL_RULES = (
    ("heat_shield", ("heat+shield", "heatshield", "ablat")),
    ("black_radiator", ("black+radiator",)),
    ("solar_cell", ("solar", "cell", "panel", "photovolt")),
    ("dish", ("dish", "reflector", "hga")),
    ("silver_mli", ("silver", "beta", "aluminized+mli", "aluminised+mli")),
    ("gold_mli", ("gold", "foil", "mli", "kapton", "bronze", "copper", "blanket")),
    ("white_paint", ("white",)),
    ("black_paint", ("black", "dark", "carbon", "graphite")),
    ("white_paint", ("paint", "radiator")),
    ("titanium", ("titan", "nozzle", "engine", "thruster", "rtg")),
    ("aluminium", ("alumin", "metal", "steel", "grey", "gray", "chrome", "mirror")),
)
_SEMANTIC_RULES = (
    ("heat_shield", ("heat+shield", "heatshield")),
    ("dish", ("dish", "reflector", "hga")),
    ("antenna", ("antenna", "whip", "rpws", "lga", "mga")),
    ("solar_panel", ("solar", "panel", "wing", "photovolt")),
    ("boom", ("boom", "mast", "magnetometer")),
    ("engine", ("engine", "nozzle")),
    ("thruster", ("thruster", "rcs")),
    ("rtg", ("rtg",)),
    ("radiator", ("radiator",)),
    ("probe", ("probe", "huygens")),
    ("docking_port", ("docking", "dock+port")),
    ("truss", ("truss",)),
    ("instrument", ("instrument", "camera", "sensor", "telescope", "mirror", "spectrometer",
                    "imager", "lidar")),
    ("module", ("module",)),
    ("bus", ("bus",)),
)


@dataclass(frozen=True, slots=True)
class PartReport:
    """What validation did to one part of the file.

    Attributes
    ----------
    name : str
        Component name given to the part (also for dropped parts).
    source_node : str
        Scene-graph node (or geometry) name in the file.
    source_material : str or None
        Material name in the file, if any.
    faces_in : int
        Triangles in the file.
    removed_nan : int
        Faces removed because they touch a non-finite vertex.
    removed_degenerate : int
        Faces removed because of a repeated vertex index or zero area (float64 or float32).
    removed_duplicate : int
        Faces removed because their vertex triple repeats an earlier face.
    faces_out : int
        Triangles kept; 0 means the part was dropped.
    watertight : bool
        Every edge of the kept faces is shared by exactly two faces.
    winding_consistent : bool
        Shared edges run in opposite directions in their two faces.
    """

    name: str
    source_node: str
    source_material: str | None
    faces_in: int
    removed_nan: int
    removed_degenerate: int
    removed_duplicate: int
    faces_out: int
    watertight: bool
    winding_consistent: bool

    @property
    def dropped(self) -> bool:
        """True when no face survived and the part is not in the model."""
        return self.faces_out == 0


@dataclass(frozen=True, slots=True)
class MeshReport:
    """Validation and repair report of one :func:`load_mesh` call.

    Attributes
    ----------
    path : str
        File that was read.
    unit_scale_m : float
        Metres per file unit that were applied [m].
    parts : tuple of PartReport
        Every triangle part of the file, in component order, dropped parts included.
    skipped : tuple of str
        Geometry without triangles (points, lines, empty meshes) that was ignored.
    origin_offset_m : tuple of float
        Point of the scaled file frame that became the body origin [m].
    """

    path: str
    unit_scale_m: float
    parts: tuple
    skipped: tuple = ()
    origin_offset_m: tuple = (0.0, 0.0, 0.0)

    def _total(self, field: str) -> int:
        return int(sum(getattr(p, field) for p in self.parts))

    @property
    def faces_in(self) -> int:
        """Triangles in the file."""
        return self._total("faces_in")

    @property
    def faces_out(self) -> int:
        """Triangles in the returned model."""
        return self._total("faces_out")

    @property
    def removed_nan(self) -> int:
        return self._total("removed_nan")

    @property
    def removed_degenerate(self) -> int:
        return self._total("removed_degenerate")

    @property
    def removed_duplicate(self) -> int:
        return self._total("removed_duplicate")

    @property
    def dropped_parts(self) -> tuple:
        """Names of parts left without faces (not in the model)."""
        return tuple(p.name for p in self.parts if p.dropped)

    @property
    def n_watertight(self) -> int:
        """Kept parts that are watertight."""
        return sum(1 for p in self.parts if not p.dropped and p.watertight)

    @property
    def n_winding_inconsistent(self) -> int:
        """Kept parts whose winding is not consistent (never repaired)."""
        return sum(1 for p in self.parts if not p.dropped and not p.winding_consistent)

    def non_finite_note(self) -> str | None:
        """One line when faces touching NaN/inf vertices were removed (a corrupt file, unlike the
        routine degenerate and duplicate faces of exported meshes), else None."""
        if not self.removed_nan:
            return None
        return (f"{Path(self.path).name}: {self.removed_nan} of {self.faces_in} triangles touch a NaN/inf vertex and "
                f"were removed; the other {self.faces_out} are rendered")

    def summary(self) -> str:
        """One line: parts and triangles kept, faces removed by reason, mesh quality flags."""
        kept = len(self.parts) - len(self.dropped_parts)
        line = (f"{Path(self.path).name}: {kept}/{len(self.parts)} parts, "
                f"{self.faces_out}/{self.faces_in} triangles kept "
                f"(removed {self.removed_nan} non-finite, {self.removed_degenerate} degenerate, "
                f"{self.removed_duplicate} duplicate); {self.n_watertight}/{kept} parts watertight, "
                f"{self.n_winding_inconsistent} winding-inconsistent; unit_scale_m={self.unit_scale_m:g}")
        if self.dropped_parts:
            line += f"; dropped: {', '.join(self.dropped_parts)}"
        if self.skipped:
            line += f"; skipped {len(self.skipped)} geometry without triangles"
        return line


# --------------------------------------------------------------------------- helpers
def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    text = text if len(text) <= 160 else text[:157] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _sanitise(text: str) -> str:
    """``"High-Gain Antenna.001"`` → ``"high_gain_antenna_001"``; empty → ``"part"``."""
    text = re.sub(r"([a-z])([A-Z])", r"\1_\2", text)
    out = re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")
    return out or "part"


def _words(text: str | None) -> list:
    if not text:
        return []
    return re.findall(r"[a-z]+", re.sub(r"([a-z])([A-Z])", r"\1 \2", text).lower())


def _match(rules, *texts) -> str | None:
    """Result of the first rule that matches, trying the texts in order (None if none matches)."""
    for text in texts:
        words = _words(text)
        for result, alternatives in rules:
            for alt in alternatives:
                if all(any(w.startswith(stem) for w in words) for stem in alt.split("+")):
                    return result
    return None


MESH_FILE_LIMIT_BYTES = 8 << 30
"""Largest mesh file read [bytes]; a device or pipe is refused before trimesh opens it."""


def _check_path(path) -> tuple[Path, str]:
    try:
        p = Path(os.fspath(path))
    except TypeError:
        raise ValueError(f"path must be a str or os.PathLike, got {type(path).__name__}") from None
    if not p.exists():
        raise ValueError(f"mesh file {p}: does not exist")
    if p.is_dir():
        raise ValueError(f"mesh file {p}: is a directory, expected a file")
    from .files import check_regular_file
    check_regular_file(p, limit_bytes=MESH_FILE_LIMIT_BYTES, what=f"mesh file {p}")
    formats = sorted(trimesh.available_formats(), key=len, reverse=True)
    lower = p.name.lower()
    for fmt in formats:
        if lower.endswith("." + fmt):
            return p, fmt
    allowed = sorted(fmt for fmt in formats if "_" not in fmt)  # stl_ascii is not an extension
    raise ValueError(f"mesh file {p}: unsupported format {p.suffix or '(no extension)'!r}; "
                     f"allowed: {', '.join(allowed)}")


def _check_map(mapping, allowed, what: str) -> dict:
    if mapping is None:
        return {}
    if not isinstance(mapping, Mapping):
        raise ValueError(f"{what} must be a dict of name -> value, got {type(mapping).__name__}")
    for key, value in mapping.items():
        if value not in allowed:
            raise ValueError(f"{what}[{key!r}] must be one of {', '.join(allowed)}; got {value!r}")
    return dict(mapping)


def _areas(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    with np.errstate(all="ignore"):
        return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)


def _compact(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices and renumber faces."""
    used = np.unique(f)
    remap = np.zeros(len(v), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f].reshape(-1, 3)


def _scene_parts(scene: trimesh.Scene, p: Path) -> tuple[list, list]:
    """Per triangle node: (node, geometry, material name, vertices [file units], faces, transform,
    file normals, visual)."""
    parts, skipped = [], []
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            skipped.append(str(node))
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        f = np.asarray(geom.faces)
        if (f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer)
                or f.min() < 0 or f.max() >= len(v) or v.ndim != 2 or v.shape[1] != 3):
            raise ValueError(f"mesh file {p}: corrupt part {node!r}: face indices out of range "
                             f"or malformed arrays (vertices {v.shape}, faces {f.shape})")
        material = getattr(getattr(geom.visual, "material", None), "name", None)
        parts.append((str(node), str(geom_name), material, v, f.astype(np.int64),
                      np.asarray(transform, dtype=np.float64), _file_normals(geom, len(v)), geom.visual))
    return parts, skipped


def _file_normals(geom: trimesh.Trimesh, n_vertices: int) -> np.ndarray | None:
    """The vertex normals the file itself gave (glTF ``NORMAL``, OBJ ``vn``), else None.

    With ``process=False`` trimesh's loaders pass the file's normals to the ``Trimesh``
    constructor, which puts them in its cache; normals trimesh would compute are never there
    before someone asks for them."""
    cache = getattr(getattr(geom, "_cache", None), "cache", {})
    n = cache.get("vertex_normals") if isinstance(cache, dict) else None
    if n is None:
        return None
    n = np.asarray(n, dtype=np.float64)
    return n if n.shape == (n_vertices, 3) else None


def _corner_normals(n_file: np.ndarray, f_file: np.ndarray, transform: np.ndarray, v: np.ndarray,
                    f: np.ndarray) -> np.ndarray:
    """Authored normals at the corners of the kept faces ``f`` (vertices ``v`` [m]), from the
    file's vertex normals ``n_file`` at the corners ``f_file`` of the same faces in the file.

    Normals transform with the inverse transpose of the node's linear part (a normal is a
    covector; e.g. Akenine-Möller et al., *Real-Time Rendering*, 4th ed., sec. 4.1.7), then are
    normalised. A face whose usable normals all point against its geometric normal
    (``(v1 - v0) x (v2 - v0)``) has them turned over: the file winds that face the other way
    round, and winding is kept as authored. Corners still against the geometric normal, zero,
    or non-finite are NaN: the crease rule fills them in."""
    with np.errstate(all="ignore"):
        M = np.linalg.inv(transform[:3, :3]).T
        n = n_file[f_file] @ M.T  # (n_faces, 3, 3)
        length = np.linalg.norm(n, axis=2, keepdims=True)
        n = n / length
        tri = v[f]
        g = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        good = np.isfinite(n).all(axis=2) & (length[..., 0] > 1e-12)
        dot = np.einsum("fkj,fj->fk", n, g)
        against = np.where(good, dot < 0, True).all(axis=1) & good.any(axis=1)
        n[against] *= -1.0
        dot[against] *= -1.0
        good &= dot > 0
    n[~good] = np.nan
    return n


def _clean(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int, int, np.ndarray]:
    """Steps 1–5 in float64: returns vertices, faces, removed (non-finite, degenerate, duplicate),
    and the index in ``f`` of each kept face."""
    idx = np.arange(len(f))
    ok_vertex = np.all(np.isfinite(v), axis=1)
    with np.errstate(invalid="ignore"):
        ok_vertex &= np.all(np.abs(v) <= _F32_MAX, axis=1)
    keep = ok_vertex[f].all(axis=1)
    n_nan = int(len(f) - keep.sum())
    f, idx = f[keep], idx[keep]
    if len(f) == 0:
        return v[:0], f, n_nan, 0, 0, idx
    v, f = _compact(v, f)
    welded, inverse = np.unique(v + 0.0, axis=0, return_inverse=True)  # + 0.0: -0 equals +0
    v, f = welded, inverse.reshape(-1)[f]
    degenerate = ((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
                  | (_areas(v, f) <= DEGENERATE_AREA_M2))
    n_degenerate = int(degenerate.sum())
    f, idx = f[~degenerate], idx[~degenerate]
    if len(f) == 0:
        return v[:0], f, n_nan, n_degenerate, 0, idx
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    n_duplicate = int(len(f) - len(first))
    f, idx = f[np.sort(first)], idx[np.sort(first)]
    v, f = _compact(v, f)
    return v, f, n_nan, n_degenerate, n_duplicate, idx


def _origin_offset(cleaned: list, recentre: str) -> np.ndarray:
    if recentre == "none":
        return np.zeros(3)
    if recentre == "bbox":
        lo = np.min([v.min(axis=0) for v, f in cleaned], axis=0)
        hi = np.max([v.max(axis=0) for v, f in cleaned], axis=0)
        return 0.5 * (lo + hi)
    weighted, total = np.zeros(3), 0.0
    for v, f in cleaned:
        a = _areas(v, f)
        weighted += (a[:, None] * v[f].mean(axis=1)).sum(axis=0)
        total += a.sum()
    return weighted / total


def _pick(mapping: dict, keys) -> str | None:
    for key in keys:
        if key is not None and key in mapping:
            return mapping[key]
    return None


# --------------------------------------------------------------------------- public API
def load_mesh(path, *, unit_scale_m: float, name: str | None = None,
              material_map: dict | None = None, semantic_map: dict | None = None,
              default_material: str = "aluminium",
              recentre: str = "none", crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG,
              authored_normals: bool = True, file_materials: bool = True) -> tuple[TargetModel, MeshReport]:
    """Load a mesh file as a target model, one component per part, validated and repaired.

    Parameters
    ----------
    path : str or os.PathLike
        Mesh file in any format trimesh reads here (``trimesh.available_formats()``: glb,
        gltf, obj, ply, stl, off, and archives of them).
    unit_scale_m : float, keyword-only
        Metres per file unit, finite and > 0 (1 for metres, 0.001 for millimetres) [m].
    name : str, optional, keyword-only
        Target name; default: the sanitised file stem.
    material_map : dict of str to str, optional, keyword-only
        Component name, node name, geometry name or file material name → one of
        :data:`~raytrace.model.MATERIALS`. Every key must name something in the file.
    semantic_map : dict of str to str, optional, keyword-only
        Same keys → one of :data:`~raytrace.model.SEMANTIC_CLASSES`.
    default_material : str, keyword-only
        Material of parts that neither map nor name heuristic assigns.
    recentre : {"none", "bbox", "centroid"}, keyword-only
        Body-frame origin: as authored (default), the centre of the axis-aligned bounding
        box, or the area-weighted surface centroid of all kept faces.
    crease_angle_deg : float, keyword-only
        Shading normals (where the file gives none, or ``authored_normals`` is False) average
        the faces around a vertex whose normals are within this angle of the face's own: 0
        shades every face flat, 180 smooths across every edge; default 30 [deg].
    authored_normals : bool, keyword-only
        Use the file's own vertex normals (glTF ``NORMAL``, OBJ ``vn``) as the shading normals
        of the parts that have them (default True); False applies the crease rule everywhere.
    file_materials : bool, keyword-only
        Shade the parts whose file material has a texture (glTF base colour, metallic-roughness
        or normal texture; OBJ ``map_Kd``) from it (:func:`raytrace.surfaces.surface_from_visual`),
        unless ``material_map`` names the part (default True); False: presets everywhere.

    Returns
    -------
    model : TargetModel
        Components in the body frame [m]; ``metadata`` holds ``source_path``,
        ``unit_scale_m``, ``recentre``, ``origin_offset_m``, ``crease_angle_deg`` and
        ``authored_normal_parts`` (how many components shade with the file's normals).
    report : MeshReport
        Per-part counts of removed faces and mesh-quality flags.

    Raises
    ------
    ValueError
        For invalid arguments; a missing, unreadable, unsupported or corrupt file; a file
        without triangles; or one whose faces are all non-finite, degenerate or duplicates.
        The message is one line and names the file.

    Notes
    -----
    See the module docstring for the repair order. A vertex ``x`` of node ``k`` becomes
    ``unit_scale_m * (T_k x) - origin_offset_m`` where ``T_k`` is the node's world transform.
    A mirroring transform (``det T_k < 0``) reverses that part's winding; like any winding
    defect it is left as is (the renderer turns normals towards the camera).
    """
    p, file_type = _check_path(path)
    if (not isinstance(unit_scale_m, numbers.Real) or isinstance(unit_scale_m, bool)
            or not math.isfinite(unit_scale_m) or unit_scale_m <= 0):
        raise ValueError(f"unit_scale_m must be a finite number > 0 (metres per file unit, "
                         f"e.g. 0.001 for millimetres), got {unit_scale_m!r}")
    scale = float(unit_scale_m)
    if recentre not in RECENTRE_MODES:
        raise ValueError(f"recentre must be one of {', '.join(RECENTRE_MODES)}; got {recentre!r}")
    if default_material not in MATERIALS:
        raise ValueError(f"default_material must be one of {', '.join(MATERIALS)}; got {default_material!r}")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise ValueError(f"name must be a non-empty string or None, got {name!r}")
    crease = check_crease_angle_deg(crease_angle_deg)
    if not isinstance(authored_normals, (bool, np.bool_)):
        raise ValueError(f"authored_normals must be true or false, got {authored_normals!r}")
    if not isinstance(file_materials, (bool, np.bool_)):
        raise ValueError(f"file_materials must be true or false, got {file_materials!r}")
    materials = _check_map(material_map, MATERIALS, "material_map")
    semantics = _check_map(semantic_map, SEMANTIC_CLASSES, "semantic_map")

    try:
        with np.errstate(all="ignore"):
            # OBJ: one part per object x material (trimesh merges objects by default)
            extra = {"split_objects": True} if file_type == "obj" else {}
            scene = trimesh.load_scene(str(p), file_type=file_type, process=False, **extra)
    except Exception as exc:  # trimesh raises many types for corrupt input
        raise ValueError(f"mesh file {p}: cannot be read as {file_type} ({_one_line(exc)})") from None
    raw, skipped = _scene_parts(scene, p)
    if not raw:
        raise ValueError(f"mesh file {p}: contains no triangles (empty file, or only points/lines)")

    # names: sanitised node names (file name → stem), unique by suffix
    names, taken = [], set()
    for node, *_ in raw:
        base = _sanitise(p.stem + node[len(p.name):] if node.startswith(p.name) else node)
        unique, k = base, 2
        while unique in taken:
            unique, k = f"{base}_{k}", k + 1
        taken.add(unique)
        names.append(unique)
    known = set(names) | {r[0] for r in raw} | {r[1] for r in raw} | {r[2] for r in raw if r[2]}
    for what, mapping in (("material_map", materials), ("semantic_map", semantics)):
        unknown = sorted(set(mapping) - known)
        if unknown:
            raise ValueError(f"{what} keys {unknown} name no part or material of {p.name}; "
                             f"parts: {', '.join(names)}")

    cleaned, counts, kept = [], [], []
    for node, geom_name, material, v, f, transform, _, _ in raw:
        with np.errstate(all="ignore"):
            v = (v @ transform[:3, :3].T + transform[:3, 3]) * scale
        v, f, n_nan, n_deg, n_dup, idx = _clean(v, f)
        cleaned.append((v, f))
        counts.append([n_nan, n_deg, n_dup])
        kept.append(idx)
    live = [(v, f) for v, f in cleaned if len(f)]
    offset = _origin_offset(live, recentre) if live else np.zeros(3)

    components, parts = [], []
    n_authored = 0
    file_textures = file_texture_names(p, file_type) if file_materials else None
    for (node, geom_name, material, _, f_in, transform, n_file, visual), part_name, (v, f), (n_nan, n_deg, n_dup), \
            idx in zip(raw, names, cleaned, counts, kept):
        watertight = winding = False
        if len(f):
            v = v - offset
            flat32 = _areas(v.astype(np.float32).astype(np.float64), f) <= DEGENERATE_AREA_M2
            n_deg += int(flat32.sum())
            f, idx = f[~flat32], idx[~flat32]
        if len(f):
            v, f = _compact(v, f)
            mesh = trimesh.Trimesh(vertices=v, faces=f, process=False, validate=False,
                                   metadata={"source_node": node, "source_material": material})
            watertight, winding = bool(mesh.is_watertight), bool(mesh.is_winding_consistent)
            keys = (part_name, node, geom_name, material)
            mat = (_pick(materials, keys) or _match(_MATERIAL_RULES, material, part_name)
                   or default_material)
            sem = _pick(semantics, keys) or _match(_SEMANTIC_RULES, part_name, material) or "other"
            normals = None
            if authored_normals and n_file is not None:
                normals = _corner_normals(n_file, f_in[idx], transform, v, f)
                n_authored += 1
            surface = None
            if file_materials and not _pick(materials, keys):
                surface = surface_from_visual(visual, f_in[idx], f"mesh file {p}: part {part_name!r}", file_textures)
            components.append(Component(name=part_name, mesh=mesh, material=mat, semantic=sem,
                                        crease_angle_rad=math.radians(crease), corner_normals=normals,
                                        surface=surface))
        parts.append(PartReport(name=part_name, source_node=node, source_material=material,
                                faces_in=len(f_in), removed_nan=n_nan, removed_degenerate=n_deg,
                                removed_duplicate=n_dup, faces_out=len(f), watertight=watertight,
                                winding_consistent=winding))

    report = MeshReport(path=str(p), unit_scale_m=scale, parts=tuple(parts), skipped=tuple(skipped),
                        origin_offset_m=tuple(float(x) for x in offset))
    if not components:
        raise ValueError(f"mesh file {p}: nothing renderable left after repair: all {report.faces_in} "
                         f"faces removed ({report.removed_nan} non-finite, {report.removed_degenerate} "
                         f"degenerate, {report.removed_duplicate} duplicate)")
    if len(components) > 65535:
        raise ValueError(f"mesh file {p}: {len(components)} parts, at most 65535 fit uint16 instance ids")
    model_name = name if name is not None else _sanitise(p.stem)
    n_tri = sum(len(c.mesh.faces) for c in components)
    model = TargetModel(
        name=model_name, components=tuple(components),
        description=(f"user mesh {p.name}: {len(components)} parts, {n_tri} triangles, "
                     f"unit_scale_m={scale:g}, origin {recentre if recentre != 'none' else 'as authored'}"),
        metadata={"source_path": str(p), "unit_scale_m": scale, "recentre": recentre,
                  "origin_offset_m": report.origin_offset_m, "crease_angle_deg": crease,
                  "authored_normal_parts": n_authored})
    return model, report


def component_summary(model: TargetModel) -> list:
    """One dict per component, in instance-id order, for printing.

    Returns
    -------
    list of dict
        Keys ``name``, ``material``, ``semantic`` and ``faces`` (triangle count).
    """
    return [{"name": c.name, "material": c.material, "semantic": c.semantic,
             "faces": len(c.mesh.faces)} for c in model.components]
