"""The unrolled skin map's geometry, the design CLI's errors, and the API key on design writes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from plots.coverage import skin_coverage, unroll
from service.app import create_app
from service.cli import main


def test_unroll_places_points_by_polar_angle_from_anterior_towards_plus_x_and_height():
    # oracle: points on a cylinder about z at known angles (0 = anterior -y, 90 = +x) and heights
    angles = np.array([0.0, 30.0, 90.0, 180.0, 270.0])
    z = np.array([0.0, 0.01, 0.02, 0.03, 0.04])
    psi = np.radians(angles)
    pts = np.column_stack([0.15 * np.sin(psi), -0.15 * np.cos(psi), z])
    a, h = unroll(pts, centre_m=np.zeros(3))
    assert np.allclose(a, angles, atol=1e-9) and np.allclose(h, z)
    fig = skin_coverage(pts, [1.0, 2.0, np.nan, 4.0, 5.0], chosen_m=pts[:2], sites_m=pts[3:])
    assert fig.axes[0].get_xlim() == (0.0, 360.0)


def test_cli_refuses_a_bad_spec_with_the_apis_json_and_exit_2(tmp_path, capsys):
    spec = tmp_path / "cov.json"
    spec.write_text(json.dumps({"candidates": {"spacing_m": 0.0001}}))
    assert main(["design", "coverage", str(spec), "--out", str(tmp_path / "out"), "--workers", "0"]) == 2
    err = json.loads(capsys.readouterr().err)
    assert err["detail"][0]["loc"] == ["spec", "candidates", "spacing_m"]
    lay = tmp_path / "lay.json"
    lay.write_text(json.dumps({"sensors": 4}))
    assert main(["design", "layout", str(lay), "--coverage", str(tmp_path / "none")]) == 2
    assert json.loads(capsys.readouterr().err)["detail"][0]["loc"] == ["spec", "coverage"]


@pytest.mark.parametrize("path", ["/v1/design/coverage", "/v1/design/layout"])
def test_design_writes_need_the_api_key_when_the_server_has_keys(make_settings, path):
    app = create_app(make_settings(api_keys="k" * 20, load_builtins=False))
    with TestClient(app, raise_server_exceptions=False) as c:
        body = {"sensors": 4, "coverage": "cv-0000000000000000"} if path.endswith("layout") else {}
        r = c.post(path, json=body)
        assert r.status_code == 401 and r.json()["detail"][0]["loc"] == ["header", "x-api-key"]


def test_spec_files_read_exponents_as_numbers(tmp_path):
    """YAML 1.1's safe loader reads ``1e-6`` (no dot) as a string, and a layout spec with it was refused."""
    from service.design_cli import _read

    (tmp_path / "a.json").write_text('{"max_model_error_s": 1e-6}')
    (tmp_path / "a.yaml").write_text("max_model_error_s: 1e-6\n")
    assert _read(str(tmp_path / "a.json")) == {"max_model_error_s": 1e-6}
    assert _read(str(tmp_path / "a.yaml")) == {"max_model_error_s": 1e-6}
