"""docs/service.md's worked upload example (three nested spheres) runs as written: its Python
block, then its curl block on the files the Python block wrote, against the live server."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.conftest import HANG_GUARD_S

pytestmark = pytest.mark.e2e

DOC = Path(__file__).resolve().parents[2] / "docs" / "service.md"


def _example_blocks() -> tuple[str, str]:
    section = DOC.read_text().split("### Worked example", 1)[1].split("\n## ", 1)[0]
    (python,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    (shell,) = re.findall(r"```sh\n(.*?)```", section, flags=re.S)
    return python, shell


def test_the_worked_upload_example_runs(live_url, tmp_path):
    python, shell = _example_blocks()
    env = {**os.environ, "CAPSULE_RT_URL": live_url, "BASE_URL": live_url}
    if not os.environ.get("CAPSULE_RT_URL"):  # the suite's own keyless server; CI's server container needs it
        env.pop("CAPSULE_RT_KEY", None)
    out = subprocess.run([sys.executable, "-c", python], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=HANG_GUARD_S)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    pid = lines[0].split()[0]
    assert pid.startswith("up-") and "'muscle': 'fat'" in lines[0] and "'fat': 'skin'" in lines[0]
    assert "'capsule': ('capsule', 'muscle')" in lines[1] and "'contact': ('sensor', 'skin')" in lines[1]
    assert "'air': ('sensor', 'air')" in lines[1]
    assert lines[2].startswith("contact skin ") and lines[3].startswith("air air ")
    ids = [pid]
    try:
        if shutil.which("curl") is None:
            pytest.skip("curl is not installed")
        out = subprocess.run(["bash", "-c", "set -euo pipefail\n" + shell], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=HANG_GUARD_S)
        assert out.returncode == 0, out.stderr
        again = json.loads(out.stdout)
        ids.append(again["id"])
        assert {o["name"]: o["parent"] for o in again["organs"]} == {"skin": "air", "fat": "skin", "muscle": "fat"}
    finally:
        for phantom_id in ids:
            httpx.delete(f"{live_url}/v1/phantoms/{phantom_id}", timeout=HANG_GUARD_S)
