"""Channel frequency response over a band: magnitude in dB and unwrapped phase, with the phase slope.

H(f) = sum_k b_k(f) exp(-j 2 pi f tau_k) (estimators.profile, the API's gain
convention): from every path's ``band_gains`` (frequency-dependent tissue, as
POST /v1/channel returns them with a ``band``), or, for a profile without
them, from its carrier gains taken as frequency-flat over ``band``. The
least-squares slope of the unwrapped phase gives the group delay
tau_g = -(d phi / d f) / (2 pi), what multi-tone PDOA ranging estimates
(thesis Eq 5.3-5.5; docs/service.md).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from pydantic import BaseModel, ConfigDict, Field, model_validator

from estimators.errors import EstimatorInputError
from estimators.profile import PathProfile
from plots.figure import PALETTE, Int, PlotInputError, PlotRequest, new_figure
from plots.profile import MAX_BAND_POINTS, ProfileData, band_gains, delays_s, gains

_EXAMPLE = {
    "profile": {
        "receiver": "rx",
        "paths": [
            {"delay_s": 1.3389e-9, "gain": {"re": 1.6e-2, "im": 0.0}},
            {"delay_s": 2.2e-9, "gain": {"re": -4e-3, "im": 2e-3}},
        ],
    },
    "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21},
}


class BandSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    start_hz: float = Field(gt=0.0, le=1e12, description="First frequency [Hz].")
    stop_hz: float = Field(gt=0.0, le=1e12, description="Last frequency [Hz] (> start_hz).")
    points: Int = Field(ge=2, le=MAX_BAND_POINTS, description="Equally spaced frequencies [-].")

    @model_validator(mode="after")
    def _order(self) -> "BandSpec":
        if not self.stop_hz > self.start_hz:
            raise ValueError("stop_hz must be greater than start_hz")
        return self


class CfrRequest(PlotRequest):
    """Body of POST /v1/plots/cfr (the arguments of :func:`frequency_response`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_EXAMPLE]})

    profile: ProfileData = Field(description="A channel profile; with band_gains on every path (a channel "
                                 "traced with a `band`), or hand-made with `band`.")
    band: BandSpec | None = Field(None, description="Frequencies to evaluate H at (default: the band_gains' "
                                  "own); needed for a profile without band_gains.")
    height_in: float = Field(5.5, ge=2.0, le=20.0, description="Figure height [in].")


def response(profile: ProfileData, band_spec: BandSpec | None) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies [Hz], complex H) of a validated profile; PlotInputError names the bad field."""
    any_band = any(p.band_gains for p in profile.paths)
    freqs, per_path = band_gains(profile) if any_band or band_spec is None else (None, None)
    try:
        model = PathProfile(delays_s(profile), gains(profile), band_frequencies_hz=freqs, band_gains=per_path,
                            gains_include_delay_phase=profile.gains_include_delay_phase,
                            reference_frequency_hz=profile.reference_frequency_hz)
        if band_spec is not None:
            freqs = np.linspace(band_spec.start_hz, band_spec.stop_hz, band_spec.points)
        return freqs, model.frequency_response(freqs)
    except EstimatorInputError as exc:
        raise PlotInputError(exc.reason, "band" if exc.field == "frequencies_hz" else exc.field) from None


def frequency_response(profile, *, band: dict | None = None, title: str | None = None, width_in: float = 8.0,
                       height_in: float = 5.5) -> Figure:
    """Two panels over frequency [MHz]: 20 log10 |H(f)| [dB] and the unwrapped phase of H [rad]
    with its least-squares line and the group delay it implies (see module docstring)."""
    req = CfrRequest.model_validate(dict(profile=profile, band=band, title=title, width_in=width_in,
                                         height_in=height_in))
    freqs, h = response(req.profile, req.band)
    if not np.any(h != 0):
        raise PlotInputError("the response is zero at every frequency", "profile.paths")
    f_mhz = freqs / 1e6
    mag = np.abs(h)
    tiny = mag[mag > 0].min()
    mag_db = 20.0 * np.log10(np.maximum(mag, tiny))
    phase = np.unwrap(np.angle(h))
    slope, intercept = np.polyfit(freqs - freqs[0], phase, 1)
    tau_g_ns = -slope / (2.0 * np.pi) * 1e9

    fig = new_figure(req.width_in, req.height_in)
    top, bottom = fig.subplots(2, 1, sharex=True)
    top.plot(f_mhz, mag_db, color=PALETTE[0], marker="o", markersize=3, linewidth=1.4, label="|H(f)|")
    top.set_ylabel(r"$|H(f)|$ [dB]")
    bottom.plot(f_mhz, phase, color=PALETTE[1], marker="o", markersize=3, linewidth=1.4,
                label=r"unwrapped $\angle H(f)$")
    bottom.plot(f_mhz, intercept + slope * (freqs - freqs[0]), color="0.3", linestyle="--", linewidth=1.0,
                label=rf"linear fit: $\tau_g = -\frac{{1}}{{2\pi}}\frac{{d\phi}}{{df}}$ = {tau_g_ns:.4g} ns")
    bottom.set_ylabel(r"Phase $\angle H(f)$ [rad]")
    bottom.set_xlabel("Frequency [MHz]")
    bottom.legend(loc="best", fontsize="small")
    for ax in (top, bottom):
        ax.grid(True, color="0.9", linewidth=0.6)
        ax.set_axisbelow(True)
    prof = req.profile
    if req.title is not None:
        fig.suptitle(req.title)
    else:
        what = f"receiver {prof.receiver}" if prof.receiver else f"{len(prof.paths)} paths"
        source = "per-path band gains" if all(p.band_gains for p in prof.paths) else "frequency-flat path gains"
        fig.suptitle(f"Channel frequency response: {what} ({source})")
    return fig
