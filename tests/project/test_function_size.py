"""Functions that read in one screen: no function of the product is over 80 lines.

Read from the source (AST) over the folders that install as the package (`normbox_lab/`,
`drivers/`, `sim/`, `protocols/`).  A function's length is its ``def`` line to its last line,
decorators left out, nested functions and docstrings counted in.  A longer function fails
unless it is listed in `EXCEPTIONS` with its reason; an exception that names no function any
more, or a function back under the limit, fails too, so the list only shrinks.

    python tests/project/test_function_size.py      # the 15 longest functions, with their lengths
"""

from __future__ import annotations

import ast
from pathlib import Path

from test_import_graph import module_files

MAX_LINES = 80

#: qualified name (module.Class.function) → why it stays longer than MAX_LINES
EXCEPTIONS: dict[str, str] = {
    "normbox_lab.predict.patchset.PatchSetTracer._trace_patches": (
        "a Dr.Jit kernel body: everything it does is traced into one kernel, and it reads as "
        "that kernel, top to bottom (lane setup, the first vertex's QMC draws, the loop, the "
        "per-lane sums)"),
    "normbox_lab.predict.bandpath.BandPathTracer._path_loop": (
        "a Dr.Jit kernel body: the bounce closure and the dr.while_loop over its state are one "
        "recorded loop (with the band loop inside it) and read best together"),
}


def function_lengths(modules: dict[str, Path]) -> dict[str, int]:
    """Qualified name → lines, for every function and method (nested ones too)."""
    out: dict[str, int] = {}

    def walk(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}.{child.name}"
                assert child.end_lineno is not None
                out[name] = max(out.get(name, 0), child.end_lineno - child.lineno + 1)
                walk(child, name)
            elif isinstance(child, ast.ClassDef):
                walk(child, f"{prefix}.{child.name}")
            else:
                walk(child, prefix)

    for module, path in modules.items():
        walk(ast.parse(path.read_text(encoding="utf-8")), module)
    return out


def test_lengths_are_measured_def_to_last_line(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    body = "\n".join(f"        x{i} = {i}" for i in range(MAX_LINES))
    src.write_text(f"class C:\n    @staticmethod\n    def f():\n{body}\n\n\ndef g():\n"
                   "    def h():\n        return 1\n    return h\n")
    got = function_lengths({"m": src})
    assert got == {"m.C.f": MAX_LINES + 1, "m.g": 4, "m.g.h": 2}


def test_no_function_is_over_the_limit() -> None:
    lengths = function_lengths(module_files())
    too_long = sorted(f"{name}: {n} lines" for name, n in lengths.items()
                      if n > MAX_LINES and name not in EXCEPTIONS)
    assert too_long == []


def test_every_exception_is_still_needed() -> None:
    lengths = function_lengths(module_files())
    for name, reason in EXCEPTIONS.items():
        assert reason.strip()
        assert name in lengths, f"{name}: no such function any more"
        assert lengths[name] > MAX_LINES, f"{name}: {lengths[name]} lines, drop the exception"


if __name__ == "__main__":
    ranked = sorted(function_lengths(module_files()).items(), key=lambda kv: -kv[1])
    for name, n in ranked[:15]:
        print(f"{n:4d}  {name}{'  (excepted)' if name in EXCEPTIONS else ''}")
