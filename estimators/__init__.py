"""CapsuleRT estimators: TOA / PDOA / RSS ranging and Cramér-Rao bounds as pure functions.

Input is a channel profile (no dependency on the tracer or the service):

    PathProfile(delays_s, gains, band_frequencies_hz=None, band_gains=None,
                gains_include_delay_phase=False, reference_frequency_hz=None, group_delays_s=None)
        .channel_model -> "band_gains" | "group_delay" | "non_dispersive"   (how H(f) is known)
        .frequency_response(frequencies_hz) -> complex H(f)

Ranging (Monte Carlo, vectorised over trials, seeded; return result dataclasses):

    estimate_toa(profile, method="all"|"first_peak"|"all_peaks"|"gcc"|"envelope",
                 waveform=ToneBurst()|GaussianPulse()|dict, snr_db=30.0, trials=100, seed=0,
                 relative_permittivity=27.9, true_distance_m=None,
                 return_estimates=False, link=None, check=None) -> list[TOAResult]
    toa_samples(profile, waveform=None) -> int      (samples per trial: the unit of TOA work)
    estimate_pdoa(profile, frequencies_hz=None, band=None, method="two_tone"|"regression",
                  snr_db=30.0, trials=100, seed=0, relative_permittivity=27.9,
                  true_distance_m=None, duration_s=None, return_estimates=False, link=None, check=None) -> PDOAResult

    The TOA waveform goes through the profile's own H(f) (dispersion, Fresnel, absorption at
    every frequency when the profile has band gains); PDOA's tones default to the profile's band.
    ``link=LinkBudget(...)`` (or its dict) replaces ``snr_db`` by P_t + G - kTBF.
    ``check`` (a callable raising to stop) is called inside the Monte Carlo loops (service deadlines).
    estimate_rss(profile=None, *, rss_dbm=None, transmit_power_dbm=None,
                 model="cm2_deep_tissue"|"cm2_near_surface", trials=100, seed=0,
                 true_distance_m=None, shadowing=True, return_estimates=False, check=None) -> RSSResult

``check`` (optional) is the stop protocol of the long loops: a no-argument callable
called between chunks of work that raises to stop the computation (a deadline, a
client that went away); the exception propagates unchanged. The estimators know
nothing of who calls them.

Bounds (closed forms, derivations in estimators.bounds):

    toa_crlb(carrier_hz, duration_s, bandwidth_hz, snr_db, relative_permittivity=27.9, delay_s=0.0)
        -> TOABound(sigma_s, sigma_m)                                     (Eq 4.16-4.17, w = 2 pi f)
    pdoa_crlb(center_hz, tone_spacing_hz, snr_db, duration_s=None, relative_permittivity=27.9)
        -> PDOABound(sigma_s, sigma_m, sigma_phase_difference_s, sigma_phase_difference_m)  (Eq 5.16)
    multitone_crlb(frequencies_hz, snr_db, duration_s=None, relative_permittivity=27.9) -> PDOABound
    rss_crlb(shadowing_db, path_loss_exponent, distance_m) -> RSSBound(sigma_m)
    waveform_toa_crlb(waveform, snr_db, bandwidth_hz, relative_permittivity=27.9,
                      carrier_phase_known=True) -> TOABound

Channel outputs (estimators.channel_response; Sionna RT's cfr / cir / taps, absolute delays):

    cfr(profile, frequencies_hz) -> H(f)
    cir(profile, sample_rate_hz, bandwidth_hz=None, centre_hz=None, ...) -> (times_s, h)
    taps(profile, bandwidth_hz, centre_hz=None, l_min=None, l_max=None) -> (l, h_l)

Results carry method, distance_m (mean), delay_s, std_m, error_m / rmse_m
(with true_distance_m), crlb_m, trials, snr_db (the SNR used), channel_model
(TOA also band_coverage) and optionally estimates_m; PDOAResult
adds max_unambiguous_range_m, crlb_phase_difference_m, wrapped and
wrap_reason; RSSResult adds model, path_loss_db, median_distance_m.

Conventions: SNR definitions are in estimators.waveforms (TOA: per-sample,
W = fs/2) and estimators.pdoa (in-band, E/N0 = SNR W T0); profile gain phase
conventions in estimators.profile. Randomness only from ``seed``.

Errors: every invalid input raises EstimatorInputError (a ValueError) with
``.field`` (dotted request path) and ``.reason``; map it to HTTP 422.
"""

from .bounds import PDOABound, RSSBound, TOABound, multitone_crlb, pdoa_crlb, rss_crlb, toa_crlb, waveform_toa_crlb
from .channel_response import cfr, cir, taps
from .constants import DEFAULT_RELATIVE_PERMITTIVITY, SPEED_OF_LIGHT_M_PER_S, velocity_m_per_s
from .errors import EstimatorInputError
from .link import MICS_EIRP_DBM, LinkBudget
from .pdoa import estimate_pdoa
from .profile import PathProfile, single_path
from .results import PDOAResult, RSSResult, TOAResult
from .rss import CM2_MODELS, estimate_rss
from .toa import estimate_toa, make_waveform, toa_samples
from .waveforms import GaussianPulse, ToneBurst

__all__ = [
    "CM2_MODELS", "DEFAULT_RELATIVE_PERMITTIVITY", "EstimatorInputError", "GaussianPulse", "LinkBudget",
    "MICS_EIRP_DBM", "PDOABound", "PDOAResult", "PathProfile", "RSSBound", "RSSResult", "SPEED_OF_LIGHT_M_PER_S",
    "TOABound", "TOAResult", "ToneBurst", "cfr", "cir", "estimate_pdoa", "estimate_rss", "estimate_toa",
    "make_waveform", "multitone_crlb", "pdoa_crlb", "rss_crlb", "single_path", "taps", "toa_crlb", "toa_samples",
    "velocity_m_per_s", "waveform_toa_crlb",
]
