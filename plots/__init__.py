"""CapsuleRT figures (matplotlib, Agg canvas, no display): plain data in the JSON shapes the API
returns, a matplotlib Figure out.

    from plots import power_delay_profile, render
    fig = power_delay_profile(channel["profiles"][0])          # a Figure
    fig.savefig("pdp.png")
    png = render("pdp", {"profile": channel["profiles"][0]})   # bytes, as POST /v1/plots/pdp

Kinds (``plots.registry.KINDS``; CLI ``capsule-rt plot KIND input.json -o out.png|svg|pdf``):
``pdp`` :func:`power_delay_profile`, ``cfr`` :func:`frequency_response`,
``crlb`` :func:`crlb_vs_frequency`, ``ranging_errors`` :func:`ranging_errors`,
``localization_cdf`` :func:`localization_cdf`, ``tract_errors`` :func:`tract_errors`,
``path_loss`` :func:`path_loss`.
Bad data raises pydantic.ValidationError or :class:`PlotInputError`, naming the field.
"""

from plots.cfr import frequency_response
from plots.crlb import crlb_vs_frequency
from plots.figure import FORMATS, PlotInputError, figure_bytes
from plots.localization import localization_cdf, path_loss, tract_errors
from plots.pdp import power_delay_profile
from plots.ranging_errors import ranging_errors
from plots.registry import KINDS, render

__all__ = ["FORMATS", "KINDS", "PlotInputError", "crlb_vs_frequency", "figure_bytes", "frequency_response",
           "localization_cdf", "path_loss", "power_delay_profile", "ranging_errors", "render", "tract_errors"]
