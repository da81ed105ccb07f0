"""In-plane BRDF: θi = −80…0 step 10 × θo = −80…80 step 10 = 153 geometries per material.

The gonioreflectometer (QE Pro + light and detector arms tilted ±4° out of plane, DESIGN §1)
takes dark and white (Spectralon) references after each material is mounted (a `calibrate`
step, kept as a calibration artifact of the run), then every geometry.  Mounting a material is
an operator prompt.  Keys: ``p07/i-80/o+40``, ``wall/i-30/o+0``.  Materials default to the 24
ColorChecker patches and the grey wall paint ("wall").
"""

from __future__ import annotations

from typing import Any

from normbox_lab.acquire.engine import Step, calibrate, measure, prompt
from normbox_lab.core.spectral import patch_name
from normbox_lab.protocols._common import (
    Angles,
    Patches,
    Positive,
    Role,
    check_parameters,
    material_key,
    signed_key,
)

PARAMETERS: dict[str, Any] = {
    "materials": [*range(1, 25), "wall"],
    "theta_i_deg": [-80, -70, -60, -50, -40, -30, -20, -10, 0],
    "theta_o_deg": [-80, -70, -60, -50, -40, -30, -20, -10, 0, 10, 20, 30, 40, 50, 60, 70, 80],
    "tilt_deg": 4.0,
    "gonio": "gonio",
}
#: θi is the light arm's angle, θo the detector arm's: each within that arm's configured range
LIMITS = {"materials": Patches(names=True), "theta_i_deg": Angles(role="gonio_light_arm"),
          "theta_o_deg": Angles(role="gonio_detector_arm"), "tilt_deg": Positive("°", zero=True,
                                                                                maximum=45.0),
          "gonio": Role()}


def _is_patch(m: Any) -> bool:
    if isinstance(m, (int, float)) and not isinstance(m, bool):
        return True
    return str(m).isascii() and str(m).isdigit()


def material_label(m: Any) -> str:
    if _is_patch(m):
        return f"patch {int(m)} ({patch_name(int(m))})"
    return f"{m} paint"


def steps(params: dict[str, Any], lab: Any = None) -> list[Step]:
    check_parameters(LIMITS, params, lab)
    gonio = params["gonio"]
    out: list[Step] = []
    for m in params["materials"]:
        mk = material_key(m)
        material = int(m) if _is_patch(m) else str(m)
        out.append(prompt(f"{mk}/mount", f"mount {material_label(m)} on the gonioreflectometer",
                          action="mount_gonio_material", material=material,
                          sets={"gonio_sample": mk}))
        out.append(calibrate(f"{mk}/calibrate", gonio, requires={"gonio_sample": mk},
                             sets={"gonio_cal": mk}, material=material))
        for ti in params["theta_i_deg"]:
            for to in params["theta_o_deg"]:
                out.append(measure(f"{mk}/{signed_key('i', ti)}/{signed_key('o', to)}", gonio,
                                   requires={"gonio_sample": mk, "gonio_cal": mk},
                                   material=material, theta_i_deg=float(ti),
                                   theta_o_deg=float(to), tilt_deg=float(params["tilt_deg"])))
    return out
