"""``capsule-rt localize`` / ``localize-evaluate`` (local, no HTTP) and the typed client's
``localize`` / ``localize_evaluate`` (over the in-process app's transport).

Oracle as in test_localize_api.py: noiseless ranges computed here with math.dist from a
chosen position must give that position back; errors name the sensor's field.
"""

from __future__ import annotations

import json
import math

import pytest

from service.cli import build_parser, main
from service.client import APIError, Client
from service.schemas.localize import LocalizeEvaluateResponse, LocalizeResponse

TRUE = (0.012, -0.021, 0.034)
LAYOUT = [(0.15, 0.02, 0.0), (-0.12, 0.05, 0.03), (0.01, -0.14, 0.06), (0.03, 0.11, -0.09),
          (0.02, 0.01, 0.18), (-0.05, -0.06, -0.12)]
FIX = {"method": "nonlinear", "sensors": [{"position_m": list(s), "range_m": math.dist(s, TRUE), "sigma_m": 0.001}
                                          for s in LAYOUT]}
EVALUATE = {"capsule": {"site": "stomach"},
            "sensors": [{"site": s} for s in ("belt_anterior", "belt_left", "belt_posterior", "upper_right",
                                              "upper_anterior_left", "upper_left")],
            "methods": ["nonlinear"], "trials": 2, "rays": 3000}


@pytest.fixture(autouse=True)
def _data_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("CAPSULE_RT_DATA_DIR", str(tmp_path / "data"))


def test_localize_command_prints_the_fix(tmp_path, capsys):
    req = tmp_path / "fix.json"
    req.write_text(json.dumps(FIX))
    assert main(["localize", str(req)]) == 0
    out = LocalizeResponse.model_validate(json.loads(capsys.readouterr().out))
    assert math.dist(out.position_m, TRUE) < 1e-9  # noiseless ranges: exact to round-off


def test_localize_command_names_the_bad_field(tmp_path, capsys):
    bad = json.loads(json.dumps(FIX))
    bad["sensors"][3]["position_m"] = bad["sensors"][1]["position_m"]  # a duplicate
    req = tmp_path / "fix.json"
    req.write_text(json.dumps(bad))
    assert main(["localize", str(req)]) == 2
    detail = json.loads(capsys.readouterr().err)["detail"]
    assert detail[0]["loc"] == ["body", "sensors", 3, "position_m"]


def test_localize_evaluate_command_writes_statistics(tmp_path):
    req, out = tmp_path / "ev.json", tmp_path / "out.json"
    req.write_text(json.dumps(EVALUATE))
    assert main(["localize-evaluate", str(req), "-o", str(out)]) == 0
    body = LocalizeEvaluateResponse.model_validate(json.loads(out.read_text()))
    assert body.methods[0].method == "nonlinear" and len(body.methods[0].errors_m) == 2


def test_every_localize_option_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name in ("localize", "localize-evaluate"):
        for action in sub.choices[name]._actions:
            assert action.help, (name, action.dest)


def test_client_methods(api):
    with Client("http://testserver", transport=api._transport) as client:
        fix = client.localize(FIX)
        assert isinstance(fix, LocalizeResponse) and math.dist(fix.position_m, TRUE) < 1e-9
        ev = client.localize_evaluate(EVALUATE)
        assert isinstance(ev, LocalizeEvaluateResponse) and ev.trials == 2
        flat = [{"position_m": [x, y, 0.0], "range_m": 0.1} for x, y in ((0.1, 0), (0, 0.1), (-0.1, 0), (0.05, -0.1))]
        with pytest.raises(APIError) as err:  # valid locally, refused by the server: coplanar sensors
            client.localize({"sensors": flat})
        assert err.value.status == 422 and ["body", "sensors"] in err.value.fields
