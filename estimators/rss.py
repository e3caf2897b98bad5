"""RSS ranging: inversion of the IEEE 802.15.6 CM2 implant path-loss model (thesis Eq 2.2, Table 2.2).

    PL(d) = PL(d0) + 10 n log10(d / d0) + S,   S ~ N(0, sigma^2) dB,   d0 = 0.05 m

    deep tissue:   PL(d0) = 47.14 dB, n = 4.26, sigma = 7.85 dB
    near surface:  PL(d0) = 49.81 dB, n = 4.22, sigma = 6.81 dB

The path loss comes from the profile (PL = -10 log10 sum_k |a_k|^2, the
incoherent received power of all paths over unit transmitted power) or from a
measured RSS and the transmit power (PL = P_tx - RSS). Each Monte Carlo trial
draws a shadowing term S and inverts

    d_hat = d0 10^((PL + S - PL(d0)) / (10 n)),

so the estimates are log-normal around the median d0 10^((PL - PL(d0)) / (10 n))
(their mean is larger by exp((ln 10 sigma / (10 n))^2 / 2)). The bound is
ln(10) sigma d / (10 n) (bounds.rss_crlb).

Note the model's PL includes whatever antenna gains IEEE CM2 measured with;
the profile's path gain (Friis-normalised, isotropic antennas) is not
calibrated against it, so RSS distances from a traced profile are only as
good as that match -- which is the point of exposing them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import Check, checkpoint, finite_float, generator, trials_count
from .bounds import rss_crlb
from .errors import EstimatorInputError
from .profile import PathProfile
from .results import RSSResult, summarise

REFERENCE_DISTANCE_M = 0.05


@dataclass(frozen=True)
class PathLossModel:
    name: str
    path_loss_d0_db: float
    exponent: float
    shadowing_db: float
    reference_distance_m: float = REFERENCE_DISTANCE_M

    def median_distance_m(self, path_loss_db):
        """Invert PL(d) without shadowing."""
        return self.reference_distance_m * 10.0 ** ((np.asarray(path_loss_db) - self.path_loss_d0_db)
                                                    / (10.0 * self.exponent))

    def path_loss_db(self, distance_m):
        """PL(d) without shadowing (the forward model)."""
        return self.path_loss_d0_db + 10.0 * self.exponent * np.log10(np.asarray(distance_m)
                                                                     / self.reference_distance_m)


CM2_MODELS = {
    "cm2_deep_tissue": PathLossModel("cm2_deep_tissue", 47.14, 4.26, 7.85),
    "cm2_near_surface": PathLossModel("cm2_near_surface", 49.81, 4.22, 6.81),
}


def estimate_rss(profile: PathProfile | None = None, *, rss_dbm: float | None = None,
                 transmit_power_dbm: float | None = None, model: "str | PathLossModel" = "cm2_deep_tissue",
                 trials: int = 100, seed=0, true_distance_m: float | None = None,
                 shadowing: bool = True, return_estimates: bool = False,
                 check: Check = None) -> RSSResult:
    """Monte Carlo RSS ranging (docs/api.md POST /v1/ranging/rss).

    Give ``profile`` (path loss = -path gain; ``transmit_power_dbm`` is then not
    needed) or ``rss_dbm`` together with ``transmit_power_dbm``. ``model`` is
    ``cm2_deep_tissue`` | ``cm2_near_surface``, or a :class:`PathLossModel` (one fitted to a
    phantom: ``sweeps.pathloss.fit_path_loss``). ``shadowing=False`` gives the
    deterministic inversion in every trial. trials 1..10000, seed int >= 0 or Generator.
    ``check`` (``estimators._checks.Check``) is called once before the draws (they take
    microseconds).
    """
    if isinstance(model, PathLossModel):  # e.g. one fitted to a phantom (sweeps.pathloss)
        m = model
        finite_float(m.path_loss_d0_db, "model.path_loss_d0_db")
        finite_float(m.exponent, "model.exponent", positive=True)
        finite_float(m.shadowing_db, "model.shadowing_db", nonnegative=True)
        finite_float(m.reference_distance_m, "model.reference_distance_m", positive=True)
        model = m.name
    elif model not in CM2_MODELS:
        raise EstimatorInputError(f"unknown model {model!r} ({' | '.join(CM2_MODELS)})", "model")
    else:
        m = CM2_MODELS[model]
    if (profile is None) == (rss_dbm is None):
        raise EstimatorInputError("give exactly one of profile or rss_dbm", "profile")
    if profile is not None:
        if not isinstance(profile, PathProfile):
            raise EstimatorInputError("must be a PathProfile", "profile")
        path_loss = -profile.path_gain_db
    else:
        rss = finite_float(rss_dbm, "rss_dbm")
        if transmit_power_dbm is None:
            raise EstimatorInputError("required with rss_dbm (path loss = transmit power - RSS)",
                                      "transmit_power_dbm")
        path_loss = finite_float(transmit_power_dbm, "transmit_power_dbm") - rss
    n_trials = trials_count(trials)
    rng = generator(seed)
    if true_distance_m is not None:
        true_distance_m = finite_float(true_distance_m, "true_distance_m", positive=True)

    checkpoint(check)
    s = m.shadowing_db * rng.standard_normal(n_trials) if shadowing else np.zeros(n_trials)
    est = m.median_distance_m(path_loss + s)
    median = float(m.median_distance_m(path_loss))
    stats = summarise(est, true_distance_m)
    crlb = rss_crlb(m.shadowing_db, m.exponent, true_distance_m if true_distance_m is not None else median).sigma_m
    return RSSResult(method="rss", model=model, distance_m=stats.distance_m, median_distance_m=median,
                     path_loss_db=float(path_loss), std_m=stats.std_m, error_m=stats.error_m,
                     rmse_m=stats.rmse_m, crlb_m=crlb, trials=n_trials,
                     estimates_m=est if return_estimates else None)
