"""The architecture as documented is the tree as it is.

- The README's architecture section names every package, and in brackets every module of it,
  exactly once; nothing it names is missing from the tree.
- docs/architecture.md (one page, one text diagram) names each module it walks through once,
  and every module it names exists.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: the source roots of the distribution (drivers/, sim/, protocols/ install as normbox_lab.*)
SOURCE_ROOTS = ("normbox_lab", "drivers", "sim", "protocols")


def packages_on_disk() -> dict[str, set[str]]:
    """Package folder (relative, e.g. ``normbox_lab/tui/tabs``) → its module names."""
    out: dict[str, set[str]] = {}
    for root in SOURCE_ROOTS:
        for init in (ROOT / root).rglob("__init__.py"):
            folder = init.parent
            out[folder.relative_to(ROOT).as_posix()] = {
                p.stem for p in folder.glob("*.py") if p.stem != "__init__"}
    return out


def readme_tree() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Architecture"):]
    start = section.index("```\n") + 4
    return section[start:section.index("```", start)]


def readme_packages() -> dict[str, list[str]]:
    """Package folder → the module names its bracketed list gives, in order (duplicates kept)."""
    label = re.compile(r"^( *)([\w.]+/)(?=\s|$)")
    blocks: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    current = ""
    for line in readme_tree().splitlines():
        m = label.match(line)
        if m:
            indent = len(m.group(1))
            while stack and stack[-1][0] >= indent:
                stack.pop()
            current = f"{stack[-1][1] if stack else ''}{m.group(2)}"
            stack.append((indent, current))
            line = line[m.end():]
        key = current.rstrip("/")
        blocks[key] = blocks.get(key, "") + line + "\n"
    return {package: [name for bracket in re.findall(r"\[([^\]]*)\]", text)
                      for name in bracket.split()]
            for package, text in blocks.items()}


def test_readme_tree_names_every_package_and_module_exactly_once():
    disk = packages_on_disk()
    listed = readme_packages()
    missing_packages = sorted(set(disk) - set(listed))
    assert missing_packages == [], f"README tree lacks packages {missing_packages}"
    for package, modules in disk.items():
        named = Counter(listed[package])
        twice = sorted(n for n, k in named.items() if k > 1)
        assert twice == [], f"README names {package} modules more than once: {twice}"
        assert set(named) == modules, (
            f"{package}: README lists {sorted(set(named) - modules)} that do not exist and "
            f"lacks {sorted(modules - set(named))}")


def test_readme_tree_parser_sees_nested_packages():
    listed = readme_packages()
    assert "normbox_lab/tui/tabs" in listed and "drivers" in listed
    assert "cli" in listed["normbox_lab"] and "cli" not in listed["normbox_lab/core"]


MODULE_PATH = re.compile(r"(?<![\w/.])((?:normbox_lab/)?(?:core|acquire|predict|analyze|images|"
                         r"tui|tui/tabs|commands|drivers|sim|protocols)/\w+\.py|cli\.py)")


def test_architecture_page_is_one_diagram_naming_each_module_once():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    assert text.count("```") == 2, "one text diagram"
    named = Counter(MODULE_PATH.findall(text))
    twice = sorted(n for n, k in named.items() if k > 1)
    assert twice == [], f"docs/architecture.md names these modules more than once: {twice}"
    for name in named:
        path = name if name.startswith(("normbox_lab/", "drivers/", "sim/", "protocols/")) \
            else f"normbox_lab/{name}"
        assert (ROOT / path).is_file(), f"docs/architecture.md names {name}, which is not there"
    # the walk goes from the emulator's bytes to the report
    for stop in ("sim/cs1000.py", "drivers/cs1000.py", "acquire/runner.py", "acquire/store.py",
                 "analyze/compare.py", "analyze/report.py"):
        assert stop in named, stop
