"""CPU time to the console's first paint of two builds, launched alternately (so both see the
same load), N rounds.

    .venv/bin/python docs/tui-screens/first_paint_compare.py N before=/path/to/old/tree after=

Each ``NAME=PATH`` is a build: PATH (a folder holding an older ``normbox_lab`` package, e.g.
``git archive COMMIT normbox_lab | tar -x -C /tmp/old``) goes first on ``PYTHONPATH``; an empty
PATH is the installed working tree.  Each launch runs ``normbox-lab tui
--exit-after-first-paint`` in a new temporary folder and reads the CPU time of the process at
the first paint (as `first_paint.py`); the last line gives the 1-minute load seen during the
rounds.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

EXE = str(Path(sys.executable).with_name("normbox-lab"))


def cpu_at_first_paint(pythonpath: str) -> float:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([EXE, "tui", "--exit-after-first-paint", "--store",
                              os.path.join(tmp, "s.sqlite")], cwd=tmp, capture_output=True,
                             text=True, check=True, env=env).stdout
    return float(out[out.rindex("first-paint-wall-time"):].split()[5])


def main() -> None:
    rounds = int(sys.argv[1])
    builds = [arg.partition("=") for arg in sys.argv[2:]]
    cpu: dict[str, list[float]] = {name: [] for name, _, _ in builds}
    loads = []
    for _ in range(rounds):
        for name, _, path in builds:
            cpu[name].append(cpu_at_first_paint(path))
            loads.append(os.getloadavg()[0])
    for name, values in cpu.items():
        print(f"{name}: CPU at first paint median {statistics.median(values):.3f} s "
              f"(min {min(values):.3f}, max {max(values):.3f}, {len(values)} runs)")
    print(f"load (1 min) during: {min(loads):.2f}-{max(loads):.2f}, median "
          f"{statistics.median(loads):.2f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
