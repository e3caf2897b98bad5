"""The validated inputs every Monte Carlo estimator shares (TOA, PDOA). Apart from the validators
(estimators._checks) because it needs the velocity (estimators.constants), which needs a validator:
together they were an import cycle."""

from __future__ import annotations

from typing import Any

from ._checks import LINK_SNR_FLOOR_DB, finite_float, generator, relative_permittivity, snr_db, trials_count
from .constants import velocity_m_per_s


class MonteCarloInputs:
    """The validated inputs every Monte Carlo estimator shares."""

    __slots__ = ("snr_db", "trials", "rng", "relative_permittivity", "velocity_m_per_s", "true_distance_m")

    def __init__(self, snr_db_value: Any, trials: Any, seed: Any, relative_permittivity_value: Any,
                 true_distance_m: Any, from_link: bool = False) -> None:
        self.snr_db = (snr_db(snr_db_value, "link", LINK_SNR_FLOOR_DB) if from_link
                       else snr_db(snr_db_value))
        self.trials = trials_count(trials)
        self.rng = generator(seed)
        self.relative_permittivity = relative_permittivity(relative_permittivity_value)
        self.velocity_m_per_s = velocity_m_per_s(self.relative_permittivity)
        self.true_distance_m = (None if true_distance_m is None
                                else finite_float(true_distance_m, "true_distance_m", nonnegative=True))
