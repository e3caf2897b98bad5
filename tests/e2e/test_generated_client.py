"""Standard generators take the OpenAPI document as served (issue 37): ``openapi-python-client``
generates a client with every operation, ``datamodel-code-generator`` generates the models, and
a channel, a ranging and a localization request go through the generated client to a live
server, their bodies and answers also read by the generated models.

The document is the live server's ``/openapi.json``, which for a server with the default limits
is the shipped ``openapi.json`` (tests/service/test_openapi.py holds them equal). The generators'
only tolerated complaints are the responses they cannot type (binary figures and meshes, the YAML
body of POST /v1/sweeps): their operations are still generated.
"""

from __future__ import annotations

import importlib
import math
import re
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

pytestmark = pytest.mark.e2e

BIN = Path(sys.executable).parent
#: What openapi-python-client prints when it drops a schema or an operation (a broken client).
DROPPED = re.compile(r"Unable to (parse|process)|will not be generated|Failure to process|Could not")


def _tool(name: str) -> str:
    path = BIN / name
    assert path.exists(), f"{name} is not installed next to {sys.executable} (the test extra provides it)"
    return str(path)


@pytest.fixture(scope="module")
def generated(live_url, tmp_path_factory):
    """(the generated client package, the generated models module), importable from a scratch directory."""
    root = tmp_path_factory.mktemp("generated")
    document = root / "openapi.json"
    document.write_bytes(httpx.get(f"{live_url}/openapi.json", timeout=60).content)
    out = subprocess.run([_tool("openapi-python-client"), "generate", "--path", str(document), "--meta", "none",
                          "--output-path", str(root / "capsule_client")],
                         capture_output=True, text=True, timeout=600, cwd=root)
    log = out.stdout + out.stderr
    assert out.returncode == 0, log[-4000:]
    assert not DROPPED.search(log), log[-8000:]
    out = subprocess.run([_tool("datamodel-codegen"), "--input", str(document), "--input-file-type", "openapi",
                          "--output", str(root / "capsule_models.py"), "--output-model-type",
                          "pydantic_v2.BaseModel", "--formatters", "ruff-format"],
                         capture_output=True, text=True, timeout=600, cwd=root)
    assert out.returncode == 0, (out.stdout + out.stderr)[-4000:]
    sys.path.insert(0, str(root))
    try:
        yield importlib.import_module("capsule_client"), importlib.import_module("capsule_models")
    finally:
        sys.path.remove(str(root))
        for name in [m for m in sys.modules if m.split(".")[0] in ("capsule_client", "capsule_models")]:
            del sys.modules[name]


def test_every_operation_is_generated(generated, live_url):
    client, _ = generated
    served = httpx.get(f"{live_url}/openapi.json", timeout=60).json()
    operation_ids = {op["operationId"] for item in served["paths"].values() for op in item.values()
                     if isinstance(op, dict) and "operationId" in op}
    modules = {p.stem for p in Path(client.__file__).parent.glob("api/*/*.py") if p.stem != "__init__"}
    assert {re.sub(r"[^a-z0-9]+", "_", op.lower()) for op in operation_ids} <= modules


def test_channel_ranging_and_localization_through_the_generated_client(generated, live_url):
    """Each answer equals the one the same JSON body gets sent by hand (the server is deterministic
    for a request and its seed), so the generated client sends the body the user built, and reads
    the answer back whole; the localization is also checked against the point it was made from."""
    client, models = generated
    from capsule_client.api.channel import compute_channel
    from capsule_client.api.localization import localize
    from capsule_client.api.ranging import ranging_toa
    from capsule_client.models import ChannelRequest, ChannelResponse, LocalizeRequest, LocalizeResponse, ToaRequest

    api = client.Client(base_url=live_url, timeout=httpx.Timeout(120.0), raise_on_unexpected_status=True)
    by_hand = httpx.Client(base_url=live_url, timeout=120.0)

    # channel: the thesis' three-path case
    body = {"scenario": "thesis-fig-5-6", "rays": 20000}
    models.ChannelRequest.model_validate(body)  # the generated models take the same body
    answer = compute_channel.sync_detailed(client=api, body=ChannelRequest.from_dict(body))
    assert answer.status_code == 200, answer.content[:2000]
    channel = answer.parsed
    assert isinstance(channel, ChannelResponse)
    models.ChannelResponse.model_validate_json(answer.content)
    expected = by_hand.post("/v1/channel", json=body).json()
    assert [[p.delay_s for p in profile.paths] for profile in channel.profiles] == \
        [[p["delay_s"] for p in profile["paths"]] for profile in expected["profiles"]]
    assert channel.profiles[0].to_dict()["paths"] == expected["profiles"][0]["paths"]

    # ranging: that profile, unchanged, through TOA (generalized cross-correlation, 30 dB)
    body = {"profile": channel.profiles[0].to_dict(), "method": "gcc", "snr_db": 30, "trials": 20, "seed": 1,
            "true_distance_m": 0.076}
    models.ToaRequest.model_validate(body)
    answer = ranging_toa.sync_detailed(client=api, body=ToaRequest.from_dict(body))
    assert answer.status_code == 200, answer.content[:2000]
    models.RangingResponse.model_validate_json(answer.content)
    expected = by_hand.post("/v1/ranging/toa", json=body).json()
    assert (answer.parsed.distance_m, answer.parsed.std_m) == (expected["distance_m"], expected["std_m"])
    assert [r.method for r in answer.parsed.results] == [r["method"] for r in expected["results"]]

    # localization: exact ranges from six sensors around a known point; the fix is that point
    capsule = (0.01, -0.02, 0.03)
    sensors = [(0.1, 0, 0), (-0.1, 0, 0), (0, 0.1, 0), (0, -0.1, 0), (0, 0, 0.1), (0, 0, -0.1)]
    body = {"method": "nonlinear", "sensors": [
        {"position_m": list(map(float, s)), "range_m": math.dist(s, capsule), "sigma_m": 0.002} for s in sensors]}
    models.LocalizeRequest.model_validate(body)
    answer = localize.sync_detailed(client=api, body=LocalizeRequest.from_dict(body))
    assert answer.status_code == 200, answer.content[:2000]
    assert isinstance(answer.parsed, LocalizeResponse)
    models.LocalizeResponse.model_validate_json(answer.content)
    assert answer.parsed.position_m == by_hand.post("/v1/localize", json=body).json()["position_m"]
    # noiseless ranges: least squares converges onto the point (1 um: the solver's tolerance, not physics)
    assert math.dist(answer.parsed.position_m, capsule) < 1e-6, answer.parsed.position_m
    by_hand.close()


def test_the_generated_client_reports_a_refusal(generated, live_url):
    """A bad request is the server's 422 naming the field, parsed into the generated error model."""
    client, _ = generated
    from capsule_client.api.channel import compute_channel
    from capsule_client.models import ChannelRequest, ErrorResponse

    api = client.Client(base_url=live_url, timeout=httpx.Timeout(60.0))
    answer = compute_channel.sync_detailed(client=api, body=ChannelRequest.from_dict(
        {"scenario": "thesis-fig-5-6", "rays": 0}))
    assert answer.status_code == 422
    assert isinstance(answer.parsed, ErrorResponse)
    assert answer.parsed.detail[0].loc[-1] == "rays"
