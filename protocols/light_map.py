"""Light map: the radiometer measures the opal panel at 25 points (5 × 5 grid).

DESIGN §1: the panel's homogeneity (±3 %) is sampled at 25 points.  Aiming the radiometer at a
point is an operator prompt; keys ``r1c1`` … ``r5c5`` (row 1 = the side towards the open face).
The measurement metadata carries the point's position on the panel in mm from its centre.
"""

from __future__ import annotations

from typing import Any

from normbox_lab.acquire.engine import Step, measure, prompt, wait_stable
from normbox_lab.protocols._common import (
    LAMP,
    READS_SPECTRA,
    Count,
    Positive,
    Role,
    check_parameters,
)

PARAMETERS: dict[str, Any] = {
    "rows": 5,
    "columns": 5,
    "panel_x_mm": 220.0,     # the ceiling aperture (DESIGN §1)
    "panel_y_mm": 200.0,
    "margin_mm": 20.0,       # distance of the outer points from the panel edge
    "radiometer": "radiometer",
    "lamp": "sphere",
}
LIMITS = {"rows": Count(maximum=50), "columns": Count(maximum=50),
          "panel_x_mm": Positive("mm"), "panel_y_mm": Positive("mm"),
          "margin_mm": Positive("mm", zero=True), "radiometer": Role(READS_SPECTRA),
          "lamp": Role(LAMP)}


def grid_mm(n: int, size_mm: float, margin_mm: float) -> list[float]:
    if n == 1:
        return [0.0]
    span = size_mm - 2 * margin_mm
    return [-span / 2 + span * i / (n - 1) for i in range(n)]


def steps(params: dict[str, Any], lab: Any = None) -> list[Step]:
    check_parameters(LIMITS, params, lab)
    rad, lamp = params["radiometer"], params["lamp"]
    ys = grid_mm(int(params["rows"]), float(params["panel_y_mm"]), float(params["margin_mm"]))
    xs = grid_mm(int(params["columns"]), float(params["panel_x_mm"]), float(params["margin_mm"]))
    out = [wait_stable("lamp", lamp)]
    for r, y in enumerate(ys, 1):
        for c, x in enumerate(xs, 1):
            key = f"r{r}c{c}"
            aim = f"panel:{r},{c}"
            out.append(prompt(f"{key}/aim", f"aim the radiometer at panel point row {r}, "
                              f"column {c} (x = {x:+.0f} mm, y = {y:+.0f} mm)",
                              action="aim_panel", x_mm=x, y_mm=y, sets={"aim": aim}))
            out.append(measure(key, rad, requires={"aim": aim, lamp: "stable"}, row=r,
                               column=c, x_mm=x, y_mm=y))
    return out
