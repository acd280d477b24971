"""Embree called from numba kernels, one ray at a time, without a round of Python per batch.

:class:`raytrace.scene.Scene` traces batches of rays through ``embreex`` (arrays in, arrays
out). A kernel that follows a path bounce by bounce would then return to Python at every
bounce level and carry every ray's state through NumPy arrays. This module instead calls
``rtcIntersect1`` / ``rtcOccluded1`` of the Embree 4 library that the ``embreex`` wheel ships,
directly from compiled code: numba declares them as external symbols
(:class:`numba.types.ExternalFunction`), resolved at load time in the library that
:func:`available` loads into the process with llvmlite, so the kernels that call them are
cached like any other (an address baked in through ``ctypes`` would not be).

The scene is built here a second time, from the same float32 vertices and triangles, one
geometry per component in order (geomID = component index), with the flag ``embreex`` uses
(``robust``): the hits are the same, bit for bit, as embreex's (checked in
``tests/raytrace/test_fused_gather.py``; Embree 4.4's API, ``rtcore_ray.h`` /
``rtcore_scene.h``). Built with ``robust=False`` it lets Embree take the faster arithmetic
its robust mode avoids (:attr:`raytrace.scene.Scene.direct_fast`).

Ray layout (``RTCRayHit``, 16-byte aligned, float32 / uint32 words): 0–2 origin, 3 tnear,
4–6 direction, 7 time, 8 tfar, 9 mask, 10 id, 11 flags, 12–14 Ng, 15 u, 16 v, 17 primID,
18 geomID, 19 instID. ``RTCRay`` for occlusion is words 0–11; a blocked ray's tfar becomes −inf.
"""

from __future__ import annotations

import ctypes
import glob
import os

import numpy as np
import numba
from numba import types

from ._jit import inline, pjit_exact

_LIB = None
_ERROR = None
INVALID = 0xFFFFFFFF
RAY_WORDS = 32  # one RTCRayHit (20 words) padded to 128 bytes


def _library_path() -> str | None:
    try:
        import embreex
    except ImportError:
        return None
    root = os.path.dirname(os.path.dirname(embreex.__file__))
    found = sorted(glob.glob(os.path.join(root, "embreex.libs", "libembree4*.so*")))
    return found[0] if found else None


def available() -> bool:
    """Whether Embree 4 is loaded (from the embreex wheel) for the kernels here."""
    global _LIB, _ERROR
    if _LIB is not None:
        return True
    if _ERROR is not None:
        return False
    path = _library_path()
    if path is None:
        _ERROR = "no libembree4 in the embreex wheel"
        return False
    try:
        import llvmlite.binding as llvm
        llvm.load_library_permanently(path)
        lib = ctypes.CDLL(path)
        P = ctypes.c_void_p
        for name, args, res in (("rtcNewDevice", [ctypes.c_char_p], P), ("rtcReleaseDevice", [P], None),
                                ("rtcNewScene", [P], P), ("rtcReleaseScene", [P], None),
                                ("rtcSetSceneFlags", [P, ctypes.c_int], None),
                                ("rtcSetSceneBuildQuality", [P, ctypes.c_int], None),
                                ("rtcNewGeometry", [P, ctypes.c_int], P),
                                ("rtcSetSharedGeometryBuffer",
                                 [P, ctypes.c_int, ctypes.c_uint, ctypes.c_int, P, ctypes.c_size_t, ctypes.c_size_t,
                                  ctypes.c_size_t], None),
                                ("rtcCommitGeometry", [P], None), ("rtcAttachGeometry", [P, P], ctypes.c_uint),
                                ("rtcReleaseGeometry", [P], None), ("rtcCommitScene", [P], None),
                                ("rtcGetDeviceError", [P], ctypes.c_int)):
            f = getattr(lib, name)
            f.argtypes, f.restype = args, res
    except (OSError, AttributeError) as exc:
        _ERROR = str(exc)
        return False
    _LIB = lib
    return True


# Embree 4 enums (rtcore_device.h, rtcore_scene.h, rtcore_geometry.h, rtcore_buffer.h)
_SCENE_FLAG_ROBUST = 1 << 2
_BUILD_QUALITY_MEDIUM = 1
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003


class DirectScene:
    """An Embree scene of a :class:`raytrace.scene.Scene`'s components for the kernels of
    this module; ``handle`` is the ``RTCScene`` pointer they take. It keeps the vertex and
    index arrays Embree shares alive, and releases the scene with itself. ``robust``: Embree's
    robust traversal and intersection (``RTC_SCENE_FLAG_ROBUST``, as embreex builds its
    scenes), which no ray passes through the edge shared by two triangles of a closed mesh;
    without it Embree is faster and such leaks are rare (see
    :attr:`raytrace.scene.Scene.direct_fast`)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, vertex_offset, face_offset, robust: bool = True):
        if not available():
            raise RuntimeError(f"Embree 4 is not available for direct calls: {_ERROR}")
        lib = _LIB
        self._lib = lib
        self._device = lib.rtcNewDevice(None)
        if not self._device:
            raise RuntimeError("Embree could not create a device")
        self._scene = lib.rtcNewScene(self._device)
        lib.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST if robust else 0)
        lib.rtcSetSceneBuildQuality(self._scene, _BUILD_QUALITY_MEDIUM)
        self._keep = []
        for k in range(len(vertex_offset) - 1):
            V = vertices[vertex_offset[k]:vertex_offset[k + 1]]
            F = faces[face_offset[k]:face_offset[k + 1]] - vertex_offset[k]
            v = np.zeros((len(V) + 1, 3), dtype=np.float32)  # one spare row: Embree loads 16 bytes per vertex
            v[:len(V)] = V
            f = np.ascontiguousarray(F, dtype=np.uint32)
            g = lib.rtcNewGeometry(self._device, _GEOMETRY_TYPE_TRIANGLE)
            lib.rtcSetSharedGeometryBuffer(g, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, v.ctypes.data, 0, 12, len(V))
            lib.rtcSetSharedGeometryBuffer(g, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, f.ctypes.data, 0, 12, len(F))
            lib.rtcCommitGeometry(g)
            lib.rtcAttachGeometry(self._scene, g)
            lib.rtcReleaseGeometry(g)
            self._keep += [v, f]
        lib.rtcCommitScene(self._scene)
        err = lib.rtcGetDeviceError(self._device)
        if err != 0:
            raise RuntimeError(f"Embree failed to build the scene (error {err})")
        self.handle = int(self._scene)

    def __del__(self):
        lib = getattr(self, "_lib", None)
        if lib is not None and getattr(self, "_scene", None):
            lib.rtcReleaseScene(self._scene)
            lib.rtcReleaseDevice(self._device)
            self._scene = None


# loaded on import: a kernel below is linked (compiled, or loaded from numba's cache) against
# the symbols of the library already in the process
available()
_intersect1 = types.ExternalFunction("rtcIntersect1", types.void(types.uintp, types.voidptr, types.voidptr))
_occluded1 = types.ExternalFunction("rtcOccluded1", types.void(types.uintp, types.voidptr, types.voidptr))


@inline
def ray_buffer():
    """A scratch ``RTCRayHit`` for :func:`intersect1` / :func:`occluded1`: float32 words,
    16-byte aligned (call once per thread's block of rays, not per ray)."""
    raw = np.empty(RAY_WORDS + 4, np.float32)
    off = ((16 - (raw.ctypes.data % 16)) % 16) // 4
    return raw[off:off + RAY_WORDS]


@inline
def _load_ray(buf, ox, oy, oz, dx, dy, dz):
    """Write the ray o + t·d, t ∈ [0, ∞), into words 0–11 of ``buf`` (float32, every mask bit
    set); returns the buffer's uint32 view."""
    ib = buf.view(np.uint32)
    buf[0] = np.float32(ox)
    buf[1] = np.float32(oy)
    buf[2] = np.float32(oz)
    buf[3] = np.float32(0.0)
    buf[4] = np.float32(dx)
    buf[5] = np.float32(dy)
    buf[6] = np.float32(dz)
    buf[7] = np.float32(0.0)
    buf[8] = np.float32(np.inf)
    ib[9] = np.uint32(INVALID)
    ib[10] = np.uint32(0)
    ib[11] = np.uint32(0)
    return ib


@inline
def intersect1(scene, buf, ox, oy, oz, dx, dy, dz):
    """The closest hit of the ray o + t·d (t ≥ 0; float32, as ``Scene.intersect``):
    (geomID, primID, u, v, tfar) with geomID −1 on a miss (tfar then inf)."""
    ib = _load_ray(buf, ox, oy, oz, dx, dy, dz)
    ib[18] = np.uint32(INVALID)
    ib[19] = np.uint32(INVALID)
    _intersect1(scene, buf.ctypes, 0)
    g = ib[18]
    if g == INVALID:
        return -1, -1, buf[15], buf[16], buf[8]
    return np.int32(g), np.int32(ib[17]), buf[15], buf[16], buf[8]


@inline
def occluded1(scene, buf, ox, oy, oz, dx, dy, dz):
    """Whether the ray o + t·d (t ≥ 0, float32) hits anything."""
    ib = _load_ray(buf, ox, oy, oz, dx, dy, dz)
    _occluded1(scene, buf.ctypes, 0)
    return buf[8] < np.float32(0.0)


# what embreex reports for a ray that hits nothing: its initial tfar, and u = v = 0
EMBREEX_MISS_TFAR = np.float32(1e37)


@pjit_exact
def intersect_batch(scene, O, D, geom, prim, u, v, tfar):
    """:func:`intersect1` for each ray (O[i], D[i]) (float64 or float32 rows): the arrays of
    ``Scene.intersect`` through ``embreex``, bit for bit, misses included (geomID = primID = −1,
    u = v = 0, tfar = EMBREEX_MISS_TFAR)."""
    n = O.shape[0]
    for b in numba.prange((n + 255) // 256):
        buf = ray_buffer()
        for i in range(b * 256, min(n, (b + 1) * 256)):
            g, p, uu, vv, t = intersect1(scene, buf, O[i, 0], O[i, 1], O[i, 2], D[i, 0], D[i, 1], D[i, 2])
            geom[i] = g
            if g < 0:
                prim[i] = -1
                u[i] = np.float32(0.0)
                v[i] = np.float32(0.0)
                tfar[i] = EMBREEX_MISS_TFAR
            else:
                prim[i] = p
                u[i] = uu
                v[i] = vv
                tfar[i] = t


@pjit_exact
def occluded_batch(scene, O, D, out):
    """:func:`occluded1` for each ray (O[i], D[i])."""
    n = O.shape[0]
    for b in numba.prange((n + 255) // 256):
        buf = ray_buffer()
        for i in range(b * 256, min(n, (b + 1) * 256)):
            out[i] = occluded1(scene, buf, O[i, 0], O[i, 1], O[i, 2], D[i, 0], D[i, 1], D[i, 2])
