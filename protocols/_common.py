"""What the shipped protocols share, re-exported from `normbox_lab.acquire.params` (the one
parser and validator of every number and list a person or a script gives): reading-key
formatting, and the declared kinds and limits of protocol parameters.  (Patch names and
numbers, ColorChecker Classic order, are `normbox_lab.core.spectral`'s.)

Every protocol declares what each parameter may hold in `LIMITS` and checks its parameters
with `check_parameters(LIMITS, params, lab)` before it builds a step, so the command line, the
console and scripts all go through the same check (they all build the plan).  A protocol file
of your own may import the same names from here or from `normbox_lab.acquire.params`.

    LIMITS = {"angles_deg": Angles(role_param="rotator"), "patches": Patches(),
              "repeats": Count(), "lamp_timeout_s": Positive("s")}
"""

from __future__ import annotations

from normbox_lab.acquire.params import (
    LAMP,
    MOVES,
    READS_SPECTRA,
    Angles,
    Count,
    Limit,
    Number,
    ParameterError,
    Patches,
    Positive,
    Role,
    angle_key,
    angle_limits_deg,
    check_parameters,
    material_key,
    signed_key,
)

__all__ = ["LAMP", "MOVES", "READS_SPECTRA", "Angles", "Count", "Limit", "Number",
           "ParameterError", "Patches", "Positive",
           "Role", "angle_key", "angle_limits_deg", "check_parameters", "material_key",
           "signed_key"]
