"""What the example scripts share: where the figure goes, and a channel profile in the JSON shape
the API returns (what the `plots` package draws)."""

from __future__ import annotations

import argparse
from pathlib import Path


def parser(doc: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=doc)
    p.add_argument("--out", type=Path, default=Path("."), help="directory for the figure (default: here)")
    return p


def save(fig, out: Path, name: str) -> Path:
    """Write a matplotlib figure as ``out/name`` (PNG) and say where."""
    from plots.figure import figure_bytes

    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    path.write_bytes(figure_bytes(fig, "png"))
    print(f"figure: {path}")
    return path


def profile_json(profile, frequency_hz: float) -> dict:
    """A traced receiver profile (``raytrace`` result) as POST /v1/channel writes ``profiles[i]``."""
    return {
        "receiver": profile.receiver,
        "gains_include_delay_phase": True,
        "reference_frequency_hz": frequency_hz,
        "paths": [{"delay_s": p.delay_s, "gain": {"re": p.gain.real, "im": p.gain.imag},
                   "interactions": [{"kind": i.kind} for i in p.interactions]} for p in profile.paths],
    }
