"""Reference sweep: 24 ColorChecker patches × 13 sample angles = 312 radiometer readings.

Angle-major (DESIGN §1): the holder is set to each angle first, then each patch is placed by
hand and measured, so every patch sees exactly the same angle.  Keys: ``a30/p07``.  Each
measurement requires the angle, the patch and a stable lamp, so a resumed run re-moves and
re-prompts exactly what the first missing reading needs.

Copy this file, edit it, and run it with ``normbox-lab run my_sweep.py``.
"""

from __future__ import annotations

from typing import Any

from normbox_lab.acquire.engine import Step, measure, move, prompt, wait_stable
from normbox_lab.core.spectral import patch_name
from normbox_lab.protocols._common import (
    LAMP,
    MOVES,
    READS_SPECTRA,
    Angles,
    Patches,
    Positive,
    Role,
    angle_key,
    check_parameters,
)

PARAMETERS: dict[str, Any] = {
    "angles_deg": [30, 35, 40, 45, 50, 55, 60, 65, 70, 75, 80, 85, 90],
    "patches": list(range(1, 25)),
    "rotator": "rotator",        # lab roles
    "radiometer": "radiometer",
    "lamp": "sphere",
    "lamp_timeout_s": 3600.0,
}
#: what each parameter may hold (checked before a step is built; angles against the configured
#: range of the instrument named by "rotator")
LIMITS = {"angles_deg": Angles(role_param="rotator"), "patches": Patches(),
          "rotator": Role(MOVES), "radiometer": Role(READS_SPECTRA),
          "lamp": Role(LAMP),
          "lamp_timeout_s": Positive("s")}


def steps(params: dict[str, Any], lab: Any = None) -> list[Step]:
    check_parameters(LIMITS, params, lab)
    rot, rad, lamp = params["rotator"], params["radiometer"], params["lamp"]
    out = [wait_stable("lamp", lamp, timeout_s=float(params["lamp_timeout_s"]))]
    for angle in params["angles_deg"]:
        a = float(angle)
        ak = angle_key(a)
        out.append(move(f"{ak}/move", rot, a, label=f"set the sample angle to {a:g}°"))
        for p in params["patches"]:
            name = patch_name(p)
            sample = f"patch:{int(p)}"
            out.append(prompt(f"{ak}/p{int(p):02d}/place", f"place patch {int(p)} ({name})",
                              action="place_patch", patch=int(p), sets={"sample": sample}))
            out.append(measure(f"{ak}/p{int(p):02d}", rad,
                               requires={rot: a, "sample": sample, lamp: "stable"},
                               angle_deg=a, patch=int(p), patch_name=name))
    return out
