"""POST /v1/track and /v1/track/evaluate through the app: answers, and 422s naming the field."""

from __future__ import annotations

import numpy as np

from raytrace.body.torso import default_torso


def _body(n=20):
    line = default_torso().centrelines["gi_tract"]
    s = 0.25 + 1e-3 * np.arange(n)
    pts = line.point_m(s)
    obs = [{"t_s": 0.5 * k, "rf": {"position_m": pts[k].tolist(), "covariance_m2": (1e-4 * np.eye(3)).tolist()},
            "visual": None if k == 0 else {"advance_m": 1e-3, "advance_sigma_m": 1e-4, "roll_deg": 2.0,
                                           "roll_sigma_deg": 0.1}} for k in range(n)]
    return {"observations": obs, "config": {"initial_s_m": 0.25, "initial_s_sigma_m": 0.005}}, s


def test_track_answers_a_trajectory_with_uncertainty(api):
    body, s = _body()
    for tracker in ("kalman", "particle"):
        r = api.post("/v1/track", json={**body, "tracker": tracker})
        assert r.status_code == 200, r.text
        steps = r.json()["steps"]
        assert len(steps) == len(s)
        est = np.array([p["s_m"] for p in steps])
        # exact fixes (10 mm declared) and exact advances (0.1 mm declared): within 3 mm of the truth
        assert np.max(np.abs(est - s)) < 3e-3
        assert all(p["s_sigma_m"] > 0 for p in steps)
        assert abs(steps[-1]["roll_deg"] - 2.0 * (len(s) - 1)) < 1.0


def test_track_names_the_bad_field(api):
    body, _ = _body(3)
    body["observations"][1]["t_s"] = 0.0
    r = api.post("/v1/track", json=body)
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "observations", 1, "t_s"]
    body, _ = _body(3)
    body["observations"][0]["rf"]["covariance_m2"] = [[1, 0, 0], [0, -1, 0], [0, 0, 1]]
    r = api.post("/v1/track", json=body)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "observations", 0, "rf", "covariance_m2"]
    r = api.post("/v1/track", json={**body, "centreline": "nope"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "centreline"]
    r = api.post("/v1/track", json={**body, "config": {"particles": 5}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:3] == ["body", "config", "particles"]
    r = api.post("/v1/track/evaluate", json={"journey": {"steps": 100000}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:3] == ["body", "journey", "steps"]
    r = api.post("/v1/track/evaluate", json={"trackers": ["magic"]})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:3] == ["body", "trackers", 0]


def test_evaluate_video_only_needs_no_trace(api):
    """The video tracker alone needs no RF trace: a quick answer with the rmse per tracker and its
    consistency (NEES of s and NIS of the advances against their bands; 3 runs of 40 steps)."""
    r = api.post("/v1/track/evaluate", json={"journey": {"steps": 40, "seed": 2}, "trackers": ["video"], "runs": 3})
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["rf_positions_traced"] == 0 and out["runs"] == 3
    assert 0.0 < out["rmse_m"]["video"] < 0.02  # the prior alone is drawn 5 mm off
    assert len(out["trajectory"]["video"]) == 40 and len(out["truth"]) == 40
    c = out["consistency"]["video"]
    assert set(c) == {"nees", "nis_visual"}
    assert c["nees"]["samples"] == 120 and c["nees"]["effective"] == 3 and c["nees"]["dof"] == 1
    assert c["nees"]["lower"] < 1.0 < c["nees"]["upper"] and c["nis_visual"]["samples"] > 0
    r = api.post("/v1/track/evaluate", json={"journey": {"steps": 1000}, "runs": 6, "trackers": ["video"]})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "runs"], r.text


def test_track_takes_a_fix_bias_and_the_new_gates(api):
    """A fix's bias covariance with rf_correlation_length_m (docs/tracking.md): a stopped capsule's
    repeated fixes keep the uncertainty at the bias's; a speed range drops an impossible advance;
    a bias covariance that is not positive semi-definite is refused naming it."""
    line = default_torso().centrelines["gi_tract"]
    p = line.point_m(0.25).tolist()
    bias = (6.4e-5 * np.eye(3)).tolist()
    obs = [{"t_s": 0.5 * k, "rf": {"position_m": p, "covariance_m2": (1e-10 * np.eye(3)).tolist(),
                                   "bias_covariance_m2": bias}} for k in range(20)]
    cfg = {"initial_s_m": 0.25, "initial_s_sigma_m": 0.02, "rf_correlation_length_m": 0.003,
           "speed_range_m_per_s": [-0.002, 0.004]}
    r = api.post("/v1/track", json={"observations": obs, "config": cfg})
    assert r.status_code == 200, r.text
    assert r.json()["steps"][-1]["s_sigma_m"] > 6e-3  # 8 mm of bias, not averaged away
    obs[5]["visual"] = {"advance_m": -0.003, "advance_sigma_m": 1e-4}  # -6 mm/s: not a motion
    r = api.post("/v1/track", json={"observations": obs, "config": cfg, "tracker": "particle"})
    assert r.status_code == 200, r.text
    obs[3]["rf"]["bias_covariance_m2"] = [[1e-4, 0, 0], [0, -1e-4, 0], [0, 0, 1e-4]]
    r = api.post("/v1/track", json={"observations": obs, "config": cfg})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "observations", 3, "rf",
                                                                      "bias_covariance_m2"], r.text


def test_evaluate_keeps_to_the_servers_ray_and_interaction_limits(make_settings):
    """The app of this test allows 5000 rays and 3 interactions: more is a 422 naming the field before
    any work starts; the defaults (20 000 rays, 6 interactions) are lowered to the server's limits (a video-only
    run answers)."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(make_settings(max_rays=5000, max_interactions=3))) as client:
        r = client.post("/v1/track/evaluate", json={"rays": 6000})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "rays"], r.text
        assert "5000" in r.json()["detail"][0]["msg"]
        r = client.post("/v1/track/evaluate", json={"max_interactions": 4})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "max_interactions"], r.text
        r = client.post("/v1/track/evaluate", json={"journey": {"steps": 20, "seed": 2}, "trackers": ["video"]})
        assert r.status_code == 200, r.text
