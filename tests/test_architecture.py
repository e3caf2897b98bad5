"""The layering of docs/architecture.md, read off the import statements (AST, no import).

Inside ``raytrace`` a layer imports only the layers below it; ``raytrace`` and
``estimators`` never import ``service``; ``estimators`` does not import ``raytrace``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: raytrace's layers, bottom first; a module may import its own layer and those before it.
LAYERS = ["errors", "physics", "body", "engine", "spec", "results", "solver", "top"]


def _layer(module: str) -> str:
    parts = module.split(".")
    if parts[0] != "raytrace" or len(parts) == 1:
        return "top"
    return parts[1] if parts[1] in LAYERS else "top"


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
            out += [f"{node.module}.{a.name}" for a in node.names if node.module == "raytrace"]
    return out


def _modules(package: str):
    for path in sorted((ROOT / package).rglob("*.py")):
        yield ".".join(path.relative_to(ROOT).with_suffix("").parts), path


#: The Embree binding (docs/architecture.md, "Downward only"): the engine's modules below ``body``, which
#: ``body`` may use for its own ray queries (a phantom's checks and medium lookups). They import nothing of
#: the project but each other and ``raytrace.errors``.
EMBREE_BINDING = {"raytrace.engine.embree", "raytrace.engine.segments", "raytrace.engine.jit",
                  "raytrace.engine.records"}


@pytest.mark.parametrize("module, path", list(_modules("raytrace")), ids=lambda v: str(v))
def test_raytrace_layers_import_downward_only(module, path):
    mine = LAYERS.index(_layer(module))
    for imported in _imports(path):
        root = imported.split(".")[0]
        assert root not in ("service", "estimators"), f"{module} imports {imported}"
        if root == "raytrace" and imported != "raytrace":
            if LAYERS[mine] == "body" and imported in EMBREE_BINDING:
                continue
            assert LAYERS.index(_layer(imported)) <= mine, f"{module} ({LAYERS[mine]}) imports {imported}"


@pytest.mark.parametrize("module", sorted(EMBREE_BINDING))
def test_the_embree_binding_imports_nothing_above_it(module):
    path = ROOT / (module.replace(".", "/") + ".py")
    for imported in _imports(path):
        if imported.split(".")[0] == "raytrace":
            assert imported in EMBREE_BINDING or imported == "raytrace.errors", f"{module} imports {imported}"


@pytest.mark.parametrize("module, path", list(_modules("estimators")), ids=lambda v: str(v))
def test_estimators_import_neither_the_tracer_nor_the_service(module, path):
    for imported in _imports(path):
        assert imported.split(".")[0] not in ("service", "raytrace"), f"{module} imports {imported}"


def test_the_layer_table_knows_every_subpackage():
    parts = {p.stem for p in (ROOT / "raytrace").iterdir() if (p / "__init__.py").exists() or p.suffix == ".py"}
    assert parts - {"__init__", "scenarios"} <= set(LAYERS), parts - set(LAYERS)


#: The packages above the physics and what each may import of the project (docs/architecture.md):
#: none imports the service; a package not listed here must be added with its rule.
LIBRARIES = {
    "sweeps": {"raytrace", "estimators"},
    "evaluation": {"raytrace", "estimators", "sweeps", "tracking", "vision"},  # studies compose the libraries
    "tracking": {"raytrace"},  # trackers on plain arrays and a centreline (docs/tracking.md)
    "plots": {"estimators"},
    "vision": {"raytrace"},
    "fullwave": {"raytrace"},
    # sensor layout design: traces (raytrace), bounds and fixes (estimators), travel-time fields (evaluation),
    # the sweeps' engines, phantom sources and atomic writes (sweeps) (docs/design.md)
    "design": {"raytrace", "estimators", "evaluation", "sweeps"},
}
PROJECT = {"raytrace", "estimators", "service", *LIBRARIES}


@pytest.mark.parametrize("package", sorted(LIBRARIES))
def test_libraries_import_only_what_the_architecture_allows(package):
    allowed = LIBRARIES[package] | {package}
    for module, path in _modules(package):
        for imported in _imports(path):
            root = imported.split(".")[0]
            assert root not in PROJECT or root in allowed, f"{module} imports {imported}"


def test_every_top_level_package_has_a_rule():
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert packages - {"tests", "bench", "tools"} <= PROJECT, packages - PROJECT


#: The only modules that may import numba, llvmlite or ctypes (docs/architecture.md, "One engine fence").
COMPILED = ("raytrace/engine/", "vision/kernels.py", "sweeps/heap.py")


def test_compiled_code_stays_behind_the_engine_fence():
    offenders = []
    for init in sorted(ROOT.glob("*/__init__.py")):
        package = init.parent.name
        if package in ("tests", ".venv"):
            continue
        for module, path in _modules(package):
            rel = path.relative_to(ROOT).as_posix()
            bad = [m for m in _imports(path) if m.split(".")[0] in ("numba", "llvmlite", "ctypes")]
            if bad and not rel.startswith(COMPILED):
                offenders.append(f"{rel}: {sorted(set(bad))}")
    assert not offenders, offenders
