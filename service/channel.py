"""Channel requests: resolve scenario / phantom / antennas, run the tracer, convert the result.

Pure functions (no HTTP), shared by the route and ``capsule-rt channel``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from raytrace.solver.budget import Budget
from raytrace.errors import InvalidGeometryError
from raytrace.results import ChannelResult
from raytrace.spec import Antenna
from raytrace.body.phantom import Material, Phantom
from service.errors import NotFound, Unprocessable
from service.registry import Registry
from service.schemas import GAIN_DB_FLOOR, AntennaIn, ChannelRequest
from service.settings import Settings

DEFAULT_PHANTOM = "torso"
DEFAULT_FREQUENCY_HZ = 402e6
DEFAULT_MAX_INTERACTIONS = 6
DEFAULT_RAYS = 100_000
DEFAULT_DYNAMIC_RANGE_DB = 80.0

#: Antennas must lie inside the phantom's bounding box grown by this fraction of its diagonal.
BOUNDS_MARGIN_FRACTION = 0.5


@dataclass
class ResolvedChannel:
    phantom_id: str
    scenario: str | None
    phantom: Phantom
    transmitter: Antenna
    receivers: list[Antenna]
    frequency_hz: float
    band_frequencies_hz: np.ndarray | None
    max_interactions: int
    rays: int
    dynamic_range_db: float
    homogeneous: Material | None


def merged_request(req: ChannelRequest, registry: Registry) -> ChannelRequest:
    """The request with the scenario's fields filled in where the request leaves them unset."""
    if req.scenario is None:
        return req
    spec = registry.scenarios.get(req.scenario)
    if spec is None:
        known = ", ".join(sorted(registry.scenarios)) or "none"
        raise NotFound(f"unknown scenario {req.scenario!r}; known scenarios: {known} (GET /v1/scenarios)", loc=["body", "scenario"])
    base = {"phantom": spec.phantom, **spec.request}
    explicit = req.model_dump(exclude_unset=True)
    merged = {**base, **{k: v for k, v in explicit.items() if v is not None}}
    merged["scenario"] = req.scenario
    return ChannelRequest.model_validate(merged)


def _check_limits(req: ChannelRequest, settings: Settings) -> None:
    checks = [
        ("rays", req.rays, settings.max_rays),
        ("max_interactions", req.max_interactions, settings.max_interactions),
        ("receivers", len(req.receivers or []), settings.max_receivers),
        ("band", req.band.points if req.band else None, settings.max_band_points),
    ]
    for name, value, cap in checks:
        if value is not None and value > cap:
            loc = ["body", "band", "points"] if name == "band" else ["body", name]
            raise Unprocessable(f"{value} exceeds this server's limit of {cap}", loc=loc)


def _antenna(spec: AntennaIn, phantom: Phantom, phantom_id: str, where: list, name: str) -> Antenna:
    leaf = "site" if spec.site is not None else "position_m"
    field = _dotted(where, leaf)
    if spec.site is not None:
        site = phantom.sites.get(spec.site)
        if site is None:
            known = ", ".join(sorted(phantom.sites)) or "none"
            raise NotFound(
                f"phantom {phantom_id!r} has no site {spec.site!r}; its sites: {known}", loc=["body", *where, "site"]
            )
        position = np.asarray(site.position_m, float)
    else:
        position = np.asarray(spec.position_m, float)
    lo, hi = phantom.bounds_m
    margin = BOUNDS_MARGIN_FRACTION * float(np.linalg.norm(hi - lo))
    if np.any(position < lo - margin) or np.any(position > hi + margin):
        raise InvalidGeometryError(
            f"position {position.tolist()} m is outside the phantom's bounds {lo.tolist()}..{hi.tolist()} m "
            f"(grown by {margin:.3g} m)",
            field=field,
        )
    # Medium lookup: rejects a position on an organ surface, naming the field.
    phantom.medium_index(position[None, :], field=field)
    pol = np.asarray(spec.polarization, float)
    pol = pol / np.linalg.norm(pol)
    return Antenna(position_m=position, name=name, polarization=pol, pattern=spec.pattern)


def _dotted(where: list, leaf: str) -> str:
    out = ""
    for w in where:
        out += f"[{w}]" if isinstance(w, int) else (f".{w}" if out else str(w))
    return f"{out}.{leaf}"


def resolve(req: ChannelRequest, registry: Registry, settings: Settings) -> ResolvedChannel:
    """Validate a channel request against the phantom and the server limits."""
    req = merged_request(req, registry)
    _check_limits(req, settings)
    phantom_id = req.phantom or DEFAULT_PHANTOM
    phantom = registry.get(phantom_id, field_loc=["body", "phantom"])
    if req.transmitter is None:
        raise Unprocessable("a transmitter is required (or a scenario that supplies one)", loc=["body", "transmitter"])
    if not req.receivers:
        raise Unprocessable("at least one receiver is required (or a scenario that supplies them)", loc=["body", "receivers"])
    tx = _antenna(req.transmitter, phantom, phantom_id, ["transmitter"], "transmitter")
    receivers = []
    names = set()
    for i, r in enumerate(req.receivers):
        name = r.name or r.site or f"r{i}"
        if name in names:
            raise Unprocessable(f"receiver name {name!r} is used twice", loc=["body", "receivers", i, "name"])
        names.add(name)
        rx = _antenna(r, phantom, phantom_id, ["receivers", i], name)
        if np.linalg.norm(rx.position_m - tx.position_m) < 1e-6:
            raise InvalidGeometryError("receiver coincides with the transmitter", field=f"receivers[{i}].position_m")
        receivers.append(rx)
    band = None
    if req.band is not None:
        band = np.linspace(req.band.start_hz, req.band.stop_hz, req.band.points)
    homogeneous = None
    if req.homogeneous is not None:
        homogeneous = Material(
            relative_permittivity=req.homogeneous.relative_permittivity,
            conductivity_s_per_m=req.homogeneous.conductivity_s_per_m,
        )
    return ResolvedChannel(
        phantom_id=phantom_id,
        scenario=req.scenario,
        phantom=phantom,
        transmitter=tx,
        receivers=receivers,
        frequency_hz=float(req.frequency_hz or DEFAULT_FREQUENCY_HZ),
        band_frequencies_hz=band,
        max_interactions=DEFAULT_MAX_INTERACTIONS if req.max_interactions is None else req.max_interactions,
        rays=req.rays or DEFAULT_RAYS,
        dynamic_range_db=req.dynamic_range_db or DEFAULT_DYNAMIC_RANGE_DB,
        homogeneous=homogeneous,
    )


def run(resolved: ResolvedChannel, budget: Budget | None = None) -> ChannelResult:
    """Trace (blocking; call from a worker thread)."""
    from raytrace.solver.tracer import trace_channel

    return trace_channel(
        resolved.phantom,
        resolved.transmitter,
        resolved.receivers,
        resolved.frequency_hz,
        band_frequencies_hz=resolved.band_frequencies_hz,
        max_interactions=resolved.max_interactions,
        rays=resolved.rays,
        dynamic_range_db=resolved.dynamic_range_db,
        homogeneous=resolved.homogeneous,
        budget=budget,
    )


# ------------------------------------------------------------------ conversion
def _f(x: float) -> float:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"non-finite value {x} in a tracer result")
    return x


def _db(x: float) -> float:
    x = float(x)
    if math.isnan(x):
        raise ValueError("NaN dB value in a tracer result")
    return max(x, GAIN_DB_FLOOR)


def _c(z: complex) -> dict[str, float]:
    z = complex(z)
    return {"re": _f(z.real), "im": _f(z.imag)}


def _v(a) -> list[float]:
    return [_f(x) for x in np.asarray(a, float).reshape(3)]


def result_to_dict(result: ChannelResult, resolved: ResolvedChannel) -> dict[str, Any]:
    """The :class:`service.schemas.ChannelResponse` dict of a tracer result (no NaN/inf)."""
    band = result.band_frequencies_hz
    if band is None:
        band = resolved.band_frequencies_hz
    profiles = []
    for prof in result.profiles:
        paths = []
        for p in prof.paths:
            item: dict[str, Any] = {
                "delay_s": _f(p.delay_s),
                "gain": _c(p.gain),
                "gain_db": _db(p.gain_db),
                "length_m": _f(p.length_m),
                "interactions": [
                    {"kind": it.kind, "point_m": _v(it.point_m), "from_medium": it.from_medium, "to_medium": it.to_medium}
                    for it in p.interactions
                ],
                "segments": [{"medium": s.medium, "length_m": _f(s.length_m)} for s in p.segments],
                "band_gains": None,
            }
            if p.band_gains is not None and band is not None:
                item["band_gains"] = [
                    {"frequency_hz": _f(f), "gain": _c(g)} for f, g in zip(np.asarray(band), np.asarray(p.band_gains))
                ]
            paths.append(item)
        first = prof.first_path_delay_s
        profiles.append(
            {
                "receiver": prof.receiver,
                "position_m": _v(prof.position_m),
                "medium": prof.medium,
                "geometric_distance_m": _f(prof.geometric_distance_m),
                "paths": paths,
                "first_path_delay_s": None if first is None else _f(first),
                "path_gain_db": _db(prof.path_gain_db),
                "rms_delay_spread_s": _f(prof.rms_delay_spread_s),
                "reference_frequency_hz": _f(result.frequency_hz),
                "gains_include_delay_phase": True,
            }
        )
    return {
        "phantom": resolved.phantom_id,
        "scenario": resolved.scenario,
        "frequency_hz": _f(result.frequency_hz),
        "transmitter": {"position_m": _v(result.transmitter_position_m), "medium": result.transmitter_medium},
        "profiles": profiles,
        "stats": {
            "rays_launched": int(result.stats.rays_launched),
            "ray_segments_traced": int(result.stats.ray_segments_traced),
            "paths_found": int(result.stats.paths_found),
            "elapsed_s": _f(result.stats.elapsed_s),
        },
    }
