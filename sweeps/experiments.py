"""The thesis' experiments as built-in sweep specs (``sweeps/specs/*.yaml``) and their reports."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["builtin_spec_path", "builtin_specs"]


def builtin_specs() -> dict[str, Path]:
    """Built-in spec name -> packaged file."""
    root = resources.files("sweeps") / "specs"
    return {Path(p.name).stem: Path(str(p)) for p in root.iterdir() if p.name.endswith((".yaml", ".yml", ".json"))}


def builtin_spec_path(name: str) -> Path | None:
    return builtin_specs().get(name)
