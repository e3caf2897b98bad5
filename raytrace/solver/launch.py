"""Launch directions: a Fibonacci (golden-spiral) sphere.

Near-uniform, deterministic, any count: direction i has
``z_i = 1 - (2 i + 1) / N`` and azimuth ``i * pi (3 - sqrt 5)`` (golden angle)
(Gonzalez, "Measurement of areas on a sphere using Fibonacci and
latitude-longitude lattices", Math. Geosci. 42, 2010). Each direction stands
for a solid angle of 4 pi / N, so the angular spacing is about
``sqrt(4 pi / N)`` rad.
"""

from __future__ import annotations

import numpy as np


def fibonacci_sphere(count: int, rows: np.ndarray | None = None) -> np.ndarray:
    """(count, 3) unit vectors spread near-uniformly over the sphere; with ``rows`` (indices),
    only those rows of them: each depends on its index alone, so a launch batch, or the
    candidates of a shooting, compute their own rows (the same numbers) instead of all ``count``."""
    i = np.arange(count, dtype=float) if rows is None else np.asarray(rows, dtype=float)
    z = 1.0 - (2.0 * i + 1.0) / count
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def angular_spacing_rad(count: int) -> float:
    """Typical angle between neighbouring launch directions, sqrt(4 pi / N)."""
    return float(np.sqrt(4.0 * np.pi / count))
