"""Ranging error distributions, one row per method: signed errors as box plots, |error| as CDFs.

Input: per method, the Monte Carlo errors e_i = d_hat_i - d (estimates minus
the true distance; e.g. ``estimates_m - true_distance_m`` of
``estimators.estimate_toa(..., return_estimates=True)``) and optionally the
method's Cramér-Rao bound sigma_d, drawn as +-sigma on the box plot and as
sigma on the CDF. Boxes: quartiles, median line, mean diamond, whiskers at
the 2.5 and 97.5 percentiles. The CDF is drawn through at most 1000 order
statistics per method, so the figure's size does not grow with the trials.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from matplotlib.figure import Figure
from pydantic import BaseModel, ConfigDict, Field

from plots.figure import PALETTE, PlotInputError, PlotRequest, new_figure

#: Most errors per method, and methods per figure.
MAX_ERRORS = 100_000
MAX_METHODS = 12
#: Order statistics drawn per CDF.
CDF_POINTS = 1000
#: Largest |error| accepted [m] (a range error beyond 100 m is not an in-body range).
MAX_ERROR_M = 100.0
#: Decades of |error| a log-scale CDF spans at most (smaller errors are drawn at its left edge).
CDF_DECADES = 9

_EXAMPLE = {
    "methods": [
        {"method": "gcc", "errors_m": [3.1e-5, -2.0e-5, 1.2e-5, -4.4e-5, 0.6e-5, 2.5e-5], "crlb_m": 3.2e-5},
        {"method": "first_peak", "errors_m": [2.1e-4, -1.2e-4, 3.3e-4, 0.4e-4, -2.6e-4, 1.0e-4]},
    ],
    "true_distance_m": 0.076,
}


class MethodErrors(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: str = Field(min_length=1, max_length=40, description="Method name (legend and row label).")
    errors_m: list[Annotated[float, Field(ge=-MAX_ERROR_M, le=MAX_ERROR_M)]] = Field(
        min_length=1, max_length=MAX_ERRORS, description="Errors of the trials, estimate minus true distance [m].")
    crlb_m: float | None = Field(None, gt=0.0, le=MAX_ERROR_M, description="Cramér-Rao bound on the distance std [m].")


class RangingErrorsRequest(PlotRequest):
    """Body of POST /v1/plots/ranging_errors (the arguments of :func:`ranging_errors`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_EXAMPLE]})

    methods: list[MethodErrors] = Field(min_length=1, max_length=MAX_METHODS, description="One entry per method.")
    true_distance_m: float | None = Field(None, gt=0.0, le=100.0, description="True distance, for the title [m].")
    width_in: float = Field(9.0, ge=2.0, le=20.0, description="Figure width [in].")
    height_in: float | None = Field(None, ge=2.0, le=20.0, description="Figure height [in] (default: grows "
                                    "with the number of methods).")



def _cdf(abs_errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.sort(abs_errors)
    n = x.size
    idx = np.unique(np.linspace(0, n - 1, min(n, CDF_POINTS)).round().astype(int))
    return x[idx], (idx + 1) / n


def ranging_errors(methods, *, true_distance_m: float | None = None, title: str | None = None,
                   width_in: float = 9.0, height_in: float | None = None) -> Figure:
    """Left: box plots of the signed errors [mm] per method (CRLB as +-sigma brackets); right: the
    empirical CDF of |error| [mm] per method (CRLB as a dashed line). See the module docstring."""
    req = RangingErrorsRequest.model_validate(dict(methods=list(methods), true_distance_m=true_distance_m,
                                                   title=title, width_in=width_in, height_in=height_in))
    rows = req.methods
    names = [m.method for m in rows]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise PlotInputError(f"method {name!r} is given twice", f"methods[{i}].method")
    height = req.height_in if req.height_in is not None else min(2.4 + 0.55 * len(rows), 12.0)
    errors_mm = [np.asarray(m.errors_m, float) * 1e3 for m in rows]
    fig = new_figure(req.width_in, height)
    box_ax, cdf_ax = fig.subplots(1, 2, width_ratios=[1.15, 1.0])
    positions = np.arange(len(rows))[::-1] + 1.0  # the first method on top
    boxes = box_ax.boxplot(errors_mm, positions=positions, orientation="horizontal", whis=(2.5, 97.5),
                           showfliers=False, showmeans=True, widths=0.55, patch_artist=True,
                           tick_labels=[m.method for m in rows],
                           medianprops={"color": "0.1", "linewidth": 1.4},
                           meanprops={"marker": "D", "markerfacecolor": "white", "markeredgecolor": "0.2",
                                      "markersize": 5})
    labelled = False
    for i, (patch, m) in enumerate(zip(boxes["boxes"], rows)):
        colour = PALETTE[i % len(PALETTE)]
        patch.set(facecolor=colour, alpha=0.45, edgecolor=colour)
        if m.crlb_m is not None:
            box_ax.errorbar(0.0, positions[i] + 0.38, xerr=m.crlb_m * 1e3, color="0.15", capsize=3, linewidth=1.0,
                            label=None if labelled else r"$\pm$CRLB $\sigma_d$")
            labelled = True
    box_ax.axvline(0.0, color="0.5", linewidth=0.8)
    box_ax.set_xlabel("Error, estimate - true distance [mm]")
    box_ax.set_title("Signed error (box: quartiles; whiskers: 2.5-97.5 %)", fontsize="medium")
    if labelled:
        box_ax.legend(loc="lower right", fontsize="small")

    all_abs = np.abs(np.concatenate(errors_mm))
    positive = all_abs[all_abs > 0]
    log_x = positive.size > 0 and positive.max() > 100.0 * positive.min()
    floor = max(positive.min(), positive.max() * 10.0 ** -CDF_DECADES) if log_x else 0.0
    for i, (m, e) in enumerate(zip(rows, errors_mm)):
        colour = PALETTE[i % len(PALETTE)]
        x, y = _cdf(np.abs(e))
        if log_x:
            x = np.maximum(x, floor)
        rmse = float(np.sqrt(np.mean(e ** 2)))
        cdf_ax.step(x, y, where="post", color=colour, linewidth=1.5,
                    label=f"{m.method} (n={e.size}, RMSE {rmse:.3g} mm)")
        if m.crlb_m is not None:
            cdf_ax.axvline(max(m.crlb_m * 1e3, floor), color=colour, linestyle="--", linewidth=1.0)
    if log_x:
        cdf_ax.set_xscale("log")
    cdf_ax.set_ylim(0.0, 1.02)
    cdf_ax.set_xlabel("|error| [mm] (dashed: CRLB)")
    cdf_ax.set_ylabel("Fraction of trials")
    cdf_ax.set_title("Cumulative distribution of |error|", fontsize="medium")
    cdf_ax.legend(loc="lower right", fontsize="small")
    for ax in (box_ax, cdf_ax):
        ax.grid(True, color="0.9", linewidth=0.6)
        ax.set_axisbelow(True)
    if req.title is not None:
        fig.suptitle(req.title)
    else:
        truth = f", true distance {req.true_distance_m * 1e3:.4g} mm" if req.true_distance_m else ""
        fig.suptitle(f"Ranging errors by method{truth}")
    return fig
