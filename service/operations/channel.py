"""Channel requests: the HTTP body mapped onto a :class:`raytrace.ChannelSpec`, and the
tracer's result mapped back onto the response.

Pure functions (no HTTP), shared by the route and ``capsule-rt channel``. Every rule
and default of a channel request is the spec's (:mod:`raytrace.spec`); the service
adds only its own limits (:class:`service.settings.Settings`) and the phantom lookup
in its registry (uploads included).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from raytrace import ChannelResult, ChannelSpec, Phantom
from service import costs
from service.admission import admit, lower_or_refuse
from service.errors import NotFound, Unprocessable
from service.registry import Registry
from service.schemas import GAIN_DB_FLOOR
from service.schemas.channel import MAX_OUTPUT_SAMPLES, ChannelOutputs, ChannelRequest
from service.settings import Settings


def to_spec(req: ChannelRequest, registry: Registry, settings: Settings) -> tuple[ChannelSpec, Phantom]:
    """The request as a spec (fields it leaves unset come from its scenario, then from the
    spec's defaults), checked against this server's limits, and the phantom it names. A
    ``rays`` or ``max_interactions`` the request leaves unset is at most this server's limit
    (a scenario's or the spec's value above it is lowered to it, as the served schema's default
    says); an explicit value above the limit is refused. Raises the spec's typed errors (the
    error handlers make them 422s naming the field)."""
    base = None
    if req.scenario is not None:
        scenario = registry.scenarios.get(req.scenario)
        if scenario is None:
            known = ", ".join(sorted(registry.scenarios)) or "none"
            raise NotFound(f"unknown scenario {req.scenario!r}; known scenarios: {known} (GET /v1/scenarios)",
                           loc=["body", "scenario"])
        base = scenario.spec
    given = req.model_dump(exclude_none=True, exclude={"scenario", "outputs"})
    spec = ChannelSpec.from_dict(given, base)
    # rays and interactions the request leaves to the scenario or the spec's defaults are lowered to this
    # server's limits; given ones, the receivers and the band's points above them are refused
    knobs = {key: lower_or_refuse(given.get(key), setting, settings, (key,), default=getattr(spec, key))
             for key, setting in (("rays", "max_rays"), ("max_interactions", "max_interactions"))}
    if any(knobs[key] != getattr(spec, key) for key in knobs):
        spec = replace(spec, **knobs)
    phantom = registry.get(spec.phantom, field_loc=["body", "phantom"])
    lower_or_refuse(len(spec.receivers), "max_receivers", settings, ("receivers",), default=0)
    if spec.band is not None:
        lower_or_refuse(spec.band.points, "max_band_points", settings, ("band", "points"), default=0)
    check_footprint(spec, settings)
    _check_outputs(req.outputs, spec)
    return spec, phantom


def check_footprint(spec: ChannelSpec, settings: Settings) -> None:
    """Refuse (422, before any work) a trace whose estimated shooting exceeds the work budget or whose
    estimated peak memory exceeds one computation's share: :func:`service.costs.channel` through the one
    rule, :func:`service.admission.admit` (docs/service.md "Memory and work model")."""
    admit(costs.channel(spec, settings), settings)


def _check_outputs(outputs: ChannelOutputs | None, spec: ChannelSpec) -> None:
    """Channel outputs come from the paths' band gains: they need a band, and taps one that holds
    the band centre +- W/2 (checked before the trace, not after it)."""
    if outputs is None or not (outputs.cfr or outputs.cir or outputs.taps):
        return
    if spec.band is None:
        raise Unprocessable("channel outputs are computed from the paths' band gains: give a band",
                            loc=["body", "band"])
    f = spec.band.frequencies_hz
    if f.size < 2 and (outputs.cir or outputs.taps):
        raise Unprocessable("an impulse response or taps need a band of at least two frequencies",
                            loc=["body", "band"])
    if outputs.taps is not None:
        centre, half = 0.5 * (f[0] + f[-1]), 0.5 * (f[-1] - f[0])
        if outputs.taps.bandwidth_hz / 2 > half * (1 + 1e-12):
            raise Unprocessable(
                f"the band centre {centre:.6g} Hz +- {outputs.taps.bandwidth_hz / 2:.6g} Hz leaves the band "
                f"[{f[0]:.6g}, {f[-1]:.6g}] Hz: widen the band or narrow the taps", loc=["body", "outputs", "taps",
                                                                                       "bandwidth_hz"])


def _profile_outputs(result: ChannelResult, prof, outputs: ChannelOutputs) -> dict[str, Any]:
    """cfr / cir / taps of one receiver (estimators.channel_response), as JSON arrays."""
    from estimators import PathProfile
    from estimators.channel_response import cfr, cir, taps
    from estimators.errors import EstimatorInputError

    out: dict[str, Any] = {"cfr": None, "cir": None, "taps": None}
    band = result.band_frequencies_hz
    if not prof.paths or band is None:
        return out
    profile = PathProfile.from_traced(prof.paths, result.frequency_hz, band)
    norm = outputs.normalize_delays
    centre, width = 0.5 * (band[0] + band[-1]), float(band[-1] - band[0])
    try:
        if outputs.cfr:
            h = cfr(profile, band, normalize_delays=norm)
            out["cfr"] = {"frequency_hz": [_f(x) for x in band], "re": [_f(x) for x in h.real],
                          "im": [_f(x) for x in h.imag]}
        if outputs.cir is not None:
            c = outputs.cir
            n = c.num_samples
            if n is None:
                end = float(profile.delays_s.max()) - (profile.first_path_delay_s if norm else 0.0) + 8.0 / width
                n = max(1, int(math.ceil((end - c.start_s) * c.sample_rate_hz)) + 1)
                if n > MAX_OUTPUT_SAMPLES:
                    raise Unprocessable(f"the default span needs {n} samples, over the limit of {MAX_OUTPUT_SAMPLES}: "
                                        "give num_samples or a lower sample_rate_hz",
                                        loc=["body", "outputs", "cir", "num_samples"])
            t, h = cir(profile, c.sample_rate_hz, bandwidth_hz=width, centre_hz=centre, start_s=c.start_s,
                       num_samples=n, normalize_delays=norm)
            out["cir"] = {"time_s": [_f(x) for x in t], "re": [_f(x) for x in h.real], "im": [_f(x) for x in h.imag],
                          "centre_hz": _f(centre), "bandwidth_hz": _f(width)}
        if outputs.taps is not None:
            tp = outputs.taps
            ell, h = taps(profile, tp.bandwidth_hz, centre_hz=centre, l_min=tp.l_min, l_max=tp.l_max,
                          normalize_delays=norm)
            if ell.size > MAX_OUTPUT_SAMPLES:
                raise Unprocessable(f"{ell.size} taps exceed the limit of {MAX_OUTPUT_SAMPLES}: give l_min and l_max",
                                    loc=["body", "outputs", "taps", "l_max"])
            out["taps"] = {"l": [int(x) for x in ell], "delay_s": [_f(x) for x in ell / tp.bandwidth_hz],
                           "re": [_f(x) for x in h.real], "im": [_f(x) for x in h.imag],
                           "centre_hz": _f(centre), "bandwidth_hz": _f(tp.bandwidth_hz)}
    except EstimatorInputError as exc:
        what = "cir" if exc.field in ("num_samples", "sample_rate_hz", "start_s") else "taps"
        raise Unprocessable(exc.reason, loc=["body", "outputs", what, exc.field or ""]) from None
    return out


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


def result_to_dict(result: ChannelResult, scenario: str | None = None,
                   outputs: ChannelOutputs | None = None) -> dict[str, Any]:
    """The :class:`service.schemas.channel.ChannelResponse` dict of a tracer result (no NaN/inf), with the
    channel ``outputs`` asked for (cfr / cir / taps per receiver)."""
    band = result.band_frequencies_hz
    profiles = []
    for prof in result.profiles:
        paths = []
        for p in prof.paths:
            item: dict[str, Any] = {
                "delay_s": _f(p.delay_s),
                "group_delay_s": _f(p.group_delay_s),
                "gain": _c(p.gain),
                "gain_db": _db(p.gain_db),
                "length_m": _f(p.length_m),
                "interactions": [
                    {"kind": it.kind, "point_m": _v(it.point_m), "from_medium": it.from_medium,
                     "to_medium": it.to_medium}
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
                "validity": list(prof.validity),
                "reference_frequency_hz": _f(result.frequency_hz),
                "gains_include_delay_phase": True,
                "smallest_organ": prof.smallest_organ,
                "smallest_organ_size_wavelengths": (None if prof.smallest_organ_size_wavelengths is None
                                                    else _f(prof.smallest_organ_size_wavelengths)),
                "warnings": list(prof.warnings),
                **(_profile_outputs(result, prof, outputs) if outputs is not None
                   else {"cfr": None, "cir": None, "taps": None}),
            }
        )
    return {
        "phantom": result.phantom,
        "scenario": scenario,
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
