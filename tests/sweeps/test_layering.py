"""sweeps uses raytrace and estimators and never the service (docs/architecture.md); and neither
raytrace nor estimators imports sweeps. Read off the import statements (AST, no import)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _roots(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("path", sorted((ROOT / "sweeps").rglob("*.py")), ids=lambda p: p.name)
def test_sweeps_never_import_the_service(path):
    assert "service" not in _roots(path)


@pytest.mark.parametrize("path", sorted([*(ROOT / "raytrace").rglob("*.py"), *(ROOT / "estimators").rglob("*.py")]),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_physics_never_imports_sweeps(path):
    assert "sweeps" not in _roots(path)
