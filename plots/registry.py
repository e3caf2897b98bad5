"""The plot kinds: name -> figure function and the model of its input.

Adding a kind is one figure function (plain data in, a matplotlib Figure out,
its input model a :class:`plots.figure.PlotRequest`) and one entry in
:data:`KINDS`; the CLI (``capsule-rt plot KIND``) and the HTTP route
(``POST /v1/plots/{kind}``) are made from this table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from matplotlib.figure import Figure

from plots.cfr import CfrRequest, frequency_response
from plots.crlb import CrlbRequest, crlb_vs_frequency
from plots.figure import PlotInputError, PlotRequest, figure_bytes
from plots.localization import (
    LocalizationCdfRequest,
    PathLossRequest,
    TractErrorsRequest,
    localization_cdf,
    path_loss,
    tract_errors,
)
from plots.pdp import PdpRequest, power_delay_profile
from plots.ranging_errors import RangingErrorsRequest, ranging_errors
from plots.tracking import TrackingPlotRequest, tracking_trajectory


@dataclass(frozen=True)
class PlotKind:
    name: str
    figure: Callable[..., Figure]
    request: type[PlotRequest]
    summary: str


KINDS: dict[str, PlotKind] = {
    k.name: k
    for k in (
        PlotKind("pdp", power_delay_profile, PdpRequest,
                 "Power-delay profile: path gains [dB] against delay [ns], coloured by interactions (Fig 5.6)"),
        PlotKind("cfr", frequency_response, CfrRequest,
                 "Channel frequency response over a band: |H| [dB] and unwrapped phase with its group delay"),
        PlotKind("crlb", crlb_vs_frequency, CrlbRequest,
                 "Cramér-Rao bounds on the range against the carrier frequency (Figs 4.3, 5.3, 5.4)"),
        PlotKind("ranging_errors", ranging_errors, RangingErrorsRequest,
                 "Ranging error distributions per method: box plots and CDFs of |error|"),
        PlotKind("localization_cdf", localization_cdf, LocalizationCdfRequest,
                 "Localization error CDF per method: 3-D position error [mm] with CEP50/CEP90 and the CRLB"),
        PlotKind("tract_errors", tract_errors, TractErrorsRequest,
                 "Localization error along the GI tract: 3-D and along-tract error [mm] against s [m]"),
        PlotKind("path_loss", path_loss, PathLossRequest,
                 "Path loss against distance: a fitted log-distance model beside IEEE 802.15.6 CM2"),
        PlotKind("tracking", tracking_trajectory, TrackingPlotRequest,
                 "Capsule trajectory along the GI tract: truth and trackers, and the error over time"),
    )
}


def kind(name: str) -> PlotKind:
    try:
        return KINDS[name]
    except KeyError:
        raise PlotInputError(f"unknown plot kind {name!r}; one of {', '.join(KINDS)}", "kind") from None


def figure(name: str, body: dict[str, Any] | PlotRequest) -> tuple[Figure, int]:
    """The figure of a plot body (validated here unless already a model) and its dpi."""
    spec = kind(name)
    req = body if isinstance(body, spec.request) else spec.request.model_validate(body)
    return spec.figure(**req.figure_kwargs()), req.dpi


def render(name: str, body: dict[str, Any] | PlotRequest, fmt: str = "png") -> bytes:
    """A plot body (the JSON of POST /v1/plots/{kind}) rendered to png, svg or pdf bytes.

    Raises pydantic.ValidationError (schema) or PlotInputError (data a figure cannot be
    drawn from), both naming the field."""
    fig, dpi = figure(name, body)
    return figure_bytes(fig, fmt, dpi)
