"""Write a `comparison` artifact for the latest reference sweep in a store, for the screen captures.

The measured spectra are the run's readings; the "prediction" is the reference with a random
spectral tilt (0–50 % from 380 to 780 nm) per patch × angle, so the ΔE00 heat map shows every
rating class.  The metrics are computed by the pipeline's own `normbox_lab.analyze.compare.compare` and
stored under the pipeline's name (``ref-run-<id>``).  Usage: python synthetic_comparison.py STORE
"""

from __future__ import annotations

import sys

import numpy as np

from normbox_lab.acquire.store import Store
from normbox_lab.analyze.compare import compare
from normbox_lab.core.spectral import patch_name


def main(path: str) -> None:
    with Store(path) as store:
        run = [r for r in store.runs() if r.protocol == "reference-sweep"][-1]
        patches = [int(p) for p in run.parameters["patches"]]
        angles = [float(a) for a in run.parameters["angles_deg"]]
        ref = np.stack([np.stack([store.reading(run.id, f"a{int(a)}/p{p:02d}")
                                  .arrays["radiance_W_sr_m2_nm"] for a in angles])
                        for p in patches])
        wl = store.reading(run.id, f"a{int(angles[0])}/p{patches[0]:02d}").arrays["wavelength_nm"]
        tilt = np.linspace(-1.0, 1.0, wl.size)
        rng = np.random.default_rng(1)
        pred = ref * (1.0 + rng.uniform(0.0, 0.5, size=(len(patches), len(angles), 1)) * tilt)
        result = compare(ref, pred, wl, angles, [patch_name(p) for p in patches],
                         white_patch=patches.index(19))
        result.store(store, f"ref-run-{run.id}", run_ref=run.id)
        print(np.round(result.delta_e00, 2))


if __name__ == "__main__":
    main(sys.argv[1])
