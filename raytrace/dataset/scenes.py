"""Each process's scenes and star fields, and the scenes a pool's parent builds for its workers.

A frame task names its target by a *model spec* — ``("builtin", name)`` or ``("mesh", path,
unit_scale_m, crease_angle_deg)`` — and :func:`scene` builds the :class:`raytrace.scene.Scene` (Embree BVH,
radiance cache) once per process. :func:`prebuild_scenes` builds each target's scene and
radiance cache once in the pool's parent, on every core, and pickles them for the workers,
which load them (:func:`load_prebuilt`) instead of each building its own on its share of the
cores. The pickle is kept in the persistent cache (:mod:`raytrace._diskcache`), under a digest
of the model's content, the cache's options and the code (:func:`scene_key`): a later run with
the same target and preset loads it instead of building it again.
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np

from . import UsageError, warn
from .modalities import needs_radiance

_SCENES: dict = {}  # model spec -> Scene, in this process
_STARS: dict = {}  # (catalogue, limit, seed) -> StarField, in this process
_SCENE_LOCK = None


def load_model(spec: tuple, warn_repair: bool = False):
    """The target model of a model spec: ("builtin", name) or ("mesh", path, unit_scale_m, crease_angle_deg);
    ``warn_repair``: one line on stderr when the mesh file needed more than routine repair."""
    if spec[0] == "builtin":
        return builtin_model(spec[1])
    from ..meshio import load_mesh
    model, report = load_mesh(spec[1], unit_scale_m=spec[2], crease_angle_deg=spec[3] if len(spec) > 3 else 30.0)
    if warn_repair and report.non_finite_note():
        warn(f"--mesh {report.non_finite_note()}")
    return model


@functools.cache
def builtin_model(name: str):
    """:func:`raytrace.targets.load_target` ``(name)``, once per process, from the persistent
    cache (:mod:`raytrace._diskcache`) where an earlier run stored it: the procedural build
    takes ~0.4 s (Cassini), reading its pickle ~0.02 s. The key is the code's
    (:func:`raytrace._diskcache.code_version`: the builders are modules of :mod:`raytrace`)."""
    import pickle

    from .. import _diskcache
    from ..targets import BUILTIN_TARGETS, load_target
    if name not in BUILTIN_TARGETS:
        return load_target(name)  # its error
    return _diskcache.memoised("model", (name.encode(),), lambda: load_target(name),
                               lambda model: pickle.dumps(model, protocol=pickle.HIGHEST_PROTOCOL),
                               pickle.loads)  # our own file, checksummed


_PLANNED: dict = {}  # id(model) -> (model, its Scene): the scene planning built, for prebuild_scenes
_PLANNED_KEEP = 4  # scenes of the latest plans kept (a dataset plans one sequence per target)


def scene_of(model, warn_model: bool):
    """``raytrace.scene.Scene(model)``; its warnings about the model (a mesh far from its origin)
    as one line each on stderr when ``warn_model`` (planning, once), else dropped (the workers, which
    build the scene the plan already built). Planning's scene is kept for :func:`prebuild_scenes`
    (:func:`_planned_scene`) rather than built twice."""
    import warnings

    from ..scene import Scene
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = Scene(model)
    for w in caught if warn_model else ():
        warn(' '.join(str(w.message).split()))
    if warn_model:
        while len(_PLANNED) >= _PLANNED_KEEP:  # the oldest go (a plan that never renders)
            _PLANNED.pop(next(iter(_PLANNED)))
        _PLANNED[id(model)] = (model, scene)
    return scene


def _planned_scene(model):
    """The scene planning built for ``model`` (handed over once), else a new one."""
    kept = _PLANNED.pop(id(model), None)
    if kept is not None and kept[0] is model:
        return kept[1]
    return scene_of(model, warn_model=False)


def scene(spec: tuple, prebuilt: str | None = None):
    """The Scene of a model spec, built once per process (Embree BVH and radiance cache);
    ``prebuilt``: a file of :func:`prebuild_scenes` holding it with its radiance cache."""
    global _SCENE_LOCK
    import threading
    if _SCENE_LOCK is None:
        _SCENE_LOCK = threading.Lock()
    with _SCENE_LOCK:
        scene = _SCENES.get(spec)
        if scene is None:
            scene = load_prebuilt(prebuilt) if prebuilt else None
            if scene is None:
                scene = scene_of(load_model(spec), warn_model=False)
            scene.embree  # noqa: B018 - build now, under the lock
            _SCENES[spec] = scene
        return scene


def load_prebuilt(path: str):
    """The Scene pickled by :func:`prebuild_scenes` at ``path``, its radiance cache attached;
    None (and the worker builds its own) if the file cannot be read or is not intact."""
    import pickle
    import struct

    from .. import _diskcache
    payload = _diskcache.read_mapped(path)
    try:
        if payload is None:
            raise ValueError(f"{path} is missing, truncated or corrupt")
        # our own file, checksummed; its arrays stay on the mapped file (no copy: a CAD mesh's
        # scene is gigabytes, and the pool's workers share its pages until one writes to them)
        scene, cache, options = _diskcache.load_buffers(payload)
        scene.adopt_radiance_cache(cache, **options)
        return scene
    except (pickle.UnpicklingError, EOFError, ValueError, AttributeError, ImportError, TypeError,
            struct.error) as exc:
        warn(f"building the scene in the worker ({exc})")
        folder = _diskcache.cache_dir()
        if folder is not None and os.path.dirname(os.path.abspath(path)) == os.path.abspath(folder):
            _diskcache.discard(path)  # a broken entry of the persistent cache: the next run stores it anew
        return None


def _update_array(h, a) -> None:
    a = np.ascontiguousarray(a)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())


def scene_key(scene, options: dict) -> bytes | None:
    """The persistent cache's key of ``scene`` with the radiance cache of ``options``: a digest
    of the model's content (every component's mesh, material, semantic class, crease angle,
    albedo, authored normals and surface material; the model's name, description and metadata),
    the scene's material switch, the options and the code (:func:`raytrace._diskcache.key_digest`).
    None if the model holds something that cannot be digested (then nothing is cached)."""
    import hashlib
    import pickle

    from .. import _diskcache
    model = scene.model
    h = hashlib.sha256()
    try:
        h.update(pickle.dumps((model.name, model.description, model.metadata, bool(scene.procedural_materials),
                               sorted(options.items())), protocol=4))
        for c in model.components:
            h.update(pickle.dumps((c.name, c.material, c.semantic, float(c.mass_kg), float(c.crease_angle_rad),
                                   c.albedo, c.surface), protocol=4))
            _update_array(h, np.asarray(c.mesh.vertices, dtype=np.float64))
            _update_array(h, np.asarray(c.mesh.faces, dtype=np.int64))
            if c.corner_normals is not None:
                _update_array(h, c.corner_normals)
    except (pickle.PicklingError, TypeError, AttributeError, ValueError):
        return None
    return _diskcache.key_digest("scene", h.digest())


def shades(task: dict) -> bool:
    """Whether a frame task needs the radiance (an image modality), not the geometry alone."""
    return bool(task.get("want_rgb")) or needs_radiance(task["modalities"])


def prebuild_scenes(tasks: list, folder: str | None) -> dict:
    """Build each target's Scene and radiance cache once, here, on every core, and pickle them
    for the pool's workers: {model spec: file}. Each worker would otherwise build its own on
    its share of the cores (Cassini: ~5 s on one core, 2–3.5 s on two; the same cache bit for
    bit, tests/raytrace/test_cache_solve.py). The file is the persistent cache's entry
    (:func:`scene_key`): one a previous run stored is used as it is, without building anything;
    where there is no persistent cache, a file in ``folder``. ``folder`` None (one process renders
    every frame): only the persistent cache, and a scene built here is kept for this process's
    frames (:func:`scene`). Only for tasks that shade (the ``fast`` and ``balanced`` presets with
    an image modality); nothing is built for the others."""
    from .. import _diskcache
    out = {}
    for task in tasks:
        spec = task["model_spec"]
        if spec in out or task["cfg"]["render"]["quality"] == "reference":
            continue
        if not shades(task) or (folder is None and spec in _SCENES):  # this process has its scene
            continue
        from ..presets import preset_cache_options, quality_preset
        scene = _planned_scene(load_model(spec))
        r = task["cfg"]["render"]
        # the cache the preset's frames ask for (balanced from 12 rays: a finer lattice)
        options = preset_cache_options(quality_preset(r["quality"], r.get("samples")), scene.scale_m)
        key = scene_key(scene, options)
        path = None if key is None else _diskcache.entry_path("scene", key)
        if path is not None and _diskcache.present(path, key):
            out[spec] = path
            continue
        cache = scene.radiance_cache(**options)
        if path is not None or folder is not None:
            def dump(fh, what=(scene, cache, options)):  # streamed: a CAD mesh's scene is gigabytes
                _diskcache.dump_buffers(what, fh)
            if path is not None and _diskcache.write_stream(path, key, dump):
                out[spec] = path
            elif folder is not None:
                path = os.path.join(folder, f"scene{len(out)}.pickle")
                if not _diskcache.write_stream(path, key or bytes(32), dump):
                    raise OSError(f"cannot write {path}")
                out[spec] = path
            del dump
        if folder is None:
            scene.embree  # noqa: B018 - this process renders: keep the scene as built
            _SCENES.setdefault(spec, scene)
        del scene, cache
    return out


def star_field(cfg: dict):
    """The sequence's star field (None without stars), read or drawn once per process."""
    r = cfg["render"]
    key = (r.get("star_catalogue"), r.get("star_limit_mag"), cfg["sequence"]["seed"])
    if key[0] is None and key[1] is None:
        return None
    if key not in _STARS:
        from ..stars import StarField
        if key[0] is not None:
            try:
                _STARS[key] = StarField.from_csv(key[0], math.inf if key[1] is None else key[1])
            except ValueError as exc:
                raise UsageError(f"argument --star-catalogue: {exc}") from None
        else:  # one sky per seed: the same stars in every frame
            _STARS[key] = StarField.procedural(key[1], key[2])
    return _STARS[key]


MESH_RADIUS_PLAUSIBLE_M = (0.02, 200.0)
"""Bounding radii of real spacecraft [m]: from a 1U CubeSat's 0.087 m to the ISS's ~55 m, with room
on both sides. A user mesh outside the range was probably read in the wrong unit."""

def mesh_unit_warning(radius_m: float, path: str) -> str | None:
    """A one-line warning when a mesh loaded with the default ``--mesh-unit-m 1`` has a size
    (``radius_m``: half its bounding-box diagonal) no spacecraft has (a 1 m cube drawn in
    millimetres reads as 866 m), naming the flag."""
    lo, hi = MESH_RADIUS_PLAUSIBLE_M
    if radius_m > hi:
        guess = "millimetres: --mesh-unit-m 0.001" if radius_m > 1000 * lo else "centimetres: --mesh-unit-m 0.01"
        return (f"--mesh {path}: it is {2 * radius_m:.4g} m across (a radius of {radius_m:.4g} m), larger than any "
                f"spacecraft, read as metres (--mesh-unit-m 1); if the file is in {guess}")
    if radius_m < lo:
        return (f"--mesh {path}: it is {2 * radius_m:.3g} m across, smaller than any spacecraft, read as metres "
                "(--mesh-unit-m 1); if the file is in kilometres: --mesh-unit-m 1000")
    return None


def lighting_of(light: dict, r: dict, stars=None, seed: int = 0):
    """The :class:`raytrace.lighting.Lighting` of a frame: its ``light`` (Sun, Earth and ν in the
    body frame, from the plan) with the ``render`` table ``r`` (Earth texture and albedo, sky),
    the sequence's ``stars`` and its ``seed`` (the ``bluemarble`` clouds': the same for every
    frame of a sequence)."""
    from ..constants import SOLAR_CONSTANT_W_M2
    from ..lighting import Earth, Lighting
    earth = None
    if r["earth_texture"] != "none":
        earth = Earth(light["earth_dir_body"], light["earth_distance_m"], albedo=r["earth_albedo"],
                      texture=r["earth_texture"], R_body_from_earth=light["R_body_from_earth"], cloud_seed=int(seed))
    return Lighting(sun_dir_body=light["sun_dir_body"], sun_irradiance_W_m2=SOLAR_CONSTANT_W_M2,
                    shadow_fraction=light["shadow_fraction"], earth=earth,
                    ambient_radiance_W_m2_sr=r["ambient_W_m2_sr"], stars=stars,
                    R_body_from_eci=None if stars is None else light["R_body_from_eci"])


KEYPOINTS_FAR = 10.0
"""A keypoint farther from the body origin than this many bounding radii is warned about (a
wrong unit or frame)."""


def keypoints_of(model, path: str | None) -> dict:
    """The ``model/keypoints.json`` document of a sequence: the user's file ``path``
    (:func:`raytrace.keypoints.read_keypoints`; errors name ``--keypoints``, one line on stderr
    for points far outside the target) or, without one, the default set of ``model``
    (:func:`raytrace.keypoints.default_keypoints`)."""
    from .. import keypoints as K
    if path is None:
        names, points = K.default_keypoints(model)
        return K.keypoints_document(names, points, f"{K.DEFAULT_SOURCE}, n = {K.DEFAULT_COUNT}")
    try:
        names, points, source = K.read_keypoints(path)
    except ValueError as exc:
        raise UsageError(f"argument --keypoints: {exc}") from None
    r = float(np.linalg.norm(points, axis=1).max())
    if r > KEYPOINTS_FAR * model.bounding_radius_m:
        warn(f"--keypoints {path}: a point lies {r:.4g} m from the body origin, {r / model.bounding_radius_m:.3g}x "
             f"the target's bounding radius ({model.bounding_radius_m:.4g} m): are they in metres, in its body frame?")
    return K.keypoints_document(names, points, source or f"file {os.path.basename(path)}")


def keypoint_fields(task: dict, scene, camera, R_cam_from_body, t_cam_m) -> dict:
    """A frame's ``keypoints_px`` and ``keypoints_state`` (:func:`raytrace.keypoints.frame_keypoints`
    of the task's ``keypoints_body_m`` and its light); {} for a task without keypoints."""
    points = task.get("keypoints_body_m")
    if points is None:
        return {}
    from ..keypoints import frame_keypoints
    return frame_keypoints(scene, camera, R_cam_from_body, t_cam_m, points, task["light"])
