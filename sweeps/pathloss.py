"""A log-distance path-loss model fitted to a sweep's links (``docs/sweeps.md``, "Path loss").

    PL(d) = PL(d0) + 10 n log10(d / d0) + S,   S ~ N(0, sigma^2) dB,   d0 = 50 mm

the form of IEEE 802.15.6 CM2 (thesis Eq 2.2, Table 2.2), fitted by ordinary least squares
of the links' path loss (``-path_gain_db``: the incoherent power of every traced path) on
``10 log10(d / d0)`` with ``d`` the straight-line capsule-sensor distance; ``sigma`` is the
residuals' standard deviation with two degrees of freedom removed. The result is an
``estimators.rss.PathLossModel``: ``estimate_rss(profile, model=fitted)`` ranges with it,
and a sweep spec uses it as ``ranging.rss.model: {path_loss_d0_db, exponent, shadowing_db}``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa

from estimators.rss import REFERENCE_DISTANCE_M, PathLossModel
from raytrace.errors import InputError

__all__ = ["fit_path_loss", "fit_table", "load_model", "model_dict"]


def fit_path_loss(distances_m, path_loss_db, *, reference_distance_m: float = REFERENCE_DISTANCE_M,
                  name: str = "fitted") -> PathLossModel:
    """Least-squares PL(d0), n and sigma through (distance, path loss) pairs (module docstring)."""
    d = np.asarray(distances_m, float).ravel()
    pl = np.asarray(path_loss_db, float).ravel()
    keep = np.isfinite(d) & np.isfinite(pl) & (d > 0)
    d, pl = d[keep], pl[keep]
    if len(d) < 3 or np.ptp(d) <= 0:
        raise InputError("a fit needs at least 3 links with a path, at more than one distance", field="distances_m")
    x = 10.0 * np.log10(d / reference_distance_m)
    a = np.column_stack([np.ones_like(x), x])
    (pl0, n), *_ = np.linalg.lstsq(a, pl, rcond=None)
    resid = pl - (pl0 + n * x)
    sigma = float(np.sqrt(np.sum(resid ** 2) / max(len(d) - 2, 1)))
    return PathLossModel(name=name, path_loss_d0_db=float(pl0), exponent=float(n), shadowing_db=sigma,
                         reference_distance_m=reference_distance_m)


def fit_table(table: pa.Table, *, frequency_hz: float | None = None, name: str = "fitted") -> tuple[PathLossModel, int]:
    """The model fitted to a results table's links that have a path (at one frequency if given);
    returns it and the number of links used."""
    rows = table.to_pydict()
    d = np.array(rows["distance_m"], float)
    gain = np.array([np.nan if g is None else g for g in rows["path_gain_db"]], float)
    keep = np.isfinite(gain)
    if frequency_hz is not None:
        keep &= np.array(rows["frequency_hz"], float) == frequency_hz
    return fit_path_loss(d[keep], -gain[keep], name=name), int(keep.sum())


def model_dict(model: PathLossModel) -> dict:
    return {"name": model.name, "path_loss_d0_db": model.path_loss_d0_db, "exponent": model.exponent,
            "shadowing_db": model.shadowing_db, "reference_distance_m": model.reference_distance_m}


def load_model(path: str | Path) -> PathLossModel:
    """A model written by ``capsule-rt experiment torso-path-loss`` (``path_loss_model.json``)."""
    from sweeps.base import rss_model

    return rss_model(json.loads(Path(path).read_text()), field="model")
