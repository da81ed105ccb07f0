"""The repository cites public sources only, and its tests cannot pass by skipping.

- No file names an absolute path of a development machine or a path into a private
  reference folder: sources are cited by title in docs/references.md.
- No test skips on an import of the project's own modules or of a hard dependency: a broken
  install must turn CI red, not green-with-skips.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: what a machine path or a private reference path looks like
FORBIDDEN = re.compile(r"(/work/|/root/|/home/[a-z]|\.\./shared|shared/(reference|seeds)"
                       r"|reference/[a-z-]+\.md)")
HARD_DEPENDENCIES = ("numpy", "scipy", "colour", "serial", "mitsuba", "textual", "xarray",
                     "matplotlib", "thorlabs_apt_protocol", "normbox_lab")


def tracked_text_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.split()
    return [ROOT / f for f in out
            if Path(f).suffix in {".py", ".md", ".toml", ".cfg", ".txt", ".sh", ".ini", ""}]


def test_no_machine_or_private_reference_paths():
    offenders = []
    for path in tracked_text_files():
        if path.name == Path(__file__).name or not path.is_file():
            continue
        for lineno, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if FORBIDDEN.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{lineno}: {line.strip()}")
    assert offenders == [], "\n".join(offenders)


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
