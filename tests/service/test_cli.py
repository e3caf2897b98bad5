"""The ``capsule-rt`` command line: channel (local, no HTTP), demo, argument errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from service.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _data_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("CAPSULE_RT_DATA_DIR", str(tmp_path / "data"))


def test_channel_command_prints_the_response_json(tmp_path, capsys):
    req = tmp_path / "req.json"
    req.write_text(json.dumps({"scenario": "thesis-fig-5-6", "rays": 5000}))
    assert main(["channel", str(req)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scenario"] == "thesis-fig-5-6"
    delays = [p["delay_s"] for p in out["profiles"][0]["paths"]]
    # Thesis Fig 5.6: first path 1.338 ns (0.076 m at eps_r 27.9), three paths.
    assert delays[0] == pytest.approx(0.076 * 27.9**0.5 / 299_792_458.0, rel=1e-3)
    assert len(delays) == 3


def test_channel_command_writes_an_output_file(tmp_path):
    req = tmp_path / "req.json"
    req.write_text(json.dumps({"scenario": "thesis-fig-5-6", "rays": 2000}))
    out = tmp_path / "out.json"
    assert main(["channel", str(req), "--output", str(out)]) == 0
    assert json.loads(out.read_text())["phantom"] == "thesis-fig-5-6"


@pytest.mark.parametrize(
    "body, field",
    [
        ({"scenario": "thesis-fig-5-6", "rays": -3}, "rays"),
        ({"scenario": "nope"}, "scenario"),
        ({"phantom": "torso", "transmitter": {"position_m": [9, 9, 9]}, "receivers": [{"site": "belt_left"}],
          "rays": 100}, "transmitter"),
    ],
)
def test_channel_command_reports_bad_requests_with_the_field(tmp_path, capsys, body, field):
    req = tmp_path / "req.json"
    req.write_text(json.dumps(body))
    assert main(["channel", str(req)]) == 2
    err = json.loads(capsys.readouterr().err)
    assert any(field in item["loc"] for item in err["detail"]), err


def test_channel_command_with_a_missing_or_broken_file(tmp_path, capsys):
    assert main(["channel", str(tmp_path / "missing.json")]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text("{nope")
    assert main(["channel", str(bad)]) == 2


def test_demo_prints_paths_and_ranging_tables(capsys):
    assert main(["demo", "--rays", "3000"]) == 0
    out = capsys.readouterr().out
    assert "thesis-fig-5-6" in out and "default torso" in out
    assert "delay [ns]" in out and "gcc" in out and "CRLB [mm]" in out
    assert "1.339" in out  # the thesis' direct path, 1.338-1.339 ns


def test_unknown_command_exits_with_usage():
    out = subprocess.run([sys.executable, "-m", "service.cli", "frobnicate"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and "usage" in out.stderr
