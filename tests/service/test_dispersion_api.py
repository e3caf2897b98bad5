"""The dispersion-true ranging over HTTP and the CLI (issue 18): profiles passed unchanged, link
budgets in ranging and bounds, channel outputs as JSON arrays and .npz / CSV, the
geometric-optics limit as a 422, TOA `all` consistent with each method alone."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from tests.service.test_api import assert_field

K_BOLTZMANN = 1.380649e-23

README_CHANNEL = {  # the README's torso request (fewer rays: the in-process app's limit)
    "phantom": "torso", "frequency_hz": 402e6,
    "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21},
    "transmitter": {"site": "small_intestine_1"},
    "receivers": [{"site": "belt_anterior"}, {"site": "belt_left"}],
    "max_interactions": 6, "rays": 5000, "dynamic_range_db": 80,
}


@pytest.fixture(scope="module")
def app_client(tmp_path_factory):
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    settings = Settings(data_dir=tmp_path_factory.mktemp("data"), log_level="warning", max_rays=5000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


@pytest.fixture(scope="module")
def readme_channel(app_client):
    r = app_client.post("/v1/channel", json=README_CHANNEL)
    assert r.status_code == 200, r.text
    return r.json()


def test_a_channel_profile_passed_unchanged_to_pdoa_uses_its_own_band(app_client, readme_channel):
    # README: "Pass a returned profiles[i] object unchanged as the profile of /v1/ranging/{toa,pdoa,rss}".
    prof = readme_channel["profiles"][0]
    assert prof["warnings"] and prof["smallest_organ"]  # 402 MHz: an organ below a wavelength is crossed
    for method in ("two_tone", "regression"):
        r = app_client.post("/v1/ranging/pdoa", json={"profile": prof, "method": method, "trials": 5, "seed": 1})
        assert r.status_code == 200, r.text
        assert r.json()["channel_model"] == "band_gains"
    # the regression over the profile's own 21 tones is the one over the same band given explicitly
    same = {"profile": prof, "method": "regression", "trials": 5, "seed": 1}
    a = app_client.post("/v1/ranging/pdoa", json=same).json()
    b = app_client.post("/v1/ranging/pdoa", json={**same, "band": README_CHANNEL["band"]}).json()
    assert a == b
    r = app_client.post("/v1/ranging/rss", json={"profile": prof, "trials": 5})
    assert r.status_code == 200, r.text
    # a hand-made profile has no band of its own: the 422 says what to give
    hand = {"paths": [{"delay_s": 1.3e-9, "gain": {"re": 1e-3, "im": 0}}]}
    assert_field(app_client.post("/v1/ranging/pdoa", json={"profile": hand}), 422, "body", "frequencies_hz")


def test_toa_all_reports_the_same_methods_as_each_alone(app_client, readme_channel):
    # method "all": the thesis' three in order, the top level is GCC's, and each result is exactly
    # what that method alone returns for the same seed (the same noise realisations).
    prof = readme_channel["profiles"][0]
    common = {"profile": prof, "trials": 10, "seed": 4, "true_distance_m": prof["geometric_distance_m"]}
    everything = app_client.post("/v1/ranging/toa", json={**common, "method": "all"}).json()
    assert [r["method"] for r in everything["results"]] == ["first_peak", "all_peaks", "gcc"]
    assert everything["method"] == "gcc" and everything["distance_m"] == everything["results"][2]["distance_m"]
    for r in everything["results"]:
        alone = app_client.post("/v1/ranging/toa", json={**common, "method": r["method"]}).json()
        assert alone["results"] == [r]
        assert r["channel_model"] == "band_gains" and r["snr_db"] == 30.0 and 0 < r["band_coverage"] < 1


def test_ranging_and_bounds_take_a_link_instead_of_an_snr(app_client, readme_channel):
    profiles = readme_channel["profiles"]
    link = {"transmit_power_dbm": -16.0, "noise_figure_db": 4.0, "temperature_k": 310.0}
    out = []
    for prof in profiles:
        r = app_client.post("/v1/ranging/toa", json={"profile": prof, "method": "gcc", "link": link, "trials": 5})
        assert r.status_code == 200, r.text
        gain_w = 10 ** (prof["path_gain_db"] / 10)
        hand = 10 * math.log10(1e-3 * 10 ** (-16 / 10) * gain_w / (K_BOLTZMANN * 310.0 * 10e9 * 10 ** 0.4))
        assert r.json()["snr_db"] == pytest.approx(hand, abs=0.01)  # kTBF over fs / 2 = 10 GHz
        out.append(r.json())
    assert out[1]["crlb_m"] > 10 * out[0]["crlb_m"]  # belt_left, 30 dB down: a wide bound
    both = {"profile": profiles[0], "method": "gcc", "link": link, "snr_db": 20, "trials": 5}
    assert_field(app_client.post("/v1/ranging/toa", json=both), 422, "body", "link")
    # bounds: the same figure from the link and path_gain_db over the request's bandwidth
    body = {"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 20e6, "link": link, "path_gain_db": -41.6}
    r = app_client.post("/v1/bounds/toa", json=body)
    assert r.status_code == 200, r.text
    hand = 10 * math.log10(1e-3 * 10 ** (-16 / 10) * 10 ** (-4.16) / (K_BOLTZMANN * 310.0 * 20e6 * 10 ** 0.4))
    assert r.json()["snr_db"] == pytest.approx(hand, abs=0.01)
    plain_body = {k: v for k, v in body.items() if k not in ("link", "path_gain_db")}
    plain = app_client.post("/v1/bounds/toa", json={**plain_body, "snr_db": r.json()["snr_db"]}).json()
    assert plain["sigma_m"] == pytest.approx(r.json()["sigma_m"], rel=1e-12)
    assert_field(app_client.post("/v1/bounds/toa", json={**body, "path_gain_db": None}), 422, "body", "path_gain_db")
    r = app_client.post("/v1/bounds/pdoa", json={"center_hz": 410e6, "tone_spacing_hz": 20e6, "link": {},
                                                 "path_gain_db": -73.7})
    assert r.status_code == 200, r.text
    hand = 10 * math.log10(25e-6 * 10 ** (-7.37) / (K_BOLTZMANN * 290.0 * 20e6))
    assert r.json()["snr_db"] == pytest.approx(hand, abs=0.01)


OUTPUTS_CHANNEL = {"scenario": "thesis-fig-5-6", "rays": 5000,
                   "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21},
                   "outputs": {"cfr": True, "cir": {"sample_rate_hz": 100e6, "num_samples": 8},
                               "taps": {"bandwidth_hz": 20e6, "l_min": -2, "l_max": 3}}}


def test_channel_outputs_are_json_arrays_with_absolute_delays(app_client):
    from estimators import PathProfile
    from estimators.channel_response import cfr, taps

    r = app_client.post("/v1/channel", json=OUTPUTS_CHANNEL)
    assert r.status_code == 200, r.text
    prof = r.json()["profiles"][0]
    f = np.linspace(400e6, 420e6, 21)
    # the arrays are the Python functions' values on the same profile (1e-12)
    paths = prof["paths"]
    p = PathProfile([x["delay_s"] for x in paths], [complex(x["gain"]["re"], x["gain"]["im"]) for x in paths],
                    band_frequencies_hz=f,
                    band_gains=[[complex(b["gain"]["re"], b["gain"]["im"]) for b in x["band_gains"]] for x in paths],
                    gains_include_delay_phase=True, reference_frequency_hz=402e6)
    got = np.array(prof["cfr"]["re"]) + 1j * np.array(prof["cfr"]["im"])
    np.testing.assert_allclose(got, cfr(p, f), rtol=1e-12)
    assert prof["cfr"]["frequency_hz"] == pytest.approx(list(f))
    ell, h = taps(p, 20e6, centre_hz=410e6, l_min=-2, l_max=3)
    assert prof["taps"]["l"] == list(ell) and prof["taps"]["delay_s"] == pytest.approx(list(ell / 20e6))
    np.testing.assert_allclose(np.array(prof["taps"]["re"]) + 1j * np.array(prof["taps"]["im"]), h, rtol=1e-12)
    assert prof["cir"]["time_s"] == pytest.approx([n / 100e6 for n in range(8)])  # absolute: from emission
    assert prof["cir"]["centre_hz"] == 410e6 and prof["cir"]["bandwidth_hz"] == 20e6
    # the profile, outputs and all, goes back into the ranging endpoints unchanged
    assert app_client.post("/v1/ranging/toa", json={"profile": prof, "trials": 3}).status_code == 200


@pytest.mark.parametrize("change, loc", [
    ({"band": None}, ("body", "band")),
    ({"outputs": {"taps": {"bandwidth_hz": 40e6}}}, ("body", "outputs", "taps", "bandwidth_hz")),
])
def test_channel_outputs_need_a_band_that_holds_them(app_client, change, loc):
    body = {**OUTPUTS_CHANNEL, **change}
    body = {k: v for k, v in body.items() if v is not None}
    assert_field(app_client.post("/v1/channel", json=body), 422, *loc)


@pytest.mark.parametrize("frequency_hz", [402, 1e4])
def test_a_frequency_where_geometric_optics_fails_is_a_422_naming_it(app_client, frequency_hz):
    body = {**README_CHANNEL, "frequency_hz": frequency_hz, "band": None}
    body = {k: v for k, v in body.items() if v is not None}
    detail = assert_field(app_client.post("/v1/channel", json=body), 422, "body", "frequency_hz")["detail"]
    assert "valid range" in detail[0]["msg"] and "geometric optics" in detail[0]["msg"]


def test_cli_exports_the_channel_outputs_as_npz_and_csv(tmp_path, monkeypatch, capsys):
    from service.cli import main

    monkeypatch.setenv("CAPSULE_RT_DATA_DIR", str(tmp_path / "data"))
    req = tmp_path / "req.json"
    req.write_text(json.dumps(OUTPUTS_CHANNEL))
    assert main(["channel", str(req), "--output", str(tmp_path / "out.json"), "--export", str(tmp_path / "o.npz")]) == 0
    assert main(["channel", str(req), "--output", str(tmp_path / "out.json"), "--export", str(tmp_path / "o.csv")]) == 0
    prof = json.loads((tmp_path / "out.json").read_text())["profiles"][0]
    data = np.load(tmp_path / "o.npz")
    np.testing.assert_array_equal(data["rx/cfr"], np.array(prof["cfr"]["re"]) + 1j * np.array(prof["cfr"]["im"]))
    np.testing.assert_array_equal(data["rx/taps_l"], prof["taps"]["l"])
    np.testing.assert_array_equal(data["rx/cir_time_s"], prof["cir"]["time_s"])
    with (tmp_path / "o.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 21 + 8 + 6
    taps_rows = [r for r in rows if r["output"] == "taps"]
    assert [int(r["index"]) for r in taps_rows] == prof["taps"]["l"]
    assert [float(r["re"]) for r in taps_rows] == prof["taps"]["re"]  # repr: exact round trip
    # a request without outputs has nothing to export: exit 2 naming export
    req.write_text(json.dumps({"scenario": "thesis-fig-5-6", "rays": 2000}))
    assert main(["channel", str(req), "--output", str(tmp_path / "x.json"), "--export", str(tmp_path / "x.npz")]) == 2
    assert "export" in capsys.readouterr().err
