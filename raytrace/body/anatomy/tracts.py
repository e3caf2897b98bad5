"""Tracts: centreline files (JSON ``{"points": [...]}`` or CSV ``x,y,z``) -> centrelines with landmarks
(docs/phantoms.md, "Tracts").

A tract's points are read in the file's units and frame, cut to ``range`` (the file's first and last
points used) when given, mapped like every surface, optionally reversed (``reverse: true``: the capsule
travels from the file's last point to its first), and checked to lie in the organ the tract names: every
vertex, and points every millimetre between them. A vertex closer than ``options.tract_clearance_m`` to the
organ's surface, or outside it by at most that, is first moved to that depth inside it, along the normal of
the surface's nearest point (a mid-line grazing the wall of a collapsed lumen: the shared CT's small bowel
comes within 0.01 mm of its mid-line); the report says how many moved and how far. Vertices at either end
that lie outside the organ (a mid-line running on into the next organ, or past an organ the build clipped,
e.g. where the oesophagus leaves the scan) are trimmed and the report says how many; a point outside the
organ *between* points inside it is refused, naming the tract, the point's index in the file and where it
is. Landmarks are indices of the file's points; each becomes a capsule site ``<tract>_<landmark>`` and an
arc length along the tract; a landmark in a trimmed end gets neither, and the report says so.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from raytrace.body.anatomy.manifest import TractSpec
from raytrace.body.centreline import MAX_POINTS, Centreline
from raytrace.body.phantom import Phantom
from raytrace.errors import InputError, PhantomValidationError

__all__ = ["Tract", "read_points", "build_tract"]

MAX_TRACT_BYTES = 32 * 2**20


@dataclass
class Tract:
    name: str
    organ: str
    centreline: Centreline
    landmarks_s_m: dict[str, float]
    landmark_points_m: dict[str, np.ndarray]
    notes: list[str] = field(default_factory=list)


def read_points(path: Path, where) -> np.ndarray:
    """(n, 3) points of a centreline file, in its own units."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise PhantomValidationError(f"{path.name}: cannot be read ({exc.strerror or exc})", field=where) from None
    if size > MAX_TRACT_BYTES:
        raise PhantomValidationError(f"{path.name} is {size} bytes, over the cap of {MAX_TRACT_BYTES}", field=where)
    text = path.read_bytes().decode("utf-8", errors="replace")
    if path.suffix.lower() == ".csv":
        rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]
        try:
            float(rows[0][0])
        except (ValueError, IndexError):
            rows = rows[1:]  # a header row
        try:
            points = np.array([[float(c) for c in r[:3]] for r in rows], dtype=float)
        except ValueError as exc:
            raise PhantomValidationError(f"{path.name}: every row must be x,y,z numbers ({exc})", field=where) from None
    else:
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise PhantomValidationError(f"{path.name} is not JSON: {str(exc)[:120]}", field=where) from None
        raw = data.get("points") if isinstance(data, dict) else data
        try:
            points = np.array(raw, dtype=float)
        except (TypeError, ValueError):
            points = np.zeros((0,))
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 2:
        raise PhantomValidationError(f"{path.name}: expected {{\"points\": [[x, y, z], ...]}} (JSON) or rows x,y,z "
                                     "(CSV) with at least two points", field=where)
    if len(points) > MAX_POINTS:
        raise PhantomValidationError(f"{path.name} has {len(points)} points, over the cap of {MAX_POINTS}",
                                     field=where)
    if not np.isfinite(points).all():
        raise PhantomValidationError(f"{path.name} has non-finite coordinates", field=where)
    return points


def _media(phantom: Phantom, points: np.ndarray, where) -> np.ndarray:
    try:
        return phantom.medium_index(points, field=where)
    except InputError:  # a vertex exactly on a surface: judge by a tiny nudge
        return phantom.medium_index(points + 1e-6 * np.array([0.3, 0.5, 0.8]), field=where)


def _clear_of_wall(points: np.ndarray, mesh, clearance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``points`` with those closer than ``clearance_m`` to ``mesh`` (inside it) or outside it by at most that
    moved to ``clearance_m`` inside, along the outward normal of their nearest surface point (module docstring);
    and how far each moved [m] (0 for the others)."""
    from trimesh.proximity import closest_point

    from raytrace.body.anatomy.grid import SurfaceDistance

    distance = SurfaceDistance(mesh.vertices, mesh.faces, clearance_m)(points, upper_m=4 * clearance_m)
    near = distance <= clearance_m
    moved = np.zeros(len(points))
    if not near.any():
        return points, moved
    q, _, tri = closest_point(mesh, points[near])
    out = points.copy()
    out[near] = q - clearance_m * np.asarray(mesh.face_normals)[tri]
    moved[near] = np.linalg.norm(out[near] - points[near], axis=1)
    return out, moved


def build_tract(spec: TractSpec, points_file: np.ndarray, to_m: Callable[[np.ndarray], np.ndarray],
                phantom: Phantom, clearance_m: float = 0.0) -> Tract:
    """The tract's centreline in ``phantom`` (module docstring); ``clearance_m``: the manifest's
    ``options.tract_clearance_m`` (0: no point is moved)."""
    where = ("manifest", "tracts", spec.name)
    index = np.arange(len(points_file))
    if spec.range is not None:
        first, last = spec.range
        if last >= len(points_file):
            raise PhantomValidationError(f"range [{first}, {last}] runs past the file's {len(points_file)} points",
                                         field=(*where, "range"))
        index = index[first:last + 1]
    points = to_m(points_file[index])
    if spec.reverse:
        points, index = points[::-1], index[::-1]
    organ = phantom.organ_index(spec.organ)
    media = _media(phantom, points, where)
    notes = []
    if clearance_m > 0:
        moved_points, moved = _clear_of_wall(points, phantom.organs[organ].mesh, clearance_m)
        if moved.any():
            changed = moved > 0
            new_media = _media(phantom, moved_points[changed], where)
            keep = new_media == organ  # a lumen thinner than twice the clearance: leave the point as it was
            rows = np.flatnonzero(changed)[keep]
            points[rows], media[rows] = moved_points[rows], organ
            if len(rows):
                notes.append(f"moved {len(rows)} point(s) by up to {moved[rows].max() * 1e3:.2f} mm to lie "
                             f"{clearance_m * 1e3:g} mm inside {spec.organ!r} (the mid-line grazes its wall)")
    inside = media == organ
    if not inside.any():
        raise PhantomValidationError(f"no point of tract {spec.name!r} lies inside organ {spec.organ!r}", field=where)
    first, last = int(np.argmax(inside)), len(inside) - 1 - int(np.argmax(inside[::-1]))
    gap = np.flatnonzero(~inside[first:last + 1])
    if gap.size:
        k = first + int(gap[0])
        raise PhantomValidationError(
            f"point {int(index[k])} of tract {spec.name!r} ({np.round(points[k] * 1e3, 1).tolist()} mm) lies in "
            f"{phantom.medium_name(int(media[k]))!r}, not in {spec.organ!r}, between points inside it", field=where)
    trimmed = first + (len(points) - 1 - last)
    if trimmed:
        notes.append(f"trimmed {trimmed} end point(s) outside {spec.organ!r}")
    kept_points, kept_index = points[first:last + 1], index[first:last + 1]
    line = Centreline([(spec.organ, kept_points)], field=f"manifest.tracts.{spec.name}")
    line.check_inside(phantom, field=f"manifest.tracts.{spec.name}")
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(kept_points, axis=0), axis=1))])
    landmarks_s, landmark_points = {}, {}
    position = {int(i): k for k, i in enumerate(kept_index)}
    for mark, i in spec.landmarks.items():
        if i >= len(points_file):
            raise PhantomValidationError(f"landmark {mark!r} is point {i}, but the file has {len(points_file)} points",
                                         field=(*where, "landmarks", mark))
        if i not in position:
            notes.append(f"landmark {mark} (point {i}) lies in a trimmed end: no site")
            continue
        landmarks_s[mark] = float(arc[position[i]])
        landmark_points[mark] = kept_points[position[i]]
    return Tract(spec.name, spec.organ, line, landmarks_s, landmark_points, notes)
