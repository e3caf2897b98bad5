"""The built-in ``abdomen-ct`` phantom through the API (in-process): listed with its landmark sites, traced,
rendered inside the real lumen at arc lengths of its journey, tracked along its tract, swept every N mm along
it, and exported for the viewer. Oracles: the phantom object itself (raytrace.body.abdomen) and the
centreline, which know nothing of the service; every refusal names its field."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient

from raytrace.body.abdomen import abdomen_ct
from service.app import create_app
from service.settings import Settings
from vision.png import decode_png

LANDMARKS = ("small_intestine_DJJ", "small_intestine_JIJ", "small_intestine_ITIJ", "large_intestine_ICVc",
             "large_intestine_caecum", "large_intestine_HF", "large_intestine_SF", "large_intestine_DSJ",
             "large_intestine_RSJ", "stomach_body")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(Settings(data_dir=str(tmp_path_factory.mktemp("data")), log_level="error", max_rays=20_000))
    with TestClient(app) as c:
        yield c


def test_listed_with_its_landmark_sites(client):
    listed = {p["id"]: p for p in client.get("/v1/phantoms").json()["phantoms"]}
    assert listed["abdomen-ct"]["builtin"] and listed["abdomen-ct"]["triangles"] > 100_000
    detail = client.get("/v1/phantoms/abdomen-ct").json()
    assert [o["name"] for o in detail["organs"]][4:] == ["oesophagus", "stomach", "small_intestine",
                                                          "large_intestine"]
    sites = detail["sites"]
    for name in LANDMARKS:
        assert sites[name]["kind"] == "capsule" and sites[name]["medium"] == name.rsplit("_", 1)[0]
    assert all(s["medium"] == "skin" for s in sites.values() if s["kind"] == "sensor")
    # the attribution the licence asks for travels with the served phantom
    for needed in ("Burger", "CC BY 4.0", "doi:10.1186/s12911-023-02111-9"):
        assert needed in detail["description"], needed


def test_a_channel_from_a_landmark(client):
    sensors = [n for n, s in abdomen_ct().sites.items() if s.kind == "sensor"][:3]
    r = client.post("/v1/channel", json={"phantom": "abdomen-ct", "transmitter": {"site": "small_intestine_JIJ"},
                                         "receivers": [{"site": s} for s in sensors], "rays": 5000,
                                         "max_interactions": 2})
    assert r.status_code == 200, r.text
    profiles = r.json()["profiles"]
    assert [p["receiver"] for p in profiles] == sensors
    r = client.post("/v1/channel", json={"phantom": "abdomen-ct", "transmitter": {"site": "nowhere"},
                                         "receivers": [{"site": sensors[0]}], "rays": 5000})
    assert r.status_code == 404 and r.json()["detail"][0]["loc"][:3] == ["body", "transmitter", "site"]


def test_localized_from_its_sensor_sites(client):
    """Ranges to the abdomen's own sensor sites, resolved through the phantom: the constant-velocity fix
    lands on the landmark (exact ranges: the straight-line distances computed here from the phantom)."""
    phantom = abdomen_ct()
    truth = phantom.sites["large_intestine_HF"].position_m
    names = ["b1_000", "b2_090", "b3_180", "b4_270", "b2_315", "b3_045"]
    sensors = [{"site": n, "range_m": float(np.linalg.norm(phantom.sites[n].position_m - truth))} for n in names]
    r = client.post("/v1/localize", json={"phantom": "abdomen-ct", "method": "nonlinear", "sensors": sensors})
    assert r.status_code == 200, r.text
    assert np.linalg.norm(np.array(r.json()["position_m"]) - truth) < 1e-6
    np.testing.assert_allclose(r.json()["sensor_positions_m"][1], phantom.sites["b2_090"].position_m)
    r = client.post("/v1/localize", json={"phantom": "abdomen-ct", "method": "nonlinear",
                                          "sensors": [{"site": "nowhere", "range_m": 0.1}, *sensors[1:]]})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:4] == ["body", "sensors", 0, "site"]


@pytest.mark.parametrize("s_m", [0.03, 0.15, 1.0, 3.2])  # oesophagus, stomach, jejunum, ascending colon
def test_the_camera_renders_inside_the_real_lumen(client, s_m):
    line = abdomen_ct().centrelines["gi_tract"]
    r = client.post("/v1/vision/render", json={"phantom": "abdomen-ct", "pose": {"s_m": s_m},
                                               "camera": {"size_px": 64}})
    assert r.status_code == 200, r.text
    assert r.headers["X-Pose-Organ"] == line.organ_at(s_m)
    position = np.array([float(v) for v in r.headers["X-Pose-Position-M"].split(",")])
    np.testing.assert_allclose(position, line.point_m(s_m), atol=1e-9)
    image = decode_png(r.content)
    assert image.shape[:2] == (64, 64) and image.std() > 5  # a lit wall, not a blank frame
    r = client.post("/v1/vision/render", json={"phantom": "abdomen-ct", "pose": {"s_m": 5.0}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "pose", "s_m"]


def test_tracked_along_its_tract(client):
    line = abdomen_ct().centrelines["gi_tract"]
    s = 3.5 + 1e-3 * np.arange(20)  # the transverse colon
    pts = line.point_m(s)
    obs = [{"t_s": 0.5 * k, "rf": {"position_m": pts[k].tolist(), "covariance_m2": (1e-4 * np.eye(3)).tolist()},
            "visual": None if k == 0 else {"advance_m": 1e-3, "advance_sigma_m": 1e-4, "roll_deg": 0.0,
                                           "roll_sigma_deg": 0.1}} for k in range(20)]
    r = client.post("/v1/track", json={"phantom": "abdomen-ct", "observations": obs,
                                       "config": {"initial_s_m": 3.5, "initial_s_sigma_m": 0.005}})
    assert r.status_code == 200, r.text
    est = np.array([p["s_m"] for p in r.json()["steps"]])
    assert np.max(np.abs(est - s)) < 3e-3  # exact fixes (10 mm declared), exact advances: the torso's bound


def test_swept_every_n_mm_along_the_tract(client):
    from sweeps import load_spec
    from sweeps.plan import make_plan

    spec = load_spec({"phantom": "abdomen-ct", "capsule_positions": {"along_tract": {"ds_m": 0.5}},
                      "channel": {"rays": 5000, "max_interactions": 2}})
    plan = make_plan(spec, abdomen_ct(), "abdomen-ct")
    line = abdomen_ct().centrelines["gi_tract"]
    assert plan.n_positions == int(line.length_m // 0.5) + 1  # 0, 0.5, ..., 4.0 m
    np.testing.assert_allclose(plan.s_m, 0.5 * np.arange(plan.n_positions), atol=1e-12)
    organs = list(plan.media)
    assert organs[0] == "oesophagus" and organs[-1] == "large_intestine" and "small_intestine" in organs
    r = client.post("/v1/sweeps", json={"phantom": "abdomen-ct", "capsule_positions":
                                        {"along_tract": {"ds_m": 0.001, "stop_m": 9.0}}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:3] == ["body", "capsule_positions", "along_tract"]


def test_the_viewer_gets_its_mesh_and_manifest(client):
    r = client.get("/v1/phantoms/abdomen-ct/mesh")
    assert r.status_code == 200 and r.content[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(r.content), file_type="glb")
    assert set(scene.geometry) >= {"oesophagus", "stomach", "small_intestine", "large_intestine", "skin"}
    manifest = client.get("/v1/phantoms/abdomen-ct/manifest").json()
    pieces = manifest["centrelines"]["gi_tract"]["pieces"]
    assert [p["organ"] for p in pieces] == ["oesophagus", "stomach", "small_intestine", "large_intestine"]
