"""End-to-end over real HTTP: the typed client against a uvicorn server.

The server is ``capsule-rt serve`` in a subprocess on 127.0.0.1 (conftest
``live_url``), or the one at ``CAPSULE_RT_URL`` (the client container). Every
endpoint: the happy path, and a bad request whose ``detail`` names the field.
"""

from __future__ import annotations

import asyncio
import json
import math

import httpx
import pytest

from service.client import APIError, AsyncClient, Client
from service.schemas.channel import ChannelResponse
from service.schemas.phantoms import TissuesResponse
from tests.conftest import HANG_GUARD_S, glb_bytes, nested_phantom_meshes, phantom_manifest

pytestmark = pytest.mark.e2e

C0 = 299_792_458.0
PROFILE = {"paths": [{"delay_s": 1.338e-9, "gain": {"re": 1e-3, "im": 0.0}}]}


@pytest.fixture(scope="module")
def api(live_url):
    with Client(live_url, timeout=HANG_GUARD_S) as client:
        yield client


def expect_error(status: int, *loc, call):
    with pytest.raises(APIError) as info:
        call()
    err = info.value
    assert err.status == status, err
    locs = err.fields
    want = list(loc)
    assert any(any(loc[i : i + len(want)] == want for i in range(len(loc) - len(want) + 1)) for loc in locs), \
        (want, locs)
    assert all(item["msg"] for item in err.detail)
    return err


def test_operations(api, live_url):
    assert api.healthz().status == "ok"
    ready = api.readyz()
    assert ready.status == "ready" and ready.phantoms >= 1 and ready.scenarios >= 1
    text = api.metrics()
    assert "capsule_rt_http_requests_total" in text
    r = httpx.get(f"{live_url}/healthz", headers={"X-Request-ID": "e2e-1"}, timeout=HANG_GUARD_S)
    assert r.headers["x-request-id"] == "e2e-1"
    r = httpx.get(f"{live_url}/v1/unknown", timeout=HANG_GUARD_S)
    assert r.status_code == 404 and r.json()["detail"][0]["loc"] == ["path"]


def test_tissues(api):
    out = api.tissues(402e6)
    assert isinstance(out, TissuesResponse) and len(out.tissues) == 27
    air = next(t for t in out.tissues if t.name == "air")
    assert air.phase_velocity_m_per_s == pytest.approx(C0, rel=1e-12)
    assert air.wavelength_m == pytest.approx(C0 / 402e6, rel=1e-12)
    assert air.attenuation_db_per_m == 0.0
    expect_error(422, "query", "frequency_hz", call=lambda: api.tissues(25e9))


def test_bounds(api):
    toa = api.bound_toa({"carrier_hz": 402e6, "duration_s": 25e-9, "bandwidth_hz": 10e9, "snr_db": 30})
    assert toa.sigma_m == pytest.approx(3.2e-5, rel=0.02)  # docs/science.md: about 0.032 mm
    pdoa = api.bound_pdoa({"center_hz": 410e6, "tone_spacing_hz": 20e6, "snr_db": 30})
    assert pdoa.sigma_m == pytest.approx(0.49e-3, rel=0.02)  # docs/science.md: about 0.49 mm
    rss = api.bound_rss({"shadowing_db": math.sqrt(5), "path_loss_exponent": 3, "distance_m": 0.1})
    assert rss.sigma_m == pytest.approx(0.017, rel=0.02)  # docs/science.md: 0.017 m
    # The client validates locally; send raw bodies to see the server's answer.
    for path, body, field in [
        ("/v1/bounds/toa", {"carrier_hz": 402e6, "duration_s": -1, "bandwidth_hz": 1e9, "snr_db": 3}, "duration_s"),
        ("/v1/bounds/pdoa", {"center_hz": 410e6, "tone_spacing_hz": 20e6}, "snr_db"),
        ("/v1/bounds/rss", {"shadowing_db": 1, "path_loss_exponent": "three", "distance_m": 0.1}, "path_loss_exponent"),
    ]:
        r = api._http.post(path, json=body)
        assert r.status_code == 422 and ["body", field] in [d["loc"] for d in r.json()["detail"]], r.text


def test_phantoms_and_scenarios(api):
    listed = api.phantoms()
    ids = [p.id for p in listed.phantoms]
    assert "torso" in ids
    torso = api.phantom("torso")
    assert torso.builtin and "small_intestine" in {o.name for o in torso.organs}
    assert api.phantom_mesh("torso")[:4] == b"glTF"
    expect_error(404, "path", "phantom_id", call=lambda: api.phantom("no-such-phantom"))
    expect_error(404, "path", "phantom_id", call=lambda: api.phantom_mesh("no-such-phantom"))
    expect_error(404, "path", "phantom_id", call=lambda: api.phantom_manifest("no-such-phantom"))
    assert set(api.phantom_manifest("torso")["organs"]) == {o.name for o in torso.organs}
    expect_error(409, "path", "phantom_id", call=lambda: api.delete_phantom("torso"))
    scenarios = {sc.id: sc for sc in api.scenarios().scenarios}
    assert "thesis-fig-5-6" in scenarios
    assert scenarios["thesis-fig-5-6"].phantom == "thesis-fig-5-6"


def test_upload_lifecycle(api):
    glb, manifest = glb_bytes(nested_phantom_meshes()), phantom_manifest()
    info = api.upload_phantom(glb, manifest)
    try:
        assert info.id.startswith("up-") and info.sites["capsule"].medium == "organ"
        assert api.phantom(info.id).organs == info.organs
        mesh = api.phantom_mesh(info.id)
        assert mesh[:4] == b"glTF"
        assert api.phantom_manifest(info.id)["organs"] == manifest["organs"]
        ch = api.channel({"phantom": info.id, "transmitter": {"site": "capsule"}, "receivers": [{"site": "sensor"}],
                          "rays": 1000, "max_interactions": 2})
        assert ch.profiles[0].medium == "air"
    finally:
        api.delete_phantom(info.id)
    expect_error(404, "path", "phantom_id", call=lambda: api.phantom(info.id))
    broken = glb_bytes(nested_phantom_meshes("open"))
    err = expect_error(422, "organs", "organ", call=lambda: api.upload_phantom(broken, manifest))
    assert "watertight" in err.detail[0]["msg"]
    expect_error(422, "body", "mesh", call=lambda: api.upload_phantom(b"not a glb at all", manifest))


def test_upload_over_the_cap_is_refused_while_streaming(live_url):
    """A 64 MB chunked upload (no Content-Length) to a server capped at 20 MB: 413, not a full read."""
    manifest = json.dumps(phantom_manifest())
    boundary = "e2eboundary"
    head = (
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"manifest\"\r\n\r\n{manifest}\r\n"
        f"--{boundary}\r\nContent-Disposition: form-data; name=\"mesh\"; filename=\"big.glb\"\r\n\r\n"
    ).encode()
    sent = {"bytes": 0}

    def body():
        yield head
        chunk = b"glTF" + b"\0" * (1024 * 1024 - 4)
        for _ in range(64):
            sent["bytes"] += len(chunk)
            yield chunk

    try:
        r = httpx.post(f"{live_url}/v1/phantoms", content=body(),
                       headers={"content-type": f"multipart/form-data; boundary={boundary}"}, timeout=HANG_GUARD_S)
    except httpx.HTTPError:
        pytest.fail("the server should answer 413, not drop the connection")
    assert r.status_code == 413, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "mesh"]
    assert httpx.get(f"{live_url}/healthz", timeout=HANG_GUARD_S).status_code == 200


def test_channel_scenario_and_ranging(api):
    ch = api.channel({"scenario": "thesis-fig-5-6", "rays": 20000})
    assert isinstance(ch, ChannelResponse) and ch.scenario == "thesis-fig-5-6"
    prof = ch.profiles[0]
    assert prof.paths, "the thesis case must have at least its direct path"
    direct = prof.paths[0]
    # Thesis: direct path 0.076 m at eps_r 27.9 -> 1.338 ns.
    assert direct.delay_s == pytest.approx(0.076 * math.sqrt(27.9) / C0, rel=1e-3)
    toa = api.ranging_toa({"profile": prof.model_dump(), "method": "all", "trials": 20, "seed": 1,
                           "true_distance_m": 0.076})
    assert {r.method for r in toa.results} == {"first_peak", "all_peaks", "gcc"}
    assert toa.distance_m == pytest.approx(0.076, abs=0.01)
    pdoa = api.ranging_pdoa({"profile": prof.model_dump(), "method": "regression",
                             "band": {"start_hz": 400e6, "stop_hz": 420e6, "points": 21}, "trials": 20, "seed": 1,
                             "true_distance_m": 0.076})
    assert pdoa.max_unambiguous_range_m and pdoa.distance_m > 0
    rss = api.ranging_rss({"profile": prof.model_dump(), "trials": 50, "seed": 1})
    assert rss.distance_m > 0 and rss.model == "cm2_deep_tissue"


def test_channel_and_ranging_errors(api):
    r = api._http.post("/v1/channel", json={"scenario": "thesis-fig-5-6", "rays": 10**7})
    assert r.status_code == 422 and ["body", "rays"] in [d["loc"] for d in r.json()["detail"]]
    expect_error(404, "body", "scenario", call=lambda: api.channel({"scenario": "no-such-case", "rays": 100}))
    expect_error(404, "body", "phantom", call=lambda: api.channel(
        {"phantom": "nope", "transmitter": {"position_m": [0, 0, 0]}, "receivers": [{"position_m": [0, -0.2, 0]}]}))
    expect_error(404, "body", "receivers", 0, "site", call=lambda: api.channel(
        {"phantom": "torso", "transmitter": {"site": "stomach"}, "receivers": [{"site": "nowhere"}], "rays": 100}))
    for path, body, loc in [
        ("/v1/ranging/toa", {"profile": PROFILE, "trials": 100000}, ["body", "trials"]),
        ("/v1/ranging/pdoa", {"profile": PROFILE, "frequencies_hz": [400e6, float("nan")]}, None),
        ("/v1/ranging/rss", {"profile": PROFILE, "model": "free_space"}, ["body", "model"]),
    ]:
        if loc is None:  # NaN cannot be sent as strict JSON; send the JavaScript literal
            r = api._http.post(path, content=json.dumps(body).encode(), headers={"content-type": "application/json"})
            assert r.status_code == 422, r.text
            assert any(d["loc"][:2] == ["body", "frequencies_hz"] for d in r.json()["detail"]), r.text
            continue
        r = api._http.post(path, json=body)
        assert r.status_code == 422 and loc in [d["loc"] for d in r.json()["detail"]], r.text


def test_async_client_mirrors_the_sync_one(live_url):
    async def main():
        async with AsyncClient(live_url, timeout=HANG_GUARD_S) as client:
            health, tissues, bound = await asyncio.gather(
                client.healthz(), client.tissues(2.45e9),
                client.bound_rss({"shadowing_db": 7.85, "path_loss_exponent": 4.26, "distance_m": 0.05})
            )
            return health, tissues, bound

    health, tissues, bound = asyncio.run(main())
    assert health.status == "ok" and tissues.frequency_hz == 2.45e9
    assert bound.sigma_m == pytest.approx(math.log(10) * 7.85 / (10 * 4.26) * 0.05, rel=1e-12)
