"""`capsule-rt vision render` and `vision motion`: a sequence on disk with its exact poses, the
estimates per consecutive pair with the errors against that ground truth, refusals as exit codes."""

from __future__ import annotations

import csv
import json

import numpy as np
import SimpleITK as sitk

from service.cli import main


def test_render_then_motion_over_a_sequence(tmp_path, capsys):
    out = tmp_path / "seq"
    assert main(["vision", "render", "--out", str(out), "--frames", "3", "--size-px", "96",
                 "--advance-m", "0.002", "--roll-deg", "3", "--start-s-m", "0.37"]) == 0
    meta = json.loads((out / "sequence.json").read_text())
    assert [f["file"] for f in meta["frames"]] == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    np.testing.assert_allclose([f["s_m"] for f in meta["frames"]], [0.37, 0.372, 0.374], atol=1e-12)
    np.testing.assert_allclose([f["roll_deg"] for f in meta["frames"]], [0.0, 3.0, 6.0], atol=1e-12)
    image = sitk.GetArrayFromImage(sitk.ReadImage(str(out / "frame_0001.png")))  # libpng reads them
    assert image.shape == (96, 96, 3)
    assert main(["vision", "motion", str(out), "--output", str(tmp_path / "est.csv")]) == 0
    rows = list(csv.DictReader((tmp_path / "est.csv").open()))
    assert len(rows) == 2
    for row in rows:
        assert float(row["true_roll_deg"]) == 3.0 and abs(float(row["true_advance_m"]) - 0.002) < 1e-12
        # 96 px frames: a coarse check (the 192 px pair of test_vision_http.py is held to 0.2 deg, 10 %)
        assert abs(float(row["roll_error_deg"])) < 1.0
        assert abs(float(row["advance_error_m"])) < 0.3 * 0.002
    capsys.readouterr()
    assert main(["vision", "motion", str(out / "frame_0000.png"), str(out / "frame_0001.png"),
                 "--options", '{"estimate": "rotation"}']) == 0
    assert json.loads(capsys.readouterr().out)["pairs"][0]["scale"] == 1.0


def test_refusals_exit_non_zero(tmp_path, capsys):
    assert main(["vision", "render", "--out", str(tmp_path), "--start-s-m", "5"]) == 2
    assert json.loads(capsys.readouterr().err)["detail"][0]["loc"] == ["body", "start_m"]
    (tmp_path / "a.png").write_bytes(b"not a png")
    (tmp_path / "b.png").write_bytes(b"not a png")
    assert main(["vision", "motion", str(tmp_path)]) == 1
    assert "reference: is not a PNG" in json.loads(capsys.readouterr().out)["pairs"][0]["error"]
    assert main(["vision", "motion", str(tmp_path), "--options", '{"bins": "many"}']) == 2
