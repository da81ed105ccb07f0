"""The colorimetric tables the emulators use, shipped as data so that no emulator imports
colour-science (and with it matplotlib, pandas and scipy: about 2 s of CPU) while it serves.

colour-science stays the source of every number: the file ``data/colorimetry_tables.npz`` next
to this module is written from it by

    python -m normbox_lab.sim.colour_tables --write

and ``tests/sim/test_sim_startup.py`` regenerates the tables with the installed colour-science and
checks them against the shipped file (``--check`` does the same from the command line).

What the file holds, all on 380–780 nm at 1 nm (401 values) unless said otherwise:
  ``cmfs_2deg``, ``cmfs_10deg``  (401, 3) x̄ ȳ z̄ of the CIE 1931 2° and CIE 1964 10° standard
                                 observers (colour's ``MSDS_CMFS``; tabulated at 1 nm there, so
                                 taken as they are);
  ``d65``                        CIE illuminant D65 (colour's ``SDS_ILLUMINANTS["D65"]``, 5 nm,
                                 linearly interpolated to 1 nm, as the sphere emulator did);
  ``planckian_table``            (N, 3) T [K], u, v of the Planckian locus in CIE 1960 UCS that
                                 colour's Ohno (2013) method searches: 1000 … 100 000 K with
                                 spacing 1.001 (finer towards high T), the CIE 1931 2° observer
                                 on colour's default 360–780 nm shape
                                 (``colour.temperature.ohno2013.planckian_table``);
  ``colour_version``             the colour-science version that wrote the file.

`uv_to_cct_ohno2013` is Ohno's method on that table (Y. Ohno, "Practical Use and Calculation
of CCT and Duv", LEUKOS 10(1), 47–55, 2014): the nearest table entry and its two neighbours,
the triangular solution, replaced by the parabolic one when |Δuv| ≥ 0.002, as colour-science
0.4 computes it.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM

TABLES_PATH = Path(__file__).resolve().parent / "data" / "colorimetry_tables.npz"

#: colour-science's names of what the file holds
OBSERVERS = {2: "CIE 1931 2 Degree Standard Observer",
             10: "CIE 1964 10 Degree Standard Observer"}
#: the Ohno (2013) table's range and spacing (colour-science's defaults)
PLANCKIAN_START_K = 1000.0
PLANCKIAN_END_K = 100000.0
PLANCKIAN_SPACING = 1.001
#: above this |Δuv| the parabolic solution replaces the triangular one (Ohno 2014)
PARABOLIC_FROM_DUV = 0.002

ARRAY_KEYS = ("wavelength_nm", "cmfs_2deg", "cmfs_10deg", "d65", "planckian_table")


@dataclass(frozen=True)
class ColourTables:
    wavelength_nm: np.ndarray
    cmfs_2deg: np.ndarray
    cmfs_10deg: np.ndarray
    d65: np.ndarray
    planckian_table: np.ndarray
    colour_version: str

    def cmfs(self, observer_deg: int) -> np.ndarray:
        if observer_deg == 2:
            return self.cmfs_2deg
        if observer_deg == 10:
            return self.cmfs_10deg
        raise ValueError(f"observer must be 2 or 10 degrees, not {observer_deg!r}")


@functools.cache
def tables() -> ColourTables:
    """The shipped tables (read once; the arrays are read-only)."""
    with np.load(TABLES_PATH) as data:
        arrays = {k: np.array(data[k], dtype=float) for k in ARRAY_KEYS}
        version = str(data["colour_version"])
    for a in arrays.values():
        a.setflags(write=False)
    if not np.array_equal(arrays["wavelength_nm"], RADIOMETER_WAVELENGTHS_NM):
        raise ValueError(f"{TABLES_PATH.name} is not on the 380–780 nm, 1 nm grid")
    return ColourTables(colour_version=version, **arrays)


def cmfs(observer_deg: int = 2) -> np.ndarray:
    """(401, 3) x̄ ȳ z̄ at 380–780 nm, 1 nm (read-only)."""
    return tables().cmfs(observer_deg)


def d65() -> np.ndarray:
    """CIE illuminant D65 at 380–780 nm, 1 nm, as tabulated (100 at 560 nm; read-only)."""
    return tables().d65


def uv_to_cct_ohno2013(u: float, v: float) -> tuple[float, float]:
    """(T [K], Δuv) of CIE 1960 (u, v) by Ohno (2013) on the shipped Planckian table.

    Outside the table (nearest entry at either end) the end triple is used, as colour-science
    does (it warns); the caller decides what range it reports."""
    table = tables().planckian_table
    du = table[:, 1] - u
    dv = table[:, 2] - v
    dists = np.sqrt(du * du + dv * dv)
    i = min(max(int(np.argmin(dists)), 1), len(table) - 2)
    Tp, up, vp = (float(x) for x in table[i - 1])
    Ti = float(table[i, 0])
    Tn, un, vn = (float(x) for x in table[i + 1])
    dp, di, dn = float(dists[i - 1]), float(dists[i]), float(dists[i + 1])
    # triangular solution
    length = math.hypot(un - up, vn - vp)
    x = (dp**2 - dn**2 + length**2) / (2 * length)
    T_t = Tp + (Tn - Tp) * (x / length)
    vtx = vp + (vn - vp) * (x / length)
    sign = float(np.sign(v - vtx))
    duv_t = max(dp**2 - x**2, 0.0) ** 0.5 * sign
    if abs(duv_t) < PARABOLIC_FROM_DUV:
        return T_t, duv_t
    # parabolic solution
    X = (Tn - Ti) * (Tp - Tn) * (Ti - Tp)
    a = (Tp * (dn - di) + Ti * (dp - dn) + Tn * (di - dp)) / X
    b = -(Tp**2 * (dn - di) + Ti**2 * (dp - dn) + Tn**2 * (di - dp)) / X
    c = -(dp * (Tn - Ti) * Ti * Tn + di * (Tp - Tn) * Tp * Tn + dn * (Ti - Tp) * Tp * Ti) / X
    T_p = -b / (2 * a)
    return T_p, (a * T_p**2 + b * T_p + c) * sign


# --- regeneration from colour-science (imports it) -----------------------------------------------

def build_tables() -> dict[str, Any]:
    """The tables, computed now from the installed colour-science."""
    import colour
    from colour.colorimetry import handle_spectral_arguments
    from colour.temperature.ohno2013 import planckian_table

    wl = RADIOMETER_WAVELENGTHS_NM
    out: dict[str, Any] = {"wavelength_nm": wl.copy()}
    for deg, key in ((2, "cmfs_2deg"), (10, "cmfs_10deg")):
        c = colour.MSDS_CMFS[OBSERVERS[deg]]
        cwl = np.asarray(c.wavelengths, dtype=float)
        vals = np.asarray(c.values, dtype=float)
        out[key] = np.stack([np.interp(wl, cwl, vals[:, i]) for i in range(3)], axis=1)
    sd = colour.SDS_ILLUMINANTS["D65"]
    out["d65"] = np.interp(wl, np.asarray(sd.wavelengths, dtype=float),
                           np.asarray(sd.values, dtype=float))
    default_cmfs, _ = handle_spectral_arguments(None)     # what uv_to_CCT_Ohno2013 uses
    out["planckian_table"] = np.asarray(planckian_table(
        default_cmfs, PLANCKIAN_START_K, PLANCKIAN_END_K, PLANCKIAN_SPACING), dtype=float)
    out["colour_version"] = np.array(colour.__version__)
    return out


def write_tables(path: Path = TABLES_PATH) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **build_tables())


def differences(path: Path = TABLES_PATH) -> list[str]:
    """What differs between the shipped tables and colour-science's now (empty: equal)."""
    fresh = build_tables()
    out = []
    with np.load(path) as shipped:
        for key in ARRAY_KEYS:
            if key not in shipped.files:
                out.append(f"{key}: missing")
            elif shipped[key].shape != fresh[key].shape:
                out.append(f"{key}: shape {shipped[key].shape} != {fresh[key].shape}")
            elif not np.array_equal(shipped[key], fresh[key]):
                worst = float(np.max(np.abs(shipped[key] - fresh[key])))
                out.append(f"{key}: differs by up to {worst:.3g}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m normbox_lab.sim.colour_tables",
                                description="Write or check the emulators' colorimetric "
                                            "tables from colour-science.")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--write", action="store_true", help="write the shipped file anew")
    what.add_argument("--check", action="store_true",
                      help="compare the shipped file with colour-science (exit 1 if unequal)")
    args = p.parse_args(argv)
    if args.write:
        write_tables()
        print(f"wrote {TABLES_PATH}")
        return 0
    diff = differences()
    for line in diff:
        print(line)
    print("tables equal colour-science's" if not diff else "tables differ")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
