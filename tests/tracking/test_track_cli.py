"""``capsule-rt track``: a POST /v1/track body run in this process (service/track_cli.py)."""

from __future__ import annotations

import json

from raytrace import default_torso
from service.cli import main


def test_track_command_follows_fixes_on_the_centreline(tmp_path, capsys):
    """Three tight RF fixes at the centreline's point for s = 0.300 m: the Kalman estimate of s is
    0.300 m within 1 mm (fix sigma 0.1 mm, so the prior's 5 mm pull is negligible)."""
    point = default_torso().centrelines["gi_tract"].point_m(0.300).tolist()
    cov = [[1e-8, 0, 0], [0, 1e-8, 0], [0, 0, 1e-8]]
    body = {"phantom": "torso", "tracker": "kalman",
            "observations": [{"t_s": t, "rf": {"position_m": point, "covariance_m2": cov}} for t in (0.0, 0.5, 1.0)]}
    path = tmp_path / "track.json"
    path.write_text(json.dumps(body))
    assert main(["track", str(path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["steps"]) == 3
    assert abs(out["steps"][-1]["s_m"] - 0.300) < 1e-3, out["steps"][-1]


def test_track_command_names_the_bad_field(tmp_path, capsys):
    path = tmp_path / "track.json"
    path.write_text(json.dumps({"phantom": "torso", "observations": []}))
    assert main(["track", str(path)]) == 2
    detail = json.loads(capsys.readouterr().err)["detail"]
    assert detail[0]["loc"] == ["body", "observations"]


def test_the_evaluate_schema_states_the_journeys_own_bounds():
    """The journey's numeric bounds live in tracking.journey; POST /v1/track/evaluate's schema must
    say the same ones (a drift is a schema-valid request refused: the fuzzer found dt_s 5e-324)."""
    from service.schemas.tracking import JourneyIn
    from tracking.journey import _BOUNDS

    props = JourneyIn.model_json_schema()["properties"]
    for name, (low, high, closed) in _BOUNDS.items():
        if name not in props:
            continue  # not exposed over HTTP
        got = props[name]
        assert got["maximum"] == high, name
        assert got.get("minimum" if closed else "exclusiveMinimum") == low, (name, got)
