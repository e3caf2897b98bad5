"""Embree 4 through its C API, callable from the compiled kernels.

Why not only embreex: embreex's ``EmbreeScene.run`` is the right call for a
batch of rays from Python, but the tracer's inner loops (Newton's re-tracing,
the shooting's bounce, the refraction-only walk) are compiled kernels
(:mod:`raytrace.engine.kernels`) that would otherwise return to the interpreter once
per step only to hand Embree the next batch. This module declares Embree's
``rtcIntersect1`` to numba by its symbol name (from the ``libembree4`` that the
embreex wheel ships, loaded once into the process), so a kernel traces a ray to
its end with no interpreter in between, and the machine code stays cacheable
(a symbol, not an address, is baked in).

The scene is built with the C API too: one triangle geometry in float32
(Embree's own padded buffers, data copied in), by default with
``RTC_SCENE_FLAG_ROBUST`` (watertight traversal: a ray through a shared edge or
vertex hits one of the triangles, never slips between them), as embreex builds
its scenes: the hits are bit-identical to embreex's (tests/raytrace/test_embree.py).
``robust=False`` gives Embree's faster default traversal.

Layout of ``RTCRayHit`` (Embree 4 ``rtcore_ray.h``, 16-byte aligned): the ray
``org_x org_y org_z tnear dir_x dir_y dir_z time tfar mask id flags`` (float32 /
uint32 words 0-11), then the hit ``Ng_x Ng_y Ng_z u v primID geomID instID``
(words 12-19); the buffer here has 24 words, room for the optional
``instPrimID`` of builds with instance arrays.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import weakref

import llvmlite.binding
import numpy as np
from numba import njit, types

_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX = 0
_RTC_BUFFER_TYPE_VERTEX = 1
_RTC_FORMAT_UINT3 = 0x5003
_RTC_FORMAT_FLOAT3 = 0x9003
_RTC_SCENE_FLAG_ROBUST = 1 << 2
_RTC_INVALID_ID = 0xFFFFFFFF
#: float32 words of one ray-hit buffer (RTCRayHit is 80 bytes, 96 with instPrimID).
RAYHIT_WORDS = 24


def _library_path() -> str:
    """The libembree4 shipped in the embreex wheel (the one embreex itself links), else the
    system's."""
    import embreex

    root = os.path.dirname(os.path.dirname(os.path.abspath(embreex.__file__)))
    found = sorted(glob.glob(os.path.join(root, "embreex.libs", "libembree4*")))
    if found:
        return found[0]
    system = ctypes.util.find_library("embree4")
    if system is None:
        raise ImportError("libembree4 not found (neither in the embreex wheel nor on the system)")
    return system


def _load() -> ctypes.CDLL:
    path = _library_path()
    llvmlite.binding.load_library_permanently(path)  # so compiled code resolves rtcIntersect1
    lib = ctypes.CDLL(path)
    vp, c_int, c_uint, c_size = ctypes.c_void_p, ctypes.c_int, ctypes.c_uint, ctypes.c_size_t
    for name, res, args in (
        ("rtcNewDevice", vp, [ctypes.c_char_p]),
        ("rtcGetDeviceError", c_int, [vp]),
        ("rtcReleaseDevice", None, [vp]),
        ("rtcNewScene", vp, [vp]),
        ("rtcSetSceneFlags", None, [vp, c_int]),
        ("rtcCommitScene", None, [vp]),
        ("rtcReleaseScene", None, [vp]),
        ("rtcNewGeometry", vp, [vp, c_int]),
        ("rtcSetNewGeometryBuffer", vp, [vp, c_int, c_uint, c_int, c_size, c_size]),
        ("rtcCommitGeometry", None, [vp]),
        ("rtcAttachGeometry", c_uint, [vp, vp]),
        ("rtcReleaseGeometry", None, [vp]),
    ):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


_LIB = _load()

#: ``void rtcIntersect1(RTCScene scene, RTCRayHit* rayhit, RTCIntersectArguments* args)``,
#: pointers passed as integers (same registers on every 64-bit ABI numba targets).
rtc_intersect1 = types.ExternalFunction("rtcIntersect1", types.void(types.uintp, types.uintp, types.uintp))


class EmbreeScene:
    """One committed Embree scene of float32 triangles; :attr:`handle` is what kernels take.
    Released (scene, then device) when the object is collected."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, robust: bool = True):
        vertices = np.ascontiguousarray(vertices, np.float32)
        faces = np.ascontiguousarray(faces, np.uint32)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError("vertices and faces must be (N, 3) arrays")
        if len(faces) and (faces.max() >= len(vertices)):
            raise ValueError("a face indexes a vertex that does not exist")
        lib = _LIB
        device = lib.rtcNewDevice(None)
        if not device:
            raise RuntimeError("Embree could not create a device")
        scene = lib.rtcNewScene(device)
        self.handle = int(scene)
        self.triangles = len(faces)
        self._finalizer = weakref.finalize(self, _release, scene, device)
        lib.rtcSetSceneFlags(scene, _RTC_SCENE_FLAG_ROBUST if robust else 0)
        if len(faces):
            geometry = lib.rtcNewGeometry(device, _RTC_GEOMETRY_TYPE_TRIANGLE)
            for kind, fmt, data in ((_RTC_BUFFER_TYPE_VERTEX, _RTC_FORMAT_FLOAT3, vertices),
                                    (_RTC_BUFFER_TYPE_INDEX, _RTC_FORMAT_UINT3, faces)):
                target = lib.rtcSetNewGeometryBuffer(geometry, kind, 0, fmt, 12, len(data))
                if not target:
                    lib.rtcReleaseGeometry(geometry)
                    raise RuntimeError(f"Embree could not allocate a buffer (error {lib.rtcGetDeviceError(device)})")
                ctypes.memmove(target, data.ctypes.data, data.nbytes)
            lib.rtcCommitGeometry(geometry)
            lib.rtcAttachGeometry(scene, geometry)
            lib.rtcReleaseGeometry(geometry)
        lib.rtcCommitScene(scene)
        error = lib.rtcGetDeviceError(device)
        if error:
            raise RuntimeError(f"Embree failed to build the scene (error {error})")

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> tuple:
        """First hits of a batch of float32 rays: ``(primID, tfar, u, v)``; ``primID = -1`` and
        ``tfar = inf`` on a miss; the hit point is ``(1 - u - v) v0 + u v1 + v v2``."""
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(directions, np.float32)
        n = len(o)
        prim, tfar = np.empty(n, np.int32), np.empty(n, np.float32)
        u, v = np.empty(n, np.float32), np.empty(n, np.float32)
        intersect_batch(self.handle, o, d, prim, tfar, u, v)
        return prim, tfar, u, v


def _release(scene, device) -> None:
    _LIB.rtcReleaseScene(scene)
    _LIB.rtcReleaseDevice(device)


_kernel = njit(cache=True, nogil=True, error_model="numpy")


@_kernel
def ray_buffer() -> np.ndarray:
    """A 16-byte aligned float32 RTCRayHit buffer (a view into a slightly larger array)."""
    raw = np.empty(RAYHIT_WORDS + 4, np.float32)
    skip = ((16 - raw.ctypes.data % 16) % 16) // 4
    return raw[skip:skip + RAYHIT_WORDS]


@_kernel
def intersect(handle, buf, words, ptr, ox, oy, oz, dx, dy, dz):
    """First hit of one ray (float32 origin and direction, from distance 0): returns
    ``(primID or -1, tfar, u, v)``; ``buf`` is a :func:`ray_buffer`, ``words`` its uint32 view
    and ``ptr`` its address (made once per kernel call, not per ray)."""
    buf[0], buf[1], buf[2], buf[3] = ox, oy, oz, 0.0
    buf[4], buf[5], buf[6], buf[7] = dx, dy, dz, 0.0
    buf[8] = 1e37
    words[9], words[10], words[11] = _RTC_INVALID_ID, 0, 0  # mask (all), id, flags
    words[17], words[18] = _RTC_INVALID_ID, _RTC_INVALID_ID  # primID, geomID
    rtc_intersect1(handle, ptr, 0)
    if words[18] == _RTC_INVALID_ID:
        return -1, np.float32(np.inf), np.float32(0.0), np.float32(0.0)
    return np.int64(words[17]), buf[8], buf[15], buf[16]


@_kernel
def intersect_batch(handle, o, d, prim, tfar, u, v):
    """:func:`intersect` over a batch of rays, results written into ``prim, tfar, u, v``."""
    buf = ray_buffer()
    words, ptr = buf.view(np.uint32), buf.ctypes.data
    for i in range(len(o)):
        prim[i], tfar[i], u[i], v[i] = intersect(handle, buf, words, ptr, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2])
