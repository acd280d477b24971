"""Explicit scenes from a JSON file: ``python cli.py render-scene SCENE.json --out DIR``.

Schema (version 1; lengths in metres, directions unit vectors in the target's body frame)::

    {
      "meshes": [                                   # or "target": "cassini" (a built-in)
        {"path": "parts/bus.ply", "unit_scale_m": 1.0, "albedo": [0.6, 0.6, 0.6]},
        {"path": "parts/panel.obj", "unit_scale_m": 0.001, "material": "solar_cell",
         "crease_angle_deg": 30.0, "authored_normals": true,          # optional, as here
         "materials": "presets"}                                     # or "file"
      ],
      "camera": {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": 1280, "height": 960,
                 "R_cam_from_body": [9 numbers, row-major] or 3×3, "t_cam_m": [x, y, z]},
      "sun": {"sun_dir_body": [x, y, z], "sun_irradiance_W_m2": 1361.0,
              "shadow_fraction": 1.0, "angular_diameter_deg": 0.533},
      "earth": {"earth_dir_body": [x, y, z], "earth_distance_m": 6778137.0,
                "radius_m": 6378137.0, "albedo": 0.3, "texture": "uniform"},      # optional
      "ambient_radiance_W_m2_sr": 0.0,                                          # optional
      "stars": {"R_body_from_eci": [9 numbers, row-major] or 3×3,               # optional
                "limit_mag": 6.5, "seed": 0, "catalogue": "stars.csv"},
      "quality": "balanced", "samples": null, "seed": 0                        # optional
    }

Mesh paths are relative to the JSON file's folder. Each mesh file becomes one or more
components (one per part, :func:`raytrace.meshio.load_mesh`), all shaded with the entry's
``material`` (a preset of :data:`raytrace.materials.MATERIAL_PRESETS`) or its Lambertian
``albedo`` (linear RGB, or one number for grey); with ``"materials": "file"`` the parts whose
file material has a texture (glTF base colour / metallic-roughness / normal texture, OBJ
``map_Kd``) are shaded from it instead (docs/shading.md, "Materials"). Shading normals: the file's own vertex
normals where it has them, unless ``authored_normals`` is false; elsewhere the crease rule
with ``crease_angle_deg`` in [0, 180] (0 flat, 180 smooth everywhere; default 30). Camera pixel coordinates follow OpenCV: x
right, y down, z forward, integer coordinates at pixel centres.

``stars`` draws stars in the background (:mod:`raytrace.stars`): the body's attitude in the
inertial frame (J2000) is required; without ``catalogue`` (a CSV with columns ``ra_deg``,
``dec_deg``, ``v_mag``, relative to the JSON file's folder) a procedural sky of every star
brighter than ``limit_mag`` (default 6.5, at most 9) is drawn from ``seed``.

Meshes far from the file's origin (bounding-box centre beyond :data:`RECENTRE_SIZES` times
their size) are moved to their centre for float32 ray tracing (:attr:`SceneSpec.body_offset_m`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from .camera import Camera
from ._checks import finite_numbers, only_numbers
from .lighting import EARTH_RADIUS_M, EARTH_TEXTURES, SOLAR_CONSTANT_W_M2, Earth, Lighting
from .model import MATERIALS, TargetModel

__all__ = ["SceneSpec", "load_scene_file", "scene_to_dict"]

_TOP_KEYS = {"meshes", "target", "camera", "sun", "earth", "ambient_radiance_W_m2_sr", "stars", "quality", "samples",
             "seed", "version"}


@dataclass(frozen=True, slots=True, eq=False)
class SceneSpec:
    """A loaded scene file: everything :func:`raytrace.shade.render` needs."""

    model: TargetModel
    camera: Camera
    R_cam_from_body: np.ndarray
    t_cam_m: np.ndarray
    lighting: Lighting
    quality: str = "balanced"
    samples: int | None = None
    seed: int = 0
    body_offset_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Where the meshes' bounding-box centre lies in the file's body frame, when they lie far
    from its origin (more than :data:`RECENTRE_SIZES` times their size; else zeros) [m]. The
    meshes were then moved by −body_offset_m for float32 ray tracing, and ``model``,
    ``t_cam_m`` and ``lighting`` describe the same scene in that shifted frame: a point p of
    ``model`` is p + body_offset_m in the file, and the file's ``t_cam_m`` is
    ``t_cam_m − R_cam_from_body @ body_offset_m`` (:meth:`file_t_cam_m`)."""

    notes: tuple = ()
    """One line per mesh file that was repaired beyond routine clean-up (faces touching NaN/inf
    vertices removed, :meth:`raytrace.meshio.MeshReport.non_finite_note`), for the caller to show."""

    def file_t_cam_m(self) -> np.ndarray:
        """``camera.t_cam_m`` as the file gives it (the pose of the file's body frame)."""
        return self.t_cam_m - self.R_cam_from_body @ self.body_offset_m

    def frame_record(self, frame, *, scene_path: str, samples, seed, render_s: float, exposure_scale: float,
                     geometric_shadow_fraction) -> dict:
        """The ``frame.json`` of ``render-scene``: the scene file, the preset, samples and seed
        used, the time the render took [s], the exposure scale of ``rgb``, the camera and pose as
        the file gives them, the components, the frame's ``pixel_counts``, ``bbox_xywh`` and
        ``visible_fraction``, and the shadow fraction used beside the one the scene's Earth
        makes geometrically."""
        geo = frame.geometry
        return {"scene": scene_path, "quality": frame.quality.name, "samples": samples,
                "seed": seed, "render_s": render_s, "timings_s": frame.timings_s, "exposure_scale": exposure_scale,
                "width": self.camera.width, "height": self.camera.height, "K": self.camera.K.tolist(),
                "R_cam_from_body": self.R_cam_from_body.ravel().tolist(),
                "t_cam_m": self.file_t_cam_m().tolist(), "body_offset_m": self.body_offset_m.tolist(),
                "components": list(self.model.component_names),
                "pixel_counts": geo.pixel_counts.tolist(), "bbox_xywh": geo.bbox_xywh,
                "visible_fraction": None if math.isnan(geo.visible_fraction) else geo.visible_fraction,
                "shadow_fraction": self.lighting.shadow_fraction,
                "geometric_shadow_fraction": geometric_shadow_fraction}


RECENTRE_SIZES = 10.0
"""Meshes whose bounding-box centre lies farther than this many times their size (bounding-box
diagonal) from the file's origin are moved to it for rendering (:attr:`SceneSpec.body_offset_m`):
Embree holds vertices in float32, and a 1 m part 5 km from its origin (ulp 0.5 mm) otherwise
shadows itself in speckles."""


def _recentred(model: TargetModel, R: np.ndarray, t: np.ndarray, lighting: Lighting):
    """The model moved to its bounding-box centre c when that lies far from the origin, with the
    pose and Earth in the shifted frame: (model, t + R c, lighting, c); c = 0 otherwise."""
    lo = np.min([np.asarray(c.mesh.vertices).min(0) for c in model.components], axis=0)
    hi = np.max([np.asarray(c.mesh.vertices).max(0) for c in model.components], axis=0)
    c = 0.5 * (lo + hi)
    size = max(float(np.linalg.norm(hi - lo)), 1e-3)
    if float(np.linalg.norm(c)) <= RECENTRE_SIZES * size:
        return model, t, lighting, np.zeros(3)
    comps = []
    for comp in model.components:
        mesh = comp.mesh.copy()
        mesh.vertices = np.asarray(mesh.vertices, dtype=np.float64) - c
        comps.append(replace(comp, mesh=mesh))
    earth = lighting.earth
    if earth is not None:  # Earth's centre seen from the new origin
        r = earth.distance_m * np.asarray(earth.earth_dir_body) - c
        earth = replace(earth, earth_dir_body=tuple(r / np.linalg.norm(r)), distance_m=float(np.linalg.norm(r)))
    return replace(model, components=tuple(comps)), t + R @ c, replace(lighting, earth=earth), c


SCENE_FILE_LIMIT_BYTES = 64 << 20
"""Largest scene file read [bytes] (a scene file is a few kB; a device or pipe is refused)."""


def _err(msg: str) -> ValueError:
    return ValueError(f"scene file: {msg}")


def _numbers(name: str, value, n: int) -> np.ndarray:
    try:
        return finite_numbers(name, value, n, strict=True)
    except ValueError as exc:
        raise _err(str(exc)) from None


# how far from orthonormal a rotation in the file may be: what 4 printed decimals leave
# (|R Rᵀ − I| ≤ 1.6e-4 over 2000 random rotations rounded so; 6 decimals: 1.6e-6)
ROTATION_TOL = 1e-3


def _rotation(name: str, value) -> np.ndarray:
    """A rotation matrix from 9 numbers (row-major, or 3×3) that may have been rounded in
    print: within ROTATION_TOL of orthonormal (max |R Rᵀ − I|) with det > 0, replaced (unless
    orthonormal to 1e-12 already) by the nearest rotation, the orthogonal factor of its polar
    decomposition, U Vᵀ of its SVD (Higham 1986, "Computing the polar decomposition", SIAM J.
    Sci. Stat. Comput. 7(4)), so the pose rendered and written to frame.json is exactly a
    rotation."""
    R = _numbers(name, value, 9).reshape(3, 3)
    dev = float(np.abs(R @ R.T - np.eye(3)).max())
    if dev > ROTATION_TOL or np.linalg.det(R) <= 0:
        raise _err(f"{name} must be a rotation matrix (orthonormal to {ROTATION_TOL:g}, det +1), got "
                   f"max |R Rᵀ − I| = {dev:.3g}, det {np.linalg.det(R):.6g}")
    if dev <= 1e-12:  # a rotation to float64 precision: the file's numbers, as given
        return R
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _section(data: dict, key: str, required: bool = True) -> dict | None:
    v = data.get(key)
    if v is None:
        if required:
            raise _err(f"missing required key {key!r}")
        return None
    if not isinstance(v, dict):
        raise _err(f"{key} must be an object, got {type(v).__name__}")
    return v


def _model(data: dict, folder: str, notes: list | None = None) -> TargetModel:
    from .meshio import DEFAULT_CREASE_ANGLE_DEG, check_crease_angle_deg, load_mesh
    from .targets import BUILTIN_TARGETS, load_target
    if ("meshes" in data) == ("target" in data):
        raise _err("give exactly one of 'meshes' (a list of mesh files) or 'target' "
                   f"(one of {', '.join(BUILTIN_TARGETS)})")
    if "target" in data:
        if data["target"] not in BUILTIN_TARGETS:
            raise _err(f"target must be one of {', '.join(BUILTIN_TARGETS)}, got {data['target']!r}")
        return load_target(data["target"])
    meshes = data["meshes"]
    if not isinstance(meshes, list) or not meshes:
        raise _err("meshes must be a non-empty list of {path, unit_scale_m, material | albedo}")
    comps = []
    for i, m in enumerate(meshes):
        if not isinstance(m, dict) or "path" not in m:
            raise _err(f"meshes[{i}] must be an object with a 'path'")
        unknown = set(m) - {"path", "unit_scale_m", "material", "albedo", "name", "crease_angle_deg",
                            "authored_normals", "materials"}
        if unknown:
            raise _err(f"meshes[{i}]: unknown keys {sorted(unknown)} (allowed: path, unit_scale_m, material, "
                       "albedo, name, crease_angle_deg, authored_normals, materials)")
        use_file = m.get("materials", "presets")
        if use_file not in ("presets", "file"):
            raise _err(f"meshes[{i}].materials must be 'presets' or 'file', got {use_file!r}")
        crease = m.get("crease_angle_deg", DEFAULT_CREASE_ANGLE_DEG)
        try:
            crease = check_crease_angle_deg(crease, f"meshes[{i}].crease_angle_deg")
        except ValueError as exc:
            raise _err(str(exc)) from None
        authored = m.get("authored_normals", True)
        if not isinstance(authored, bool):
            raise _err(f"meshes[{i}].authored_normals must be true or false, got {authored!r}")
        if ("material" in m) == ("albedo" in m):
            raise _err(f"meshes[{i}] needs exactly one of 'material' (one of {', '.join(MATERIALS)}) or "
                       "'albedo' (linear RGB in [0, 1])")
        material = m.get("material", "white_paint")
        if material not in MATERIALS:
            raise _err(f"meshes[{i}].material must be one of {', '.join(MATERIALS)}, got {material!r}")
        albedo = None
        if "albedo" in m:
            if not only_numbers(m["albedo"]):
                raise _err(f"meshes[{i}].albedo must be 1 or 3 numbers in [0, 1], got {m['albedo']!r}")
            a = np.ravel(m["albedo"])
            if a.size not in (1, 3):
                raise _err(f"meshes[{i}].albedo must be 1 or 3 numbers in [0, 1], got {m['albedo']!r}")
            if a.size == 1:
                a = np.repeat(a, 3)
            a = _numbers(f"meshes[{i}].albedo", a, 3)
            if np.any(a < 0) or np.any(a > 1):
                raise _err(f"meshes[{i}].albedo must be 1 or 3 numbers in [0, 1], got {m['albedo']!r}")
            albedo = tuple(a.tolist())
        path = m["path"]
        if not isinstance(path, str):
            raise _err(f"meshes[{i}].path must be a string")
        path = path if os.path.isabs(path) else os.path.join(folder, path)
        try:
            part, report = load_mesh(path, unit_scale_m=m.get("unit_scale_m", 1.0), default_material=material,
                                     name=m.get("name"), crease_angle_deg=crease, authored_normals=authored,
                                     file_materials=use_file == "file")
        except ValueError as exc:
            raise _err(f"meshes[{i}]: {exc}") from None
        if notes is not None and report.non_finite_note():
            notes.append(f"meshes[{i}]: {report.non_finite_note()}")
        for c in part.components:
            name = c.name if len(meshes) == 1 else f"m{i}_{c.name}"
            # "file": a part with a textured file material keeps it, the others take the entry's
            comps.append(replace(c, name=name, material=material, albedo=None if c.surface is not None else albedo))
    return TargetModel(os.path.basename(folder) or "scene", tuple(comps), "scene file")


_CAMERA_KEYS = ("K", "width", "height", "R_cam_from_body", "t_cam_m")


def _camera(cam: dict) -> tuple[Camera, np.ndarray, np.ndarray]:
    unknown = set(cam) - set(_CAMERA_KEYS)
    if unknown:
        raise _err(f"camera: unknown keys {sorted(unknown)} (allowed: {', '.join(_CAMERA_KEYS)}; a pinhole "
                   "without distortion)")
    for key in _CAMERA_KEYS:
        if key not in cam:
            raise _err(f"camera.{key} is required")
    K = _numbers("camera.K", cam["K"], 9).reshape(3, 3)
    if not (K[0, 1] == 0 and K[1, 0] == 0 and K[2, 0] == 0 and K[2, 1] == 0 and K[2, 2] == 1):
        raise _err("camera.K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    for key in ("width", "height"):
        v = cam[key]
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 16384:
            raise _err(f"camera.{key} must be an integer in [1, 16384], got {v!r}")
    try:
        camera = Camera(int(cam["width"]), int(cam["height"]), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                        float(K[1, 2]))
    except ValueError as exc:
        raise _err(f"camera: {exc}") from None
    R = _rotation("camera.R_cam_from_body", cam["R_cam_from_body"])
    t = _numbers("camera.t_cam_m", cam["t_cam_m"], 3)
    return camera, R, t


def _stars(data: dict, folder: str):
    st = _section(data, "stars", required=False)
    if st is None:
        return None, None
    from .stars import StarField
    unknown = set(st) - {"R_body_from_eci", "limit_mag", "seed", "catalogue"}
    if unknown:
        raise _err(f"stars: unknown keys {sorted(unknown)} (allowed: R_body_from_eci, limit_mag, seed, catalogue)")
    if "R_body_from_eci" not in st:
        raise _err("stars.R_body_from_eci is required (the body's attitude in the inertial frame, 9 numbers)")
    R = _rotation("stars.R_body_from_eci", st["R_body_from_eci"])
    try:
        if "catalogue" in st:
            if "seed" in st:
                raise _err("stars: give 'seed' (procedural sky) or 'catalogue', not both")
            path = st["catalogue"]
            if not isinstance(path, str):
                raise _err("stars.catalogue must be a path (string)")
            path = path if os.path.isabs(path) else os.path.join(folder, path)
            field = StarField.from_csv(path, st.get("limit_mag", math.inf))
        else:
            field = StarField.procedural(st.get("limit_mag", 6.5), st.get("seed", 0))
    except ValueError as exc:
        msg = str(exc)
        raise (exc if msg.startswith("scene file:") else _err(f"stars: {msg}")) from None
    return field, R


def _lighting(data: dict, folder: str = ".") -> Lighting:
    sun = _section(data, "sun")
    unknown = set(sun) - {"sun_dir_body", "sun_irradiance_W_m2", "shadow_fraction", "angular_diameter_deg"}
    if unknown:
        raise _err(f"sun: unknown keys {sorted(unknown)}")
    if "sun_dir_body" not in sun:
        raise _err("sun.sun_dir_body is required (unit vector towards the Sun, body frame)")
    stars, R_body_from_eci = _stars(data, folder)
    diameter = sun.get("angular_diameter_deg", 0.533)
    if isinstance(diameter, bool) or not isinstance(diameter, (int, float)) or not 0.0 <= diameter <= 5.0:
        raise _err(f"sun.angular_diameter_deg must be a number in [0, 5] degrees (0.533 seen from Earth; 0 for a "
                   f"point Sun), got {diameter!r}")
    earth = None
    e = _section(data, "earth", required=False)
    try:
        if e is not None:
            unknown = set(e) - {"earth_dir_body", "earth_distance_m", "radius_m", "albedo", "texture"}
            if unknown:
                raise _err(f"earth: unknown keys {sorted(unknown)}")
            for key in ("earth_dir_body", "earth_distance_m"):
                if key not in e:
                    raise _err(f"earth.{key} is required")
            if not isinstance(e.get("texture", "uniform"), str):  # a JSON array is not an image here
                raise _err(f"earth.texture must be one of {', '.join(EARTH_TEXTURES)} (an equirectangular image is "
                           f"given to the Python API), got {e['texture']!r:.60}")
            earth = Earth(earth_dir_body=e["earth_dir_body"], distance_m=e["earth_distance_m"],
                          radius_m=e.get("radius_m", EARTH_RADIUS_M), albedo=e.get("albedo", 0.3),
                          texture=e.get("texture", "uniform"))
        return Lighting(sun_dir_body=sun["sun_dir_body"],
                        sun_irradiance_W_m2=sun.get("sun_irradiance_W_m2", SOLAR_CONSTANT_W_M2),
                        shadow_fraction=sun.get("shadow_fraction", 1.0),
                        sun_angular_diameter_rad=math.radians(diameter),
                        earth=earth, ambient_radiance_W_m2_sr=data.get("ambient_radiance_W_m2_sr", 0.0),
                        stars=stars, R_body_from_eci=R_body_from_eci)
    except ValueError as exc:
        msg = str(exc)
        raise (exc if msg.startswith("scene file:") else _err(msg)) from None


def load_scene_file(path) -> SceneSpec:
    """Read and validate a scene file (schema in the module docstring).

    Raises
    ------
    ValueError
        One line naming the key and what is allowed, for any missing, unknown or invalid entry,
        or an unreadable file.
    """
    path = os.fspath(path)
    from .files import read_regular_file
    try:
        raw = read_regular_file(path, limit_bytes=SCENE_FILE_LIMIT_BYTES, what=path)
    except ValueError as exc:  # missing, not a regular file, too large
        raise _err(str(exc)) from None
    try:
        data = json.loads(raw.decode("utf-8"))
    except json.JSONDecodeError as exc:
        raise _err(f"{path} is not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise _err(f"{path} is not UTF-8 text, which JSON must be (byte {exc.start}: "
                   f"{exc.object[exc.start:exc.start + 1]!r})") from None
    if not isinstance(data, dict):
        raise _err("the top level must be an object")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise _err(f"unknown keys {sorted(unknown)} (allowed: {', '.join(sorted(_TOP_KEYS))})")
    version = data.get("version", 1)
    if isinstance(version, bool) or version != 1:
        raise _err(f"version must be 1 (the only schema so far), got {version!r}")
    from .presets import QUALITIES
    quality = data.get("quality", "balanced")
    if quality not in QUALITIES:
        raise _err(f"quality must be one of {', '.join(QUALITIES)}, got {quality!r}")
    samples = data.get("samples")
    if samples is not None and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        raise _err(f"samples must be a positive integer or null, got {samples!r}")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**31:
        raise _err(f"seed must be an integer in [0, 2**31), got {seed!r}")
    camera, R, t = _camera(_section(data, "camera"))
    folder = os.path.dirname(os.path.abspath(path))
    lighting = _lighting(data, folder)
    notes = []
    model, t, lighting, offset = _recentred(_model(data, folder, notes), R, t, lighting)
    return SceneSpec(model, camera, R, t, lighting, quality, samples, seed, offset, tuple(notes))


def scene_to_dict(camera: Camera, R_cam_from_body, t_cam_m, lighting: Lighting, meshes: list,
                  quality: str = "balanced", samples: int | None = None, seed: int = 0) -> dict:
    """The JSON document of a scene (inverse of :func:`load_scene_file`); ``meshes`` is the
    list of mesh entries ({path, unit_scale_m, material | albedo})."""
    d = {"meshes": meshes,
         "camera": {"K": camera.K.tolist(), "width": camera.width, "height": camera.height,
                    "R_cam_from_body": np.asarray(R_cam_from_body, dtype=float).ravel().tolist(),
                    "t_cam_m": np.asarray(t_cam_m, dtype=float).tolist()},
         "sun": {"sun_dir_body": list(lighting.sun_dir_body), "sun_irradiance_W_m2": lighting.sun_irradiance_W_m2,
                 "shadow_fraction": lighting.shadow_fraction,
                 "angular_diameter_deg": math.degrees(lighting.sun_angular_diameter_rad)},
         "ambient_radiance_W_m2_sr": lighting.ambient_radiance_W_m2_sr,
         "quality": quality, "samples": samples, "seed": seed}
    e = lighting.earth
    if e is not None:
        if not isinstance(e.texture, str):
            raise ValueError("scene_to_dict: an Earth texture image cannot be written to a scene file")
        d["earth"] = {"earth_dir_body": list(e.earth_dir_body), "earth_distance_m": e.distance_m,
                      "radius_m": e.radius_m, "albedo": e.albedo, "texture": e.texture}
    if lighting.stars is not None:
        if lighting.stars.source is None:
            raise ValueError("scene_to_dict: stars given star by star cannot be written to a scene file")
        d["stars"] = {"R_body_from_eci": lighting.R_body_from_eci.ravel().tolist(), **lighting.stars.source}
    return d
