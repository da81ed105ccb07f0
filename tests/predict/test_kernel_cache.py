"""A second run with the same options compiles no kernel (Dr.Jit's kernel history).

Every per-run value must reach a kernel as data (an opaque value or an array), never as a
literal, and every table must be the same kind of memory in every process: the kernels one
process compiled are then found in Dr.Jit's on-disk cache by the next.  Two processes render
the same kernel paths (`tests/kernel_paths.py --no-debug`: the radiometer view, all patches per
path, the dispersive truth, the camera) with the same on-disk cache; the second must report 0
kernels compiled on every path.  (On 74a7d15 a quick demo's second run compiled 3-4 kernels:
a float32 table's NumPy address decided between packet and separate gathers.)"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "kernel_paths.py"
ROOT = SCRIPT.parent.parent
PATHS = ("radiometer_view", "all_patches", "dispersive_truth", "camera_cornell", "camera_box")


def _compiled_per_path(cache_dir: Path | None) -> dict[str, int]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(SCRIPT.parent),
                                          os.environ.get("PYTHONPATH", "")])}
    if cache_dir is not None:
        env["DRJIT_CACHE_DIR"] = str(cache_dir)
    res = subprocess.run([sys.executable, str(SCRIPT), "--no-debug", *PATHS],
                         capture_output=True, text=True, timeout=1200, cwd=ROOT, env=env,
                         check=False)
    assert res.returncode == 0, res.stdout + res.stderr[-3000:]
    found = {m.group(1): int(m.group(2)) for m in re.finditer(
        r"^path (\w+) ok .* (\d+) kernels compiled$", res.stdout, re.MULTILINE)}
    assert set(found) == set(PATHS), res.stdout
    return found


def test_a_second_process_compiles_no_kernel():
    """With the machine's own kernel cache (warm after the first run, whatever ran before)."""
    first = _compiled_per_path(None)
    second = _compiled_per_path(None)
    assert second == dict.fromkeys(PATHS, 0), (first, second)


@pytest.mark.slow
def test_from_a_cold_cache_the_first_process_compiles_and_the_second_does_not(tmp_path):
    first = _compiled_per_path(tmp_path / "drjit-cache")
    assert sum(first.values()) > 0, first
    second = _compiled_per_path(tmp_path / "drjit-cache")
    assert second == dict.fromkeys(PATHS, 0), (first, second)
