"""Power-delay profile: one stem per path, gain in dB against absolute delay in ns (thesis Fig 5.6).

A path k of h(t) = sum_k a_k delta(t - tau_k) is drawn at tau_k with height
20 log10 |a_k| (= 10 log10 of the power transfer |a_k|^2; docs/service.md),
coloured by its number of interactions (reflections, refractions and total
internal reflections; 0 in a homogeneous medium's line of sight). Paths with no
reflection at all (refracted straight through the media: the direct path) are
ringed.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.figure import Figure
from pydantic import ConfigDict, Field

from plots.figure import PALETTE, PlotRequest, new_figure
from plots.profile import ProfileData, delays_s, gains

C0_M_PER_S = 299_792_458.0
#: dB reported for a zero gain (the API's floor).
GAIN_DB_FLOOR = -400.0

_EXAMPLE = {
    "profile": {
        "receiver": "rx",
        "geometric_distance_m": 0.076,
        "paths": [
            {"delay_s": 1.3389e-9, "gain": {"re": 1.6e-2, "im": 0.0}, "interactions": []},
            {"delay_s": 2.2e-9, "gain": {"re": -4e-3, "im": 2e-3}, "interactions": [{"kind": "reflection"}]},
            {"delay_s": 3.1e-9, "gain": {"re": 1e-3, "im": -5e-4},
             "interactions": [{"kind": "reflection"}, {"kind": "reflection"}]},
        ],
    },
    "relative_permittivity": 27.9,
}


class PdpRequest(PlotRequest):
    """Body of POST /v1/plots/pdp (the arguments of :func:`power_delay_profile`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, json_schema_extra={"examples": [_EXAMPLE]})

    profile: ProfileData = Field(description="A channel profile (`profiles[i]` of POST /v1/channel) or hand-made.")
    dynamic_range_db: float = Field(60.0, gt=0.0, le=300.0, description="Paths this far below the strongest "
                                    "are left out (counted in the legend) [dB].")
    relative_permittivity: float | None = Field(
        None, ge=1.0, le=1000.0, description="Also mark d / v, v = c / sqrt(eps_r), the delay a TOA range "
        "estimate assumes for the profile's geometric_distance_m [-].")


#: Paths with this many interactions or more share one colour.
MANY_INTERACTIONS = 8
#: Above this many paths the legend goes top right instead of searching for the emptiest corner.
LEGEND_SEARCH_PATHS = 500


def _label(n: int) -> str:
    if n < 0:
        return "interactions not given"
    if n == 0:
        return "0 interactions (line of sight)"
    if n >= MANY_INTERACTIONS:
        return f"{MANY_INTERACTIONS}+ interactions"
    return "1 interaction" if n == 1 else f"{n} interactions"


def power_delay_profile(profile, *, dynamic_range_db: float = 60.0, relative_permittivity: float | None = None,
                        title: str | None = None, width_in: float = 8.0, height_in: float = 4.5) -> Figure:
    """The figure of a profile's paths: stems at tau_k [ns], height 20 log10 |a_k| [dB].

    ``profile``: a dict (or :class:`ProfileData`) with ``paths[].delay_s``, ``paths[].gain {re, im}``
    and optionally ``paths[].interactions`` (their count picks the colour), ``receiver``,
    ``reference_frequency_hz``, ``geometric_distance_m``. One stem container per interaction
    count, labelled, in increasing count; refraction-only paths ringed; the first path's delay is marked.
    """
    req = PdpRequest.model_validate(dict(profile=profile, dynamic_range_db=dynamic_range_db,
                                         relative_permittivity=relative_permittivity, title=title,
                                         width_in=width_in, height_in=height_in))
    prof = req.profile
    tau_ns = delays_s(prof) * 1e9
    mag = np.abs(gains(prof))
    with np.errstate(divide="ignore"):
        gain_db = np.where(mag > 0, 20.0 * np.log10(np.where(mag > 0, mag, 1.0)), GAIN_DB_FLOOR)
    top = float(gain_db.max())
    floor = top - req.dynamic_range_db
    counts = np.array([-1 if p.interactions is None else min(len(p.interactions), MANY_INTERACTIONS)
                       for p in prof.paths])

    fig = new_figure(req.width_in, req.height_in)
    ax = fig.add_subplot()
    for i, n in enumerate(np.unique(counts)):
        sel = (counts == n) & (gain_db >= floor)
        if not sel.any():
            continue
        colour = PALETTE[i % len(PALETTE)]
        stems = ax.stem(tau_ns[sel], gain_db[sel], bottom=floor, basefmt=" ", label=_label(int(n)))
        stems.markerline.set(color=colour, markersize=5)
        stems.stemlines.set(color=colour, linewidth=1.4)
    kinds = [None if p.interactions is None else {i.kind for i in p.interactions} for p in prof.paths]
    direct = np.array([k is not None and k <= {"refraction"} for k in kinds]) & (gain_db >= floor)
    if direct.any():  # no reflection: the path that crosses the media straight (refracted at each surface)
        ax.plot(tau_ns[direct], gain_db[direct], linestyle="none", marker="o", markersize=10, markerfacecolor="none",
                markeredgecolor="0.15", markeredgewidth=1.2, label="refraction only (direct path)")
    first = float(tau_ns.min())
    ax.axvline(first, color="0.35", linestyle=":", linewidth=1.0,
               label=rf"first path $\tau_1$ = {first:.4g} ns")
    if req.relative_permittivity is not None and prof.geometric_distance_m:
        assumed = prof.geometric_distance_m * math.sqrt(req.relative_permittivity) / C0_M_PER_S * 1e9
        ax.axvline(assumed, color="0.35", linestyle="--", linewidth=1.0,
                   label=rf"$d/v$ ({prof.geometric_distance_m * 1e3:.4g} mm, $\varepsilon_r$ "
                         rf"{req.relative_permittivity:g}) = {assumed:.4g} ns")
    hidden = int(np.sum(gain_db < floor))
    legend = ax.legend(loc="best" if len(prof.paths) <= LEGEND_SEARCH_PATHS else "upper right",
                       fontsize="small", framealpha=0.9,
                       title=f"{hidden} weaker paths (< {floor:.0f} dB) not shown" if hidden else None,
                       title_fontsize="small")
    legend.set_zorder(5)
    right = float(tau_ns[gain_db >= floor].max()) * 1.08 + 0.05
    ax.set_xlim(0.0, right)
    ax.set_ylim(floor, top + 0.1 * req.dynamic_range_db)
    ax.set_xlabel(r"Delay $\tau$ [ns]")
    ax.set_ylabel(r"Path gain $|a|^2$ [dB]")
    ax.grid(True, color="0.9", linewidth=0.6)
    ax.set_axisbelow(True)
    if req.title is not None:
        ax.set_title(req.title)
    else:
        what = f"receiver {prof.receiver}" if prof.receiver else f"{len(prof.paths)} paths"
        freq = f", {prof.reference_frequency_hz / 1e6:.6g} MHz" if prof.reference_frequency_hz else ""
        ax.set_title(f"Power-delay profile: {what}{freq}")
    return fig
