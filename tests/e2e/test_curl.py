"""The README's curl examples (docs/curl_examples.sh) run as is against a live server."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import HANG_GUARD_S

pytestmark = pytest.mark.e2e

SCRIPT = Path(__file__).resolve().parents[2] / "docs" / "curl_examples.sh"


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl is not installed")
def test_curl_examples_work(live_url):
    out = subprocess.run(
        ["bash", str(SCRIPT)], env={**os.environ, "BASE_URL": live_url}, capture_output=True, text=True,
        timeout=HANG_GUARD_S
    )
    assert out.returncode == 0, out.stderr
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.strip()]
    assert len(lines) == 5
    health, tissues, bound, channel, toa = lines
    assert health == {"status": "ok"}
    assert len(tissues["tissues"]) == 27
    assert abs(bound["sigma_m"] - 3.2e-5) < 1e-6
    assert channel["scenario"] == "thesis-fig-5-6" and channel["profiles"][0]["paths"]
    assert toa["method"] == "gcc" and abs(toa["distance_m"] - 0.076) < 1e-3
