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

The scene is built with the C API too, in float32, by default with
``RTC_SCENE_FLAG_ROBUST`` (watertight traversal: a ray through a shared edge or
vertex hits one of the triangles, never slips between them), as embreex builds
its scenes: the hits are bit-identical to embreex's (tests/raytrace/test_embree.py).
``robust=False`` gives Embree's faster default traversal. The triangles are given as
contiguous *runs* of one face table (:class:`Geometry`: by default one run of all faces; the
tracer makes one per organ), each an Embree geometry with its own 32-bit mask over one
shared vertex buffer and one shared index buffer (``rtcSetSharedGeometryBuffer``: no copy
into Embree, and two scenes of the same faces, the robust and the fast one, hold one copy
between them). A query carries a ray mask and only hits the runs whose mask it shares a bit
with: one scene then serves every subset of organs a trace needs (the surfaces between
identical materials are left out of propagation by the mask, not by another scene). A hit is
reported as the index of its face in the face table: the hit run's first face
(``base[geomID]``) plus Embree's ``primID``.

Layout of ``RTCRayHit`` (Embree 4 ``rtcore_ray.h``, 16-byte aligned): the ray
``org_x org_y org_z tnear dir_x dir_y dir_z time tfar mask id flags`` (float32 /
uint32 words 0-11), then the hit ``Ng_x Ng_y Ng_z u v primID geomID instID``
(words 12-19); the buffer here has 24 words, room for the optional
``instPrimID`` of builds with instance arrays. That layout is Embree 4's: the
library's version is read from a device when it loads (:func:`check_version`),
and any other major version is refused with an ImportError. The library is
looked up in the embreex wheel's layout of the platform, then on the system
(:func:`library_path`). Under ``NUMBA_DISABLE_JIT=1`` the kernels run as Python
and call ``rtcIntersect1`` through ctypes (:mod:`raytrace.engine.jit`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import weakref
from pathlib import Path
from typing import NamedTuple

import llvmlite.binding
import numpy as np
from numba import types

from raytrace.engine.jit import JIT_DISABLED, kernel
from raytrace.engine.records import Hits

_RTC_GEOMETRY_TYPE_TRIANGLE = 0
_RTC_BUFFER_TYPE_INDEX = 0
_RTC_BUFFER_TYPE_VERTEX = 1
_RTC_FORMAT_UINT3 = 0x5003
_RTC_FORMAT_FLOAT3 = 0x9003
_RTC_SCENE_FLAG_ROBUST = 1 << 2
_RTC_INVALID_ID = 0xFFFFFFFF
#: ``RTCDeviceProperty`` values of the version queries (Embree 3 and 4 ``rtcore_device.h``).
_RTC_DEVICE_PROPERTY_VERSION = 0
_RTC_DEVICE_PROPERTY_VERSION_MAJOR = 1
_RTC_DEVICE_PROPERTY_VERSION_MINOR = 2
_RTC_DEVICE_PROPERTY_VERSION_PATCH = 3
#: The Embree major version whose ``RTCRayHit`` layout this module writes by hand.
EMBREE_MAJOR = 4
#: float32 words of one ray-hit buffer (RTCRayHit is 80 bytes, 96 with instPrimID).
RAYHIT_WORDS = 24
#: The ray mask that hits every geometry.
ALL = 0xFFFFFFFF

#: Where the embreex wheels put the Embree library, relative to the directory holding the
#: ``embreex`` package (site-packages), per platform: auditwheel's ``embreex.libs/`` (Linux,
#: a hash in the name), delocate's ``embreex/.dylibs/`` (macOS) and delvewheel's
#: ``embreex.libs/`` (Windows, the name kept); the package directory itself last.
WHEEL_LAYOUTS: dict[str, tuple[str, ...]] = {
    "linux": ("embreex.libs/libembree4*.so*", "embreex/libembree4*.so*"),
    "darwin": ("embreex/.dylibs/libembree4*.dylib", "embreex.libs/libembree4*.dylib", "embreex/libembree4*.dylib"),
    "win32": ("embreex.libs/embree4*.dll", "embreex/embree4*.dll"),
}


def _platform(name: str) -> str:
    return "linux" if name.startswith("linux") else name


def library_path(site_dir: str | os.PathLike | None = None, platform: str = sys.platform) -> str:
    """The Embree 4 library the embreex wheel ships (the one embreex itself links), found in the
    wheel layout of ``platform`` (:data:`WHEEL_LAYOUTS`) under ``site_dir`` (by default the
    directory holding the installed ``embreex``); else the system's ``embree4``. Raises
    ImportError naming the places searched."""
    if site_dir is None:
        import embreex

        site_dir = Path(embreex.__file__).resolve().parent.parent
    site_dir = Path(site_dir)
    patterns = WHEEL_LAYOUTS.get(_platform(platform), ())
    for pattern in patterns:
        found = sorted(p for p in site_dir.glob(pattern) if p.is_file())
        if found:
            return str(found[0])
    system = ctypes.util.find_library("embree4")
    if system is None:
        searched = ", ".join(str(site_dir / p) for p in patterns) or f"no wheel layout known for {platform!r}"
        raise ImportError(f"the Embree 4 library was not found: not in the embreex wheel ({searched}) "
                          "nor on the system (ctypes.util.find_library('embree4'))")
    return system


def check_version(lib, path: str) -> tuple[int, int, int]:
    """The version ``(major, minor, patch)`` of the Embree library ``lib`` (a ctypes library
    loaded from ``path``), read from a device (``rtcGetDeviceProperty``). Raises ImportError
    naming the version found and the one expected unless it is Embree :data:`EMBREE_MAJOR`:
    the ``RTCRayHit`` layout this module writes (module doc) is that of Embree 4."""
    lib.rtcNewDevice.restype, lib.rtcNewDevice.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
    lib.rtcGetDeviceProperty.restype = ctypes.c_ssize_t
    lib.rtcGetDeviceProperty.argtypes = [ctypes.c_void_p, ctypes.c_int]
    lib.rtcReleaseDevice.restype, lib.rtcReleaseDevice.argtypes = None, [ctypes.c_void_p]
    device = lib.rtcNewDevice(None)
    if not device:
        raise ImportError(f"Embree at {path} could not create a device to report its version")
    try:
        combined = int(lib.rtcGetDeviceProperty(device, _RTC_DEVICE_PROPERTY_VERSION))
        major, minor, patch = (int(lib.rtcGetDeviceProperty(device, p)) for p in (
            _RTC_DEVICE_PROPERTY_VERSION_MAJOR, _RTC_DEVICE_PROPERTY_VERSION_MINOR, _RTC_DEVICE_PROPERTY_VERSION_PATCH))
    finally:
        lib.rtcReleaseDevice(device)
    found = f"{major}.{minor}.{patch}"
    if major != EMBREE_MAJOR or combined != major * 10_000 + minor * 100 + patch:
        raise ImportError(f"Embree {EMBREE_MAJOR}.x expected (raytrace.engine.embree writes the Embree "
                          f"{EMBREE_MAJOR} RTCRayHit layout), found Embree {found} (version number {combined}) "
                          f"at {path}; install embreex>=4.4,<5 (pyproject.toml)")
    return major, minor, patch


def _load() -> tuple[ctypes.CDLL, str, tuple[int, int, int]]:
    path = library_path()
    lib = ctypes.CDLL(path)
    version = check_version(lib, path)  # before any compiled code can call into it
    if not JIT_DISABLED:
        llvmlite.binding.load_library_permanently(path)  # so compiled code resolves rtcIntersect1
    vp, c_int, c_uint, c_size = ctypes.c_void_p, ctypes.c_int, ctypes.c_uint, ctypes.c_size_t
    for name, res, args in (
        ("rtcGetDeviceError", c_int, [vp]),
        ("rtcNewScene", vp, [vp]),
        ("rtcSetSceneFlags", None, [vp, c_int]),
        ("rtcCommitScene", None, [vp]),
        ("rtcReleaseScene", None, [vp]),
        ("rtcNewGeometry", vp, [vp, c_int]),
        ("rtcSetSharedGeometryBuffer", None, [vp, c_int, c_uint, c_int, vp, c_size, c_size, c_size]),
        ("rtcSetGeometryMask", None, [vp, c_uint]),
        ("rtcCommitGeometry", None, [vp]),
        ("rtcAttachGeometryByID", None, [vp, vp, c_uint]),
        ("rtcReleaseGeometry", None, [vp]),
        ("rtcIntersect1", None, [vp, vp, vp]),
    ):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib, path, version


_LIB, LIBRARY_PATH, VERSION = _load()

if JIT_DISABLED:
    #: ``NUMBA_DISABLE_JIT=1``: the kernels run as Python and call Embree through ctypes.
    rtc_intersect1 = _LIB.rtcIntersect1
else:
    #: ``void rtcIntersect1(RTCScene scene, RTCRayHit* rayhit, RTCIntersectArguments* args)``,
    #: pointers passed as integers (same registers on every 64-bit ABI numba targets).
    rtc_intersect1 = types.ExternalFunction("rtcIntersect1", types.void(types.uintp, types.uintp, types.uintp))


class RayHit(NamedTuple):
    """One 16-byte aligned ``RTCRayHit`` buffer as the kernels hold it: the float32 words,
    the same memory as uint32 words, and its address (made once per kernel call, not per ray)."""

    buf: np.ndarray  # (RAYHIT_WORDS,) float32
    words: np.ndarray  # (RAYHIT_WORDS,) uint32 view of buf
    ptr: int  # buf's address


class Geometry(NamedTuple):
    """Runs of a face table as Embree geometries: run ``k`` is faces ``start[k]`` to
    ``stop[k] - 1``, hit by rays whose mask shares a bit with ``mask[k]`` (module doc)."""

    start: np.ndarray  # (G,) int64
    stop: np.ndarray  # (G,) int64
    mask: np.ndarray  # (G,) uint32


def buffers(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The float32 vertex buffer (padded by one float: Embree reads a vertex with one 16-byte
    load) and the uint32 index buffer of a scene, in the layout :class:`EmbreeScene` shares
    with Embree; pass the same pair to several scenes of one face table."""
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError("vertices and faces must be (N, 3) arrays")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError("a face indexes a vertex that does not exist")
    padded = np.zeros(3 * len(vertices) + 1, np.float32)
    padded[:-1] = vertices.reshape(-1)
    return padded, np.ascontiguousarray(faces, np.uint32)


class EmbreeScene:
    """One committed Embree scene of float32 triangles; :attr:`handle` is what kernels take,
    :attr:`base` (the first face of each geometry) turns a hit's ``(geomID, primID)`` into a
    face index. The scene reads ``vertices`` and ``faces`` from the arrays it was given (kept
    alive here; :func:`buffers` makes them from any arrays). Released (scene, then device) when
    the object is collected."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, robust: bool = True,
                 geometry: Geometry | None = None):
        if not (vertices.dtype == np.float32 and vertices.ndim == 1 and len(vertices) % 3 == 1
                and vertices.flags.c_contiguous and faces.dtype == np.uint32 and faces.flags.c_contiguous):
            vertices, faces = buffers(vertices, faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError("faces must be an (N, 3) array")
        n_vertices = (len(vertices) - 1) // 3
        if geometry is None:
            geometry = Geometry(np.zeros(1, np.int64), np.full(1, len(faces), np.int64), np.full(1, ALL, np.uint32))
        start, stop = np.asarray(geometry.start, np.int64), np.asarray(geometry.stop, np.int64)
        if np.any(start < 0) or np.any(stop > len(faces)) or np.any(stop < start):
            raise ValueError("a geometry's run of faces lies outside the face table")
        keep = stop > start  # an empty run is not a geometry
        start, stop, masks = start[keep], stop[keep], np.asarray(geometry.mask, np.uint32)[keep]
        self._vertices, self._faces = vertices, faces  # Embree reads them (shared buffers)
        self._robust, self._geometry = bool(robust), Geometry(start, stop, masks)
        self.base = np.ascontiguousarray(start, np.int64)
        self.triangles = int((stop - start).sum())
        self.faces = len(faces)
        lib = _LIB
        device = lib.rtcNewDevice(None)
        if not device:
            raise RuntimeError("Embree could not create a device")
        scene = lib.rtcNewScene(device)
        self.handle = int(scene)
        self._finalizer = weakref.finalize(self, _release, scene, device)
        lib.rtcSetSceneFlags(scene, _RTC_SCENE_FLAG_ROBUST if robust else 0)
        for k, (a, b, mask) in enumerate(zip(start.tolist(), stop.tolist(), masks.tolist())):
            geom = lib.rtcNewGeometry(device, _RTC_GEOMETRY_TYPE_TRIANGLE)
            lib.rtcSetSharedGeometryBuffer(geom, _RTC_BUFFER_TYPE_VERTEX, 0, _RTC_FORMAT_FLOAT3,
                                           vertices.ctypes.data, 0, 12, n_vertices)
            lib.rtcSetSharedGeometryBuffer(geom, _RTC_BUFFER_TYPE_INDEX, 0, _RTC_FORMAT_UINT3,
                                           faces.ctypes.data, 12 * a, 12, b - a)
            lib.rtcSetGeometryMask(geom, mask)
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometryByID(scene, geom, k)
            lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(scene)
        error = lib.rtcGetDeviceError(device)
        if error:
            raise RuntimeError(f"Embree failed to build the scene (error {error})")

    def __reduce__(self):
        """Pickled as what builds it, and built again when loaded: the handle is a pointer into
        this process (a phantom pickled with its scene of every face and loaded in another
        process, as the scene bench's children load it, crashed on its first cast)."""
        return EmbreeScene, (self._vertices, self._faces, self._robust, self._geometry)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, mask: int = ALL) -> Hits:
        """First hits of a batch of float32 rays (:class:`~raytrace.engine.records.Hits`:
        ``prim, tfar, u, v``) among the geometries sharing a bit with ``mask``: ``prim`` is the
        face index (module doc), -1 with ``tfar = inf`` on a miss; the hit point is
        ``(1 - u - v) v0 + u v1 + v v2``."""
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(directions, np.float32)
        if o.ndim != 2 or o.shape[1] != 3 or o.shape != d.shape:
            raise ValueError(f"origins and directions must be (N, 3) arrays of one shape, got {o.shape} and {d.shape}")
        n = len(o)
        hits = Hits(np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
        intersect_batch(self.handle, int(mask), self.base, o, d, *hits)
        return hits


def _release(scene, device) -> None:
    _LIB.rtcReleaseScene(scene)
    _LIB.rtcReleaseDevice(device)


@kernel
def ray_hit() -> RayHit:
    """A fresh :class:`RayHit`: a 16-byte aligned float32 buffer (a view into a slightly
    larger array), its uint32 view and its address."""
    raw = np.empty(RAYHIT_WORDS + 4, np.float32)
    skip = ((16 - raw.ctypes.data % 16) % 16) // 4
    buf = raw[skip:skip + RAYHIT_WORDS]
    return RayHit(buf, buf.view(np.uint32), buf.ctypes.data)


@kernel
def intersect(handle, mask, base, hit, ox, oy, oz, dx, dy, dz):
    """First hit of one ray (float32 origin and direction, from distance 0) in the scene
    ``handle`` among its geometries sharing a bit with the ray ``mask``, through the buffer
    ``hit`` (:func:`ray_hit`): returns ``(face or -1, tfar, u, v)``, the face being
    ``base[geomID] + primID`` (:attr:`EmbreeScene.base`)."""
    buf, words = hit.buf, hit.words
    buf[0], buf[1], buf[2], buf[3] = ox, oy, oz, 0.0
    buf[4], buf[5], buf[6], buf[7] = dx, dy, dz, 0.0
    buf[8] = 1e37
    words[9], words[10], words[11] = mask, 0, 0  # mask, id, flags
    words[17], words[18] = _RTC_INVALID_ID, _RTC_INVALID_ID  # primID, geomID
    rtc_intersect1(handle, hit.ptr, 0)
    if words[18] == _RTC_INVALID_ID:
        return -1, np.float32(np.inf), np.float32(0.0), np.float32(0.0)
    return base[words[18]] + np.int64(words[17]), buf[8], buf[15], buf[16]


@kernel
def intersect_batch(handle, mask, base, o, d, prim, tfar, u, v):
    """:func:`intersect` over a batch of rays, results written into ``prim, tfar, u, v``."""
    hit = ray_hit()
    for i in range(len(o)):
        prim[i], tfar[i], u[i], v[i] = intersect(handle, mask, base, hit, o[i, 0], o[i, 1], o[i, 2], d[i, 0],
                                                 d[i, 1], d[i, 2])
