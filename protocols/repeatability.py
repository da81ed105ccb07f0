"""Repeatability: the white patch measured again and again at one angle; flags changes > 1 %.

Each reading's luminance is compared with the first reading of the segment; a change above
`threshold_percent` is flagged (a warning event, stored in the run as a ``flag`` event).
Keys: ``rep01`` … ``repNN``.
"""

from __future__ import annotations

from typing import Any

from normbox_lab.acquire.engine import Step, measure, move, prompt, wait_stable
from normbox_lab.core.spectral import WHITE_PATCH, patch_name
from normbox_lab.protocols._common import (
    LAMP,
    MOVES,
    READS_SPECTRA,
    Angles,
    Count,
    Patches,
    Positive,
    Role,
    check_parameters,
)

PARAMETERS: dict[str, Any] = {
    "repeats": 10,
    "threshold_percent": 1.0,
    "angle_deg": 90.0,
    "patch": WHITE_PATCH,
    "rotator": "rotator",
    "radiometer": "radiometer",
    "lamp": "sphere",
}
LIMITS = {"repeats": Count(), "threshold_percent": Positive("%"),
          "angle_deg": Angles(role_param="rotator", many=False),
          "patch": Patches(many=False), "rotator": Role(MOVES),
          "radiometer": Role(READS_SPECTRA), "lamp": Role(LAMP)}


def steps(params: dict[str, Any], lab: Any = None) -> list[Step]:
    check_parameters(LIMITS, params, lab)
    rot, rad, lamp = params["rotator"], params["radiometer"], params["lamp"]
    a, p = float(params["angle_deg"]), int(params["patch"])
    sample = f"patch:{p}"
    out = [wait_stable("lamp", lamp), move("move", rot, a),
           prompt("place", f"place patch {p} ({patch_name(p)})", action="place_patch", patch=p,
                  sets={"sample": sample})]
    for i in range(1, int(params["repeats"]) + 1):
        out.append(measure(f"rep{i:02d}", rad, requires={rot: a, "sample": sample,
                                                         lamp: "stable"},
                           angle_deg=a, patch=p, repeat=i))
    return out


def _luminance(reading: Any) -> float:
    if getattr(reading, "colorimetry", None) is not None:
        return float(reading.colorimetry.Lv_cd_m2)
    import numpy as np

    return float(np.sum(reading.radiance_W_sr_m2_nm))


def on_reading(params: dict[str, Any], step: Step, reading: Any,
               context: dict[str, Any]) -> list[str]:
    value = _luminance(reading)
    first = context.setdefault("first", (step.key, value))
    if first[1] == 0:
        return []
    change = 100.0 * (value - first[1]) / first[1]
    if abs(change) > float(params["threshold_percent"]):
        return [(f"{step.key}: luminance changed {change:+.2f} % from {first[0]} "
                f"(threshold {params['threshold_percent']} %)")]
    return []
