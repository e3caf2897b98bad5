"""Link budgets (estimators.link, docs/science.md (S24)) against the hand-computed kTBF figure."""

from __future__ import annotations

import math

import pytest

from estimators import EstimatorInputError, PathProfile, estimate_pdoa, estimate_toa, toa_crlb
from estimators.link import LinkBudget, link_snr_db

K_BOLTZMANN = 1.380649e-23  # J/K, exact (SI 2019), written here: the oracle shares nothing with the code


def _hand_snr_db(p_tx_w, gain_db, temperature_k, bandwidth_hz, nf_db):
    """P_r / (k T B F) by hand, in watts, then in dB."""
    p_rx_w = p_tx_w * 10 ** (gain_db / 10)
    noise_w = K_BOLTZMANN * temperature_k * bandwidth_hz * 10 ** (nf_db / 10)
    return 10 * math.log10(p_rx_w / noise_w)


def test_snr_from_a_link_budget_is_the_kTBF_figure():
    # 25 uW (the MICS EIRP limit, the default) through -41.6 dB into kTBF at 310 K, 20 MHz, 6 dB.
    # Tolerance 0.01 dB (the issue's); the two computations agree to rounding (~1e-13 dB).
    link = LinkBudget(noise_figure_db=6.0, temperature_k=310.0, bandwidth_hz=20e6)
    assert link.transmit_power_dbm == pytest.approx(10 * math.log10(25e-6 / 1e-3), abs=1e-12)  # -16.02 dBm
    expected = _hand_snr_db(25e-6, -41.6, 310.0, 20e6, 6.0)
    assert link.snr_db(-41.6) == pytest.approx(expected, abs=0.01)
    # the defaults: 290 K, 0 dB noise figure, the bandwidth the caller passes (the method's)
    assert LinkBudget().snr_db(-73.7, 10e9) == pytest.approx(_hand_snr_db(25e-6, -73.7, 290.0, 10e9, 0.0), abs=0.01)
    assert link_snr_db(None, -41.6, 20e6, 30.0) == 30.0  # no link: the SNR given


def test_each_sensor_gets_its_own_snr_and_a_deep_shadow_a_wide_bound():
    # Two single-path sensors 32 dB apart in path gain (the README's belt_anterior / belt_left),
    # TOA with the default 25 ns burst at 20 GS/s: the link's noise bandwidth is fs / 2 (the
    # per-sample SNR's), so snr_db = the kTBF figure over 10 GHz; the shadowed sensor's SNR is
    # 32 dB lower and its bound 10^(32/20) = 40 x wider (sigma ~ 1 / sqrt(SNR), (S15)).
    near = PathProfile([2.45e-9], [10 ** (-41.6 / 20)])
    far = PathProfile([4.17e-9], [10 ** (-73.7 / 20)])
    link = {"transmit_power_dbm": -16.0, "noise_figure_db": 5.0}
    (a,) = estimate_toa(near, method="gcc", link=link, trials=20, seed=1)
    (b,) = estimate_toa(far, method="gcc", link=link, trials=20, seed=1)
    assert a.snr_db == pytest.approx(_hand_snr_db(10 ** (-16 / 10) * 1e-3, -41.6, 290.0, 10e9, 5.0), abs=0.01)
    assert b.snr_db == pytest.approx(_hand_snr_db(10 ** (-16 / 10) * 1e-3, -73.7, 290.0, 10e9, 5.0), abs=0.01)
    assert b.crlb_m / a.crlb_m == pytest.approx(10 ** ((73.7 - 41.6) / 20), rel=1e-9)
    assert b.crlb_m == pytest.approx(toa_crlb(402e6, 25e-9, 10e9, b.snr_db).sigma_m, rel=1e-12)
    assert b.std_m > 10 * a.std_m  # and the Monte Carlo spread follows


def test_pdoa_link_uses_the_tones_span_as_noise_bandwidth():
    p = PathProfile([1.339e-9], [0.01])
    band = {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}
    r = estimate_pdoa(p, band=band, method="regression", link={"noise_figure_db": 3.0}, trials=5)
    assert r.snr_db == pytest.approx(_hand_snr_db(25e-6, -40.0, 290.0, 20e6, 3.0), abs=0.01)


@pytest.mark.parametrize("link, field", [
    ({"noise_figure_db": -1}, "link.noise_figure_db"),
    ({"temperature_k": 0}, "link.temperature_k"),
    ({"bandwidth_hz": float("nan")}, "link.bandwidth_hz"),
    ({"transmit_power_dbm": 500}, "link.transmit_power_dbm"),
    ({"power": 1}, "link"),
])
def test_bad_links_raise_naming_the_field(link, field):
    with pytest.raises(EstimatorInputError) as exc:
        estimate_toa(PathProfile([1e-9], [0.1]), method="gcc", link=link, trials=2)
    assert exc.value.field == field
