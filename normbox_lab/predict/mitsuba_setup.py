"""Which Mitsuba spectral variant works on this machine?  (`python -m normbox_lab.predict.mitsuba_setup`)

`llvm_ad_spectral` aborts the whole process (not an exception) when only libLLVM 15 is present
on some CPUs, so it is probed in a child process.  The answer is cached in
`.cache/mitsuba-variant` and may be forced with the environment variable
``NORMBOX_MITSUBA_VARIANT``.  Order of preference: cuda_ad_spectral (a GPU), llvm_ad_spectral,
scalar_spectral.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

PREFERENCE = ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")
CACHE = Path(".cache") / "mitsuba-variant"

_PROBE = """
import sys, mitsuba as mi, drjit as dr
mi.set_variant(sys.argv[1])
scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"},
    "sensor": {"type": "perspective", "film": {"type": "specfilm", "width": 2, "height": 2,
               "component_format": "float32",
               "band": {"type": "spectrum", "value": [(400.0, 1.0), (700.0, 1.0)]}}},
    "emitter": {"type": "constant"}})
img = mi.render(scene, spp=1)
import numpy as np
print(float(np.mean(np.array(img))))
"""


def probe(variant: str, timeout_s: float = 120.0) -> bool:
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE, variant], capture_output=True,
                             timeout=timeout_s, text=True, check=False)
    except subprocess.TimeoutExpired:
        return False
    return res.returncode == 0


def choose_variant(use_cache: bool = True) -> str:
    forced = os.environ.get("NORMBOX_MITSUBA_VARIANT")
    if forced:
        return forced
    if use_cache and CACHE.exists():
        cached = CACHE.read_text().strip()
        if cached in PREFERENCE:
            return cached
    for variant in PREFERENCE:
        if probe(variant):
            try:
                CACHE.parent.mkdir(parents=True, exist_ok=True)
                CACHE.write_text(variant + "\n")
            except OSError:
                pass
            return variant
    raise RuntimeError("no Mitsuba spectral variant works here (is `mitsuba` installed?)")


def main() -> int:
    variant = choose_variant(use_cache=False)
    if variant == "scalar_spectral":
        print("WARNING: Mitsuba's llvm_ad_spectral does not run here (libLLVM ≥ 16 missing? "
              "as root: apt-get install -y libllvm19). Falling back to scalar_spectral: "
              "rendering works but is much slower.", file=sys.stderr)
    print(f"mitsuba variant: {variant}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
