"""examples/: every input file is a request the server accepts as is, and every script runs (with
small settings, so the suite stays fast) and draws its figure.

The request files are posted to an in-process app with the default settings (the limits a user's
`make run` has); the sweep spec is read by the sweeps' own loader and the full-wave request by its
model (running either is a job of minutes: tests/sweeps and tests/fullwave run such jobs). The
scripts run as a user runs them, `python examples/NAME.py ...` in a scratch directory.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"

#: Each request file and the operation it is the body of (POST, JSON).
REQUESTS = {
    "channel.json": "/v1/channel",
    "fullwave_channel.json": "/v1/channel",
    "localize.json": "/v1/localize",
    "localize_evaluate.json": "/v1/localize/evaluate",
    "ranging_toa.json": "/v1/ranging/toa",
    "ranging_pdoa.json": "/v1/ranging/pdoa",
    "ranging_rss.json": "/v1/ranging/rss",
    "bounds_toa.json": "/v1/bounds/toa",
    "bounds_pdoa.json": "/v1/bounds/pdoa",
    "bounds_rss.json": "/v1/bounds/rss",
    "render.json": "/v1/vision/render",
    "track.json": "/v1/track",
    "track_evaluate.json": "/v1/track/evaluate",
    **{f"plots/{p.name}": f"/v1/plots/{p.stem}" for p in sorted((EXAMPLES / "plots").glob("*.json"))},
}
#: Inputs of jobs, checked by their readers, not run here.
JOB_INPUTS = {"sweep.yaml", "fullwave.json"}


def test_every_input_file_is_listed_here_and_in_the_examples_readme():
    files = {p.relative_to(EXAMPLES).as_posix() for p in EXAMPLES.rglob("*") if p.suffix in (".json", ".yaml")}
    assert files == set(REQUESTS) | JOB_INPUTS
    readme = (EXAMPLES / "README.md").read_text()
    named = {f"`{n.split('/')[1][:-5]}`" if n.startswith("plots/") else n for n in files}  # plots: by kind
    missing = [n for n in named | {p.name for p in EXAMPLES.glob("*.py") if not p.name.startswith("_")}
               if n not in readme]
    assert missing == []
    assert len(REQUESTS) >= 20  # the plots' files were found


@pytest.fixture(scope="module")
def default_app(tmp_path_factory):
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    # the default settings but the deadline: no verdict may depend on the speed of a busy machine
    settings = Settings(data_dir=tmp_path_factory.mktemp("examples-data"), log_level="warning",
                        request_deadline_s=3600)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


@pytest.mark.parametrize("name", sorted(REQUESTS))
def test_request_file_is_accepted(default_app, name):
    body = json.loads((EXAMPLES / name).read_text())
    r = default_app.post(REQUESTS[name], json=body, headers={"Accept": "*/*"})
    assert r.status_code == 200, r.text[:2000]


def test_job_inputs_are_valid():
    from service.schemas.fullwave import FullwaveRequest
    from sweeps import load_spec

    spec = load_spec(EXAMPLES / "sweep.yaml")
    assert spec.data["phantom"] == "torso" and spec.data["localization"]  # read as written, the fix included
    FullwaveRequest.model_validate(json.loads((EXAMPLES / "fullwave.json").read_text()))


#: Each script with the small settings its test runs it with, and a line its output must have.
SCRIPTS = {
    "fig_5_6_channel.py": (["--rays", "20000"], "path: delay 1.3390 ns"),  # the scenario's direct path (README)
    "ranging.py": (["--rays", "20000", "--trials", "20"], "regression: distance"),
    "sweep_along_tract.py": (["--ds-mm", "200", "--trials", "5", "--workers", "1"], "fixes: median 3-D error"),
    "localization_cdf.py": (["--trials", "5", "--rays", "20000", "--methods", "nonlinear,joint_velocity"],
                            "joint_velocity: RMSE"),
    "track.py": (["--steps", "20", "--rays", "5000"], "fused_pf: RMSE along the tract"),
    "video_pair.py": (["--size-px", "128"], "rotation"),
}


def test_every_script_is_run_here():
    assert set(SCRIPTS) == {p.name for p in EXAMPLES.glob("*.py") if not p.name.startswith("_")}


@pytest.mark.slow
@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_script_runs_and_draws_its_figure(script, tmp_path):
    args, expected = SCRIPTS[script]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, str(EXAMPLES / script), *args, "--out", str(tmp_path)], cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-4000:]
    assert expected in out.stdout, out.stdout
    figures = [line.split("figure: ", 1)[1] for line in out.stdout.splitlines() if line.startswith("figure: ")]
    assert len(figures) == 1 and Path(figures[0]).parent == tmp_path
    assert Path(figures[0]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
