"""Target models: named components, each a triangle mesh with a material and a semantic class.

A :class:`TargetModel` is what the ray tracer renders: its components become one Embree
geometry each, so an Embree ``geomID`` maps to a component and component ``k`` (0-based) is
written as instance id ``k + 1`` (0 is background).

Frames and units: every mesh is in the target's **body frame**, in metres, with the origin at
the centre of mass (docs/conventions.md, "Body frame").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

__all__ = [
    "DEFAULT_CREASE_ANGLE_RAD",
    "MATERIALS",
    "SEMANTIC_CLASSES",
    "Component",
    "TargetModel",
    "centre_on_mass",
]

MATERIALS = (
    "gold_mli",        # gold-coloured multi-layer insulation (Kapton/aluminised)
    "silver_mli",      # silver / aluminised MLI, beta cloth
    "white_paint",     # white thermal paint, white radiators
    "black_paint",     # black paint, dark composites
    "solar_cell",      # photovoltaic cells (dark blue), cover glass
    "aluminium",       # bare or anodised aluminium structure, booms, trusses
    "black_radiator",  # black-anodised or black-painted radiator panels
    "dish",            # antenna reflector surface (white paint)
    "heat_shield",     # ablative heat shield (dark, matte)
    "titanium",        # metallic engine nozzles, RTG fins (grey metal)
)
"""Material names a component may use; the shading gives each a BRDF preset (docs/shading.md,
"Materials")."""

SEMANTIC_CLASSES = (
    "bus", "module", "solar_panel", "antenna", "dish", "boom", "engine", "thruster",
    "instrument", "radiator", "docking_port", "heat_shield", "probe", "rtg", "truss", "other",
)
"""Semantic classes of components (for segmentation labels); index = class id - 1."""

DEFAULT_CREASE_ANGLE_RAD = math.radians(30.0)
"""Shading normals are averaged only across edges whose dihedral angle is below this."""


@dataclass(frozen=True, slots=True, eq=False)
class Component:
    """One part of a target.

    Attributes
    ----------
    name : str
        Unique within the target, lower case with underscores (``"high_gain_antenna"``).
    mesh : trimesh.Trimesh
        Geometry in the body frame [m].
    material : str
        One of :data:`MATERIALS`.
    semantic : str
        One of :data:`SEMANTIC_CLASSES`.
    mass_kg : float
        Mass used to place the centre of mass [kg] (0 for massless dressing such as foil).
    crease_angle_rad : float
        Shading-normal crease angle: smooth across gentler edges, faceted across sharper
        ones [rad].
    albedo : tuple of 3 float or None
        When set, the component is shaded as a pure Lambertian surface with this linear RGB
        albedo in [0, 1] instead of its material's BRDF preset (``material`` still names
        what it is) [-].
    corner_normals : numpy.ndarray or None
        Authored shading normals, shape (n_faces, 3, 3): the unit normal at each corner of
        each face (on the side of the face's geometric normal), NaN where the file gave none
        usable; those corners, and every corner when None, get the crease-angle normal [-].
    surface : raytrace.surfaces.SurfaceMaterial or None
        A material that varies over the surface (a file's textured material), used instead of
        the preset unless ``albedo`` is set (docs/shading.md, "Materials").
    """

    name: str
    mesh: trimesh.Trimesh
    material: str
    semantic: str
    mass_kg: float = 0.0
    crease_angle_rad: float = DEFAULT_CREASE_ANGLE_RAD
    albedo: tuple | None = None
    corner_normals: np.ndarray | None = None
    surface: object = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"component name must be a non-empty string, got {self.name!r}")
        if self.material not in MATERIALS:
            raise ValueError(f"component {self.name}: material must be one of {', '.join(MATERIALS)}; "
                             f"got {self.material!r}")
        if self.semantic not in SEMANTIC_CLASSES:
            raise ValueError(f"component {self.name}: semantic must be one of {', '.join(SEMANTIC_CLASSES)}; "
                             f"got {self.semantic!r}")
        if not isinstance(self.mesh, trimesh.Trimesh):
            raise ValueError(f"component {self.name}: mesh must be a trimesh.Trimesh, got {type(self.mesh).__name__}")
        if len(self.mesh.faces) == 0:
            raise ValueError(f"component {self.name}: mesh has no faces")
        if not np.all(np.isfinite(self.mesh.vertices)):
            raise ValueError(f"component {self.name}: mesh has NaN/inf vertices")
        if not (math.isfinite(self.mass_kg) and self.mass_kg >= 0.0):
            raise ValueError(f"component {self.name}: mass_kg must be finite and >= 0, got {self.mass_kg!r}")
        if not (0.0 <= self.crease_angle_rad <= math.pi):
            raise ValueError(f"component {self.name}: crease_angle_rad must be in [0, pi], "
                             f"got {self.crease_angle_rad!r}")
        if self.albedo is not None:
            a = tuple(float(x) for x in np.ravel(self.albedo))
            if len(a) != 3 or not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in a):
                raise ValueError(f"component {self.name}: albedo must be 3 numbers in [0, 1] (linear RGB), "
                                 f"got {self.albedo!r}")
            object.__setattr__(self, "albedo", a)
        if self.corner_normals is not None:
            n = np.asarray(self.corner_normals, dtype=np.float64)
            if n.shape != (len(self.mesh.faces), 3, 3):
                raise ValueError(f"component {self.name}: corner_normals must have shape (n_faces, 3, 3) = "
                                 f"({len(self.mesh.faces)}, 3, 3), got {n.shape}")
            object.__setattr__(self, "corner_normals", n)
        uv = getattr(self.surface, "corner_uv", None)
        if uv is not None and np.shape(uv) != (len(self.mesh.faces), 3, 2):
            raise ValueError(f"component {self.name}: surface.corner_uv must have shape (n_faces, 3, 2) = "
                             f"({len(self.mesh.faces)}, 3, 2), got {np.shape(uv)}")

    @property
    def semantic_id(self) -> int:
        """Semantic class id, 1-based (0 is background)."""
        return SEMANTIC_CLASSES.index(self.semantic) + 1


@dataclass(frozen=True, slots=True, eq=False)
class TargetModel:
    """A target: an ordered tuple of components (component k has instance id k + 1).

    Attributes
    ----------
    name : str
        Target name (``"cassini"``).
    components : tuple of Component
        Parts in instance-id order; names unique.
    description : str
        One line: what it is and where its dimensions come from.
    """

    name: str
    components: tuple
    description: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        comps = tuple(self.components)
        object.__setattr__(self, "components", comps)
        if not comps:
            raise ValueError(f"target {self.name}: needs at least one component")
        if len(comps) > 65535:
            raise ValueError(f"target {self.name}: at most 65535 components fit uint16 instance ids, "
                             f"got {len(comps)}")
        names = [c.name for c in comps]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"target {self.name}: component names must be unique, repeated: {sorted(dup)}")

    @property
    def component_names(self) -> tuple:
        return tuple(c.name for c in self.components)

    @property
    def n_triangles(self) -> int:
        return int(sum(len(c.mesh.faces) for c in self.components))

    @property
    def bounds_m(self) -> np.ndarray:
        """Axis-aligned bounds in the body frame, shape (2, 3) [m]."""
        lo = np.min([c.mesh.bounds[0] for c in self.components], axis=0)
        hi = np.max([c.mesh.bounds[1] for c in self.components], axis=0)
        return np.array([lo, hi])

    @property
    def bounding_radius_m(self) -> float:
        """Largest vertex distance from the body origin (the centre of mass) [m]."""
        return float(max(np.linalg.norm(c.mesh.vertices, axis=1).max() for c in self.components))

    def combined_mesh(self) -> trimesh.Trimesh:
        """All components in one mesh (component order kept) — for export and tests."""
        return trimesh.util.concatenate([c.mesh for c in self.components])


def centre_on_mass(components) -> tuple:
    """Translate components so that their mass-weighted centroid is at the origin.

    Each component's centre of mass is its volume centroid when the mesh is watertight,
    otherwise its area-weighted surface centroid. Components with ``mass_kg = 0`` do not
    count. Returns new components (meshes copied) and leaves the inputs unchanged.
    """
    comps = tuple(components)
    total = sum(c.mass_kg for c in comps)
    if not total > 0.0:
        raise ValueError("centre_on_mass needs at least one component with mass_kg > 0")
    com = np.zeros(3)
    for c in comps:
        if c.mass_kg > 0.0:
            centre = c.mesh.center_mass if c.mesh.is_watertight and c.mesh.volume > 0 else c.mesh.centroid
            com += c.mass_kg * np.asarray(centre)
    com /= total
    out = []
    for c in comps:
        mesh = c.mesh.copy()
        mesh.apply_translation(-com)
        out.append(Component(name=c.name, mesh=mesh, material=c.material, semantic=c.semantic,
                             mass_kg=c.mass_kg, crease_angle_rad=c.crease_angle_rad, albedo=c.albedo,
                             corner_normals=c.corner_normals, surface=c.surface))
    return tuple(out)
