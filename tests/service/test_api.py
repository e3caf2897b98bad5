"""In-process API tests: catalogue, bounds, channel, ranging, errors, limits, metrics, request ids.

Uploads are in tests/service/test_uploads.py, saturation in tests/service/test_saturation.py.
Every bad request must get a 4xx whose ``detail[].loc`` names the field.
"""

from __future__ import annotations

import cmath
import json
import math

import pytest

from service.schemas.channel import ChannelResponse

C0 = 299_792_458.0

SMALL_CHANNEL = {
    "phantom": "torso",
    "transmitter": {"site": "small_intestine_1"},
    "receivers": [{"site": "belt_anterior"}, {"name": "side", "site": "belt_left"}],
    "rays": 2000,
    "max_interactions": 6,  # small intestine -> cavity -> muscle -> fat -> skin: 4 refractions
}

PROFILE = {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}},
                     {"delay_s": 2.0e-9, "gain": {"re": -2e-4, "im": 1e-4}}]}


def assert_field(response, status: int, *field: str | int) -> dict:
    """The response has ``status`` and some detail item whose loc contains ``field`` in order."""
    assert response.status_code == status, response.text
    body = response.json()
    assert isinstance(body["detail"], list) and body["detail"], body
    for item in body["detail"]:
        assert set(item) == {"loc", "msg", "type"}, item
        assert item["msg"]
    locs = [item["loc"] for item in body["detail"]]
    want = list(field)
    assert any(
        any(loc[i : i + len(want)] == want for i in range(len(loc) - len(want) + 1)) for loc in locs
    ), f"no detail names {want}: {locs}"
    return body


def post_raw(api, path: str, text: str):
    return api.post(path, content=text.encode(), headers={"content-type": "application/json"})


# ------------------------------------------------------------------ operations
def test_healthz_readyz_and_request_id(api):
    r = api.get("/healthz", headers={"X-Request-ID": "trace-42"})
    assert r.status_code == 200 and r.json() == {"status": "ok"}
    assert r.headers["x-request-id"] == "trace-42"
    r = api.get("/healthz", headers={"X-Request-ID": "bad id with spaces/and\\slashes"})
    assert r.headers["x-request-id"] != "bad id with spaces/and\\slashes"
    assert len(r.headers["x-request-id"]) == 32  # a fresh uuid4 hex
    r = api.get("/readyz")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ready" and body["phantoms"] >= 1 and body["ray_engine"] == "embree"


def test_metrics_count_routes_by_template_and_rays(api):
    api.get("/v1/phantoms/torso")
    api.get("/v1/phantoms/does-not-exist")
    r = api.post("/v1/channel", json=SMALL_CHANNEL)
    assert r.status_code == 200, r.text
    text = api.get("/metrics").text
    assert 'capsule_rt_http_requests_total{method="GET",route="/v1/phantoms/{phantom_id}",status="200"} 1.0' in text
    assert 'capsule_rt_http_requests_total{method="GET",route="/v1/phantoms/{phantom_id}",status="404"} 1.0' in text
    assert "capsule_rt_http_request_duration_seconds_bucket" in text
    rays = [line for line in text.splitlines() if line.startswith("capsule_rt_rays_launched_total ")]
    assert rays and float(rays[0].split()[1]) == r.json()["stats"]["rays_launched"] > 0
    assert "capsule_rt_compute_in_flight 0.0" in text
    assert "capsule_rt_compute_queue_depth 0.0" in text


def test_json_log_lines_carry_the_request_id():
    import logging

    from service.logs import JsonFormatter, request_id_var

    token = request_id_var.set("rid-7")
    try:
        record = logging.makeLogRecord({"name": "capsule_rt.test", "levelname": "INFO", "msg": "hello %s",
                                        "args": ("x",), "route": "/v1/x"})
        line = json.loads(JsonFormatter().format(record))
    finally:
        request_id_var.reset(token)
    assert line["request_id"] == "rid-7" and line["msg"] == "hello x" and line["route"] == "/v1/x"


def test_unknown_route_and_method_are_json_errors(api):
    assert_field(api.get("/v1/nothing"), 404, "path")
    r = api.put("/v1/channel", json={})
    assert r.status_code == 405 and r.json()["detail"][0]["type"] == "method_not_allowed"


# ------------------------------------------------------------------ catalogue
def test_tissues_at_402_mhz_match_the_plane_wave_closed_forms(api):
    f = 402e6
    r = api.get("/v1/tissues", params={"frequency_hz": f})
    assert r.status_code == 200
    body = r.json()
    names = [t["name"] for t in body["tissues"]]
    assert len(names) == 27 and "muscle" in names and names[-1] == "air"
    eps0 = 8.8541878128e-12
    for t in body["tissues"]:
        # Oracle: k = (w/c) sqrt(eps' - j sigma/(w eps0)) with cmath, independent of raytrace.physics.em.
        w = 2 * math.pi * f
        n = cmath.sqrt(complex(t["relative_permittivity"], -t["conductivity_s_per_m"] / (w * eps0)))
        assert t["phase_velocity_m_per_s"] == pytest.approx(C0 / n.real, rel=1e-9)
        assert t["wavelength_m"] == pytest.approx(C0 / (f * n.real), rel=1e-9)
        assert t["attenuation_db_per_m"] == pytest.approx(20 * math.log10(math.e) * w / C0 * abs(n.imag),
                                                          rel=1e-9, abs=1e-12)
    muscle = next(t for t in body["tissues"] if t["name"] == "muscle")
    # IFAC-CNR calculator, muscle at 402 MHz: eps' 57.1, sigma 0.797 S/m (3 digits published).
    assert muscle["relative_permittivity"] == pytest.approx(57.1, abs=0.05)
    assert muscle["conductivity_s_per_m"] == pytest.approx(0.797, abs=0.001)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "abc", "1e12", "1"])
def test_tissues_rejects_bad_frequencies(api, value):
    assert_field(api.get("/v1/tissues", params={"frequency_hz": value}), 422, "query", "frequency_hz")


def test_tissues_requires_the_frequency(api):
    assert_field(api.get("/v1/tissues"), 422, "query", "frequency_hz")


def test_phantoms_and_scenarios(api):
    phantoms = api.get("/v1/phantoms").json()["phantoms"]
    torso = next(p for p in phantoms if p["id"] == "torso")
    assert torso["builtin"] and torso["triangles"] > 1000
    detail = api.get("/v1/phantoms/torso").json()
    assert {o["name"] for o in detail["organs"]} >= {"skin", "small_intestine"}
    kinds = {s["kind"] for s in detail["sites"].values()}
    assert kinds == {"capsule", "sensor"}
    for site in detail["sites"].values():
        assert (site["medium"] == "skin") == (site["kind"] == "sensor")  # contact sensors, mid-skin
    r = api.get("/v1/scenarios")
    assert r.status_code == 200
    for sc in r.json()["scenarios"]:
        assert sc["description"] and sc["phantom"]


@pytest.mark.parametrize("pid", ["does-not-exist", "up-0000000000000000"])
def test_unknown_phantom_is_404(api, pid):
    assert_field(api.get(f"/v1/phantoms/{pid}"), 404, "path", "phantom_id")
    assert_field(api.get(f"/v1/phantoms/{pid}/mesh"), 404, "path", "phantom_id")


@pytest.mark.parametrize("pid", ["..", "UP-X", "a%2F..%2Fb", "%2E%2E", "a.b", "x" * 65, "-lead"])
def test_phantom_ids_with_path_characters_never_reach_the_filesystem(api, pid):
    for method in ("get", "delete"):
        r = getattr(api, method)(f"/v1/phantoms/{pid}")
        assert 400 <= r.status_code < 500, (pid, r.status_code)
        assert r.json()["detail"][0]["loc"][0] == "path"


def test_builtin_phantom_cannot_be_deleted(api):
    assert_field(api.delete("/v1/phantoms/torso"), 409, "path", "phantom_id")
    assert api.get("/v1/phantoms/torso").status_code == 200


def test_builtin_mesh_is_a_glb_with_organ_nodes(api):
    import io

    import trimesh

    r = api.get("/v1/phantoms/torso/mesh")
    assert r.status_code == 200 and r.headers["content-type"] == "model/gltf-binary"
    assert r.content[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(r.content), file_type="glb", force="scene")
    organs = {o["name"] for o in api.get("/v1/phantoms/torso").json()["organs"]}
    assert organs <= set(scene.graph.nodes_geometry)


# ------------------------------------------------------------------ bounds
def test_bounds_reproduce_the_science_md_numbers(api):
    # docs/science.md: 402 MHz, W = 10 GHz, T0 = 25 ns, SNR 30 dB, eps_r 27.9 -> about 0.032 mm.
    r = api.post("/v1/bounds/toa", json={"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9,
                                         "snr_db": 30, "relative_permittivity": 27.9})
    assert r.status_code == 200
    assert r.json()["sigma_m"] == pytest.approx(0.032e-3, rel=0.02)
    assert r.json()["sigma_m"] == pytest.approx(r.json()["sigma_s"] * C0 / math.sqrt(27.9), rel=1e-12)
    # docs/science.md: f0 = 410 MHz, W = 20 MHz, SNR 30 dB, W T0 = 1 -> about 0.49 mm.
    r = api.post("/v1/bounds/pdoa", json={"center_hz": 410e6, "tone_spacing_hz": 20e6, "snr_db": 30})
    assert r.status_code == 200
    assert r.json()["sigma_m"] == pytest.approx(0.49e-3, rel=0.02)
    assert r.json()["sigma_phase_difference_m"] > r.json()["sigma_m"]
    # docs/science.md: sigma = sqrt 5 dB, n = 3, d = 0.1 m -> 0.017 m.
    r = api.post("/v1/bounds/rss", json={"shadowing_db": math.sqrt(5), "path_loss_exponent": 3, "distance_m": 0.1})
    assert r.status_code == 200
    assert r.json()["sigma_m"] == pytest.approx(0.017, rel=0.02)


@pytest.mark.parametrize(
    "path, body, field",
    [
        ("/v1/bounds/toa", {"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9}, "snr_db"),
        ("/v1/bounds/toa", {"carrier_hz": -1, "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30}, "carrier_hz"),
        ("/v1/bounds/toa", {"carrier_hz": "fast", "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30},
         "carrier_hz"),
        ("/v1/bounds/pdoa", {"center_hz": 410e6, "tone_spacing_hz": 900e6, "snr_db": 30}, "tone_spacing_hz"),
        ("/v1/bounds/pdoa", {"center_hz": 410e6, "tone_spacing_hz": 20e6, "snr_db": 30, "bogus": 1}, "bogus"),
        ("/v1/bounds/rss", {"shadowing_db": 2, "path_loss_exponent": 3, "distance_m": 0}, "distance_m"),
    ],
)
def test_bounds_reject_bad_inputs(api, path, body, field):
    assert_field(api.post(path, json=body), 422, "body", field)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_numbers_are_rejected_everywhere(api, literal):
    raw = f'{{"shadowing_db": {literal}, "path_loss_exponent": 3, "distance_m": 0.1}}'
    assert_field(post_raw(api, "/v1/bounds/rss", raw), 422, "body", "shadowing_db")
    body = json.dumps(SMALL_CHANNEL).replace('"rays": 2000', '"dynamic_range_db": %s' % literal)
    assert_field(post_raw(api, "/v1/channel", body), 422, "body", "dynamic_range_db")
    raw = ('{"phantom": "torso", "transmitter": {"position_m": [0, %s, 0]}, "receivers": [{"site": "belt_left"}]}'
           % literal)
    assert_field(post_raw(api, "/v1/channel", raw), 422, "body", "transmitter", "position_m")
    raw = '{"profile": {"paths": [{"delay_s": 1e-9, "gain": {"re": %s, "im": 0}}]}}' % literal
    assert_field(post_raw(api, "/v1/ranging/toa", raw), 422, "body", "profile", "paths", 0, "gain", "re")


def test_malformed_json_is_422_naming_the_body(api):
    r = post_raw(api, "/v1/channel", '{"phantom": "torso",')
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][0] == "body"


# ------------------------------------------------------------------ channel
def test_channel_happy_path_on_the_default_torso(api):
    body = {**SMALL_CHANNEL, "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 3}}
    r = api.post("/v1/channel", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["phantom"] == "torso" and out["frequency_hz"] == 402e6
    assert out["transmitter"]["medium"] == "small_intestine"
    assert [p["receiver"] for p in out["profiles"]] == ["belt_anterior", "side"]
    for prof in out["profiles"]:
        assert prof["medium"] == "skin"  # torso sensor sites are contact sensors
        delays = [p["delay_s"] for p in prof["paths"]]
        assert delays == sorted(delays)
        for p in prof["paths"]:
            # Nothing travels faster than light in vacuum: delay >= distance / c.
            assert p["delay_s"] >= prof["geometric_distance_m"] / C0
            assert [g["frequency_hz"] for g in p["band_gains"]] == [400e6, 410e6, 420e6]
            assert p["gain_db"] >= -400.0
    assert out["stats"]["rays_launched"] == 2000
    # the route serialises the tracer's dict itself (not through the model): it must be exactly
    # a ChannelResponse, field for field (extra fields and NaN / infinity are forbidden there)
    assert ChannelResponse.model_validate(out).model_dump(mode="json") == out
    assert r.headers["content-type"] == "application/json"


def test_channel_scenario_lookup(api):
    scenarios = api.get("/v1/scenarios").json()["scenarios"]
    sc = scenarios[0]
    r = api.post("/v1/channel", json={"scenario": sc["id"], "rays": 2000, "max_interactions": 2})
    assert r.status_code == 200, r.text
    assert r.json()["scenario"] == sc["id"] and r.json()["phantom"] == sc["phantom"]


CHANNEL_BAD = [
    ({"rays": 5001}, ("body", "rays"), 422),  # above this server's cap (settings)
    ({"rays": 2_000_000}, ("body", "rays"), 422),  # above the schema ceiling
    ({"rays": 0}, ("body", "rays"), 422),
    ({"rays": "many"}, ("body", "rays"), 422),
    ({"max_interactions": 11}, ("body", "max_interactions"), 422),
    ({"max_interactions": -1}, ("body", "max_interactions"), 422),
    ({"receivers": [{"site": "belt_left"}] * 65}, ("body", "receivers"), 422),
    ({"receivers": []}, ("body", "receivers"), 422),
    ({"band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 202}}, ("body", "band", "points"), 422),
    ({"band": {"start_hz": 420e6, "stop_hz": 400e6, "points": 3}}, ("body", "band"), 422),
    ({"frequency_hz": 30e9}, ("body", "frequency_hz"), 422),
    ({"phantom": "nope"}, ("body", "phantom"), 404),
    ({"phantom": "../etc/passwd"}, ("body", "phantom"), 422),
    ({"scenario": "nope"}, ("body", "scenario"), 404),
    ({"transmitter": {"site": "liver_core"}}, ("body", "transmitter", "site"), 404),
    ({"transmitter": {"site": "small_intestine_1", "position_m": [0, 0, 0]}}, ("body", "transmitter"), 422),
    ({"transmitter": {"position_m": [0, 0]}}, ("body", "transmitter", "position_m"), 422),
    ({"transmitter": {"position_m": [3.0, 0, 0]}}, ("body", "transmitter", "position_m"), 422),
    ({"transmitter": {"site": "small_intestine_1", "polarization": [0, 0, 0]}}, ("body", "transmitter"), 422),
    ({"receivers": [{"site": "belt_left"}, {"site": "belt_left"}]}, ("body", "receivers", 1, "name"), 422),
    ({"receivers": [{"position_m": [-0.02, -0.025, 0.015]}]}, ("body", "receivers", 0, "position_m"), 422),
    ({"homogeneous": {"relative_permittivity": 0.5}}, ("body", "homogeneous", "relative_permittivity"), 422),
    ({"surprise": True}, ("body", "surprise"), 422),
]


@pytest.mark.parametrize("patch, loc, status", CHANNEL_BAD, ids=[str(i) for i in range(len(CHANNEL_BAD))])
def test_channel_rejects_bad_requests(api, patch, loc, status):
    assert_field(api.post("/v1/channel", json={**SMALL_CHANNEL, **patch}), status, *loc)


def test_channel_without_antennas_or_scenario(api):
    assert_field(api.post("/v1/channel", json={"receivers": [{"site": "belt_left"}]}), 422, "body", "transmitter")
    assert_field(api.post("/v1/channel", json={"transmitter": {"site": "stomach"}}), 422, "body", "receivers")


def test_channel_work_budget_gives_503_with_advice(make_settings, monkeypatch):
    from fastapi.testclient import TestClient

    import service.costs
    from raytrace.solver.footprint import Footprint
    from service.app import create_app

    with TestClient(create_app(make_settings(max_ray_segments=100)), raise_server_exceptions=False) as api:
        # a shooting estimated over the cap is refused before any work (deterministic: 422, not 503)
        assert_field(api.post("/v1/channel", json=SMALL_CHANNEL), 422, "body", "rays")
        # an estimate that was wrong (too low): the budget checked while tracing stops it
        monkeypatch.setattr(service.costs, "trace_footprint", lambda spec, config: Footprint(1, 0, 0, 0, 0))
        r = api.post("/v1/channel", json=SMALL_CHANNEL)
        assert r.status_code == 503 and "Retry-After" in r.headers
        assert r.json()["detail"][0]["type"] == "work_budget_exceeded"
        assert "lower rays" in r.json()["detail"][0]["msg"]


def test_channel_deadline_gives_504(make_settings):
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(make_settings(request_deadline_s=1e-9)), raise_server_exceptions=False) as api:
        r = api.post("/v1/channel", json=SMALL_CHANNEL)
        assert r.status_code == 504, r.text
        assert r.json()["detail"][0]["type"] == "deadline_exceeded"


def test_zero_gain_is_reported_at_the_documented_floor():
    from raytrace.results import ReceiverProfile
    from service.operations import channel as ops
    from service.schemas import GAIN_DB_FLOOR

    prof = ReceiverProfile("r", __import__("numpy").zeros(3), "air", 0.1, ())
    assert prof.path_gain_db == -math.inf
    assert ops._db(prof.path_gain_db) == GAIN_DB_FLOOR == -400.0


# ------------------------------------------------------------------ ranging
def test_ranging_toa_on_a_single_path_profile(api):
    body = {"profile": {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}}]}, "method": "all",
            "snr_db": 30, "trials": 20, "seed": 3, "true_distance_m": 0.076}
    r = api.post("/v1/ranging/toa", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert [x["method"] for x in out["results"]] == ["first_peak", "all_peaks", "gcc"]
    assert out["method"] == "gcc"
    # Thesis: 1.338 ns at eps_r 27.9 is 0.076 m; GCC is within 1 mm at 30 dB (thesis Ch. 4 max error 1.85 mm).
    assert out["distance_m"] == pytest.approx(0.076, abs=1e-3)
    assert out["trials"] == 20 and out["crlb_m"] > 0
    again = api.post("/v1/ranging/toa", json=body).json()
    assert again == out  # seeded: the same request gives the same answer


def test_ranging_toa_envelope_method(api):
    # The envelope-only estimator: no carrier phase, so its spread at 30 dB is
    # set by the 25 ns burst's envelope, far above GCC's carrier-phase bound,
    # but it is unbiased on a single path (0.076 m within 5 mm).
    body = {"profile": {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}}]}, "method": "envelope",
            "snr_db": 30, "trials": 50, "seed": 3, "true_distance_m": 0.076}
    r = api.post("/v1/ranging/toa", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["method"] == "envelope" and [x["method"] for x in out["results"]] == ["envelope"]
    assert out["distance_m"] == pytest.approx(0.076, abs=5e-3)


def test_ranging_accepts_a_channel_profile_as_is(api):
    ch = api.post("/v1/channel", json=SMALL_CHANNEL).json()
    prof = next(p for p in ch["profiles"] if p["paths"])  # both sensors have a direct path
    r = api.post("/v1/ranging/toa", json={"profile": prof, "method": "gcc", "trials": 5})
    assert r.status_code == 200, r.text


def test_ranging_pdoa(api):
    body = {"profile": {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}}]}, "method": "regression",
            "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}, "snr_db": 40, "trials": 20, "seed": 1,
            "true_distance_m": 0.076}
    r = api.post("/v1/ranging/pdoa", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    # v / tone spacing (1 MHz)
    assert out["max_unambiguous_range_m"] == pytest.approx(C0 / math.sqrt(27.9) / 1e6, rel=1e-6)
    assert out["distance_m"] == pytest.approx(0.076, abs=0.01)


def test_ranging_rss(api):
    r = api.post("/v1/ranging/rss", json={"profile": PROFILE, "model": "cm2_deep_tissue", "trials": 50, "seed": 1})
    assert r.status_code == 200, r.text
    assert r.json()["distance_m"] > 0


RANGING_BAD = [
    ("/v1/ranging/toa", {"profile": PROFILE, "trials": 10001}, ("body", "trials")),
    ("/v1/ranging/toa", {"profile": {"paths": []}}, ("body", "profile", "paths")),
    ("/v1/ranging/toa", {"profile": {"paths": [{"delay_s": -1e-9, "gain": {"re": 1, "im": 0}}]}},
     ("body", "profile", "paths", 0, "delay_s")),
    ("/v1/ranging/toa", {"profile": PROFILE, "method": "psychic"}, ("body", "method")),
    ("/v1/ranging/toa", {"profile": PROFILE,
                         "waveform": {"kind": "tone_burst", "carrier_hz": 402e6, "sample_rate_hz": 500e6}},
     ("body", "waveform")),
    ("/v1/ranging/toa", {"profile": {"paths": [{"delay_s": 1e-9, "gain": {"re": 0, "im": 0}}]}}, ("body", "profile")),
    ("/v1/ranging/pdoa", {"profile": PROFILE, "frequencies_hz": [400e6]}, ("body", "frequencies_hz")),
    ("/v1/ranging/pdoa", {"profile": PROFILE, "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 500}},
     ("body", "band", "points")),
    ("/v1/ranging/rss", {"profile": PROFILE, "model": "free_space"}, ("body", "model")),
    ("/v1/ranging/rss", {"profile": PROFILE, "trials": "x"}, ("body", "trials")),
]


@pytest.mark.parametrize("path, body, loc", RANGING_BAD, ids=[str(i) for i in range(len(RANGING_BAD))])
def test_ranging_rejects_bad_requests(api, path, body, loc):
    assert_field(api.post(path, json=body), 422, *loc)


def test_server_limit_on_trials_is_enforced(make_settings):
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(make_settings(max_trials=10)), raise_server_exceptions=False) as api:
        assert_field(api.post("/v1/ranging/toa", json={"profile": PROFILE, "trials": 11}), 422, "body", "trials")
        assert api.post("/v1/ranging/toa", json={"profile": PROFILE, "trials": 10}).status_code == 200


def test_channel_profiles_declare_their_gain_convention_for_ranging(api):
    """A profile whose gains carry exp(-j 2 pi f tau) (as the tracer's do) ranges like the plain one."""
    f = 402e6
    plain = [{"delay_s": 1.338e-9, "gain": {"re": 0.15, "im": 0.0}},
             {"delay_s": 1.706e-9, "gain": {"re": -0.08, "im": 0.05}}]
    phased = []
    for p in plain:
        a = complex(p["gain"]["re"], p["gain"]["im"]) * cmath.exp(-2j * math.pi * f * p["delay_s"])
        phased.append({"delay_s": p["delay_s"], "gain": {"re": a.real, "im": a.imag}})
    common = {"method": "gcc", "trials": 10, "seed": 5, "true_distance_m": 0.076}
    a = api.post("/v1/ranging/toa", json={**common, "profile": {"paths": plain}}).json()
    b = api.post("/v1/ranging/toa", json={**common, "profile": {"paths": phased, "gains_include_delay_phase": True,
                                                                "reference_frequency_hz": f}}).json()
    assert b["distance_m"] == pytest.approx(a["distance_m"], rel=1e-9)
    # The flag without its frequency is a schema error naming the profile.
    missing_reference = {**common, "profile": {"paths": phased, "gains_include_delay_phase": True}}
    assert_field(api.post("/v1/ranging/toa", json=missing_reference), 422, "body", "profile")


def test_every_request_example_of_the_docs_works(make_settings):
    """The /docs examples are a tutorial: each one must succeed against the default limits."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.schemas import channel as sc
    from service.schemas import ranging as sr

    routes = {
        sc.ChannelRequest: "/v1/channel",
        sr.ToaRequest: "/v1/ranging/toa",
        sr.PdoaRequest: "/v1/ranging/pdoa",
        sr.RssRequest: "/v1/ranging/rss",
        sr.ToaBoundRequest: "/v1/bounds/toa",
        sr.PdoaBoundRequest: "/v1/bounds/pdoa",
        sr.RssBoundRequest: "/v1/bounds/rss",
    }
    with TestClient(create_app(make_settings(max_rays=1_000_000))) as api:
        for model, path in routes.items():
            for example in model.model_config["json_schema_extra"]["examples"]:
                r = api.post(path, json=example)
                assert r.status_code == 200, (path, example, r.text)


def test_metric_labels_stay_bounded_whatever_the_client_sends(api):
    for i in range(5):
        api.request(f"BREW{i}", "/v1/nothing/{i}")
        api.get(f"/v1/random/path/{i}")
    text = api.get("/metrics").text
    assert "BREW" not in text and "/v1/random" not in text
    assert 'method="OTHER",route="unmatched"' in text


def test_an_unexpected_bug_is_a_json_500_with_the_request_id(make_settings):
    """The last-resort handler: no traceback leaks, the request id ties the answer to the log."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    app = create_app(make_settings())

    @app.get("/boom")
    async def boom():
        raise RuntimeError("secret internals")

    with TestClient(app, raise_server_exceptions=False) as api:
        r = api.get("/boom", headers={"X-Request-ID": "bug-1"})
        assert r.status_code == 500
        assert r.headers["x-request-id"] == "bug-1"
        item = r.json()["detail"][0]
        assert item["type"] == "internal" and "bug-1" in item["msg"] and "secret" not in item["msg"]
        assert 'route="/boom",status="500"' in api.get("/metrics").text


def test_a_broken_builtin_is_reported_not_fatal(make_settings, monkeypatch):
    from fastapi.testclient import TestClient

    import raytrace.body.library as sc
    from service.app import create_app

    real = sc.builtin_phantoms

    def with_a_broken_one():
        factories = dict(real())

        def broken():
            raise RuntimeError("mesh generator exploded")

        factories["half-space"] = broken
        return factories

    monkeypatch.setattr(sc, "builtin_phantoms", with_a_broken_one)
    with TestClient(create_app(make_settings())) as api:
        ready = api.get("/readyz").json()
        assert ready["status"] == "ready"
        assert any("half-space" in e and "exploded" in e for e in ready["errors"])
        assert any("scenario 'half-space' unavailable" in e for e in ready["errors"])
        ids = [p["id"] for p in api.get("/v1/phantoms").json()["phantoms"]]
        assert "torso" in ids and "half-space" not in ids
        assert "half-space" not in [s["id"] for s in api.get("/v1/scenarios").json()["scenarios"]]
