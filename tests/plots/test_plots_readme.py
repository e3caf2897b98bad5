"""The README's pictures: committed, PNG, the sizes their commands make, and the request the PDP's
command traces is a valid channel request."""

from __future__ import annotations

import json
import struct
from pathlib import Path

from service.schemas.channel import ChannelRequest

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", head[16:24])


def test_readme_pictures_exist_with_their_commands():
    assert "](docs/img/viewer.png)" in README and "](docs/img/pdp.png)" in README
    assert "capsule-rt channel docs/img/pdp_request.json -o channel.json" in README
    assert "capsule-rt plot pdp channel.json -o docs/img/pdp.png" in README
    assert "CAPSULE_RT_VIEWER_SCREENSHOT=docs/img/viewer.png" in README
    assert png_size(ROOT / "docs/img/pdp.png") == (1200, 675)  # 8 x 4.5 in at 150 dpi, the PDP's defaults
    assert png_size(ROOT / "docs/img/viewer.png") == (1400, 820)  # the browser test's viewport
    ChannelRequest.model_validate(json.loads((ROOT / "docs/img/pdp_request.json").read_text()))
