"""Localization figures (docs/localization.md): the position-error CDF per method, the error along
the GI tract from a sweep's localization table, and path loss against distance with a fitted
log-distance model beside IEEE 802.15.6 CM2.

* ``localization_cdf``: per method the 3-D errors |x_hat - x| of the trials (the ``errors_m`` of a
  POST /v1/localize/evaluate method), drawn as the empirical CDF through at most 1000 order
  statistics; CEP50 / CEP90 are where it crosses 0.5 / 0.9; the position CRLB (sqrt trace) dashed.
* ``tract_errors``: the rows of a sweep's localization table (``GET .../results?table=localization``
  as JSON, or its ``rows``): 3-D error [mm] against the truth's arc length ``s_m`` along the
  centreline, one line per method, and the along-tract error (s of the estimate minus s of the
  truth) below when the rows carry it. Rows without ``s_m`` or ``error_m`` are left out (counted).
* ``path_loss``: (distance, path loss) pairs, e.g. a sweep's ``distance_m`` and ``-path_gain_db``;
  the least-squares model PL(d) = PL(d0) + 10 n log10(d / d0) (d0 = 50 mm, thesis Eq 2.2;
  :func:`estimators.localization.fit_path_loss_model`) with its +-1 sigma shadowing band, and the
  CM2 deep-tissue and near-surface models (thesis Table 2.2) over the same distances.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from matplotlib.figure import Figure
from pydantic import BaseModel, ConfigDict, Field

from estimators.errors import EstimatorInputError
from estimators.localization import fit_path_loss_model
from estimators.rss import CM2_MODELS, REFERENCE_DISTANCE_M
from plots.figure import PALETTE, Data, PlotInputError, PlotRequest, new_figure

MAX_ERRORS = 100_000
MAX_METHODS = 12
MAX_ROWS = 100_000
MAX_POINTS = 100_000
CDF_POINTS = 1000
MAX_ERROR_M = 100.0

_ERR = Annotated[float, Field(ge=0.0, le=MAX_ERROR_M)]


# ------------------------------------------------------------------ error CDF
class MethodPositionErrors(BaseModel):
    model_config = ConfigDict(extra="ignore", allow_inf_nan=False)

    method: str = Field(min_length=1, max_length=40, description="Method name (legend).")
    errors_m: list[_ERR | None] = Field(min_length=1, max_length=MAX_ERRORS, description="3-D position error of "
                                        "every trial [m] (null: a trial without a fix, counted as a failure).")
    crlb_m: float | None = Field(None, ge=0.0, le=MAX_ERROR_M, description="Position bound sqrt(trace CRLB) [m].")


_CDF_EXAMPLE = {"methods": [
    {"method": "nonlinear", "errors_m": [0.071, 0.069, 0.074, 0.070, 0.072], "crlb_m": 2.8e-5},
    {"method": "model_based", "errors_m": [0.011, 0.012, 0.013, 0.012, 0.011], "crlb_m": 2.8e-5}]}


class LocalizationCdfRequest(PlotRequest):
    """Body of POST /v1/plots/localization_cdf: ``{"methods": <the methods of a POST
    /v1/localize/evaluate answer>}`` works as is (their other fields are ignored)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_CDF_EXAMPLE]})

    methods: list[MethodPositionErrors] = Field(min_length=1, max_length=MAX_METHODS, description="One entry per "
                                                "method.")


def _cdf(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.sort(x)
    idx = np.unique(np.linspace(0, x.size - 1, min(x.size, CDF_POINTS)).round().astype(int))
    return x[idx], (idx + 1) / x.size


def localization_cdf(methods, *, title: str | None = None, width_in: float = 8.0, height_in: float = 4.5) -> Figure:
    """Empirical CDF of the 3-D position error [mm] per method, CRLB dashed (module docstring)."""
    req = LocalizationCdfRequest.model_validate(dict(methods=list(methods), title=title, width_in=width_in,
                                                     height_in=height_in))
    fig = new_figure(req.width_in, req.height_in)
    ax = fig.subplots()
    names = [m.method for m in req.methods]
    for i, m in enumerate(req.methods):
        if m.method in names[:i]:
            raise PlotInputError(f"method {m.method!r} is given twice", f"methods[{i}].method")
        e = np.array([x for x in m.errors_m if x is not None], float) * 1e3
        if e.size == 0:
            raise PlotInputError("every trial failed: nothing to draw", f"methods[{i}].errors_m")
        colour = PALETTE[i % len(PALETTE)]
        x, y = _cdf(e)
        failed = len(m.errors_m) - e.size
        note = f", {failed} failed" if failed else ""
        # a failed trial never reaches the CDF: the curve tops out at the share of fixes
        ax.step(x, y * e.size / len(m.errors_m), where="post", color=colour, linewidth=1.6,
                label=f"{m.method}: CEP50 {np.percentile(e, 50):.3g}, CEP90 {np.percentile(e, 90):.3g} mm{note}")
        if m.crlb_m is not None and m.crlb_m > 0:
            ax.axvline(m.crlb_m * 1e3, color=colour, linestyle="--", linewidth=1.0)
    values = [x * 1e3 for m in req.methods for x in m.errors_m if x is not None and x > 0]
    values += [m.crlb_m * 1e3 for m in req.methods if m.crlb_m]
    if values and max(values) > 100.0 * min(values):
        ax.set_xscale("log")
        # at most 12 decades shown: a subnormal error (5e-324 m) would put ticks at 1e-330, which
        # underflow to 0 and break the tick labels
        ax.set_xlim(left=max(min(values), max(values) * 1e-12))
    for level in (0.5, 0.9):
        ax.axhline(level, color="0.6", linewidth=0.7, linestyle=":")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("3-D position error |x_hat - x| [mm] (dashed: position CRLB)")
    ax.set_ylabel("Fraction of trials")
    ax.grid(True, color="0.9", linewidth=0.6)
    ax.set_axisbelow(True)
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(req.title or "Localization error, cumulative distribution per method")
    return fig


# ------------------------------------------------------------------ error along the GI tract
class TractRow(Data):
    method: str = Field(min_length=1, max_length=40, description="Localizer name.")
    s_m: float | None = Field(None, ge=-100.0, le=100.0, description="Arc length of the true position along "
                              "the centreline [m].")
    error_m: float | None = Field(None, ge=0.0, le=MAX_ERROR_M, description="3-D position error [m].")
    along_tract_error_m: float | None = Field(None, ge=-100.0, le=100.0, description="s of the estimate minus s "
                                              "of the truth [m].")
    frequency_hz: float | None = Field(None, gt=0.0, le=1e12, description="Carrier [Hz] (one line per method and "
                                       "carrier when the rows hold several).")


_TRACT_EXAMPLE = {"rows": [
    {"method": "nonlinear", "s_m": s, "error_m": e, "along_tract_error_m": a}
    for s, e, a in ((0.05, 0.031, 0.012), (0.25, 0.042, -0.020), (0.45, 0.028, 0.008), (0.65, 0.055, 0.031))],
    "junctions_s_m": [0.2, 0.5]}


class TractErrorsRequest(PlotRequest):
    """Body of POST /v1/plots/tract_errors: a sweep's localization table as JSON (``columns`` ignored)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_TRACT_EXAMPLE]})

    rows: list[TractRow] = Field(min_length=1, max_length=MAX_ROWS, description="Rows of the localization table.")
    columns: list[Annotated[str, Field(max_length=100)]] | None = Field(
        None, max_length=200, description="The table's column names (ignored: the rows name their fields).")
    junctions_s_m: list[Annotated[float, Field(ge=-100.0, le=100.0)]] | None = Field(
        None, max_length=64, description="Arc lengths where one organ's piece ends [m] (the centreline's "
        "junctions_s_m), drawn as vertical lines.")
    height_in: float = Field(6.0, ge=2.0, le=20.0, description="Figure height [in].")


def tract_errors(rows, *, junctions_s_m=None, columns=None, title: str | None = None, width_in: float = 8.0,
                 height_in: float = 6.0) -> Figure:
    """3-D error and along-tract error [mm] against s [m], one line per method (module docstring)."""
    req = TractErrorsRequest.model_validate(dict(rows=list(rows), junctions_s_m=junctions_s_m, title=title,
                                                 width_in=width_in, height_in=height_in))
    groups: dict[tuple[str, float | None], list[TractRow]] = {}
    for r in req.rows:
        if r.s_m is not None and r.error_m is not None:
            groups.setdefault((r.method, r.frequency_hz), []).append(r)
    if not groups:
        raise PlotInputError("no row has both s_m and error_m (positions off the centreline?)", "rows")
    several_f = len({f for _, f in groups}) > 1
    along = any(r.along_tract_error_m is not None for g in groups.values() for r in g)
    fig = new_figure(req.width_in, req.height_in)
    axes = fig.subplots(2, 1, sharex=True) if along else [fig.subplots()]
    for i, ((method, f), g) in enumerate(sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1] or 0.0))):
        g = sorted(g, key=lambda r: r.s_m)
        s = np.array([r.s_m for r in g])
        label = method + (f" @ {f / 1e6:.0f} MHz" if several_f and f else "")
        colour = PALETTE[i % len(PALETTE)]
        axes[0].plot(s, [r.error_m * 1e3 for r in g], marker="o", markersize=3.5, color=colour, label=label)
        if along:
            pts = [(r.s_m, r.along_tract_error_m * 1e3) for r in g if r.along_tract_error_m is not None]
            if pts:
                axes[1].plot(*zip(*pts), marker="o", markersize=3.5, color=colour, label=label)
    for ax in axes:
        for j in req.junctions_s_m or []:
            ax.axvline(j, color="0.55", linewidth=0.8, linestyle=":")
        ax.grid(True, color="0.9", linewidth=0.6)
        ax.set_axisbelow(True)
    axes[0].set_ylabel("3-D position error [mm]")
    axes[0].legend(loc="upper right", fontsize="small")
    if along:
        axes[1].axhline(0.0, color="0.5", linewidth=0.8)
        axes[1].set_ylabel("Along-tract error [mm]")
    axes[-1].set_xlabel("Position of the capsule along the GI tract, s [m]")
    skipped = len(req.rows) - sum(len(g) for g in groups.values())
    note = f" ({skipped} rows without s_m or error_m left out)" if skipped else ""
    fig.suptitle((req.title or "Localization error along the GI tract") + note)
    return fig


# ------------------------------------------------------------------ path loss vs distance
_PL_EXAMPLE = {"distances_m": [0.05, 0.07, 0.09, 0.11, 0.13, 0.15, 0.18],
               "path_loss_db": [47.0, 53.5, 58.0, 62.4, 64.9, 68.3, 71.0]}


class PathLossRequest(PlotRequest):
    """Body of POST /v1/plots/path_loss."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_PL_EXAMPLE]})

    distances_m: list[Annotated[float, Field(ge=1e-6, le=100.0)]] = Field(
        min_length=3, max_length=MAX_POINTS, description="Capsule-sensor distances [m].")
    path_loss_db: list[Annotated[float, Field(ge=-100.0, le=400.0)]] = Field(
        min_length=3, max_length=MAX_POINTS, description="Path loss of each link [dB] (-path_gain_db).")
    reference_distance_m: float = Field(REFERENCE_DISTANCE_M, gt=0.0, le=10.0, description="d0 of the model [m] "
                                        "(CM2: 50 mm).")


def path_loss(distances_m, path_loss_db, *, reference_distance_m: float = REFERENCE_DISTANCE_M,
              title: str | None = None, width_in: float = 8.0, height_in: float = 4.5) -> Figure:
    """Scatter of path loss [dB] against distance [mm] (log axis), the fitted log-distance model with
    its shadowing band, and the two CM2 models (module docstring)."""
    req = PathLossRequest.model_validate(dict(distances_m=list(distances_m), path_loss_db=list(path_loss_db),
                                              reference_distance_m=reference_distance_m, title=title,
                                              width_in=width_in, height_in=height_in))
    if len(req.distances_m) != len(req.path_loss_db):
        raise PlotInputError(f"{len(req.path_loss_db)} path losses for {len(req.distances_m)} distances",
                             "path_loss_db")
    d, pl = np.array(req.distances_m), np.array(req.path_loss_db)
    try:
        model = fit_path_loss_model(d, pl, reference_distance_m=req.reference_distance_m)
    except EstimatorInputError as exc:
        raise PlotInputError(exc.reason, "distances_m" if "distance" in str(exc.field) else "path_loss_db") from exc
    fig = new_figure(req.width_in, req.height_in)
    ax = fig.subplots()
    ax.scatter(d * 1e3, pl, s=14, color="0.25", alpha=0.7, label=f"links (n={d.size})", zorder=3)
    grid = np.geomspace(d.min(), d.max(), 200)
    fit = model.path_loss_db(grid)
    ax.plot(grid * 1e3, fit, color=PALETTE[0], linewidth=2.0, gid="fit",
            label=f"fit: PL(d0) {model.path_loss_d0_db:.1f} dB, n {model.exponent:.2f}, "
                  f"sigma {model.shadowing_db:.1f} dB")
    ax.fill_between(grid * 1e3, fit - model.shadowing_db, fit + model.shadowing_db, color=PALETTE[0], alpha=0.15)
    for k, (name, m) in enumerate(CM2_MODELS.items()):
        ax.plot(grid * 1e3, m.path_loss_db(grid), color=PALETTE[1 + k], linestyle="--", linewidth=1.4, gid=name,
                label=f"IEEE 802.15.6 CM2 {name.removeprefix('cm2_').replace('_', ' ')}: n {m.exponent:.2f}, "
                      f"sigma {m.shadowing_db:.2f} dB")
    ax.set_xscale("log")
    ax.set_xlabel(f"Distance d [mm] (log scale; d0 = {req.reference_distance_m * 1e3:g} mm)")
    ax.set_ylabel("Path loss [dB]")
    ax.grid(True, which="both", color="0.9", linewidth=0.6)
    ax.set_axisbelow(True)
    ax.legend(loc="upper left", fontsize="small")
    ax.set_title(req.title or "Path loss against distance: fitted log-distance model and IEEE 802.15.6 CM2")
    return fig
