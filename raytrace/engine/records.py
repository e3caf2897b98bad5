"""The records the compiled kernels take: named, typed groups of arrays, checked once in Python.

A kernel of :mod:`raytrace.engine.kernels` takes a handful of these records instead of dozens
of positional arrays: the scene's face tables, the media table, the per-ray state, the step
records, the differential and line-search inputs, Newton's settings, the shooting's rays. Each
record is a :class:`typing.NamedTuple` (numba passes it to nopython code as a struct of its
fields, flattened into the same machine arguments as the loose arrays were, and reads its
fields by name), and each field declares what the kernels are compiled for: dtype, shape in
named dimensions (``"F"`` faces, ``"M+1"`` media with air, ``"P"`` rays ...), whether the kernel
writes into it, and for index tables the range of their values (the kernels run without bounds
checks). :func:`build` is the one way Python makes a record: it checks every field against
that declaration, binds the named dimensions across the record's fields (a ``(M,)`` parent
table swapped with the ``(M + 1,)`` material classes, or float32 normals where float64 are
expected, fail here with a :class:`RecordError` naming the record and the field, instead of
being read as something else by compiled code). Records made by a kernel (its outputs) are
typed by numba and are passed on as they are.
"""

from __future__ import annotations

import functools
import typing
from dataclasses import dataclass
from typing import Annotated, NamedTuple

import numpy as np


class RecordError(TypeError):
    """A kernel record field of the wrong type, dtype, shape, layout or range."""


@dataclass(frozen=True)
class Array:
    """A field holding a C-contiguous array of ``dtype`` and ``shape`` (ints, or dimension
    names, optionally ``"NAME+k"`` / ``"NAME-k"``, bound across the fields of one record);
    ``out``: the kernel writes into it (it must be writeable); ``within``: its values lie in
    ``[lo, hi)`` (ints or dimension names), checked on non-empty arrays."""

    dtype: str
    shape: tuple
    out: bool = False
    within: tuple | None = None


@dataclass(frozen=True)
class Scalar:
    """A field holding one Python scalar of ``kind`` (``int``, ``float`` or ``bool``);
    ``nonzero``: zero is refused (a null pointer)."""

    kind: type
    nonzero: bool = False


def _f64(*shape, out=False, within=None):
    return Annotated[np.ndarray, Array("float64", shape, out, within)]


def _f32(*shape, out=False):
    return Annotated[np.ndarray, Array("float32", shape, out)]


def _i64(*shape, out=False, within=None):
    return Annotated[np.ndarray, Array("int64", shape, out, within)]


def _i32(*shape, out=False):
    return Annotated[np.ndarray, Array("int32", shape, out)]


def _bool(*shape, out=False):
    return Annotated[np.ndarray, Array("bool", shape, out)]


_INT = Annotated[int, Scalar(int)]
_FLOAT = Annotated[float, Scalar(float)]
_BOOL = Annotated[bool, Scalar(bool)]
_HANDLE = Annotated[int, Scalar(int, nonzero=True)]


# ------------------------------------------------------------------ tables (built once per scene / trace)
class SceneTables(NamedTuple):
    """A scene's faces in float64, for the exact kernels (:func:`~raytrace.engine.kernels.follow`,
    :func:`~raytrace.engine.kernels.newton`, :func:`~raytrace.engine.kernels.walk_step`);
    :attr:`raytrace.engine.scene.TracerScene.kernel_tables`. ``F`` faces of the phantom,
    ``G`` geometries (organs) in the Embree scene."""

    handle: _HANDLE  # the Embree scene (robust traversal) the kernels cast into
    mask: _INT  # the ray mask of this scene's faces (raytrace.engine.embree: one geometry per organ)
    base: _i64("G", within=(0, "F"))  # first face of each Embree geometry: a hit is base[geomID] + primID
    center: _f64(3)  # translation applied before the float32 conversion of Embree's queries
    face_map: _i64("F", within=(0, "F"))  # the identity (hits are faces): for kernels that take a face map
    face_normals: _f64("F", 3)  # unit, outward
    plane_d: _f64("F")  # n . v0
    frame: _f64("F", 22)  # barycentric frame and corner normals (TracerScene._barycentric_frame)
    face_organ: _i64("F")
    offset_m: _FLOAT  # spawn offset off a surface just left


class MediaTables(NamedTuple):
    """Per medium (``m + 1``: air first) and per face, for the exact kernels;
    :attr:`raytrace.solver.media.MediaTable.kernel_tables`."""

    parent: _i64("M", within=(-1, "M"))  # organ -> the medium around it
    material_class: _i64("M+1")  # same value <=> same material
    transparent: _bool("F")  # per face: the same material on both sides
    n_real: _f64("M+1")  # Re n at the centre frequency


class ShotScene(NamedTuple):
    """A scene's faces in float32 for the shooting (:func:`~raytrace.engine.kernels.bounce`)."""

    handle: _HANDLE  # the Embree scene with the fast traversal (seeds only)
    mask: _INT
    base: _i64("G", within=(0, "F"))
    face_normals: _f32("F", 3)
    corner: _f32("F", 9)
    curvature: _f32("F")  # largest normal curvature per face [1/m]
    face_organ: _i64("F")
    offset_m: _FLOAT


class ShotMedia(NamedTuple):
    """The shooting's media: float32 Re n and power attenuation, each medium's zone (the region of
    one material it belongs to: :func:`raytrace.solver.sbr.zones`) and the events it needs at
    least to reach a receiver's zone."""

    parent: _i64("M", within=(-1, "M"))
    material_class: _i64("M+1")
    transparent: _bool("F")
    n_real: _f32("M+1")
    alpha: _f32("M+1")  # power attenuation constant k0 |Im n| [Np/m]
    zone: _i64("M+1")
    need: _i64("M+1")
    #: per face, for a ray on the inside (0) / outside (1) of its organ: the least length it must
    #: still travel in that medium before it can cross towards a receiver (raytrace.solver.sbr.return_lengths)
    return_m: _f32("F", 2)
    bounds_m: _f64(2, 3)  # the scene's box (lowest, highest corner) in the centred frame


class ShotReceivers(NamedTuple):
    """Receivers as the shooting sees them: float32 positions in the scene's centred frame, and
    a uniform grid over them (cell ``(i, j, k)`` of edge ``grid_cell_m`` from ``grid_lo_m``; its
    receivers are ``cell_items[cell_start[c]:cell_start[c + 1]]``, ``c = (i * ny + j) * nz + k``),
    so that a ray segment tests only the receivers near it (:func:`raytrace.solver.sbr.receiver_grid`)."""

    position_m: _f32("R", 3)
    zone: _i64("R")  # the receiver's zone (raytrace.solver.sbr.zones)
    grid_lo_m: _f64(3)
    grid_cell_m: _FLOAT
    grid_dims: _i64(3)
    cell_start: _i64("G")
    cell_items: _i64("R", within=(0, "R"))


class ShotSettings(NamedTuple):
    """The shooting's constants of one trace (:func:`raytrace.solver.sbr.shoot`)."""

    threshold: _FLOAT  # power factor below which a ray is dropped
    kmax: _INT  # events at most
    reception_factor: _FLOAT
    curvature_margin: _FLOAT
    no_passes: _BOOL  # the scene has no transparent surface
    walk_events: _INT  # the refraction-only walk's event cap


class WalkTargets(NamedTuple):
    """Receivers of a refraction-only walk and, when each ray has its own (the zoom), which."""

    position_m: _f64("R", 3)
    material_class: _i64("R")
    ray_rx: _i64("Q", within=(0, "R"))  # per walked ray, or empty: every receiver


class NewtonSettings(NamedTuple):
    """Newton's iteration (:func:`raytrace.solver.refine.refine`, :class:`raytrace.solver.config.TracerConfig`)."""

    fractions: _f64("L")  # line-search step fractions, in trial order
    max_iterations: _INT
    tolerance_m: _FLOAT
    max_step_rad: _FLOAT
    stall_window: _INT
    stall_factor: _FLOAT
    growth: _INT


# ------------------------------------------------------------------ per call
class TraceState(NamedTuple):
    """Per ray of :func:`~raytrace.engine.kernels.follow`, updated in place: position,
    direction, medium, spawn push, events so far, signature, and in record mode its target."""

    o: _f64("P", 3, out=True)
    d: _f64("P", 3, out=True)
    med: _i64("P", out=True)
    push: _f64("P", 3, out=True)
    k: _i64("P", out=True)
    nint: _i64("P")
    ok: _bool("P", out=True)
    done: _bool("P", out=True)
    codes: _i64("P", "K")
    targets: _f64("T", 3)  # (P, 3) in record mode, else (0, 3)
    record: _BOOL


class StepRecords(NamedTuple):
    """Per step and ray (S, P, ...) of a :func:`~raytrace.engine.kernels.follow` in record mode
    (``valid[s]`` is step s of every ray); (0, 0) arrays otherwise."""

    valid: _bool("S", "P", out=True)
    point: _f64("S", "P", 3, out=True)
    face: _i64("S", "P", out=True)
    kind: _i64("S", "P", out=True)  # KIND_*
    med_from: _i64("S", "P", out=True)
    med_to: _i64("S", "P", out=True)  # far side of the surface
    normal: _f64("S", "P", 3, out=True)  # smooth outward normal
    dir_in: _f64("S", "P", 3, out=True)


class Differentials(NamedTuple):
    """Ray differentials: launch tangents in, derivatives of the last point and direction out
    (P, 2, 3); (0, 2, 3) arrays for none."""

    launch: _f64("P", 2, 3)
    point: _f64("P", 2, 3, out=True)
    direction: _f64("P", 2, 3, out=True)


class LineSearch(NamedTuple):
    """One step of Newton's backtracking per ray (:func:`~raytrace.engine.kernels.follow`'s
    line-search mode); empty arrays for none."""

    fractions: _f64("L")
    base_dir: _f64("P", 3)
    step: _f64("P", 2)
    rx: _f64("P", 3)
    old_miss: _f64("P")
    won: _i64("P", out=True)  # in: the first fraction to try; out: the one accepted, or -1
    trial_dir: _f64("P", 3, out=True)


class NewtonSeeds(NamedTuple):
    """Seeds of :func:`~raytrace.engine.kernels.newton`: launches (updated in place), signatures,
    receivers, and the outcome."""

    tx: _f64(3)
    tx_medium: _INT
    dirs: _f64("P", 3, out=True)
    codes: _i64("P", "K")
    nint: _i64("P")
    rx: _f64("P", 3)
    converged: _bool("P", out=True)
    tube: _f64("P", out=True)


class ShotRays(NamedTuple):
    """Live rays of the shooting (float32 geometry in the scene's centred frame): origin (pushed
    off the surface), direction, medium, power factor, tube radius and angle, reduced length
    sum L_i / Re n_i, events so far, event-log entry, launch index, and walk mode (0 shot,
    1 shot and walked, 2 walked only)."""

    o: _f32("N", 3)
    d: _f32("N", 3)
    med: _i64("N")
    w: _f32("N")
    rad: _f32("N")
    ang: _f32("N")
    length: _f32("N")
    nint: _i64("N")
    hist: _i64("N")
    src: _i64("N")
    mode: Annotated[np.ndarray, Array("int8", ("N",))]


class LogEntries(NamedTuple):
    """Event-log entries of one bounce (made by :func:`~raytrace.engine.kernels.bounce`): the
    parent entry, the event code and the face of each reflected or transmitted child."""

    parent: _i32("N")
    code: _i32("N")
    face: _i32("N")


class Receptions(NamedTuple):
    """Receptions of one bounce (made by :func:`~raytrace.engine.kernels.bounce`), receiver-major:
    receiver, event-log entry, events, launch index, miss over the tube radius."""

    rx: _i64("N")
    hist: _i64("N")
    n: _i64("N")
    src: _i64("N")
    close: _f64("N")


class WalkRecords(NamedTuple):
    """The refraction-only walk riding on the shooting: per launch of the batch (row
    ``src - src_base``) and receiver, the closest approach, its events and last log entry;
    (0, R) arrays for no walk."""

    miss: _f64("B", "R", out=True)
    events: _i32("B", "R", out=True)
    hist: _i32("B", "R", out=True)
    src_base: _INT


class WalkRays(NamedTuple):
    """The live rays of a refraction-only walk (row r is walked ray ``ids[r]``), float64, and
    their float32 Embree query (centred origin + spawn push, direction)."""

    ids: _i64("N")
    o: _f64("N", 3)
    d: _f64("N", 3)
    med: _i64("N")
    nint: _i64("N")
    q: _f32("N", 3)
    dq: _f32("N", 3)


class WalkOutput(NamedTuple):
    """What a walk records per walked ray, in place: closest approach per receiver column and
    the events before it, and every refraction's code."""

    miss: _f64("P", "C", out=True)
    nmiss: _i64("P", "C", out=True)
    codes: _i64("P", "X", out=True)


class Hits(NamedTuple):
    """Embree's first hits of a batch of rays (:meth:`raytrace.engine.embree.EmbreeScene.intersect`):
    primitive or -1, distance (inf on a miss), barycentrics."""

    prim: _i32("N")
    tfar: _f32("N")
    u: _f32("N")
    v: _f32("N")


# ------------------------------------------------------------------ the checker
def _token(token) -> tuple:
    """A shape token as ``(name or None, offset or size)``: ``3`` -> ``(None, 3)``,
    ``"M+1"`` -> ``("M", 1)``."""
    if isinstance(token, int):
        return None, token
    for sign in "+-":
        if sign in token:
            name, k = token.split(sign)
            return name, int(k) if sign == "+" else -int(k)
    return token, 0


@functools.cache
def _fields(cls) -> tuple:
    """Per field of ``cls``: ``(name, declaration, dtype, parsed shape)``, computed once."""
    hints = typing.get_type_hints(cls, include_extras=True)
    out = []
    for name in cls._fields:
        meta = getattr(hints[name], "__metadata__", ())
        if len(meta) != 1 or not isinstance(meta[0], (Array, Scalar)):
            raise TypeError(f"{cls.__name__}.{name} declares no Array or Scalar")
        spec = meta[0]
        if isinstance(spec, Array):
            out.append((name, spec, np.dtype(spec.dtype), tuple(_token(t) for t in spec.shape)))
        else:
            out.append((name, spec, None, None))
    return tuple(out)


def _value(token, bound: dict):
    """A shape token's value under the dimensions bound so far (None if its name is free)."""
    name, k = _token(token)
    if name is None:
        return k
    return bound[name] + k if name in bound else None


def _describe(spec: Array, bound: dict) -> str:
    dims = []
    for token in spec.shape:
        value = _value(token, bound)
        dims.append(f"{token}={value}" if isinstance(token, str) and value is not None else str(token))
    return f"{spec.dtype} ({', '.join(dims)}{',' if len(dims) == 1 else ''})"


def _check_array(where: str, value, spec: Array, dtype: np.dtype, shape: tuple, bound: dict) -> np.ndarray:
    if not isinstance(value, np.ndarray):
        raise RecordError(f"{where}: expected a numpy array, {_describe(spec, bound)}; got {type(value).__name__}")
    if value.dtype != dtype:
        raise RecordError(f"{where}: expected dtype {spec.dtype}, got {value.dtype} "
                          f"({_describe(spec, bound)} expected)")
    sizes = value.shape
    if len(sizes) != len(shape):
        raise RecordError(f"{where}: expected {_describe(spec, bound)}, got shape {sizes}")
    for size, (name, k) in zip(sizes, shape):
        if name is None:
            if size == k:
                continue
        else:
            have = bound.get(name)
            if have is None and size - k >= 0:
                bound[name] = size - k
                continue
            if have is not None and have + k == size:
                continue
        raise RecordError(f"{where}: expected {_describe(spec, bound)}, got shape {sizes}")
    flags = value.flags
    if not flags.c_contiguous:
        raise RecordError(f"{where}: must be C-contiguous (np.ascontiguousarray), got strides {value.strides}")
    if spec.out and not flags.writeable:
        raise RecordError(f"{where}: the kernel writes into it, but the array is read-only")
    return value


def _check_range(where: str, value: np.ndarray, spec: Array, bound: dict) -> None:
    lo, hi = (_value(t, bound) for t in spec.within)
    if value.size and (lo is None or hi is None or value.min() < lo or value.max() >= hi):
        raise RecordError(f"{where}: values must lie in [{spec.within[0]}={lo}, {spec.within[1]}={hi}), "
                          f"got [{value.min()}, {value.max()}]")


def _check_scalar(where: str, value, spec: Scalar):
    kind = spec.kind
    if kind is bool:
        if not isinstance(value, (bool, np.bool_)):
            raise RecordError(f"{where}: expected a bool, got {type(value).__name__}")
        return bool(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise RecordError(f"{where}: expected {kind.__name__}, got {type(value).__name__}")
    if kind is int:
        if not float(value).is_integer():
            raise RecordError(f"{where}: expected an int, got {value!r}")
        value = int(value)
    else:
        value = float(value)
        if not np.isfinite(value):
            raise RecordError(f"{where}: expected a finite number, got {value!r}")
    if spec.nonzero and value == 0:
        raise RecordError(f"{where}: must not be 0 (a null handle)")
    return value


def build(cls, /, *, dims: dict | None = None, **values):
    """The record ``cls`` of ``values``, every field checked against its declaration (module
    doc); ``dims`` binds dimension names beforehand (e.g. ``{"P": rays}``). Raises
    :class:`RecordError` naming the record and the field."""
    if len(values) != len(cls._fields) or not all(name in values for name in cls._fields):
        missing = [name for name in cls._fields if name not in values]
        extra = [name for name in values if name not in cls._fields]
        raise RecordError(f"{cls.__name__}: missing fields {missing}, unknown fields {extra}")
    bound = dict(dims) if dims else {}
    out = []
    ranges = []
    for name, spec, dtype, shape in _fields(cls):
        value = values[name]
        if dtype is not None:
            out.append(_check_array(f"{cls.__name__}.{name}", value, spec, dtype, shape, bound))
            if spec.within is not None:
                ranges.append((f"{cls.__name__}.{name}", value, spec))
        else:
            out.append(_check_scalar(f"{cls.__name__}.{name}", value, spec))
    for where, value, spec in ranges:  # after every dimension is bound
        _check_range(where, value, spec, bound)
    record = cls(*out)
    invariant = _INVARIANTS.get(cls)
    if invariant is not None:
        invariant(record)
    return record


def _trace_state(s: TraceState) -> None:
    if len(s.targets) != (len(s.o) if s.record else 0):
        raise RecordError(f"TraceState.targets: {len(s.targets)} rows; record mode needs one per ray "
                          f"({len(s.o)}), otherwise none")


_INVARIANTS = {TraceState: _trace_state}


def step_records(steps: int, rays: int) -> StepRecords:
    """Step records for ``steps`` steps of ``rays`` rays (0, 0: not in record mode), filled
    with what a ray not advanced at a step keeps (no face, no kind, media -2)."""
    return build(StepRecords, valid=np.zeros((steps, rays), bool), point=np.zeros((steps, rays, 3)),
                 face=np.full((steps, rays), -1, np.int64), kind=np.full((steps, rays), -1, np.int64),
                 med_from=np.full((steps, rays), -2, np.int64), med_to=np.full((steps, rays), -2, np.int64),
                 normal=np.zeros((steps, rays, 3)), dir_in=np.zeros((steps, rays, 3)))
