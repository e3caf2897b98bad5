"""True and estimated trajectory along the GI tract, and the error over time (docs/tracking.md).

Input: the truth's times and arc lengths, and per tracker its arc lengths (and optionally their
standard deviations, drawn as a +-2 sigma band). Top: s(t) for the truth and every tracker; bottom:
the error s_hat - s [mm] per tracker with its +-2 sigma band, and the RMSE in the legend.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from matplotlib.figure import Figure
from pydantic import BaseModel, ConfigDict, Field

from plots.figure import PALETTE, PlotInputError, PlotRequest, new_figure

MAX_STEPS = 20_000
MAX_TRACKERS = 8
_S = Annotated[float, Field(ge=-100.0, le=100.0)]

_EXAMPLE = {"t_s": [0.0, 0.5, 1.0, 1.5], "s_m": [0.2, 0.2008, 0.2015, 0.2019],
            "trackers": [{"name": "fused", "s_m": [0.2001, 0.2007, 0.2016, 0.2021],
                          "s_sigma_m": [0.004, 0.002, 0.0015, 0.0013]}]}


class TrackerSeries(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    name: str = Field(min_length=1, max_length=40, description="Tracker name (legend).")
    s_m: list[_S] = Field(min_length=1, max_length=MAX_STEPS, description="Estimated arc length per step [m].")
    s_sigma_m: list[Annotated[float, Field(ge=0.0, le=100.0)]] | None = Field(
        None, max_length=MAX_STEPS, description="Its standard deviation per step [m] (optional).")


class TrackingPlotRequest(PlotRequest):
    """Body of POST /v1/plots/tracking (the arguments of :func:`tracking_trajectory`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_EXAMPLE]})

    t_s: list[Annotated[float, Field(ge=0.0, le=1e7)]] = Field(min_length=1, max_length=MAX_STEPS,
                                                                description="Time of every step [s].")
    s_m: list[_S] = Field(min_length=1, max_length=MAX_STEPS, description="True arc length per step [m].")
    trackers: list[TrackerSeries] = Field(min_length=1, max_length=MAX_TRACKERS)
    width_in: float = Field(9.0, ge=2.0, le=20.0, description="Figure width [in].")
    height_in: float = Field(6.5, ge=2.0, le=20.0, description="Figure height [in].")


def tracking_trajectory(t_s, s_m, trackers, *, title: str | None = None, width_in: float = 9.0,
                        height_in: float = 6.5) -> Figure:
    """The figure of the module docstring."""
    req = TrackingPlotRequest.model_validate(dict(t_s=list(t_s), s_m=list(s_m), trackers=list(trackers),
                                                  title=title, width_in=width_in, height_in=height_in))
    t = np.asarray(req.t_s)
    truth = np.asarray(req.s_m)
    if len(truth) != len(t):
        raise PlotInputError(f"{len(truth)} arc lengths for {len(t)} times", "s_m")
    fig = new_figure(req.width_in, req.height_in)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[1.3, 1.0])
    top.plot(t, truth * 1e3, color="0.1", linewidth=2.0, label="truth")
    for i, tr in enumerate(req.trackers):
        s = np.asarray(tr.s_m)
        if len(s) != len(t):
            raise PlotInputError(f"{len(s)} values for {len(t)} times", f"trackers[{i}].s_m")
        colour = PALETTE[i % len(PALETTE)]
        err = (s - truth) * 1e3
        rmse = float(np.sqrt(np.mean(err ** 2)))
        top.plot(t, s * 1e3, color=colour, linewidth=1.1, label=tr.name)
        bottom.plot(t, err, color=colour, linewidth=1.1, label=f"{tr.name} (RMSE {rmse:.3g} mm)")
        if tr.s_sigma_m is not None:
            sig = np.asarray(tr.s_sigma_m) * 1e3
            if len(sig) != len(t):
                raise PlotInputError(f"{len(sig)} values for {len(t)} times", f"trackers[{i}].s_sigma_m")
            bottom.fill_between(t, -2 * sig, 2 * sig, color=colour, alpha=0.12, linewidth=0)
    bottom.axhline(0.0, color="0.5", linewidth=0.8)
    top.set_ylabel("Arc length along the tract [mm]")
    bottom.set_ylabel("Error along the tract [mm]\n(band: $\\pm 2\\sigma$)")
    bottom.set_xlabel("Time [s]")
    top.legend(loc="upper left", fontsize="small")
    bottom.legend(loc="upper left", fontsize="small")
    for ax in (top, bottom):
        ax.grid(True, color="0.9", linewidth=0.6)
        ax.set_axisbelow(True)
    fig.suptitle(req.title or "Capsule position along the GI tract: truth and trackers")
    return fig
