"""The repository cites public sources only, and its tests cannot pass by skipping.

- No tracked file (code, docs, scripts, screen captures, images' text chunks: every file git
  knows) names an absolute path of a development machine or a path into a private reference
  folder: sources are cited by title in docs/references.md.
- No tracked file speaks of how it was developed: no tracker issue numbers, no work sessions.
- No test skips on an import of the project's own modules or of a hard dependency: a broken
  install must turn CI red, not green-with-skips.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: what a machine path or a private reference path looks like (written with character
#: classes, so that this file does not itself contain the paths it forbids)
FORBIDDEN = re.compile(r"(/w[o]rk/|/r[o]ot/|/h[o]me/[a-z]|\.\./sh[a]red|sh[a]red/(reference|seeds)"
                       r"|refer[e]nce/[a-z-]+\.md)")
HARD_DEPENDENCIES = ("numpy", "scipy", "colour", "serial", "mitsuba", "textual", "xarray",
                     "matplotlib", "thorlabs_apt_protocol", "normbox_lab")


#: the development process showing through: tracker issues, work sessions.  (A document's own
#: issue number, as in "Communications Protocol, issue 37", is its edition: allowed.)
PROCESS_WORDS = re.compile(
    r"(?i)((?<!protocol, )\bissues? ?#?\d+|\b(the|this|that|an|our|same|open) issues?\b(?! \d)"
    r"|\bissue's\b|\b(this|that|previous|next|later|earlier|another|helper|lead|"
    r"agent|coding|work|development) sessions?\b|\bsessions? \d+\b)")


def tracked_files() -> list[Path]:
    """Every file git tracks (text or not: a binary's text chunks can carry paths too)."""
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.split("\0")
    return [ROOT / f for f in out if f]


def offending_lines(pattern: re.Pattern[str]) -> list[str]:
    offenders = []
    for path in tracked_files():
        if path.name == Path(__file__).name or not path.is_file():
            continue
        text = path.read_bytes().decode("utf-8", errors="replace")
        for lineno, line in enumerate(text.splitlines(), 1):
            if pattern.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{lineno}: {line.strip()[:120]}")
    return offenders


def test_the_scan_covers_every_kind_of_tracked_file():
    suffixes = {p.suffix for p in tracked_files()}
    assert {".py", ".md", ".txt", ".toml", ".sh", ".png"} <= suffixes
    assert ROOT / "Makefile" in tracked_files()


def test_no_machine_or_private_reference_paths():
    offenders = offending_lines(FORBIDDEN)
    assert offenders == [], "\n".join(offenders)


def test_no_tracker_issue_or_work_session_words():
    offenders = offending_lines(PROCESS_WORDS)
    assert offenders == [], "\n".join(offenders)


def test_process_words_pattern():
    for bad in ("see issue 21", "issue #4", "The issue's acceptance test", "in this session",
                "a later session will", "session 3", "fixed in the issue"):
        assert PROCESS_WORDS.search(bad), bad
    for fine in ("APT Communications Protocol, issue 37 or later", "the operator session",
                 "tmux new-session", "once per session", "the light-map session",
                 "microsteps it has issued", "session.py: open_run"):
        assert not PROCESS_WORDS.search(fine), fine


def test_bibliography_exists_and_is_cited():
    refs = (ROOT / "docs" / "references.md").read_text()
    for key in ("[KM-CS2000]", "[KM-CS1000]", "[APT]", "[ZABER]", "[QEPRO]", "[NORMBOX]",
                "[LOW12]", "[CT82]", "[WMLT07]", "[MIST]", "[WW09]"):
        assert key in refs
    for driver in ("cs2000.py", "rotator_apt.py", "rotator_zaber.py", "qepro.py"):
        assert "docs/references.md" in (ROOT / "drivers" / driver).read_text(), driver


def test_no_importorskip_of_first_party_or_hard_dependencies():
    pattern = re.compile(r"importorskip\(\s*['\"]([\w.]+)['\"]")
    offenders = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        for match in pattern.finditer(path.read_text()):
            if match.group(1).split(".")[0] in HARD_DEPENDENCIES:
                offenders.append(f"{path.name}: importorskip({match.group(1)!r})")
    assert offenders == [], offenders
