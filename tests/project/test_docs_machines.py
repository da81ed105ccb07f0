"""Every measured time in the docs names the machine it was measured on.

A wall time, a CPU time, a compile time, a first paint or a speed-up moves with the CPU, its
vector ISA, its cores, its load and the Dr.Jit kernel cache.  docs/machines.md lists the machines
the figures were measured on, each under a label (``M-Xeon-512`` ...).  A line or table row that
states a time with a unit (s, ms, µs, min, h) next to a measurement word (measured, took, wall,
CPU, first paint, compile, bench, speed-up, faster, "at load 9", "2 cores") must have, in its
paragraph (a heading is its own), list item (with the list's lead-in), or table / code block
(with the paragraph above it, its caption), one of those labels or the words "machine not
recorded".

Not measurements, and not asked for: protocol constants ("integration time 1 s", "timeout
5 s", a "wall-clock limit") and the emulators' simulated durations.  A time followed by
"virtual" or "of lab time" is not counted, and in a paragraph about the virtual clock only a
line that says wall or CPU time is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MACHINES_DOC = ROOT / "docs" / "machines.md"
NOT_RECORDED = "machine not recorded"

#: docs left out of the check for now, with the reason
EXCLUDED: dict[str, str] = {}

#: a time with its unit: "4.5 s", "0.15–0.3 s", "619.77s", "12.4 min", "≈ 5 ms"
TIME = re.compile(r"(?<![\w.])\d+(?:[.,]\d+)?(?:\s?[–-]\s?\d+(?:[.,]\d+)?)?\s?"
                  r"(?:CPU[·\s]s|s|ms|µs|min|h)(?![\w/²])")
#: what follows a virtual-clock duration
VIRTUAL = re.compile(r"^\s*(?:\)\s*)?(?:of )?(?:virtual|lab time|of virtual)")
#: words that make a time a measurement
MEASUREMENT = re.compile(
    r"(?i)\bmeasured\b|\btook\b|\bwall\b(?![- ]clock)|\bCPU\b|\bfirst paint\b"
    r"|\bcompil(?:e|es|ed|ing|ation)\b"
    r"|\bbench\b|\bspeed-?ups?\b|\b(?:faster|slower)\b|\bload(?: average)? ?[≈~]? ?\d"
    r"|\b\d+(?: shared)?[ -]cores?\b|\b(?:cold|warm)(?: kernel)? cache\b")
#: in a paragraph about the virtual clock only these make a time a measurement
REAL_CLOCK = re.compile(r"(?i)\bwall\b(?![- ]clock)|\bCPU\b")
VIRTUAL_CLOCK = re.compile(r"(?i)virtual (?:clock|lab time)")
LABEL = re.compile(r"`(M-[A-Za-z0-9-]+)`")


def machine_labels(text: str | None = None) -> set[str]:
    """The labels docs/machines.md defines: the first column of its machine table."""
    text = MACHINES_DOC.read_text(encoding="utf-8") if text is None else text
    labels = set()
    for line in text.splitlines():
        if line.startswith("| `M-"):
            match = LABEL.match(line[2:])
            if match:
                labels.add(match.group(1))
    return labels


@dataclass(frozen=True)
class Block:
    """A paragraph, list item, table or code block: its first line number and its lines."""
    first_line: int
    lines: tuple[str, ...]
    kind: str  # "text", "item" (of a list), "table", "code", "heading"


def blocks(text: str) -> list[Block]:
    """Split a Markdown text into headings, paragraphs, list items, tables and fenced code
    blocks."""
    out: list[Block] = []
    current: list[str] = []
    start = 0
    kind = "text"
    in_code = False

    def flush() -> None:
        nonlocal current
        if current:
            out.append(Block(start, tuple(current), kind))
        current = []

    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if in_code:
            current.append(line)
            if stripped.startswith("```"):
                in_code = False
                flush()
            continue
        if stripped.startswith("```"):
            flush()
            start, kind, in_code = number, "code", True
            current.append(line)
            continue
        if not stripped:
            flush()
            continue
        if stripped.startswith("#"):
            flush()
            out.append(Block(number, (line,), "heading"))
            continue
        line_kind = "table" if stripped.startswith("|") else "text"
        new_item = line_kind == "text" and re.match(r"(?:[-*+]|\d+\.) ", stripped)
        if current and (new_item or (line_kind == "table") != (kind == "table")):
            flush()
        if not current:
            start, kind = number, ("item" if new_item else line_kind)
        current.append(line)
    flush()
    return out


def measured_times(line: str, virtual_clock: bool = False) -> list[str]:
    """The times of a line that read as measurements (none when it has no measurement word;
    in a paragraph about the virtual clock, none unless it says wall or CPU time)."""
    if not (REAL_CLOCK if virtual_clock else MEASUREMENT).search(line):
        return []
    return [m.group(0) for m in TIME.finditer(line) if not VIRTUAL.match(line[m.end():])]


def scope_of(parts: list[Block], index: int) -> list[str]:
    """The lines that may name a block's machine: the block itself; for a table or code block
    also the block above it (its caption); for a list item also the paragraph that leads into
    the list."""
    block = parts[index]
    scope = list(block.lines)
    if block.kind in ("table", "code") and index > 0:
        scope += parts[index - 1].lines
    if block.kind == "item":
        before = index - 1
        while before >= 0 and parts[before].kind == "item":
            before -= 1
        if before >= 0 and parts[before].kind == "text":
            scope += parts[before].lines
    return scope


def untagged(text: str, labels: set[str]) -> list[str]:
    """'line N: text' for each measured time whose paragraph (or table / code block with its
    caption above, or list item with the list's lead-in) names no machine label and does not
    say "machine not recorded"."""
    found = []
    parts = blocks(text)
    for index, block in enumerate(parts):
        scope = scope_of(parts, index)
        scope_text = " ".join(scope)
        tagged = NOT_RECORDED in scope_text or any(
            re.search(rf"(?<![\w-]){re.escape(label)}(?![\w-])", scope_text) for label in labels)
        if tagged:
            continue
        virtual_clock = bool(VIRTUAL_CLOCK.search(" ".join(block.lines)))
        for offset, line in enumerate(block.lines):
            if measured_times(line, virtual_clock):
                found.append(f"line {block.first_line + offset}: {line.strip()[:110]}")
    return found


def checked_docs() -> list[Path]:
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    return [p for p in docs if p.relative_to(ROOT).as_posix() not in EXCLUDED]


def test_machines_doc_defines_labels_for_cpu_isa_cores():
    text = MACHINES_DOC.read_text(encoding="utf-8")
    labels = machine_labels(text)
    assert {"M-Xeon-512", "M-EPYC-AVX2"} <= labels
    for line in text.splitlines():
        if line.startswith("| `M-"):
            assert re.search(r"AVX2|AVX-512|NEON", line), line
            assert re.search(r"\d+ cores?", line), line


def test_every_measured_time_in_the_docs_names_its_machine():
    labels = machine_labels()
    offenders = []
    for path in checked_docs():
        rel = path.relative_to(ROOT).as_posix()
        offenders += [f"{rel} {hit}" for hit in untagged(path.read_text(encoding="utf-8"), labels)]
    assert offenders == [], (
        "measured times without a machine label of docs/machines.md (or 'machine not "
        "recorded'):\n" + "\n".join(offenders))


def test_excluded_docs_exist_and_say_why():
    for rel, reason in EXCLUDED.items():
        assert (ROOT / rel).is_file(), rel
        assert reason


LABELS = {"M-Xeon-512", "M-EPYC-AVX2"}


def test_null_an_untagged_measurement_fails():
    doc = "Intro.\n\nThe render took 12.5 s of wall time at load 3.\n\nMore text.\n"
    assert untagged(doc, LABELS) == ["line 3: The render took 12.5 s of wall time at load 3."]
    # a label of another machine list is no label
    assert untagged(doc.replace("load 3", "load 3 on M-Laptop"), LABELS) != []


def test_null_an_untagged_table_row_fails_and_its_caption_tags_it():
    table = "| stage | wall |\n|---|---|\n| fit | 28.9 s wall |\n"
    assert untagged("Stages:\n\n" + table, LABELS) == ["line 5: | fit | 28.9 s wall |"]
    assert untagged("Stages (`M-EPYC-AVX2`, idle):\n\n" + table, LABELS) == []
    assert untagged("Stages (machine not recorded):\n\n" + table, LABELS) == []


def test_null_list_items_and_headings():
    items = "- the render took 3 s wall\n- the fit took 2 s wall\n"
    assert untagged("Measured:\n\n" + items, LABELS) == [
        "line 3: - the render took 3 s wall", "line 4: - the fit took 2 s wall"]
    assert untagged("Measured on M-Xeon-512, load 2:\n\n" + items, LABELS) == []
    assert untagged("- the fit took 2 s wall (M-Xeon-512)\n- the render took 3 s wall\n",
                    LABELS) == ["line 2: - the render took 3 s wall"]
    assert untagged("### Tests (took 6 s wall)\n\nText.\n", LABELS) == [
        "line 1: ### Tests (took 6 s wall)"]
    assert untagged("### Tests (took 6 s wall; machine not recorded)\n", LABELS) == []


def test_null_a_tagged_measurement_passes():
    doc = "The render took 12.5 s of wall time (M-Xeon-512, load 3, warm kernel cache).\n"
    assert untagged(doc, LABELS) == []
    # the tag must be in the same paragraph, not the one before
    doc2 = "On M-Xeon-512.\n\nThe render took 12.5 s of wall time.\n"
    assert untagged(doc2, LABELS) == ["line 3: The render took 12.5 s of wall time."]


def test_null_protocol_constants_and_virtual_time_pass():
    doc = ("The radiometer's integration time is 1 s; the client's timeout 5 s; settle 0.5 s.\n\n"
           "A full 153-geometry sweep takes 535 s virtual; the driver polls every 0.1 s.\n\n"
           "Auto-exposure: ÷4 while saturated down to 8 ms, ×4 while below 5 %.\n\n"
           "The sweep took 456.0 s of virtual lab time.\n\n"
           "On the virtual clock the first reading took 73 s; the wall-clock limit is 90 s.\n")
    assert untagged(doc, LABELS) == []


def test_null_times_and_words_found():
    assert measured_times("first paint over 7 runs: median 0.673 s, min 0.611 s") == [
        "0.673 s", "0.611 s"]
    assert measured_times("compile 43.0 s in 13 kernels") == ["43.0 s"]
    assert measured_times("2.5× faster, 17–73 s") == ["17–73 s"]
    # a ratio of readings is not a speed-up
    assert measured_times("replies 12 s late stored readings 0.21× to 12.7×") == []
    assert measured_times("a 2 s timeout, 5 shared counts") == []
    assert measured_times("(12.4 min on 2 shared cores)") == ["12.4 min"]
    assert measured_times("load average ≈ 9: 87.8 CPU·s (155 s wall)") == ["87.8 CPU·s", "155 s"]
    assert measured_times("≈ 6 s with a warm kernel cache") == ["6 s"]
    assert measured_times("took 73 s, 0.6 s wall", virtual_clock=True) == ["73 s", "0.6 s"]
    assert measured_times("took 73 s at ×0.2", virtual_clock=True) == []


def test_null_the_docs_without_their_labels_fail():
    """The check finds the real figures: with the labels taken out, the measured times of the
    first-paint, campaign and start-up sections are reported."""
    labels = machine_labels()
    for rel, at_least in (("docs/tui.md", 10), ("docs/simulation-testing.md", 8),
                          ("docs/images.md", 5)):
        text = (ROOT / rel).read_text(encoding="utf-8")
        for label in sorted(labels, key=len, reverse=True):
            text = text.replace(label, "this machine")
        text = text.replace(NOT_RECORDED, "")
        assert len(untagged(text, labels)) >= at_least, rel


def test_null_labels_come_from_the_machine_table_only():
    doc = ("Labels: `M-Fake` in a sentence.\n\n| label | CPU |\n|---|---|\n"
           "| `M-One` | AVX2, 2 cores |\n| `M-Two-512` | AVX-512, 4 cores |\n")
    assert machine_labels(doc) == {"M-One", "M-Two-512"}
