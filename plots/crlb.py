"""Cramér-Rao bounds on the range against the carrier frequency (thesis Figs 4.3, 5.3, 5.4).

Each curve is a closed form of :mod:`estimators.bounds` evaluated on a grid of
carriers: TOA of a single tone (Eq 4.16-4.17, w = 2 pi f; Fig 4.3 is
W 10 GHz, T0 25 ns, SNR 30 dB, eps_r 27.9), two-tone PDOA centred on the
carrier (Eq 5.16, E/N0 = SNR W T0; Fig 5.3 is W T0 = 1, Fig 5.4 T0 = 1 us)
with, optionally, its phase-difference-only bound, and RSS under log-normal
shadowing as a horizontal reference (frequency-free; 17 mm for sigma = sqrt 5
dB, n = 3, d = 0.1 m, the thesis' comparison). Distances in mm, log scale.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import EngFormatter
from pydantic import BaseModel, ConfigDict, Field, model_validator

from estimators import bounds
from estimators.errors import EstimatorInputError
from plots.figure import PALETTE, Int, PlotInputError, PlotRequest, new_figure

#: Most carriers per curve, and curves per kind.
MAX_CARRIERS = 2000
MAX_SERIES = 8

_EXAMPLE = {
    "carrier": {"start_hz": 100e6, "stop_hz": 3e9, "points": 300},
    "toa": [{"bandwidth_hz": 10e9, "duration_s": 25e-9, "snr_db": 30}],
    "pdoa": [{"tone_spacing_hz": 20e6, "snr_db": 30}, {"tone_spacing_hz": 20e6, "snr_db": 30, "duration_s": 1e-6}],
    "rss": [{"shadowing_db": 2.236, "path_loss_exponent": 3, "distance_m": 0.1}],
}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class CarrierRange(_Strict):
    start_hz: float = Field(ge=1.0, le=1e12, description="Lowest carrier [Hz].")
    stop_hz: float = Field(ge=1.0, le=1e12, description="Highest carrier [Hz] (> start_hz).")
    points: Int = Field(200, ge=2, le=MAX_CARRIERS, description="Carriers on the grid [-].")
    log: bool = Field(False, description="Log-spaced carriers and a log frequency axis.")

    @model_validator(mode="after")
    def _order(self) -> "CarrierRange":
        if not self.stop_hz > self.start_hz:
            raise ValueError("stop_hz must be greater than start_hz")
        return self

    def grid_hz(self) -> np.ndarray:
        if self.log:
            return np.geomspace(self.start_hz, self.stop_hz, self.points)
        return np.linspace(self.start_hz, self.stop_hz, self.points)


class ToaSeries(_Strict):
    bandwidth_hz: float = Field(ge=1.0, le=1e12, description="Receiver (noise) bandwidth W [Hz].")
    duration_s: float = Field(ge=1e-15, le=1.0, description="Observation time T0 [s].")
    snr_db: float = Field(ge=-100.0, le=200.0, description="Signal-to-noise ratio over W [dB].")
    relative_permittivity: float = Field(27.9, ge=1.0, le=1000.0, description="eps_r of v = c / sqrt(eps_r) [-].")
    label: str | None = Field(None, max_length=100, description="Legend entry (default: the parameters).")


class PdoaSeries(_Strict):
    tone_spacing_hz: float = Field(ge=1e-3, le=1e12, description="Tone spacing W [Hz] (< 2 carrier.start_hz).")
    snr_db: float = Field(ge=-100.0, le=200.0, description="In-band signal-to-noise ratio [dB].")
    duration_s: float | None = Field(None, ge=1e-15, le=1.0, description="Observation time T0 [s] "
                                     "(default 1 / tone_spacing_hz: W T0 = 1).")
    relative_permittivity: float = Field(27.9, ge=1.0, le=1000.0, description="eps_r of v = c / sqrt(eps_r) [-].")
    phase_difference: bool = Field(False, description="Also draw the phase-difference-only bound (W^2/4 term).")
    label: str | None = Field(None, max_length=100, description="Legend entry (default: the parameters).")


class RssReference(_Strict):
    shadowing_db: float = Field(gt=0.0, le=100.0, description="Shadowing standard deviation sigma [dB] (> 0: a "
                                "zero one gives a zero bound, which the log axis cannot show).")
    path_loss_exponent: float = Field(ge=0.1, le=20.0, description="Path-loss exponent n [-].")
    distance_m: float = Field(ge=1e-6, le=100.0, description="True distance [m].")
    label: str | None = Field(None, max_length=100, description="Legend entry (default: the parameters).")


class CrlbRequest(PlotRequest):
    """Body of POST /v1/plots/crlb (the arguments of :func:`crlb_vs_frequency`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_EXAMPLE]})

    carrier: CarrierRange = Field(description="The carrier (PDOA: centre) frequencies of the x axis.")
    height_in: float = Field(5.0, ge=2.0, le=20.0, description="Figure height [in].")
    toa: list[ToaSeries] = Field([], max_length=MAX_SERIES, description="TOA bound curves (Eq 4.16-4.17).")
    pdoa: list[PdoaSeries] = Field([], max_length=MAX_SERIES, description="Two-tone PDOA bound curves (Eq 5.16).")
    rss: list[RssReference] = Field([], max_length=MAX_SERIES, description="RSS bounds, horizontal lines.")

    @model_validator(mode="after")
    def _some(self) -> "CrlbRequest":
        if not (self.toa or self.pdoa or self.rss):
            raise ValueError("give at least one curve in toa, pdoa or rss")
        return self


def _hz(value: float) -> str:
    """``10 GHz``: a fresh formatter each time (an axis's formatter is bound to its axis, so none is shared)."""
    return EngFormatter(unit="Hz", sep=" ").format_eng(value)


def _s(value: float) -> str:
    return EngFormatter(unit="s", sep=" ").format_eng(value)


def _curve(fn, where: str, grid_hz: np.ndarray) -> np.ndarray:
    try:
        values = np.array([fn(f) for f in grid_hz], float)
    except EstimatorInputError as exc:
        raise PlotInputError(exc.reason, f"{where}.{exc.field}") from None
    if not np.all(np.isfinite(values) & (values > 0)):
        raise PlotInputError("gives a non-finite bound on this carrier range; use a larger snr_db or duration_s",
                             f"{where}.snr_db")
    return values


def crlb_vs_frequency(carrier, *, toa=(), pdoa=(), rss=(), title: str | None = None, width_in: float = 8.0,
                      height_in: float = 5.0) -> Figure:
    """Range-error bounds sigma_d [mm] (log) against the carrier [Hz]: one line per ``toa`` / ``pdoa``
    series (see the module docstring for the equations), dashed phase-difference bounds, dotted
    horizontal RSS references. Each line's label names its parameters."""
    req = CrlbRequest.model_validate(dict(carrier=carrier, toa=list(toa), pdoa=list(pdoa), rss=list(rss),
                                          title=title, width_in=width_in, height_in=height_in))
    grid = req.carrier.grid_hz()
    fig = new_figure(req.width_in, req.height_in)
    ax = fig.add_subplot()
    colour = iter(PALETTE * 3)
    for i, s in enumerate(req.toa):
        sigma = _curve(lambda f, s=s: bounds.toa_crlb(f, s.duration_s, s.bandwidth_hz, s.snr_db,
                                                      s.relative_permittivity).sigma_m, f"toa[{i}]", grid)
        label = s.label or (f"TOA: W {_hz(s.bandwidth_hz)}, $T_0$ {_s(s.duration_s)}, SNR {s.snr_db:g} dB, "
                            rf"$\varepsilon_r$ {s.relative_permittivity:g}")
        ax.plot(grid, sigma * 1e3, color=next(colour), linewidth=1.6, label=label)
    for i, s in enumerate(req.pdoa):
        if not s.tone_spacing_hz < 2.0 * req.carrier.start_hz:
            raise PlotInputError(f"must be below twice carrier.start_hz ({2 * req.carrier.start_hz:.6g} Hz) so "
                                 "both tones stay positive", f"pdoa[{i}].tone_spacing_hz")

        def bound(f, s=s):
            return bounds.pdoa_crlb(f, s.tone_spacing_hz, s.snr_db, s.duration_s, s.relative_permittivity)

        sigma = _curve(lambda f, bound=bound: bound(f).sigma_m, f"pdoa[{i}]", grid)
        t0 = _s(s.duration_s) if s.duration_s is not None else f"1/W ({_s(1.0 / s.tone_spacing_hz)})"
        label = s.label or (f"PDOA two tones: W {_hz(s.tone_spacing_hz)}, $T_0$ {t0}, SNR {s.snr_db:g} dB")
        c = next(colour)
        ax.plot(grid, sigma * 1e3, color=c, linewidth=1.6, label=label)
        if s.phase_difference:
            pd = _curve(lambda f, bound=bound: bound(f).sigma_phase_difference_m, f"pdoa[{i}]", grid)
            ax.plot(grid, pd * 1e3, color=c, linewidth=1.2, linestyle="--", label="  phase difference only")
    for i, r in enumerate(req.rss):
        try:
            sigma_m = bounds.rss_crlb(r.shadowing_db, r.path_loss_exponent, r.distance_m).sigma_m
        except EstimatorInputError as exc:
            raise PlotInputError(exc.reason, f"rss[{i}].{exc.field}") from None
        if not sigma_m > 0:
            raise PlotInputError("gives a zero bound (no shadowing): nothing to draw on a log axis",
                                 f"rss[{i}].shadowing_db")
        label = r.label or (rf"RSS: $\sigma$ {r.shadowing_db:.3g} dB, n {r.path_loss_exponent:g}, "
                            f"d {r.distance_m * 1e3:g} mm ({sigma_m * 1e3:.3g} mm)")
        ax.axhline(sigma_m * 1e3, color=next(colour), linewidth=1.4, linestyle=":", label=label)
    ax.set_yscale("log")
    if req.carrier.log:
        ax.set_xscale("log")
    ax.set_xlim(grid[0], grid[-1])
    ax.xaxis.set_major_formatter(EngFormatter(unit="Hz", sep=" "))  # one per axis: formatters bind to it
    ax.set_xlabel("Carrier frequency (PDOA: centre of the two tones)")
    ax.set_ylabel(r"Range error bound $\sigma_d$ [mm]")
    ax.grid(True, which="both", color="0.9", linewidth=0.6)
    ax.set_axisbelow(True)
    fig.legend(loc="outside lower center", ncols=2, fontsize="small", frameon=False)
    ax.set_title(req.title if req.title is not None else "Cramér-Rao bounds on the range vs carrier frequency")
    return fig
