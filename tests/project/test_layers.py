"""The layer rule: the rooms of normbox_lab stand on floors, and no import goes up a floor.

The graph is `test_import_graph.import_graph()`: every ``import`` / ``from … import`` counts
wherever it stands (module level, inside a function, under ``if TYPE_CHECKING:``), and the
folders that setup.py maps into the package (``drivers/`` → ``normbox_lab.drivers``, ``sim/`` →
``normbox_lab.sim``, ``protocols/`` → ``normbox_lab.protocols``) are read as those packages.

A room is the first name under ``normbox_lab`` (``normbox_lab.acquire.lab`` → ``acquire``; the
top-level modules ``cli``, ``demo`` and ``__main__`` are rooms of their own; the package's
``__init__`` is ``normbox_lab``).  A module may import its own room and any room on a *lower*
floor; an import sideways (another room on the same floor) or upwards fails, unless it is listed
in `EXCEPTIONS` with its reason.  An exception that no longer matches any import fails too, so
the list only shrinks.

    python tests/project/test_layers.py      # prints the floors and the room graph (edges, counts)
"""

from __future__ import annotations

import ast
import inspect
from collections import Counter
from pathlib import Path

import pytest
from test_import_graph import ROOT, import_graph, imports_of, module_files

#: the floors, bottom up: (rooms, what stands there)
FLOORS: tuple[tuple[tuple[str, ...], str], ...] = (
    (("core", "normbox_lab"), ("types, units, errors, clock, capabilities, transport, colour "
                               "maths, spectral EXR; the package's __init__ (version)")),
    (("drivers",), "instrument drivers behind typed interfaces (bytes in, typed readings out)"),
    (("predict",), "physics of the prediction: materials, scenes, renderers; gets plain inputs"),
    (("images",), "spectral images and figures made with the renderers"),
    (("acquire",), "lab assembly, engine, steps, store and its queries, quality gates"),
    (("sim",), "wire-level emulators, the worlds, the simulated lab's wiring (labsim)"),
    (("protocols",), "the shipped measurement protocols (plain scripts on the engine)"),
    (("analyze",), "fit, prediction runs, comparison, budget, QA, report"),
    (("campaign",), "the simulation campaign: scenarios, harness, invariants (the oracle)"),
    (("tui",), "the operator console"),
    (("demo", "demo_bench", "demo_prewarm"), "the end-to-end demo, its bench and its kernel prewarm"),
    (("commands",), "the command line's subcommands"),
    (("cli",), "the console script's entry"),
    (("__main__",), "python -m normbox_lab"),
)

#: (importing module or package prefix, imported prefix, reason).  A prefix matches the module
#: itself and everything below it (``normbox_lab``: any module).
EXCEPTIONS: tuple[tuple[str, str, str], ...] = (
    ("normbox_lab.campaign.harness", "normbox_lab.cli",
     ("the campaign's harness runs the product's own command line (cli.main) in its forked "
     "segments, as an operator would; the command line starts the campaign (sim campaign)")),
)

FLOOR_OF: dict[str, int] = {room: i for i, (rooms, _) in enumerate(FLOORS) for room in rooms}


def room_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def excepted(module: str, target: str) -> str | None:
    """The reason an upward import is allowed, or None."""
    for src, dst, reason in EXCEPTIONS:
        if _under(module, src) and _under(target, dst):
            return reason
    return None


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Every (module, imported module) that goes sideways or up a floor."""
    out = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            a, b = room_of(module), room_of(target)
            if a != b and FLOOR_OF[b] >= FLOOR_OF[a]:
                out.append((module, target))
    return out


def room_graph(graph: dict[str, set[str]]) -> Counter[tuple[str, str]]:
    """(room, room) → number of module imports between them."""
    edges: Counter[tuple[str, str]] = Counter()
    for module, targets in graph.items():
        for target in targets:
            if room_of(module) != room_of(target):
                edges[(room_of(module), room_of(target))] += 1
    return edges


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def test_every_room_stands_on_one_floor(graph: dict[str, set[str]]) -> None:
    rooms = {room_of(m) for m in graph}
    assert rooms - set(FLOOR_OF) == set()
    named = [r for rooms_, _ in FLOORS for r in rooms_]
    assert len(named) == len(set(named))


def test_the_package_dir_mapping_is_resolved(graph: dict[str, set[str]]) -> None:
    # sim/labsim.py is normbox_lab.sim.labsim, and its import of the lab is an edge sim → acquire
    assert "normbox_lab.acquire.lab" in graph["normbox_lab.sim.labsim"]
    assert "normbox_lab.core.errors" in graph["normbox_lab.drivers.cs1000"]
    assert room_of("normbox_lab.protocols.reference_sweep") == "protocols"


def test_a_function_local_import_up_a_floor_is_found(tmp_path: Path) -> None:
    core = tmp_path / "normbox_lab" / "core"
    core.mkdir(parents=True)
    (core / "__init__.py").write_text("")
    (core / "x.py").write_text("def f():\n    from normbox_lab.analyze import y\n    return y\n")
    analyze = tmp_path / "normbox_lab" / "analyze"
    analyze.mkdir()
    (analyze / "__init__.py").write_text("")
    (analyze / "y.py").write_text("")
    modules = {"normbox_lab.core.x": core / "x.py", "normbox_lab.analyze.y": analyze / "y.py"}
    g = {m: imports_of(m, p, modules) for m, p in modules.items()}
    assert upward_imports(g) == [("normbox_lab.core.x", "normbox_lab.analyze.y")]


def test_no_import_goes_up_a_floor(graph: dict[str, set[str]]) -> None:
    bad = [f"{m} → {t}" for m, t in upward_imports(graph) if excepted(m, t) is None]
    assert bad == []


def test_every_exception_names_a_module_and_a_reason(graph: dict[str, set[str]]) -> None:
    for src, _dst, reason in EXCEPTIONS:
        assert reason.strip()
        assert any(_under(m, src) for m in graph), f"{src}: no such module any more"
    # the exceptions still cover an import that would otherwise fail (else they are stale)
    up = upward_imports(graph)
    assert all(any(_under(m, src) for m, _t in up) for src, _d, _r in EXCEPTIONS)



# --- what is handed over: a store is typed ---------------------------------------------------

def untyped_stores(path: Path) -> list[str]:
    """``line: name`` of every parameter, variable or attribute named ``store`` (or
    ``…_store``) annotated ``Any`` in one file."""
    def is_any(node: ast.expr | None) -> bool:
        return (isinstance(node, ast.Name) and node.id == "Any") or (
            isinstance(node, ast.Constant) and node.value == "Any")

    def is_store(name: str) -> bool:
        return name == "store" or name.endswith("_store")

    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.arg) and is_store(node.arg) and is_any(node.annotation):
            found.append(f"{node.lineno}: {node.arg}")
        elif isinstance(node, ast.AnnAssign) and is_any(node.annotation):
            target = node.target
            name = target.id if isinstance(target, ast.Name) else \
                target.attr if isinstance(target, ast.Attribute) else ""
            if is_store(name):
                found.append(f"{node.lineno}: {name}")
    return found


def test_untyped_stores_are_found(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text("from typing import Any\n"
                   "def f(store: Any, n: Any, ref_store: 'Any') -> None: ...\n"
                   "class C:\n    def __init__(self) -> None:\n        self.store: Any = None\n"
                   "def g(store: Store) -> None: ...\n")
    assert untyped_stores(src) == ["2: store", "2: ref_store", "5: store"]


def test_no_store_is_typed_any() -> None:
    """A store is a `normbox_lab.acquire.store_api.Store` (or, below the store's floor, the
    narrow protocol of what it calls there), never ``Any``: product and tests alike."""
    files = [*module_files().values(), *sorted((ROOT / "tests").glob("*.py"))]
    bad = [f"{p.relative_to(ROOT)}:{hit}" for p in files for hit in untyped_stores(p)]
    assert bad == []


def test_the_fit_writes_through_a_part_of_the_store_protocol() -> None:
    # predict stands below acquire: a fit names an ArtifactSink, whose one method is the
    # Store's own, signature for signature
    from normbox_lab.acquire.store_api import Store
    from normbox_lab.predict.brdf_model import ArtifactSink

    own = [n for n in vars(ArtifactSink) if not n.startswith("_")]
    assert own == ["add_artifact"]
    assert inspect.signature(ArtifactSink.add_artifact) == inspect.signature(Store.add_artifact)


if __name__ == "__main__":
    g = import_graph()
    for i, (rooms, what) in reversed(list(enumerate(FLOORS))):
        print(f"floor {i:2d}  {', '.join(rooms):22s} {what}")
    print()
    for (a, b), n in sorted(room_graph(g).items(), key=lambda e: (-FLOOR_OF[e[0][0]], e[0])):
        arrow = "UP" if FLOOR_OF[b] >= FLOOR_OF[a] else "  "
        print(f"{arrow} {a:10s} -> {b:10s} {n:3d}")
    up = upward_imports(g)
    print(f"\nupward imports: {len(up)} ({sum(excepted(m, t) is None for m, t in up)} not excepted)")
    for m, t in up:
        print(f"  {m} -> {t}: {excepted(m, t) or 'NOT EXCEPTED'}")
