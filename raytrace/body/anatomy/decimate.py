"""Decimation to a triangle budget with a measured, bounded error (fast-simplification's quadric edge
collapse, aggressiveness :data:`AGGRESSIVENESS`; docs/phantoms.md, "Decimation").

:func:`decimate` asks fast-simplification for the budget; the result's distance from the input surface
is then measured at every vertex and triangle centroid of the result (the exact distance to the input's
triangles, :class:`raytrace.body.anatomy.grid.SurfaceDistance`). If it exceeds ``max_error_m``, or the
result is no longer closed and consistently wound, the reduction is relaxed (budget x 1.5, up to four
times); the least-reduced closed result is kept otherwise, and the error it reaches is what the report
states. When every attempt pinches the surface (an edge shared by more than two triangles: thin tubes
pressed together), the surface is halved step by step while each step stays closed.
"""

from __future__ import annotations

import numpy as np
import trimesh

from raytrace.body.anatomy.grid import SurfaceDistance

__all__ = ["decimate", "surface_error"]

_RELAX = 1.5
#: fast-simplification's aggressiveness (its default is 7): 3 keeps the largest error about 3x smaller at the
#: same budget (measured on the CT abdomen's wall layers: 0.41 mm against 1.2 mm at 65k triangles), for ~20 %
#: more time.
AGGRESSIVENESS = 3
_TRIES = 5


def surface_error(original: SurfaceDistance, mesh: trimesh.Trimesh) -> float:
    """Largest distance from the vertices and triangle centroids of ``mesh`` to ``original``."""
    points = np.vstack([mesh.vertices, mesh.triangles_center])
    return float(np.max(original(points))) if len(points) else 0.0


def decimate(mesh: trimesh.Trimesh, budget: int, max_error_m: float) -> tuple[trimesh.Trimesh, float]:
    """(the mesh with at most about ``budget`` triangles, its measured error [m]) (module docstring)."""
    if len(mesh.faces) <= budget:
        return mesh, 0.0
    import fast_simplification

    spacing = float(np.median(mesh.edges_unique_length)) / 2.0
    original = SurfaceDistance(mesh.vertices, mesh.faces, max(spacing, 1e-6))
    best: tuple[trimesh.Trimesh, float] | None = None
    target = budget
    for _ in range(_TRIES):
        reduction = 1.0 - min(1.0, target / len(mesh.faces))
        if reduction <= 0:
            break
        points, faces = fast_simplification.simplify(np.asarray(mesh.vertices, np.float64),
                                                     np.asarray(mesh.faces, np.int64), reduction, agg=AGGRESSIVENESS)
        out = trimesh.Trimesh(points, faces, process=True, validate=False)
        if out.is_watertight and out.is_winding_consistent:
            if out.volume < 0:
                out.invert()
            error = surface_error(original, out)
            if error <= max_error_m:
                return out, error
            if best is None or error < best[1]:
                best = (out, error)
        target = int(target * _RELAX)
    if best is None:  # every attempt pinched the surface somewhere: halve it step by step while it stays closed
        current = mesh
        while len(current.faces) > budget:
            points, faces = fast_simplification.simplify(np.asarray(current.vertices, np.float64),
                                                         np.asarray(current.faces, np.int64),
                                                         min(0.5, 1.0 - budget / len(current.faces)),
                                                         agg=AGGRESSIVENESS)
            step = trimesh.Trimesh(points, faces, process=True, validate=False)
            if not (step.is_watertight and step.is_winding_consistent):
                break
            current = step
        if current is mesh:
            return mesh, 0.0
        if current.volume < 0:
            current.invert()
        return current, surface_error(original, current)
    return best
