"""Link budget: each sensor's SNR from its own path gain (docs/science.md "Link budget").

A ranging or bound request may describe the radio link instead of giving an SNR:

    P_r = P_t G,    N = k T B F,    SNR = P_r / N,

in decibels

    snr_db = P_t,dBm + G_dB - (10 log10(k T B / 1 mW) + F_dB)           (S24)

with P_t the transmit power (default the MICS limit, 25 uW EIRP = -16.02 dBm:
ETSI EN 301 839 / FCC 47 CFR 95.2565, the capsule's band), G the channel's power
gain between isotropic antennas (a profile's ``path_gain_db``, 10 log10 sum_k |a_k|^2:
the incoherent sum of its paths), k Boltzmann's constant, T the noise temperature
(default 290 K, the reference temperature noise figures are quoted at, IEEE Std
100), B the receiver's noise bandwidth and F its noise figure (default 0 dB: the
thermal floor of an ideal receiver; a real one adds its own, typically 3-10 dB).

B defaults to the bandwidth the method's SNR is defined over, so that the SNR handed
to the method means what the method assumes: TOA's per-sample SNR is over W = fs / 2
(docs/science.md (S4)), PDOA's in-band SNR over the tones' span W, a TOA bound's over
its ``bandwidth_hz``, a PDOA bound's over its tone spacing. With those, the bounds'
E/N0 = SNR W T0 = P_r T0 / (k T F): the bandwidth cancels, as it should.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

from ._checks import finite_float
from .errors import EstimatorInputError

BOLTZMANN_J_PER_K = 1.380649e-23
"""k, exact (SI 2019)."""

MICS_EIRP_W = 25e-6
"""MICS (402-405 MHz) EIRP limit, 25 uW (ETSI EN 301 839, FCC 47 CFR 95.2565)."""

MICS_EIRP_DBM = 10.0 * math.log10(MICS_EIRP_W / 1e-3)
"""The same in dBm: -16.02 dBm."""

REFERENCE_TEMPERATURE_K = 290.0
"""T0 of noise figures (IEEE Std 100)."""


@dataclass(frozen=True)
class LinkBudget:
    """Transmit power, receiver noise figure, noise temperature and (optionally) the noise
    bandwidth of (S24). Each sensor's SNR then follows from its own path gain."""

    transmit_power_dbm: float = MICS_EIRP_DBM
    noise_figure_db: float = 0.0
    temperature_k: float = REFERENCE_TEMPERATURE_K
    bandwidth_hz: float | None = None

    def __post_init__(self) -> None:
        p = finite_float(self.transmit_power_dbm, "link.transmit_power_dbm")
        if not -100.0 <= p <= 60.0:
            raise EstimatorInputError(f"must lie in [-100, 60] dBm, got {p!r}", "link.transmit_power_dbm")
        nf = finite_float(self.noise_figure_db, "link.noise_figure_db", nonnegative=True)
        if nf > 60.0:
            raise EstimatorInputError(f"must lie in [0, 60] dB, got {nf!r}", "link.noise_figure_db")
        t = finite_float(self.temperature_k, "link.temperature_k", positive=True)
        if not 1.0 <= t <= 1e4:
            raise EstimatorInputError(f"must lie in [1, 10000] K, got {t!r}", "link.temperature_k")
        b = None if self.bandwidth_hz is None else finite_float(self.bandwidth_hz, "link.bandwidth_hz", positive=True)
        if b is not None and b < 1.0:
            raise EstimatorInputError(f"a noise bandwidth is at least 1 Hz, got {b:g}", "link.bandwidth_hz")
        for name, value in (("transmit_power_dbm", p), ("noise_figure_db", nf), ("temperature_k", t),
                            ("bandwidth_hz", b)):
            object.__setattr__(self, name, value)

    def noise_power_dbm(self, bandwidth_hz: float | None = None) -> float:
        """10 log10(k T B / 1 mW) + F: the receiver's noise power over ``bandwidth_hz``
        (default: this link's own ``bandwidth_hz``, which is then required)."""
        b = self.bandwidth_hz if self.bandwidth_hz is not None else bandwidth_hz
        if b is None:
            raise EstimatorInputError("a noise bandwidth is needed (no default here)", "link.bandwidth_hz")
        b = finite_float(b, "link.bandwidth_hz", positive=True)
        return 10.0 * math.log10(BOLTZMANN_J_PER_K * self.temperature_k * b / 1e-3) + self.noise_figure_db

    def snr_db(self, path_gain_db: float, bandwidth_hz: float | None = None) -> float:
        """(S24): P_t + G - N [dB] for a channel of power gain ``path_gain_db``; the noise
        bandwidth is this link's ``bandwidth_hz``, else ``bandwidth_hz`` (the method's)."""
        g = float(path_gain_db)
        if math.isnan(g) or g == math.inf:
            raise EstimatorInputError(f"the channel's path gain must be a number, got {g!r}", "profile")
        return self.transmit_power_dbm + g - self.noise_power_dbm(bandwidth_hz)


def make_link(spec: LinkBudget | Mapping | None) -> LinkBudget | None:
    """A :class:`LinkBudget` from itself, a dict of its fields (the requests' ``link``), or None."""
    if spec is None or isinstance(spec, LinkBudget):
        return spec
    if not isinstance(spec, Mapping):
        raise EstimatorInputError("must be an object {transmit_power_dbm, noise_figure_db, temperature_k, "
                                  "bandwidth_hz}", "link")
    known = {f.name for f in fields(LinkBudget)}
    extra = set(spec) - known
    if extra:
        raise EstimatorInputError(f"unknown field(s) {sorted(extra)}", "link")
    return LinkBudget(**{k: v for k, v in spec.items() if v is not None})


def link_snr_db(link: LinkBudget | Mapping | None, path_gain_db: float, bandwidth_hz: float | None,
                snr_db: float | None) -> float | None:
    """The SNR a method runs at: (S24) from ``link`` when one is given, else ``snr_db`` as is.

    SNRs below the estimators' floor of -50 dB (a sensor in deep shadow) are returned as
    they are: the caller decides (the ranging estimators refuse them naming ``link``, the
    bounds evaluate them)."""
    link = make_link(link)
    if link is None:
        return snr_db
    return link.snr_db(path_gain_db, bandwidth_hz)
