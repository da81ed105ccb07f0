"""The import graph of normbox_lab, read from the source (AST), function-local imports included.

`drivers/`, `sim/` and `protocols/` install as `normbox_lab.drivers` … (setup.py), so they are
mapped into the package here.  Every ``import`` and ``from … import`` statement counts wherever
it stands (module level, inside a function, under ``if TYPE_CHECKING:``): a cycle hidden behind
a function-local import is still a cycle.

Asserted: the graph has no cycle, and ``normbox_lab.analyze`` imports neither
``normbox_lab.sim`` nor ``normbox_lab.demo`` (analysis sits above the simulator, not below it).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: source folder → the package it installs as (setup.py's MAPPED_FOLDERS, plus the package)
FOLDERS = {"normbox_lab": "normbox_lab", "drivers": "normbox_lab.drivers",
           "sim": "normbox_lab.sim", "protocols": "normbox_lab.protocols"}


def module_files() -> dict[str, Path]:
    """Dotted module name → source file, for every module of the installed package."""
    out: dict[str, Path] = {}
    for folder, package in FOLDERS.items():
        base = ROOT / folder
        for path in sorted(base.rglob("*.py")):
            rel = path.relative_to(base).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([package, *parts])] = path
    return out


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of a dotted name that is one of our modules."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in modules:
            return cand
    return None


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Our modules imported anywhere in `path` (function bodies and TYPE_CHECKING included)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    is_package = path.name == "__init__.py"
    package = module if is_package else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                got = _resolve(alias.name, modules)
                if got:
                    found.add(got)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base_parts = package.split(".")
                base_parts = base_parts[: len(base_parts) - (node.level - 1)]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                # `from pkg import mod` imports the submodule; `from mod import name` the module
                got = _resolve(f"{base}.{alias.name}", modules) or _resolve(base, modules)
                if got:
                    found.add(got)
    found.discard(module)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = module_files()
    return {m: imports_of(m, p, modules) for m, p in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def test_the_graph_covers_the_mapped_folders(graph: dict[str, set[str]]) -> None:
    # the reader sees every part of the installed package, and real edges in it
    for name in ("normbox_lab.sim.world", "normbox_lab.drivers.cs1000",
                 "normbox_lab.protocols.reference_sweep", "normbox_lab.analyze.pipeline",
                 "normbox_lab.demo"):
        assert name in graph
    assert "normbox_lab.core.errors" in graph["normbox_lab.drivers.cs1000"]
    # a function-local import is an edge too (demo imports the pipeline inside run_demo)
    assert "normbox_lab.analyze.pipeline" in graph["normbox_lab.demo"]


def test_function_local_imports_and_relative_imports_count(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from pkg import b\n    return b\n")
    (pkg / "b.py").write_text("from . import a\n")
    modules = {"pkg": pkg / "__init__.py", "pkg.a": pkg / "a.py", "pkg.b": pkg / "b.py"}
    g = {m: imports_of(m, p, modules) for m, p in modules.items()}
    assert g["pkg.a"] == {"pkg.b"} and g["pkg.b"] == {"pkg.a"}
    assert cycles(g) == [["pkg.a", "pkg.b"]]


def test_no_import_cycle(graph: dict[str, set[str]]) -> None:
    assert cycles(graph) == []


def test_analysis_sits_above_the_simulator(graph: dict[str, set[str]]) -> None:
    bad = sorted(f"{m} → {t}" for m, targets in graph.items()
                 if m == "normbox_lab.analyze" or m.startswith("normbox_lab.analyze.")
                 for t in targets
                 if t == "normbox_lab.demo" or t == "normbox_lab.sim"
                 or t.startswith("normbox_lab.sim."))
    assert bad == []
