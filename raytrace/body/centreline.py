"""A centreline through a phantom's organs: a capsule's path, positions by arc length.

A :class:`Centreline` is a chain of *pieces*, each a polyline inside one organ's
lumen (the GI tract: stomach, small intestine, ascending, transverse and descending
colon). A position along it is its arc length ``s_m`` from the start, counted inside
the lumens only: where one piece ends and the next begins (a junction between two
organ meshes, e.g. the pylorus or a colic flexure, which a phantom of separate closed
organs does not model as a duct) the point jumps from the end of one piece to the start
of the next while ``s`` stays continuous. ``junctions_s_m`` lists those arc lengths;
every other point is on a straight segment inside its piece's organ.

API (every method takes a scalar or an array and answers in the same shape)::

    line.length_m                     total arc length [m]
    line.point_m(s)                   position at arc length s, (3,) or (n, 3) [m]
    line.tangent(s)                   unit direction of travel at s (the segment's)
    line.organ_at(s)                  name of the organ (piece) at s
    line.project(p)                   arc length of the point of the line nearest to p
    line.distance_m(p)                distance from p to the line [m]
    line.sample_s(ds_m)               arc lengths 0, ds, 2 ds, ... <= length_m

At a vertex or a junction ``point_m``/``tangent``/``organ_at`` are right-continuous
(they answer for the segment that starts there); at ``s = length_m`` they answer for
the last segment. ``s`` outside ``[0, length_m]`` is an :class:`InputError` naming
``s_m``. :func:`smooth_polyline` turns a few control points into a dense, smooth
polyline (centripetal Catmull-Rom), so the tangent turns by small steps, as a
capsule's heading does.

The JSON form (``to_dict`` / ``from_dict``, also the ``centrelines`` entry of an
upload manifest, ``raytrace.body.gltf``) is
``{"pieces": [{"organ": "stomach", "points_m": [[x, y, z], ...]}, ...]}``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from raytrace.errors import InputError, PhantomValidationError

__all__ = ["GI_TRACT", "MAX_POINTS", "Centreline", "Piece", "smooth_polyline"]

#: Name of the GI tract's centreline in :attr:`Phantom.centrelines`.
GI_TRACT = "gi_tract"
#: Most vertices over all pieces of one centreline (keeps projection and uploads bounded).
MAX_POINTS = 20_000
#: Consecutive vertices closer than this are one vertex (a zero-length segment has no tangent) [m].
MIN_SEGMENT_M = 1e-9


@dataclass(frozen=True, eq=False)
class Piece:
    """One polyline inside one organ: ``points_m`` (n >= 2, read-only (n, 3) array)."""

    organ: str
    points_m: np.ndarray


class Centreline:
    """A chain of polyline pieces with arc length (module docstring). Immutable."""

    def __init__(self, pieces: Sequence[Piece] | Sequence[tuple[str, Any]], *, field: str = "pieces") -> None:
        if isinstance(pieces, (str, bytes, Mapping)) or not isinstance(pieces, Sequence) or not pieces:
            raise InputError("a centreline is a non-empty list of pieces", field=field)
        clean: list[Piece] = []
        total = 0
        for i, piece in enumerate(pieces):
            where = f"{field}[{i}]"
            organ, points = (piece.organ, piece.points_m) if isinstance(piece, Piece) else piece
            if not isinstance(organ, str) or not organ:
                raise InputError(f"an organ is a non-empty name, got {organ!r}", field=f"{where}.organ")
            try:
                p = np.array(points, dtype=float)
            except (TypeError, ValueError):
                raise InputError("expected a list of [x, y, z] points", field=f"{where}.points_m") from None
            if p.ndim != 2 or p.shape[1] != 3:
                raise InputError("expected a list of [x, y, z] points", field=f"{where}.points_m")
            if not np.isfinite(p).all():
                raise InputError("coordinates must be finite numbers", field=f"{where}.points_m")
            keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > MIN_SEGMENT_M])
            p = p[keep]
            if len(p) < 2:
                raise InputError("a piece needs at least two distinct points", field=f"{where}.points_m")
            total += len(p)
            if total > MAX_POINTS:
                raise InputError(f"more than {MAX_POINTS} points", field=field)
            p.flags.writeable = False
            clean.append(Piece(organ, p))
        self.pieces: tuple[Piece, ...] = tuple(clean)
        starts, ends, piece_of = [], [], []
        for k, piece in enumerate(self.pieces):
            starts.append(piece.points_m[:-1])
            ends.append(piece.points_m[1:])
            piece_of.append(np.full(len(piece.points_m) - 1, k))
        self._a = np.concatenate(starts)
        self._b = np.concatenate(ends)
        self._piece = np.concatenate(piece_of)
        self._len = np.linalg.norm(self._b - self._a, axis=1)
        self._s0 = np.concatenate([[0.0], np.cumsum(self._len)[:-1]])
        self._dir = (self._b - self._a) / self._len[:, None]
        self.length_m = float(self._s0[-1] + self._len[-1])
        # a piece's last segment projects to just short of its end: the end's own arc length is
        # the next piece's start (right-continuity), and the end is a different point
        last = np.append(self._piece[1:] != self._piece[:-1], False)
        self._t_max = np.where(last, self._len - 1e-12 * max(self.length_m, 1.0), self._len)
        # the start of each later piece's first segment, as _segment finds it (the same cumulative sum: a sum
        # per piece would differ in the last bit and put the junction in the previous piece's last segment)
        first = np.flatnonzero(np.diff(self._piece)) + 1
        #: Arc lengths where one piece ends and the next begins (the position jumps there).
        self.junctions_s_m: tuple[float, ...] = tuple(float(x) for x in self._s0[first])

    # ------------------------------------------------------------ queries
    def _segment(self, s: Any) -> tuple[np.ndarray, np.ndarray, tuple]:
        arr = np.asarray(s, dtype=float)
        if not np.isfinite(arr).all():
            raise InputError("arc length must be finite", field="s_m")
        tol = 1e-12 * max(self.length_m, 1.0)
        if np.any(arr < -tol) or np.any(arr > self.length_m + tol):
            bad = arr.ravel()[np.argmax((arr.ravel() < -tol) | (arr.ravel() > self.length_m + tol))]
            raise InputError(f"{bad:g} m is outside the centreline's [0, {self.length_m:.6g}] m", field="s_m")
        flat = np.clip(arr.ravel(), 0.0, self.length_m)
        k = np.clip(np.searchsorted(self._s0, flat, side="right") - 1, 0, len(self._s0) - 1)
        return flat, k, arr.shape

    def point_m(self, s: Any) -> np.ndarray:
        """Position [m] at arc length ``s`` (linear along the segment holding s)."""
        flat, k, shape = self._segment(s)
        t = np.clip((flat - self._s0[k]) / self._len[k], 0.0, 1.0)
        return (self._a[k] + t[:, None] * (self._b[k] - self._a[k])).reshape(shape + (3,))

    def tangent(self, s: Any) -> np.ndarray:
        """Unit direction of travel (increasing s) at arc length ``s``."""
        _, k, shape = self._segment(s)
        return self._dir[k].reshape(shape + (3,))

    def organ_at(self, s: Any) -> str | np.ndarray:
        """Organ name at arc length ``s`` (a str for a scalar, an object array otherwise)."""
        _, k, shape = self._segment(s)
        names = np.array([p.organ for p in self.pieces], dtype=object)[self._piece[k]]
        return str(names[0]) if shape == () else names.reshape(shape)

    def _nearest(self, points_m: Any) -> tuple[np.ndarray, np.ndarray, tuple]:
        p = np.asarray(points_m, dtype=float)
        if p.shape[-1:] != (3,) or not np.isfinite(p).all():
            raise InputError("expected finite [x, y, z] point(s)", field="position_m")
        shape = p.shape[:-1]
        q = p.reshape(-1, 3)
        best_s = np.empty(len(q))
        best_d = np.empty(len(q))
        for start in range(0, len(q), 256):  # bounded memory: 256 points x segments at once
            chunk = q[start:start + 256]
            rel = chunk[:, None, :] - self._a[None, :, :]
            t = np.clip(np.einsum("psk,sk->ps", rel, self._dir), 0.0, self._t_max[None, :])
            foot = self._a[None, :, :] + t[..., None] * self._dir[None, :, :]
            d = np.linalg.norm(chunk[:, None, :] - foot, axis=2)
            j = np.argmin(d, axis=1)  # the first (smallest s) of equally near segments
            rows = np.arange(len(chunk))
            best_s[start:start + 256] = self._s0[j] + t[rows, j]
            best_d[start:start + 256] = d[rows, j]
        return best_s, best_d, shape

    def project(self, points_m: Any) -> float | np.ndarray:
        """Arc length [m] of the point of the line nearest to each point (the first one on a tie).
        A point nearest to the end of a piece projects 1e-12 of the length before the junction,
        so that ``point_m(project(p))`` is that end, not the next piece's start."""
        s, _, shape = self._nearest(points_m)
        return float(s[0]) if shape == () else s.reshape(shape)

    def distance_m(self, points_m: Any) -> float | np.ndarray:
        """Distance [m] from each point to the line."""
        _, d, shape = self._nearest(points_m)
        return float(d[0]) if shape == () else d.reshape(shape)

    def sample_s(self, ds_m: float, start_m: float = 0.0, stop_m: float | None = None) -> np.ndarray:
        """Arc lengths ``start_m, start_m + ds_m, ...`` up to ``stop_m`` (default the end), included."""
        stop = self.length_m if stop_m is None else float(stop_m)
        if not (np.isfinite(ds_m) and ds_m > 0):
            raise InputError(f"must be a positive number of metres, got {ds_m!r}", field="ds_m")
        n = int(np.floor((stop - start_m) / ds_m * (1 + 1e-12))) + 1
        return start_m + ds_m * np.arange(max(n, 0))

    # ------------------------------------------------------------ checks and JSON
    def check_inside(self, phantom, *, step_m: float = 1e-3, field: str = "centreline") -> None:
        """Raise :class:`PhantomValidationError` unless every point of every piece (sampled every
        ``step_m`` and at every vertex) lies in its organ's medium (``phantom.medium_index``)."""
        names = [o.name for o in phantom.organs]
        for i, piece in enumerate(self.pieces):
            if piece.organ not in names:
                raise PhantomValidationError(f"the phantom has no organ {piece.organ!r}",
                                             field=f"{field}.pieces[{i}].organ")
            a, b = piece.points_m[:-1], piece.points_m[1:]
            n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step_m).astype(int))
            seg = np.repeat(np.arange(len(a)), n)
            t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
            pts = np.concatenate([piece.points_m, a[seg] + t[:, None] * (b[seg] - a[seg])])
            try:
                media = phantom.medium_index(pts, field=f"{field}.pieces[{i}]")
            except InputError as exc:
                raise PhantomValidationError(exc.reason, field=exc.field) from None
            want = names.index(piece.organ)
            bad = np.flatnonzero(media != want)
            if bad.size:
                where = phantom.medium_name(int(media[bad[0]]))
                raise PhantomValidationError(
                    f"point {np.round(pts[bad[0]], 6).tolist()} m of the piece in {piece.organ!r} lies in "
                    f"{where!r}: a centreline piece must stay inside its organ", field=f"{field}.pieces[{i}]")

    def to_dict(self) -> dict[str, Any]:
        return {"pieces": [{"organ": p.organ, "points_m": p.points_m.tolist()} for p in self.pieces]}

    @classmethod
    def from_dict(cls, data: Any, *, field: str = "centreline", scale: float = 1.0,
                  points_key: str = "points_m") -> "Centreline":
        """From the JSON form; ``scale`` multiplies the coordinates (an upload's ``mm``)."""
        if not isinstance(data, Mapping):
            raise InputError("expected an object with 'pieces'", field=field)
        unknown = sorted(set(data) - {"pieces"})
        if unknown:
            raise InputError(f"unknown field(s) {', '.join(unknown)}", field=f"{field}.{unknown[0]}")
        pieces = data.get("pieces")
        if not isinstance(pieces, list) or not pieces:
            raise InputError("required: a non-empty list of pieces", field=f"{field}.pieces")
        out = []
        for i, piece in enumerate(pieces):
            where = f"{field}.pieces[{i}]"
            if not isinstance(piece, Mapping):
                raise InputError("expected an object {organ, " + points_key + "}", field=where)
            extra = sorted(set(piece) - {"organ", points_key})
            if extra:
                raise InputError(f"unknown field(s) {', '.join(extra)}", field=f"{where}.{extra[0]}")
            if points_key not in piece:
                raise InputError("required", field=f"{where}.{points_key}")
            pts = piece[points_key]
            if isinstance(pts, (str, bytes)) or not isinstance(pts, Sequence) or len(pts) > MAX_POINTS:
                raise InputError(f"expected a list of at most {MAX_POINTS} [x, y, z] points",
                                 field=f"{where}.{points_key}")
            try:
                arr = np.array(pts, dtype=float) * scale
            except (TypeError, ValueError):
                raise InputError("expected a list of [x, y, z] points", field=f"{where}.{points_key}") from None
            out.append((piece.get("organ"), arr))
        try:
            return cls(out, field="pieces")
        except InputError as exc:
            where = exc.field.replace("points_m", points_key) if exc.field else "pieces"
            raise type(exc)(exc.reason, field=f"{field}.{where}") from None

    def __repr__(self) -> str:
        organs = " -> ".join(p.organ for p in self.pieces)
        return f"Centreline({organs}, length {self.length_m * 1e3:.1f} mm)"


def smooth_polyline(control_m: Any, step_m: float = 2e-3) -> np.ndarray:
    """A dense polyline through ``control_m`` (n >= 2 points): centripetal Catmull-Rom
    (alpha = 1/2, which neither cusps nor self-intersects between control points; Yuksel,
    Schaefer & Keyser 2011), each span sampled at about ``step_m``; the ends are extended
    by reflecting the neighbouring control point. Passes exactly through every control point."""
    p = np.asarray(control_m, dtype=float)
    if len(p) < 3:
        return p.copy()
    ext = np.concatenate([[2 * p[0] - p[1]], p, [2 * p[-1] - p[-2]]])
    out = [p[0]]
    for i in range(1, len(ext) - 2):
        p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
        t0 = 0.0
        t1 = t0 + np.linalg.norm(p1 - p0) ** 0.5
        t2 = t1 + np.linalg.norm(p2 - p1) ** 0.5
        t3 = t2 + np.linalg.norm(p3 - p2) ** 0.5
        n = max(2, int(np.ceil(np.linalg.norm(p2 - p1) / step_m)))
        t = np.linspace(t1, t2, n + 1)[1:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.extend((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    return np.array(out)
