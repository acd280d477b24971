"""Geometry and light: Embree ray casting on trimesh meshes of the targets.

Planned content (issue 3 onwards): the four built-in targets, the pinhole camera, one hit
record per primary ray and every AOV from it (depth, normals, instance ids), then Numba
shading. ``raytrace`` knows nothing of orbits: it receives poses and light directions
already expressed in the target's body frame.
"""
