"""Sensor belts: rings of contact sensors on the skin at given heights (docs/phantoms.md, "Sensors").

A belt at ``height_m`` lies in the horizontal plane that far above the body's lowest point. Its centre is
the centroid of the body's cross-section there (the length-weighted midpoints of the section's
segments). Sensor *i* of *n* is at polar angle ``start_deg + 360 i / n`` around that centre, measured
from anterior (-y) towards the subject's left (+x) as on the default torso; its position is where a ray
from the centre in that direction last leaves the body surface, moved :data:`SENSOR_DEPTH_M` (1 mm, the
torso's contact sites) inward along that triangle's normal, so it lies inside the skin.
"""

from __future__ import annotations

import numpy as np
import trimesh

from raytrace.body.anatomy.manifest import SensorBelt
from raytrace.body.torso import SENSOR_DEPTH_M
from raytrace.errors import PhantomValidationError

__all__ = ["SENSOR_DEPTH_M", "belt_positions"]


def belt_positions(skin: trimesh.Trimesh, belt: SensorBelt, index: int) -> dict[str, np.ndarray]:
    """Sensor name -> position [m] of one belt on the outer skin surface (module docstring)."""
    where = ("manifest", "sensors", "belts", index, "height_m")
    lo, hi = skin.bounds
    z = lo[2] + belt.height_m
    if not lo[2] < z < hi[2]:
        raise PhantomValidationError(
            f"belt {belt.name!r} at {belt.height_m:g} m above the body's lowest point is outside the body, which is "
            f"{hi[2] - lo[2]:.3g} m tall", field=where)
    segments = trimesh.intersections.mesh_plane(skin, [0.0, 0.0, 1.0], [0.0, 0.0, z])
    if not len(segments):
        raise PhantomValidationError(f"belt {belt.name!r}: the body has no cross-section at that height", field=where)
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    centre = (segments.mean(axis=1) * lengths[:, None]).sum(axis=0) / max(lengths.sum(), 1e-12)
    angles = belt.start_deg + 360.0 * np.arange(belt.count) / belt.count
    rad = np.radians(angles)
    directions = np.stack([np.sin(rad), -np.cos(rad), np.zeros_like(rad)], axis=1)
    origins = np.repeat(centre[None, :], belt.count, axis=0)
    locations, ray, tri = skin.ray.intersects_location(origins, directions, multiple_hits=True)
    out = {}
    for k, angle in enumerate(angles):
        hits = np.flatnonzero(ray == k)
        if not len(hits):
            raise PhantomValidationError(f"belt {belt.name!r}: no skin along {angle:g} deg from the section's centre",
                                         field=where)
        far = hits[np.argmax(np.linalg.norm(locations[hits] - centre, axis=1))]
        normal = skin.face_normals[tri[far]]
        if np.dot(normal, directions[k]) <= 0:  # the last crossing leaves the body: its normal faces out
            normal = directions[k]
        name = f"{belt.name}_{int(round(angle)) % 360:03d}"
        out[name] = locations[far] - SENSOR_DEPTH_M * normal
    return out
