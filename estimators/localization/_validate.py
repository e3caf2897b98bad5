"""Input checks shared by the position estimators (all raise EstimatorInputError naming the field).

A 3-D fix needs sensors that span 3-D space: no two closer than
:data:`MIN_SENSOR_SEPARATION_M`, and the smallest principal extent of the
sensor cloud at least :data:`MIN_FLATNESS` of the largest (else they are
coplanar, or collinear when two extents vanish).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import EstimatorInputError

#: Two sensors closer than this are duplicates [m].
MIN_SENSOR_SEPARATION_M = 1e-4
#: Ratio of the smallest to the largest principal extent of the sensor cloud below which
#: the sensors are coplanar (one extent) or collinear (two): a 3-D fix is then ill-posed.
MIN_FLATNESS = 1e-3
#: Most sensors one fix accepts (work bound).
MAX_SENSORS = 1024


def sensor_positions(value: Any, field: str = "sensors", *, minimum: int = 4) -> np.ndarray:
    """(N, 3) finite sensor positions spanning 3-D space, N >= ``minimum``."""
    try:
        s = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise EstimatorInputError("must be an (N, 3) array of positions in metres", field) from None
    if s.ndim != 2 or s.shape[1] != 3:
        raise EstimatorInputError(f"must be an (N, 3) array of positions in metres, got shape {s.shape}", field)
    if len(s) < minimum:
        raise EstimatorInputError(f"a 3-D fix with this method needs at least {minimum} sensors, got {len(s)}", field)
    if len(s) > MAX_SENSORS:
        raise EstimatorInputError(f"at most {MAX_SENSORS} sensors, got {len(s)}", field)
    bad = ~np.isfinite(s).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise EstimatorInputError(f"coordinates must be finite numbers, got {s[i].tolist()}",
                                  f"{field}[{i}].position_m")
    d = np.linalg.norm(s[:, None, :] - s[None, :, :], axis=2)
    d[np.diag_indices(len(s))] = np.inf
    if d.min() < MIN_SENSOR_SEPARATION_M:
        i, j = np.unravel_index(np.argmin(d), d.shape)
        i, j = sorted((int(i), int(j)))
        raise EstimatorInputError(
            f"duplicate sensors: sensors {i} and {j} are {d[i, j]:.3g} m apart "
            f"(< {MIN_SENSOR_SEPARATION_M} m); remove one", f"{field}[{j}].position_m")
    extents = np.linalg.svd(s - s.mean(axis=0), compute_uv=False)
    if extents[2] < MIN_FLATNESS * extents[0]:
        shape = "collinear" if extents[1] < MIN_FLATNESS * extents[0] else "coplanar"
        raise EstimatorInputError(
            f"the sensors are {shape}: a 3-D position is not determined (its mirror image fits as well); "
            "add a sensor off their plane", field)
    return s


def per_sensor(value: Any, n: int, field: str, *, positive: bool = False, nonnegative: bool = False,
               allow_none: bool = False) -> np.ndarray | None:
    """A finite (N,) array (a scalar is broadcast), optionally > 0 or >= 0."""
    if value is None:
        if allow_none:
            return None
        raise EstimatorInputError("is required", field)
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise EstimatorInputError("must be numbers", field) from None
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise EstimatorInputError(f"must hold one value per sensor ({n}), got shape {a.shape}", field)
    for i, v in enumerate(a):
        if not np.isfinite(v):
            raise EstimatorInputError(f"must be finite, got {v!r}", f"{field}[{i}]")
        if positive and v <= 0.0:
            raise EstimatorInputError(f"must be > 0, got {v!r}", f"{field}[{i}]")
        if nonnegative and v < 0.0:
            raise EstimatorInputError(f"must be >= 0, got {v!r}", f"{field}[{i}]")
    return a


def position(value: Any, field: str) -> np.ndarray:
    try:
        p = np.asarray(value, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise EstimatorInputError("must be three numbers (metres)", field) from None
    if not np.isfinite(p).all():
        raise EstimatorInputError(f"coordinates must be finite numbers, got {p.tolist()}", field)
    return p


LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")


def loss_name(value: Any, field: str = "loss") -> str:
    if value not in LOSSES:
        raise EstimatorInputError(f"unknown loss {value!r} ({' | '.join(LOSSES)})", field)
    return value
