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


# ------------------------------------------------------------------------------------ import cycles
def module_graph(root: Path, packages) -> dict[str, set[str]]:
    """Every module of ``packages`` under ``root`` -> the project modules it imports, read from the AST:
    top-level imports and imports inside functions alike (a cycle hidden in a function is still a
    cycle: it runs when the function does), relative ones resolved, ``from package import module``
    pointing at the module."""
    modules: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(here[:len(here) - node.level + 1] + ([node.module] if node.module else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return out


def test_the_project_has_no_import_cycle():
    """No cycle among the project's modules, imports inside functions included (docs/architecture.md)."""
    assert import_cycles(module_graph(ROOT, sorted(PROJECT))) == []


def test_the_cycle_check_finds_a_cycle_hidden_in_a_function(tmp_path):
    """The check can fail: a synthetic package whose cycle runs through an import inside a function, a
    relative import and a ``from package import module``."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import b\n")
    (pkg / "sub" / "b.py").write_text("from . import c\n")
    (pkg / "sub" / "c.py").write_text("def late():\n    from pkg import a\n    return a\n")
    (pkg / "d.py").write_text("import pkg.a\n")  # imports into the cycle, is not part of it
    graph = module_graph(tmp_path, ["pkg"])
    assert graph["pkg.sub.c"] == {"pkg.a"}
    assert import_cycles(graph) == [["pkg.a", "pkg.sub.b", "pkg.sub.c"]]
    (pkg / "sub" / "c.py").write_text("def late():\n    return 1\n")
    assert import_cycles(module_graph(tmp_path, ["pkg"])) == []


# ------------------------------------------------------------------------------- the service's layers
def _service_modules(under: str = ""):
    for module, path in _modules("service"):
        if module.startswith(f"service.{under}" if under else "service"):
            yield module, path, {m for m in _imports(path) if m.split(".")[0] in PROJECT}


def test_only_the_app_imports_the_routes():
    """Routes are thin handlers (docs/architecture.md, "The service's layers"): the CLIs, the client, the
    jobs and the operations share the application layer (service.operations) and the models
    (service.schemas), never a route module."""
    for module, _, imported in _service_modules():
        if module.startswith("service.routes") or module == "service.app":
            continue
        assert not [m for m in imported if m.startswith("service.routes")], (module, imported)


def test_operations_know_no_http_and_schemas_no_tracer():
    for module, path, _ in _service_modules("operations"):
        assert not [m for m in _imports(path) if m.split(".")[0] in ("fastapi", "starlette")
                    or m.startswith("service.routes")], module
    for module, path, _ in _service_modules("schemas"):
        bad = [m for m in _imports(path) if m.split(".")[0] in ("raytrace", "fullwave", "fastapi")
               or m.startswith(("service.operations", "service.routes", "service.settings"))]
        assert not bad, (module, bad)
