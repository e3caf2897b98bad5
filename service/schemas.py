"""Request and response models of the HTTP API (``docs/api.md``), pydantic v2.

Conventions:

* SI units, the unit in the field name and in brackets in its description.
* Every request model forbids unknown fields and non-finite numbers
  (``NaN`` / ``Infinity`` get a 422), and its types are strict: a boolean or
  a numeric string is not a number, 1.5 is not an integer. Where fields
  depend on each other (exactly one of two), the schema says it with
  ``oneOf``. Responses never contain non-finite numbers either:
  a zero gain's ``-inf`` dB is clamped to :data:`GAIN_DB_FLOOR` (-400 dB).
* Complex numbers are ``{"re": float, "im": float}``.
* Array sizes and compute knobs are bounded; the ``le`` bounds here are the
  hard ceilings of :mod:`service.settings`, which an operator may tighten.
* Errors (every 4xx/5xx) have the body :class:`ErrorResponse`: ``detail`` is a
  list of ``{loc, msg, type}`` whose ``loc`` names the offending field
  (``["body", "receivers", 0, "position_m"]``), the same shape FastAPI uses
  for schema violations.
"""

from __future__ import annotations

from dataclasses import fields as dataclass_fields
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
    model_validator,
)

from estimators.channel_response import MIN_RATE_HZ
from estimators.link import MICS_EIRP_DBM
from raytrace.body import gltf
from raytrace.physics.tissues import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ, TISSUE_NAMES
from raytrace.spec import MAX_DYNAMIC_RANGE_DB, ChannelSpec
from service.settings import (
    MAX_BAND_POINTS,
    MAX_INTERACTIONS,
    MAX_PROFILE_PATHS,
    MAX_RAYS,
    MAX_RECEIVERS,
    MAX_TRIALS,
)

#: dB value reported for a zero gain / power (instead of -inf) [dB].
GAIN_DB_FLOOR = -400.0

#: The channel spec's defaults, quoted in the field descriptions (the spec applies them).
SPEC_DEFAULTS = {f.name: f.default for f in dataclass_fields(ChannelSpec)}

ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"
NAME_PATTERN = gltf.NAME_PATTERN.pattern  # organ and site names: the upload's own rule

PhantomId = Annotated[str, StringConstraints(pattern=ID_PATTERN)]
ScenarioId = Annotated[str, StringConstraints(pattern=ID_PATTERN)]
Name = Annotated[str, StringConstraints(pattern=NAME_PATTERN)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


def _integral(value: Any) -> Any:
    """JSON Schema's ``integer`` is any number without a fractional part (``100.0``, ``1e2``): such
    a float becomes the int; every other value goes on to strict validation (a boolean or a
    numeric string stays refused)."""
    if type(value) is float and value.is_integer():
        return int(value)
    return value


#: An integer field of a request: strict, but 100.0 counts, as the schema's ``integer`` says.
Int = Annotated[int, BeforeValidator(_integral)]


def int_range(ge: int, le: int) -> Any:
    """An ``Int`` between ``ge`` and ``le``, for optional fields: written this way (the bounds before
    the validator) the schema says ``minimum``/``maximum``; ``Int | None = Field(ge=...)`` would
    emit pydantic's internal ``ge`` keys, which no schema tool reads."""
    return Annotated[int, Field(ge=ge, le=le), BeforeValidator(_integral)]
FrequencyHz = Annotated[float, Field(ge=FREQUENCY_MIN_HZ, le=FREQUENCY_MAX_HZ)]


class Strict(BaseModel):
    """Base of request models: no unknown fields, no NaN / infinity, strict types (``"rays": true``
    and ``"rays": "5"`` are refused, as the schema's ``integer`` says)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class Out(BaseModel):
    """Base of response models (strict as well: a profile's paths, interactions and segments
    come back inside ranging requests)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


# ----------------------------------------------------------------- errors
class ErrorItem(BaseModel):
    loc: list[str | int] = Field(description="Where the problem is: location then field path, e.g. [\"body\", \"rays\"].")
    msg: str = Field(description="Why it was rejected.")
    type: str = Field(description="Machine-readable error type.")


class ErrorResponse(BaseModel):
    detail: list[ErrorItem]


# ----------------------------------------------------------------- shared
class Complex(Strict):
    re: float = Field(description="Real part [same unit as the quantity].")
    im: float = Field(description="Imaginary part [same unit as the quantity].")


class Band(Strict):
    start_hz: FrequencyHz = Field(description="First frequency [Hz].")
    stop_hz: FrequencyHz = Field(description="Last frequency [Hz] (> start_hz).")
    points: Int = Field(ge=2, le=MAX_BAND_POINTS, description="Number of equally spaced frequencies [-].")

    @model_validator(mode="after")
    def _order(self) -> "Band":
        if not self.stop_hz > self.start_hz:
            raise ValueError("stop_hz must be greater than start_hz")
        return self


class HomogeneousMedium(Strict):
    relative_permittivity: float = Field(ge=1.0, le=1000.0, description="Relative permittivity eps_r' [-].")
    conductivity_s_per_m: float = Field(0.0, ge=0.0, le=1000.0, description="Conductivity [S/m].")


class AntennaIn(Strict):
    """An antenna: either ``position_m`` or a phantom ``site`` (exactly one; the channel spec,
    :class:`raytrace.spec.Antenna`, enforces it and the schema states it)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False,
                              json_schema_extra={"oneOf": [
                                  {"required": ["position_m"], "properties": {"position_m": {"type": "array"}}},
                                  {"required": ["site"], "properties": {"site": {"type": "string"}}}]})

    position_m: Vec3 | None = Field(None, description="Position [m] (phantom coordinates).")
    site: Name | None = Field(None, description="Name of one of the phantom's sites (GET /v1/phantoms/{id}).")
    polarization: Vec3 | None = Field(
        None, description="Polarization vector [-], normalised by the server (default [0, 0, 1]: z).")
    pattern: Literal["isotropic", "dipole"] | None = Field(None, description="Radiation pattern (default isotropic).")


class ReceiverIn(AntennaIn):
    name: Name | None = Field(None, description="Receiver name (default: the site name, or r<index>).")


# ----------------------------------------------------------------- channel
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

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            # what ChannelSpec requires: a scenario, or a transmitter and receivers of one's own
            "anyOf": [{"required": ["scenario"], "properties": {"scenario": {"type": "string"}}},
                      {"required": ["transmitter", "receivers"],
                       "properties": {"transmitter": {"type": "object"}, "receivers": {"type": "array"}}}],
            "examples": [
                {
                    "phantom": "torso",
                    "frequency_hz": 402e6,
                    "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 5},
                    "transmitter": {"site": "small_intestine_1"},
                    "receivers": [
                        {"name": "s1", "site": "belt_anterior"},
                        {"name": "s2", "position_m": [0.0984, -0.1005, 0.0], "polarization": [0, 0, 1], "pattern": "dipole"},
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
        None, description="Built-in scenario id (GET /v1/scenarios) supplying phantom, antennas and frequency; explicit fields override it."
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
    )
    max_interactions: Annotated[int, Field(ge=1, le=MAX_INTERACTIONS), BeforeValidator(_integral)] | None = Field(
        None, description=f"Max reflections + refractions per path [-] (default {SPEC_DEFAULTS['max_interactions']}, "
        f"<= {MAX_INTERACTIONS}).",
    )
    rays: Annotated[int, Field(ge=1, le=MAX_RAYS), BeforeValidator(_integral)] | None = Field(
        None, description=f"Rays launched from the transmitter [-] (default {SPEC_DEFAULTS['rays']}, <= {MAX_RAYS}).",
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
        description="Absolute group delay at the carrier, sum L n_g / c with the tissues' group index [s]: "
        "when a pulse's envelope arrives (docs/science.md, 'Phase and group delay')."
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
        description="Regimes where full-wave (FDTD) comparisons showed geometric optics to be off that this "
        "receiver is in: near_field, in_air_near_body, grazing_exit, near_critical_angle, no_direct_path "
        "(docs/validation.md, 'Validity per receiver').")
    reference_frequency_hz: float = Field(description="Frequency at which `paths[].gain` is evaluated (the carrier) [Hz].")
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


# ----------------------------------------------------------------- ranging
#: Bound on each component of an input path gain [-]: a passive channel has |a| <= 1 (caustics
#: are capped at +20 dB); the margin keeps |a|^2 sums far from float overflow.
MAX_GAIN_COMPONENT = 1e6


class GainIn(Strict):
    re: float = Field(ge=-MAX_GAIN_COMPONENT, le=MAX_GAIN_COMPONENT, description="Real part [-].")
    im: float = Field(ge=-MAX_GAIN_COMPONENT, le=MAX_GAIN_COMPONENT, description="Imaginary part [-].")


#: JSON Schema of a number that is not zero (without ``not``, which fuzzers handle poorly).
_NONZERO = {"anyOf": [{"exclusiveMinimum": 0}, {"exclusiveMaximum": 0}]}


class PathGainIn(GainIn):
    """A path's complex gain: not zero (a path of zero gain carries nothing; leave it out)."""

    model_config = ConfigDict(
        json_schema_extra={"anyOf": [{"properties": {"re": _NONZERO}}, {"properties": {"im": _NONZERO}}]}
    )

    @model_validator(mode="after")
    def _nonzero(self) -> "PathGainIn":
        if self.re == 0.0 and self.im == 0.0:
            raise ValueError("a path's gain must not be zero (a path of zero gain carries nothing: leave it out)")
        return self


class BandGainIn(Strict):
    frequency_hz: FrequencyHz = Field(description="Frequency [Hz].")
    gain: GainIn = Field(description="Complex path gain at that frequency [-].")


class PathIn(Strict):
    """A path of a profile: at least delay and complex gain; the other channel fields are accepted and ignored."""

    delay_s: float = Field(ge=0.0, le=1e-3, description="Absolute (phase) delay [s].")
    gain: PathGainIn = Field(description="Complex gain [-], not zero.")
    group_delay_s: float | None = Field(None, ge=0.0, le=1e-3, description="Absolute group delay [s] (as a channel "
                                        "profile gives it).")
    gain_db: float | None = None
    length_m: float | None = None
    interactions: list[Interaction] | None = Field(None, max_length=64)
    segments: list[Segment] | None = Field(None, max_length=128)
    band_gains: list[BandGainIn] | None = Field(
        None, max_length=MAX_BAND_POINTS,
        description="Gains per frequency: used when every path lists the same distinct frequencies, else ignored.",
    )


#: JSON schema of "some path has a non-zero gain" (``contains``): a profile of zero gains carries no signal.
class ProfileIn(Strict):
    """A channel profile: ``profiles[i]`` of POST /v1/channel as is, or a hand-made ``{"paths": [...]}``."""

    model_config = ConfigDict(
        json_schema_extra={
            "oneOf": [
                {"properties": {"gains_include_delay_phase": {"const": False}}},
                {"required": ["gains_include_delay_phase", "reference_frequency_hz"],
                 "properties": {"gains_include_delay_phase": {"const": True}}},
            ],
        }
    )

    paths: list[PathIn] = Field(min_length=1, max_length=MAX_PROFILE_PATHS)
    receiver: str | None = Field(None, max_length=64)
    position_m: Vec3 | None = None
    medium: str | None = Field(None, max_length=128)
    geometric_distance_m: float | None = None
    first_path_delay_s: float | None = None
    path_gain_db: float | None = None
    rms_delay_spread_s: float | None = None
    smallest_organ: str | None = Field(None, max_length=128)
    smallest_organ_size_wavelengths: float | None = None
    warnings: list[Annotated[str, StringConstraints(max_length=1000)]] | None = Field(None, max_length=16)
    cfr: CfrOut | None = None
    cir: CirOut | None = None
    taps: TapsOut | None = None
    validity: list[Annotated[str, StringConstraints(max_length=64)]] | None = Field(
        None, max_length=16, description="The channel response's validity flags (ignored by the estimators).")
    gains_include_delay_phase: bool = Field(
        False,
        description="false (default, a hand-made h(t) = sum a_k delta(t - delay_k)): gains exclude the propagation "
        "phase exp(-j 2 pi f delay_k); true (profiles from POST /v1/channel): they include it at "
        "reference_frequency_hz (band_gains at their own frequencies).",
    )
    reference_frequency_hz: float = Field(
        None, ge=FREQUENCY_MIN_HZ, le=FREQUENCY_MAX_HZ,
        description="Frequency of `gain` [Hz]: required when gains_include_delay_phase is true.",
    )

    @model_validator(mode="after")
    def _reference(self) -> "ProfileIn":
        if self.gains_include_delay_phase and self.reference_frequency_hz is None:
            raise ValueError("reference_frequency_hz is required when gains_include_delay_phase is true")
        return self


_EXAMPLE_PROFILE = {
    "paths": [
        {"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}},
        {"delay_s": 2.1e-9, "gain": {"re": -3e-4, "im": 2e-4}},
    ]
}


class LinkIn(Strict):
    """A radio link instead of an SNR: snr_db = P_t + G - 10 log10(k T B / 1 mW) - F (docs/science.md (S24)),
    G the profile's path gain."""

    transmit_power_dbm: float = Field(MICS_EIRP_DBM, ge=-100.0, le=60.0, description="Transmit power (EIRP) [dBm] "
                                      "(default the MICS limit, 25 uW = -16.02 dBm).")
    noise_figure_db: float = Field(0.0, ge=0.0, le=60.0, description="Receiver noise figure F [dB] (default 0: the "
                                   "thermal floor).")
    temperature_k: float = Field(290.0, ge=1.0, le=1e4, description="Noise temperature T [K] (default 290 K, the "
                                 "noise figure's reference).")
    bandwidth_hz: float | None = Field(None, ge=1.0, le=1e12, description="Noise bandwidth B [Hz] (default the "
                                       "method's: TOA fs / 2, PDOA the tones' span, bounds their bandwidth).")


class RangingCommon(Strict):
    profile: ProfileIn
    snr_db: float = Field(30.0, ge=-50.0, le=200.0, description="Signal-to-noise ratio [dB] (or give `link`).")
    link: LinkIn | None = Field(None, description="Derive the SNR from this link budget and the profile's path "
                                "gain instead of `snr_db`.")
    trials: Int = Field(
        100, ge=1, le=MAX_TRIALS,
        description=f"Monte Carlo noise realisations [-] (<= {MAX_TRIALS}; default 100, or this server's limit "
        "if lower).",
    )
    seed: Int = Field(
        0, ge=0, le=2**53 - 1, description="Seed of the noise generator [-] (<= 2^53 - 1: exact as any JSON number)."
    )
    relative_permittivity: float = Field(
        27.9, ge=1.0, le=1000.0, description="Assumed relative permittivity for delay-to-distance [-]."
    )
    true_distance_m: float | None = Field(
        None, gt=0.0, le=100.0, description="True distance [m]; adds error statistics."
    )


class Waveform(Strict):
    kind: Literal["tone_burst", "gaussian_pulse"] = Field("tone_burst", description="Transmitted waveform.")
    carrier_hz: float = Field(402e6, gt=0.0, le=100e9, description="Carrier frequency [Hz].")
    duration_s: float = Field(25e-9, gt=0.0, le=1e-6, description="Observation / burst duration [s].")
    sample_rate_hz: float = Field(20e9, gt=0.0, le=1e12, description="Sample rate [Hz].")
    bandwidth_hz: float | None = Field(None, gt=0.0, le=100e9, description="Bandwidth of a pulse [Hz].")


class ToaRequest(RangingCommon):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            "not": {"required": ["snr_db", "link"]},  # the link budget sets the SNR: not both
            "examples": [
                {
                    "profile": _EXAMPLE_PROFILE,
                    "method": "all",
                    "snr_db": 30,
                    "trials": 20,
                    "seed": 1,
                    "true_distance_m": 0.076,
                    "waveform": {"kind": "tone_burst", "carrier_hz": 402e6, "duration_s": 25e-9, "sample_rate_hz": 20e9},
                }
            ]
        },
    )
    method: Literal["first_peak", "all_peaks", "gcc", "envelope", "all"] = Field(
        "gcc",
        description="TOA estimator: `first_peak` (Eq 4.18), `all_peaks` (Eq 4.19-4.21), `gcc` (Eq 4.22-4.24), "
        "`envelope` (cross-correlation envelope only, no carrier phase), `all`: the thesis' three.",
    )
    waveform: Waveform = Field(default_factory=Waveform, description="Transmitted waveform.")


class PdoaRequest(RangingCommon):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            "examples": [
                {
                    "profile": _EXAMPLE_PROFILE,
                    "method": "regression",
                    "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21},
                    "snr_db": 30,
                    "trials": 50,
                    "seed": 1,
                    "true_distance_m": 0.076,
                }
            ],
            # at most one of frequencies_hz and band (neither: the profile's own band, a channel profile's
            # band_gains); the link budget sets the SNR: not both
            "allOf": [{"not": {"required": ["frequencies_hz", "band"]}}, {"not": {"required": ["snr_db", "link"]}}],
        },
    )
    method: Literal["two_tone", "regression"] = Field("two_tone", description="PDOA estimator.")
    frequencies_hz: list[FrequencyHz] = Field(
        None,
        min_length=2,
        max_length=MAX_BAND_POINTS,
        json_schema_extra={"uniqueItems": True},
        description="Distinct tone frequencies [Hz], in any order (two_tone uses the lowest and the highest; "
        "regression needs them equally spaced). At most one of frequencies_hz and band; neither: the profile's band.",
    )
    band: Band = Field(
        None, description="Equally spaced tones (two_tone uses its ends). At most one of frequencies_hz and band; neither: the profile's band."
    )
    duration_s: float | None = Field(
        None, ge=1e-12, le=1e-3, description="Observation time per tone [s] (default: the estimator's, 1 / tone spacing)."
    )

    @model_validator(mode="after")
    def _tones(self) -> "PdoaRequest":
        if self.frequencies_hz is not None and self.band is not None:
            raise ValueError("give at most one of frequencies_hz or band (neither: the profile's own band)")
        if self.frequencies_hz is not None and len(set(self.frequencies_hz)) != len(self.frequencies_hz):
            raise ValueError("frequencies_hz must be distinct")
        return self


class RssRequest(RangingCommon):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            "not": {"required": ["snr_db", "link"]},  # the link budget sets the SNR: not both
            "examples": [
                {"profile": _EXAMPLE_PROFILE, "model": "cm2_deep_tissue", "trials": 200, "seed": 1, "true_distance_m": 0.076}
            ],
            "oneOf": [
                {"required": ["profile"], "properties": {"rss_dbm": False}},
                {"required": ["rss_dbm", "transmit_power_dbm"], "properties": {"profile": False}},
            ],
        },
    )
    model: Literal["cm2_deep_tissue", "cm2_near_surface"] = Field(
        "cm2_deep_tissue", description="IEEE 802.15.6 CM2 path-loss model (thesis Table 2.2)."
    )
    profile: ProfileIn = Field(
        None,
        description="Channel profile: its path gain gives the path loss. Give it, or rss_dbm with transmit_power_dbm.",
    )
    rss_dbm: float = Field(
        None, ge=-300.0, le=100.0,
        description="Measured received power [dBm], with transmit_power_dbm (not with a profile).",
    )
    transmit_power_dbm: float = Field(
        None, ge=-100.0, le=100.0, description="Transmit power [dBm], with rss_dbm; ignored with a profile."
    )
    shadowing: bool = Field(True, description="Draw log-normal shadowing per trial (false: deterministic inversion).")

    @model_validator(mode="after")
    def _source(self) -> "RssRequest":
        if self.profile is not None and self.rss_dbm is not None:
            raise ValueError("give a profile or rss_dbm, not both")
        if self.profile is None and (self.rss_dbm is None or self.transmit_power_dbm is None):
            raise ValueError("give a profile, or rss_dbm together with transmit_power_dbm")
        return self


class RangingResult(Out):
    method: str
    distance_m: float = Field(description="Mean estimated distance [m].")
    delay_s: float | None = Field(None, description="Mean estimated delay [s].")
    std_m: float = Field(description="Standard deviation of the estimates [m].")
    error_m: float | None = Field(None, description="Mean error (estimate - true) [m].")
    rmse_m: float | None = Field(None, description="Root-mean-square error [m].")
    crlb_m: float | None = Field(None, description="Cramér-Rao bound on the distance std [m].")
    trials: int
    max_unambiguous_range_m: float | None = Field(None, description="PDOA: v / (f2 - f1) [m].")
    crlb_phase_difference_m: float | None = Field(None, description="PDOA: bound from the tone spacing alone [m].")
    wrapped: bool | None = Field(None, description="PDOA: the estimate may have wrapped (range ambiguity).")
    wrap_reason: str | None = Field(None, description="PDOA: why a wrap is suspected.")
    model: str | None = Field(None, description="RSS: the path-loss model inverted.")
    path_loss_db: float | None = Field(None, description="RSS: deterministic path loss that was inverted [dB].")
    median_distance_m: float | None = Field(None, description="RSS: inversion without shadowing [m].")
    snr_db: float | None = Field(None, description="TOA / PDOA: the SNR the trials ran at (given, or from `link`) "
                                 "[dB].")
    channel_model: str | None = Field(
        None, description="TOA / PDOA: how the channel was evaluated: `band_gains` (dispersion, Fresnel and "
        "absorption at every frequency), `group_delay` (first-order: phase and group delays), or "
        "`non_dispersive` (delays only).")
    band_coverage: float | None = Field(None, description="TOA, band_gains: share of the waveform's energy inside "
                                        "the profile's band [-].")


class RangingResponse(RangingResult):
    """The requested method's result at the top level (docs/api.md); for TOA ``method: all``
    the top level is the ``gcc`` result. ``results`` lists every method computed."""

    results: list[RangingResult] = Field(description="One result per method computed (three for TOA `all`).")


# ----------------------------------------------------------------- bounds
class ToaBoundRequest(Strict):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            # the SNR, or a link with the channel's gain, not both
            "anyOf": [{"required": ["snr_db"], "properties": {"snr_db": {"type": "number"}}},
                      {"required": ["link", "path_gain_db"],
                       "properties": {"link": {"type": "object"}, "path_gain_db": {"type": "number"}}}],
            "not": {"required": ["snr_db", "link"],
                    "properties": {"snr_db": {"type": "number"}, "link": {"type": "object"}}},
            "examples": [
                {"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30, "relative_permittivity": 27.9}
            ]
        },
    )
    carrier_hz: float = Field(ge=1.0, le=1e12, description="Tone frequency [Hz].")
    duration_s: float = Field(ge=1e-15, le=1.0, description="Observation time T0 [s].")
    bandwidth_hz: float = Field(ge=1.0, le=1e12, description="Receiver (noise) bandwidth W [Hz].")
    snr_db: float | None = Field(None, ge=-50.0, le=200.0, description="Signal-to-noise ratio [dB] (or give `link` "
                                 "and `path_gain_db`).")
    relative_permittivity: float = Field(27.9, ge=1.0, le=1000.0, description="Relative permittivity [-].")
    delay_s: float = Field(0.0, ge=0.0, le=1.0, description="True delay tau [s].")
    link: LinkIn | None = Field(None, description="Derive the SNR over `bandwidth_hz` from this link instead.")
    path_gain_db: float | None = Field(None, ge=-400.0, le=20.0, description="With `link`: the channel's power "
                                       "gain, a profile's path_gain_db [dB].")


class PdoaBoundRequest(Strict):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            # the SNR, or a link with the channel's gain, not both
            "anyOf": [{"required": ["snr_db"], "properties": {"snr_db": {"type": "number"}}},
                      {"required": ["link", "path_gain_db"],
                       "properties": {"link": {"type": "object"}, "path_gain_db": {"type": "number"}}}],
            "not": {"required": ["snr_db", "link"],
                    "properties": {"snr_db": {"type": "number"}, "link": {"type": "object"}}},
            "examples": [
                {"center_hz": 410e6, "tone_spacing_hz": 20e6, "snr_db": 30, "duration_s": 50e-9, "relative_permittivity": 27.9}
            ]
        },
    )
    center_hz: float = Field(ge=1.0, le=1e12, description="Centre frequency f0 [Hz].")
    tone_spacing_hz: float = Field(ge=1e-3, le=1e12, description="Tone spacing W [Hz] (< 2 center_hz).")
    snr_db: float | None = Field(None, ge=-50.0, le=200.0, description="In-band signal-to-noise ratio [dB] (or "
                                 "give `link` and `path_gain_db`).")
    duration_s: float | None = Field(
        None, ge=1e-15, le=1.0, description="Observation time T0 [s] (default 1 / tone_spacing_hz, i.e. W T0 = 1)."
    )
    relative_permittivity: float = Field(27.9, ge=1.0, le=1000.0, description="Relative permittivity [-].")
    link: LinkIn | None = Field(None, description="Derive the in-band SNR over the tone spacing from this link "
                                "instead.")
    path_gain_db: float | None = Field(None, ge=-400.0, le=20.0, description="With `link`: the channel's power "
                                       "gain, a profile's path_gain_db [dB].")


class RssBoundRequest(Strict):
    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={"examples": [{"shadowing_db": 2.236, "path_loss_exponent": 3.0, "distance_m": 0.1}]},
    )
    shadowing_db: float = Field(ge=0.0, le=100.0, description="Shadowing standard deviation sigma [dB].")
    path_loss_exponent: float = Field(ge=0.1, le=20.0, description="Path-loss exponent n [-].")
    distance_m: float = Field(ge=1e-6, le=100.0, description="True distance [m].")


class ToaBoundResponse(Out):
    sigma_s: float = Field(description="Bound on the delay std [s].")
    sigma_m: float = Field(description="Bound on the distance std [m].")
    snr_db: float | None = Field(None, description="The SNR the bound is for (given, or from `link`) [dB].")


class PdoaBoundResponse(Out):
    sigma_s: float = Field(description="Bound on the delay std, two-tone with carrier term [s].")
    sigma_m: float = Field(description="Bound on the distance std, two-tone with carrier term [m].")
    sigma_phase_difference_s: float = Field(description="Bound on the delay std from the tone spacing alone [s].")
    sigma_phase_difference_m: float = Field(description="Bound on the distance std from the tone spacing alone [m].")
    snr_db: float | None = Field(None, description="The SNR the bound is for (given, or from `link`) [dB].")


class RssBoundResponse(Out):
    sigma_m: float = Field(description="Bound on the distance std [m].")


# ----------------------------------------------------------------- catalogue
class TissueOut(Out):
    name: str
    relative_permittivity: float = Field(description="eps_r' [-].")
    conductivity_s_per_m: float = Field(description="Effective conductivity [S/m].")
    loss_tangent: float = Field(description="sigma / (w eps0 eps_r') [-].")
    phase_velocity_m_per_s: float = Field(description="Phase velocity [m/s].")
    attenuation_db_per_m: float = Field(description="Attenuation [dB/m].")
    wavelength_m: float = Field(description="Wavelength in the tissue [m].")


class TissuesResponse(Out):
    frequency_hz: float = Field(description="Frequency [Hz].")
    tissues: list[TissueOut]


class OrganOut(Out):
    name: str
    tissue: str | None = Field(None, description="Gabriel 1996 tissue, or null for an explicit medium.")
    relative_permittivity: float | None = Field(None, description="Explicit medium: eps_r' [-].")
    conductivity_s_per_m: float | None = Field(None, description="Explicit medium: conductivity [S/m].")
    triangles: int
    parent: str = Field(description="Containing organ, or `air`.")
    bounds_m: list[Vec3] = Field(description="Axis-aligned bounds [[xmin,ymin,zmin],[xmax,ymax,zmax]] [m].")


class SiteOut(Out):
    kind: Literal["capsule", "sensor"]
    position_m: Vec3 = Field(description="Position [m].")
    medium: str


class PhantomSummary(Out):
    id: str
    name: str
    description: str = ""
    builtin: bool
    triangles: int
    bounds_m: list[Vec3] = Field(description="Axis-aligned bounds [m].")


class PhantomOut(PhantomSummary):
    organs: list[OrganOut]
    sites: dict[str, SiteOut]


class PhantomsResponse(Out):
    phantoms: list[PhantomSummary]


class ScenarioOut(Out):
    id: str
    description: str
    phantom: str
    frequency_hz: float | None = Field(None, description="Carrier [Hz].")
    notes: str = Field("", description="Assumptions and what the case is meant to show.")
    request: dict[str, Any] = Field(description="The channel request fields this scenario supplies.")


class ScenariosResponse(Out):
    scenarios: list[ScenarioOut]


class ManifestTissue(Strict):
    tissue: Literal[TISSUE_NAMES] = Field(  # type: ignore[valid-type]
        description="Gabriel 1996 tissue (GET /v1/tissues)."
    )


class ManifestMedium(Strict):
    relative_permittivity: float = Field(ge=1.0, le=gltf.MAX_PERMITTIVITY, description="Explicit medium eps_r' [-].")
    conductivity_s_per_m: float = Field(
        0.0, ge=0.0, le=gltf.MAX_CONDUCTIVITY_S_PER_M, description="Explicit medium conductivity [S/m]."
    )


class ManifestSite(Strict):
    kind: Literal["capsule", "sensor"] | None = Field(
        None, description="Required for a site inside tissue (capsule, or a contact sensor in the skin); "
        "without it a site in air is a sensor."
    )
    position_m: Vec3 = Field(description="Position [m] (always metres, whatever `units`).")


class ManifestCentrelinePiece(Strict):
    organ: Name = Field(description="The organ (mesh node) this piece runs inside.")
    points: list[Vec3] = Field(min_length=2, max_length=20_000, description="Polyline vertices in `units`.")


class ManifestCentreline(Strict):
    pieces: list[ManifestCentrelinePiece] = Field(
        min_length=1, max_length=256, description="Pieces in travel order; the position jumps between pieces.")


class Manifest(Strict):
    """The JSON part of an upload (docs/api.md "POST /v1/phantoms").

    This model documents the manifest in the API schema; the one validator is
    ``raytrace.body.gltf.validate_manifest`` (with the loader's checks against the
    mesh), whose constants these bounds are."""

    model_config = ConfigDict(
        extra="forbid",
        allow_inf_nan=False,
        strict=True,
        json_schema_extra={
            "examples": [
                {
                    "name": "box with a sphere",
                    "units": "m",
                    "organs": {
                        "body": {"tissue": "muscle"},
                        "organ": {"relative_permittivity": 11.6, "conductivity_s_per_m": 0.08},
                    },
                    "sites": {
                        "capsule": {"kind": "capsule", "position_m": [0.0, 0.0, 0.01]},
                        "sensor": [0.0, -0.15, 0.0],
                    },
                }
            ]
        },
    )

    name: str = Field(min_length=1, max_length=gltf.MAX_NAME_CHARS, description="Human name of the phantom.")
    description: str = Field("", max_length=gltf.MAX_DESCRIPTION_CHARS)
    units: Literal[tuple(gltf.UNITS)] = Field(  # type: ignore[valid-type]
        description=f"Unit of the mesh coordinates (and of `[x, y, z]` sites); the mesh's largest extent in "
        f"metres must lie in {gltf.MIN_EXTENT_M:g}-{gltf.MAX_EXTENT_M:g} m."
    )
    organs: dict[Name, ManifestTissue | ManifestMedium] = Field(
        min_length=1, max_length=gltf.MAX_ORGANS, description="Mesh node name -> medium (a tissue, or an explicit one)."
    )
    sites: dict[Name, Vec3 | ManifestSite] = Field(
        default_factory=dict,
        max_length=gltf.MAX_SITES,
        description="Site name -> [x, y, z] in `units` (a site in air: a sensor), or {kind, position_m} with the "
        "position in metres (kind required inside tissue).",
    )
    centrelines: dict[Name, ManifestCentreline] = Field(
        default_factory=dict,
        max_length=16,
        description="Named paths through the organs (the GI tract: `gi_tract`); a capsule position may be given by "
        "arc length along one (sweeps). Every point must lie inside its piece's organ.",
    )


class UploadResponse(PhantomOut):
    pass


class Health(Out):
    status: Literal["ok"]


class Readiness(Out):
    status: Literal["ready", "starting"]
    phantoms: int
    scenarios: int
    ray_engine: str
    errors: list[str] = Field(default_factory=list, description="Built-ins that failed to load (the rest is served).")
