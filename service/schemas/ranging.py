"""Models of ranging (POST /v1/ranging/{toa,pdoa,rss}: a channel profile in, distance estimates out) and
of the Cramér-Rao bounds (POST /v1/bounds/{toa,pdoa,rss}) (``docs/api.md`` "Ranging", "Bounds")."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import ConfigDict, Field, StringConstraints, model_validator

from estimators.link import MICS_EIRP_DBM
from estimators.pdoa import METHODS as PDOA_METHODS
from estimators.rss import CM2_MODELS
from estimators.toa import METHODS as TOA_METHODS
from service.limits import MAX_BAND_POINTS, MAX_PROFILE_PATHS, MAX_TRIALS, capped
from service.schemas import Band, FrequencyHz, Int, Out, Strict, Vec3, alternatives
from service.schemas.channel import CfrOut, CirOut, Interaction, Segment, TapsOut
from service.schemas.constants import FREQUENCY_MAX_HZ, FREQUENCY_MIN_HZ

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
        json_schema_extra=alternatives([{"properties": {"re": _NONZERO}}, {"properties": {"im": _NONZERO}}],
                                       keyword="anyOf")
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
    group_delay_s: float | None = Field(None, ge=-1e-3, le=1e-3, description="Absolute group delay [s] (as a channel "
                                        "profile gives it: the phase slope of the path's gain, negative in a "
                                        "dipole's reactive near field).")
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
        json_schema_extra=alternatives([
            {"properties": {"gains_include_delay_phase": {"const": False}}},
            {"required": ["gains_include_delay_phase", "reference_frequency_hz"],
             "properties": {"gains_include_delay_phase": {"const": True}}},
        ])
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
        "if lower).", json_schema_extra=capped("max_trials"),
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
    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
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
                    "waveform": {"kind": "tone_burst", "carrier_hz": 402e6, "duration_s": 25e-9,
                                 "sample_rate_hz": 20e9},
                }
            ]
        },
    )
    method: Literal[(*TOA_METHODS, "all")] = Field(  # type: ignore[valid-type]  # estimators.toa's registry
        "gcc",
        description="TOA estimator: `first_peak` (Eq 4.18), `all_peaks` (Eq 4.19-4.21), `gcc` (Eq 4.22-4.24), "
        "`envelope` (cross-correlation envelope only, no carrier phase), `all`: the thesis' three.",
    )
    waveform: Waveform = Field(default_factory=Waveform, description="Transmitted waveform.")


class PdoaRequest(RangingCommon):
    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
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
    method: Literal[PDOA_METHODS] = Field(  # type: ignore[valid-type]  # estimators.pdoa's methods
        "two_tone", description="PDOA estimator.")
    frequencies_hz: list[FrequencyHz] = Field(
        None,
        min_length=2,
        max_length=MAX_BAND_POINTS,
        json_schema_extra=capped("max_band_points", uniqueItems=True),
        description="Distinct tone frequencies [Hz], in any order (two_tone uses the lowest and the highest; "
        "regression needs them equally spaced). At most one of frequencies_hz and band; neither: the profile's band.",
    )
    band: Band = Field(
        None, description="Equally spaced tones (two_tone uses its ends). At most one of frequencies_hz and band; "
        "neither: the profile's band."
    )
    duration_s: float | None = Field(
        None, ge=1e-12, le=1e-3,
        description="Observation time per tone [s] (default: the estimator's, 1 / tone spacing)."
    )

    @model_validator(mode="after")
    def _tones(self) -> "PdoaRequest":
        if self.frequencies_hz is not None and self.band is not None:
            raise ValueError("give at most one of frequencies_hz or band (neither: the profile's own band)")
        if self.frequencies_hz is not None and len(set(self.frequencies_hz)) != len(self.frequencies_hz):
            raise ValueError("frequencies_hz must be distinct")
        return self


class RssRequest(RangingCommon):
    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
        json_schema_extra={
            "not": {"required": ["snr_db", "link"]},  # the link budget sets the SNR: not both
            "examples": [
                {"profile": _EXAMPLE_PROFILE, "model": "cm2_deep_tissue", "trials": 200, "seed": 1,
                 "true_distance_m": 0.076}
            ],
            **alternatives([
                {"required": ["profile"], "not": {"required": ["rss_dbm"]}},
                {"required": ["rss_dbm", "transmit_power_dbm"], "not": {"required": ["profile"]}},
            ]),
        },
    )
    model: Literal[tuple(CM2_MODELS)] = Field(  # type: ignore[valid-type]  # estimators.rss's models
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
def _snr_or_link(example: dict) -> dict:
    """The schema of a bound request: the SNR, or a link with the channel's gain, not both."""
    return {
        **alternatives([{"required": ["snr_db"], "properties": {"snr_db": {"type": "number"}}},
                        {"required": ["link", "path_gain_db"],
                         "properties": {"link": {"type": "object"}, "path_gain_db": {"type": "number"}}}],
                       keyword="anyOf"),
        "not": {"required": ["snr_db", "link"],
                "properties": {"snr_db": {"type": "number"}, "link": {"type": "object"}}},
        "examples": [example],
    }

class ToaBoundRequest(Strict):
    model_config = ConfigDict(json_schema_extra=_snr_or_link(
        {"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30, "relative_permittivity": 27.9}))
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
    model_config = ConfigDict(json_schema_extra=_snr_or_link(
        {"center_hz": 410e6, "tone_spacing_hz": 20e6, "snr_db": 30, "duration_s": 50e-9,
         "relative_permittivity": 27.9}))
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
    model_config = ConfigDict(  # Strict's rules are inherited; only the schema extras here
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
