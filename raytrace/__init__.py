"""Geometry and light: Embree ray casting on trimesh meshes of the targets.

The four built-in targets (``targets``), meshes from files (``meshio``, ``model``), the pinhole
camera (``camera``), one hit record per primary ray and every AOV from it: depth, normals,
instance ids (``scene``); the lighting environment (``lighting``, ``environment``, ``stars``),
materials (``materials``, ``brdf``) and Numba shading of the Sun, Earth, sky and
inter-reflection (``shade``, with the radiance cache ``cache`` and the path tracer behind the
``reference`` preset, ``pathtrace``); explicit scene files (``scenefile``) and frame export
(``export``).
``raytrace`` knows nothing of orbits: it receives poses and light directions already
expressed in the target's body frame.

Their numba kernels live in modules of their own, one topic each (``_sampling``, ``_surface``,
``_rows``, ``_gather``, ``_filter``, ``_edges``, ``_background``, ``_paths``, ``_cache_kernels``,
``_kernels``, ``_embree``), which import no module that holds the objects driving them (``shade``
with ``_context`` and ``_antialias``, ``cache``, ``scene``).

``_jit``, which every module with kernels imports, sets numba's thread policy and, on Linux,
malloc's thresholds for the large per-frame arrays (docs/shading.md, "Memory").
"""
