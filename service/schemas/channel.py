"""Models of a channel computation, POST /v1/channel (``docs/api.md`` "Channel"): the request (antennas,
band, outputs) and the response (profiles of paths, channel outputs, trace statistics)."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field

from estimators.channel_response import MIN_RATE_HZ
from service.limits import MAX_INTERACTIONS, MAX_RAYS, MAX_RECEIVERS, capped
from service.schemas import (
    GAIN_DB_FLOOR,
    Band,
    Complex,
    FrequencyHz,
    Name,
    Out,
    PhantomId,
    ScenarioId,
    Strict,
    Vec3,
    alternatives,
    int_range,
)
from service.schemas.constants import MAX_DYNAMIC_RANGE_DB, SPEC_DEFAULTS

#: The channel spec's defaults, quoted in the field descriptions (the spec applies them).


class HomogeneousMedium(Strict):
    relative_permittivity: float = Field(ge=1.0, le=1000.0, description="Relative permittivity eps_r' [-].")
    conductivity_s_per_m: float = Field(0.0, ge=0.0, le=1000.0, description="Conductivity [S/m].")


class AntennaIn(Strict):
    """An antenna: either ``position_m`` or a phantom ``site`` (exactly one; the channel spec,
    :class:`raytrace.spec.Antenna`, enforces it and the schema states it)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False,
                              json_schema_extra=alternatives([
                                  {"required": ["position_m"], "properties": {"position_m": {"type": "array"}}},
                                  {"required": ["site"], "properties": {"site": {"type": "string"}}}]))

    position_m: Vec3 | None = Field(None, description="Position [m] (phantom coordinates).")
    site: Name | None = Field(None, description="Name of one of the phantom's sites (GET /v1/phantoms/{id}).")
    polarization: Vec3 | None = Field(
        None, description="Polarization vector [-], normalised by the server (default [0, 0, 1]: z).")
    pattern: Literal["isotropic", "dipole"] | None = Field(None, description="Radiation pattern (default isotropic).")


class ReceiverIn(AntennaIn):
    name: Name | None = Field(None, description="Receiver name (default: the site name, or r<index>).")


#: Cap on the samples of an impulse response / the taps per receiver [-].
MAX_OUTPUT_SAMPLES = 4096


class CirIn(Strict):
    sample_rate_hz: float = Field(ge=MIN_RATE_HZ, le=1e12, description="Sampling rate of the impulse response [Hz].")
    num_samples: int_range(1, MAX_OUTPUT_SAMPLES) | None = Field(
        None,
        description=f"Samples [-] (default: up to 8 / bandwidth after the last path; <= {MAX_OUTPUT_SAMPLES}).")
    start_s: float = Field(0.0, ge=-1e-3, le=1e-3, description="Time of the first sample [s] (0: the emission).")


class TapsIn(Strict):
    bandwidth_hz: float = Field(ge=MIN_RATE_HZ, le=20e9, description="System bandwidth W: taps at l / W [Hz]; the band "
                                "centre +- W/2 must lie inside `band`.")
    l_min: int_range(-100_000, 100_000) | None = Field(None, description="First tap index [-] (default: six "
                              "before the first path's).")
    l_max: int_range(-100_000, 100_000) | None = Field(None, description="Last tap index [-] (default: six after "
                              "the last path's).")


class ChannelOutputs(Strict):
    """Per-receiver channel outputs as channel emulators give them (docs/science.md "Channel outputs"),
    computed from the paths' band gains: the request needs a `band`."""

    cfr: bool = Field(False, description="The summed frequency response H(f) at every band frequency (complex, "
                      "with dispersion).")
    cir: CirIn | None = Field(None, description="The baseband impulse response over the band (around its centre), "
                              "sampled at `sample_rate_hz` [1/s].")
    taps: TapsIn | None = Field(None, description="Discrete taps h_l = h(l / W) / W at bandwidth W around the band "
                                "centre [-].")
    normalize_delays: bool = Field(False, description="Time axis from the first path's delay instead of the "
                                   "emission (absolute delays by default).")


class ChannelRequest(Strict):
    """A channel computation (docs/api.md "Channel")."""

    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
        json_schema_extra={
            # what ChannelSpec requires: a scenario, or a transmitter and receivers of one's own
            **alternatives([{"required": ["scenario"], "properties": {"scenario": {"type": "string"}}},
                            {"required": ["transmitter", "receivers"],
                             "properties": {"transmitter": {"type": "object"}, "receivers": {"type": "array"}}}],
                           keyword="anyOf"),
            "examples": [
                {
                    "phantom": "torso",
                    "frequency_hz": 402e6,
                    "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 5},
                    "transmitter": {"site": "small_intestine_1"},
                    "receivers": [
                        {"name": "s1", "site": "belt_anterior"},
                        {"name": "s2", "position_m": [0.0984, -0.1005, 0.0], "polarization": [0, 0, 1],
                         "pattern": "dipole"},
                    ],
                    "max_interactions": 3,
                    "rays": 20000,
                    "dynamic_range_db": 80,
                },
                {"scenario": "thesis-fig-5-6", "rays": 20000},
            ]
        },
    )

    phantom: PhantomId | None = Field(
        None, description=f"Phantom id (GET /v1/phantoms); default: the scenario's, else `{SPEC_DEFAULTS['phantom']}`."
    )
    scenario: ScenarioId | None = Field(
        None, description="Built-in scenario id (GET /v1/scenarios) supplying phantom, antennas and frequency; "
        "explicit fields override it."
    )
    homogeneous: HomogeneousMedium | None = Field(
        None, description="Replace every body tissue by this one medium (same geometry)."
    )
    frequency_hz: FrequencyHz | None = Field(
        None, description=f"Carrier frequency [Hz]; default: the scenario's, else {SPEC_DEFAULTS['frequency_hz']:g}."
    )
    band: Band | None = Field(None, description="Also return each path's complex gain over this band.")
    transmitter: AntennaIn | None = Field(None, description="Transmitter (the capsule); required without a scenario.")
    receivers: list[ReceiverIn] | None = Field(
        None,
        min_length=1,
        max_length=MAX_RECEIVERS,
        description=f"Receivers (skin sensors), 1..{MAX_RECEIVERS}; required without a scenario.",
        json_schema_extra=capped("max_receivers"),
    )
    max_interactions: int_range(1, MAX_INTERACTIONS) | None = Field(
        None, description=f"Max reflections + refractions per path [-] (default {SPEC_DEFAULTS['max_interactions']}, "
        f"<= {MAX_INTERACTIONS}).", json_schema_extra=capped("max_interactions"),
    )
    rays: int_range(1, MAX_RAYS) | None = Field(
        None, description=f"Rays launched from the transmitter [-] (default {SPEC_DEFAULTS['rays']}, <= {MAX_RAYS}).",
        json_schema_extra=capped("max_rays"),
    )
    dynamic_range_db: float | None = Field(
        None, gt=0.0, le=MAX_DYNAMIC_RANGE_DB,
        description="Paths weaker than the strongest by more than this are dropped [dB] "
        f"(default {SPEC_DEFAULTS['dynamic_range_db']:g}).",
    )
    outputs: ChannelOutputs | None = Field(
        None, description="Also return each receiver's frequency response, impulse response and/or taps "
        "(requires `band`).")
    near_field: bool | None = Field(
        None, description="Give the refraction-only paths the dipole near-field terms (exact in one medium, "
        f"approximate through interfaces; docs/validation.md) (default {SPEC_DEFAULTS['near_field']}).",
    )


class Interaction(Out):
    kind: Literal["reflection", "refraction", "total_internal_reflection"]
    point_m: Vec3 = Field(description="Where it happens [m].")
    from_medium: str = Field(description="Medium the wave arrives in.")
    to_medium: str = Field(description="Medium on the far side of the surface.")


class Segment(Out):
    medium: str
    length_m: float = Field(description="Length of the straight piece [m].")


class BandGain(Out):
    frequency_hz: float = Field(description="Frequency [Hz].")
    gain: Complex = Field(description="Complex path gain at that frequency [-].")


class PathOut(Out):
    delay_s: float = Field(description="Absolute phase delay at the carrier, sum L Re n / c [s].")
    group_delay_s: float = Field(
        description="Absolute group delay at the carrier, the phase slope -d arg(gain) / d omega of the path's "
        "own gain (tissue dispersion, lossy Fresnel phases, the near-field term) [s]: when a pulse's envelope "
        "arrives (docs/science.md, 'Phase and group delay', (S22)); negative in a dipole's reactive near field."
    )
    gain: Complex = Field(
        description="Complex gain a_k of h(t) = sum a_k delta(t - delay_k) at the carrier frequency_hz, "
        "baseband-equivalent (it includes the propagation phase exp(-j 2 pi f tau_k)); |a_k|^2 is the "
        "power transfer between the antennas [-]."
    )
    gain_db: float = Field(description=f"20 log10 |gain| [dB] (floor {GAIN_DB_FLOOR:g}).")
    length_m: float = Field(description="Geometric length [m].")
    interactions: list[Interaction]
    segments: list[Segment]
    band_gains: list[BandGain] | None = None


class CfrOut(Out):
    frequency_hz: list[float] = Field(description="Frequencies [Hz] (the band's).")
    re: list[float] = Field(description="Re H(f) [-].")
    im: list[float] = Field(description="Im H(f) [-].")


class CirOut(Out):
    time_s: list[float] = Field(description="Sample times [s]: absolute (0 = emission) unless normalize_delays.")
    re: list[float] = Field(description="Re h(t) [1/s].")
    im: list[float] = Field(description="Im h(t) [1/s].")
    centre_hz: float = Field(description="Frequency the baseband is taken around [Hz].")
    bandwidth_hz: float = Field(description="Band the response is limited to, centred on centre_hz [Hz].")


class TapsOut(Out):
    l: list[int] = Field(description="Tap indices [-].")  # noqa: E741 (Sionna's and the textbooks' name)
    delay_s: list[float] = Field(description="Tap delays l / W [s]: absolute unless normalize_delays.")
    re: list[float] = Field(description="Re h_l [-].")
    im: list[float] = Field(description="Im h_l [-].")
    centre_hz: float = Field(description="Frequency the baseband is taken around [Hz].")
    bandwidth_hz: float = Field(description="W [Hz].")


class ProfileOut(Out):
    receiver: str
    position_m: Vec3 = Field(description="Receiver position [m].")
    medium: str = Field(description="Medium at the receiver.")
    geometric_distance_m: float = Field(description="Straight-line transmitter-receiver distance [m].")
    paths: list[PathOut] = Field(description="Paths sorted by delay.")
    first_path_delay_s: float | None = Field(description="Delay of the first path [s] (null: no path).")
    path_gain_db: float = Field(description=f"10 log10 sum |a_k|^2 [dB] (floor {GAIN_DB_FLOOR:g}).")
    rms_delay_spread_s: float = Field(description="Power-weighted RMS delay spread [s].")
    validity: list[str] = Field(
        default_factory=list,
        description="Regimes where full-wave (FDTD) comparisons showed the tracer to be off that this receiver "
        "is in: near_field, in_air_near_body, grazing_exit, near_critical_angle, curved_layers, no_direct_path "
        "(docs/validation.md, 'Validity per receiver').")
    reference_frequency_hz: float = Field(
        description="Frequency at which `paths[].gain` is evaluated (the carrier) [Hz].")
    gains_include_delay_phase: bool = Field(
        True,
        description="The tracer's gains include the propagation phase exp(-j k0 n L) (baseband-equivalent "
        "convention); the ranging endpoints use this flag to avoid counting it twice.",
    )
    smallest_organ: str | None = Field(None, description="The electrically smallest organ the paths cross.")
    smallest_organ_size_wavelengths: float | None = Field(
        None, description="Its width in wavelengths of its own tissue at the carrier [-] (docs/science.md, section 8).")
    warnings: list[str] = Field(default_factory=list, description="Where the ray model is doubtful (an organ "
                                "crossed is below one wavelength wide).")
    cfr: CfrOut | None = Field(None, description="With outputs.cfr: the summed frequency response over the band.")
    cir: CirOut | None = Field(None, description="With outputs.cir: the impulse response.")
    taps: TapsOut | None = Field(None, description="With outputs.taps: the discrete taps.")


class PlacedAntenna(Out):
    position_m: Vec3 = Field(description="Position [m].")
    medium: str = Field(description="Medium at the position.")


class TraceStatsOut(Out):
    rays_launched: int
    ray_segments_traced: int
    paths_found: int
    elapsed_s: float = Field(description="Wall time of the trace [s].")


class ChannelResponse(Out):
    phantom: str
    scenario: str | None = None
    frequency_hz: float = Field(description="Carrier frequency [Hz].")
    transmitter: PlacedAntenna
    profiles: list[ProfileOut]
    stats: TraceStatsOut
