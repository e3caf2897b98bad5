"""The heterogeneity-aware delay model of every (capsule position, candidate) link, from the
eikonal fields of the capsule positions (docs/design.md, "The model").

The model-based fix (docs/localization.md) measures delays tau_i = T_i(x), T_i the first-arrival
time from sensor i, and its position bound needs grad T_i at the capsule x. Building one field per
candidate (thousands) is what this module avoids, by reciprocity: the first-arrival time between
two points does not depend on which one emits, T_s(x) = T_x(s). So the fields *from the capsule*
serve every candidate s at once:

* the link's eikonal delay is T_x(s), the field from x interpolated at the candidate;
* grad_x T_s(x) by central differences of the fields from x +- h e_k (h the cell size):
  (T_{x + h e_k}(s) - T_{x - h e_k}(s)) / (2 h), seven fields per capsule position.

Why differences and not the ray's direction: following the steepest descent of T_x from s back
to x and taking the ray's direction near x disagreed with the sensors' own fields' gradients by
10 degrees (median, 33 max) on the torso, the stair-cased field near the source bending the last
cells of the descent; the central differences agree within 1.8 degrees (median; 5.7 at the 90th
percentile, 9 max) and 6 % in magnitude. ``tests/design/test_model.py`` checks both against the
sensors' own fields at the capsule (what :func:`evaluation.localization.evaluate_localization`
bounds with).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimators.localization import travel_time_field
from evaluation.fields import index_grid
from raytrace.body.phantom import Phantom


def _trilinear(time_s: np.ndarray, origin: np.ndarray, h: float, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T and grad T of the trilinear interpolant at cell-centre nodes, vectorised over ``pts``
    (clamped to the outermost centres, as :class:`estimators.localization.TravelTimeFields` does)."""
    shape = np.asarray(time_s.shape)
    lower = origin + 0.5 * h
    upper = origin + (shape - 0.5) * h
    u = (np.clip(pts, lower, upper) - lower) / h
    i0 = np.minimum(np.floor(u).astype(np.int64), shape - 2)
    f = u - i0
    t = np.zeros(len(pts))
    g = np.zeros((len(pts), 3))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1.0 - f[:, 0]
        sx = 1.0 if dx else -1.0
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1.0 - f[:, 1]
            sy = 1.0 if dy else -1.0
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1.0 - f[:, 2]
                sz = 1.0 if dz else -1.0
                v = time_s[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
                t += wx * wy * wz * v
                g[:, 0] += sx * wy * wz * v
                g[:, 1] += wx * sy * wz * v
                g[:, 2] += wx * wy * sz * v
    return t, g / h


def link_model(phantom: Phantom, positions_m: np.ndarray, candidates_m: np.ndarray, frequency_hz: float,
               cell_size_m: float, *, index_kind: str = "phase",
               on_position: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """Per (position, candidate): ``eikonal_delay_s`` (P, C) and ``gradient_s_per_m`` (P, C, 3) (module
    docstring). ``on_position(p)`` is called before each position's fields (a budget's check, progress)."""
    grid, n = index_grid(phantom, frequency_hz, cell_size_m, index_kind)
    positions_m = np.asarray(positions_m, float).reshape(-1, 3)
    cands = np.asarray(candidates_m, float).reshape(-1, 3)
    h = grid.spacing_m
    P, C = len(positions_m), len(cands)
    delay = np.zeros((P, C))
    grad = np.zeros((P, C, 3))

    def times(x: np.ndarray) -> np.ndarray:
        field = travel_time_field(n, grid.origin_m, h, x)
        return _trilinear(field.time_s, field.origin_m, field.spacing_m, cands)[0]

    for p, x in enumerate(positions_m):
        if on_position is not None:
            on_position(p)
        delay[p] = times(x)
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            grad[p, :, k] = (times(x + e) - times(x - e)) / (2.0 * h)
    return {"eikonal_delay_s": delay, "gradient_s_per_m": grad}
