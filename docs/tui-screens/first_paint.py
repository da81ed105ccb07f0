"""Time from launching `normbox-lab tui` to its first painted screen (wall clock), N runs.

    .venv/bin/python docs/tui-screens/first_paint.py [N] [extra tui arguments]

The console records `time.time()` right after its first refresh (`call_after_refresh` from
`on_mount`) and exits (`--exit-after-first-paint`); this script subtracts the launch time.  The
default world is the Mitsuba virtual Normbox: the line also says whether mitsuba was imported
before the first paint (it must not be).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXE = str(Path(sys.executable).with_name("normbox-lab"))


def once(extra: list[str]) -> tuple[float, bool, float]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.time()
        out = subprocess.run([EXE, "tui", "--exit-after-first-paint", "--store",
                              os.path.join(tmp, "s.sqlite"), *extra], cwd=tmp,
                             capture_output=True, text=True, check=True).stdout
    line = out[out.rindex("first-paint-wall-time"):].split()
    return float(line[1]) - t0, line[3] == "True", float(line[5])


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    extra = sys.argv[2:]
    runs = [once(extra) for _ in range(n)]
    times = [t for t, _, _ in runs]
    cpu = [c for _, _, c in runs]
    print(f"first paint over {n} runs: median {statistics.median(times):.3f} s, "
          f"min {min(times):.3f} s, max {max(times):.3f} s (wall, launch to first paint); "
          f"CPU time of the process at first paint: median {statistics.median(cpu):.3f} s; "
          f"mitsuba imported before first paint: {any(m for _, m, _ in runs)}")
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()
