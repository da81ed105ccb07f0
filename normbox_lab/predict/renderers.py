"""Other renderers' predictions of a reference run: read and check them (`import prediction`;
`normbox_lab.acquire.importers.import_prediction` stores them: this module never reads or
writes the store itself, except `renderers`, which lists the stored artifacts it is given).

A prediction file is what a renderer returns for a scene package (`scene_package.py`):

- CSV with the header ``patch,angle_deg,wavelength_nm,radiance_W_sr_m2_nm[,std_error]``, one
  row per configuration × wavelength; ``#`` lines are comments, ``# renderer_version: X`` is
  recorded; or
- a directory of spectral OpenEXR files, one per configuration named like its scene
  (``p19_s30.exr``), channels ``S0.<λ>nm`` in W·sr⁻¹·m⁻²·nm⁻¹; the pixels are averaged (their
  standard error is not a Monte-Carlo error and is not used).

Before anything is stored the file is checked against the reference run: every configuration
exactly once and no other, a wavelength grid in nm that covers the reference's, finite and
non-negative radiance (and standard error).  Each problem is one line naming it
(`PredictionFileError.problems`); nothing is stored then.

A stored prediction is a run (protocol ``import-prediction``, parameters: renderer, version,
reference run, file and its SHA-256) with one ``prediction`` artifact named
``ref-run-<id>@<renderer>`` (`artifact_name`), on the reference grid like ours (which keeps the
plain name ``ref-run-<id>`` and stays the default of compare, budget and the report).  The
light shares per angle (``direct_white``, ``full_white``, for the error model) are a property
of the scene, not of the renderer: they are copied from our prediction when there is one.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.core.errors import DataError

IMPORT_PROTOCOL = "import-prediction"
RENDERER_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,63}$")
CSV_COLUMNS = ("patch", "angle_deg", "wavelength_nm", "radiance_W_sr_m2_nm")
#: a plausible spectral range in nm for a visible-light renderer (Mitsuba's CIE range)
PLAUSIBLE_NM = (200.0, 2500.0)


class PredictionFileError(DataError):
    """A prediction file that does not fit its reference run; one line per problem."""

    exit_code = 2

    def __init__(self, file: str, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__(file, "prediction", "; ".join(self.problems))


def artifact_name(run_id: int, renderer: str | None = None) -> str:
    """``ref-run-<id>`` (ours, the default) or ``ref-run-<id>@<renderer>``."""
    return f"ref-run-{int(run_id)}" if not renderer else f"ref-run-{int(run_id)}@{renderer}"


def renderer_of(name: str) -> str | None:
    """The renderer part of an artifact name (None: ours)."""
    return name.split("@", 1)[1] if "@" in name else None


@dataclass
class PredictionFile:
    """Spectra as read: {(patch, angle_deg): (wavelength_nm, radiance, std_error | None)}."""

    path: str
    spectra: dict[tuple[int, float], tuple[np.ndarray, np.ndarray, np.ndarray | None]]
    header: dict[str, str] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)


def _where(patch: int, angle: float) -> str:
    return f"patch {patch} at {angle:g}°"


def read_csv(path: str | Path) -> PredictionFile:
    path = Path(path)
    header: dict[str, str] = {}
    problems: list[str] = []
    rows: dict[tuple[int, float], list[tuple[float, float, float]]] = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PredictionFileError(str(path), [f"cannot read: {exc}"]) from None
    data = []
    for line in lines:
        if line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            if sep:
                header[key.strip()] = value.strip()
            continue
        if line.strip():
            data.append(line)
    reader = csv.reader(data)
    cols = [c.strip() for c in next(reader, [])]
    missing = [c for c in CSV_COLUMNS if c not in cols]
    if missing:
        raise PredictionFileError(str(path), [
            (f"columns {', '.join(missing)} missing: the header must be "
            f"{','.join(CSV_COLUMNS)}[,std_error] (got {','.join(cols) or 'nothing'})")])
    idx = {c: cols.index(c) for c in cols}
    has_se = "std_error" in idx
    for n, rec in enumerate(reader, start=2):
        try:
            patch = int(float(rec[idx["patch"]]))
            angle = float(rec[idx["angle_deg"]])
            wl = float(rec[idx["wavelength_nm"]])
            rad = float(rec[idx["radiance_W_sr_m2_nm"]])
            se = float(rec[idx["std_error"]]) if has_se and rec[idx["std_error"]].strip() \
                else float("nan")
        except (ValueError, IndexError):
            problems.append(f"data row {n}: not numbers: {','.join(rec)}")
            if len(problems) > 5:
                break
            continue
        rows.setdefault((patch, angle), []).append((wl, rad, se))
    spectra = {}
    for key, vals in rows.items():
        arr = np.array(vals, dtype=np.float64)
        order = np.argsort(arr[:, 0], kind="stable")
        arr = arr[order]
        se = arr[:, 2] if has_se else None
        spectra[key] = (arr[:, 0], arr[:, 1], se)
    return PredictionFile(str(path), spectra, header, problems)


_EXR_NAME = re.compile(r"^p(?P<patch>\d+)_s(?P<angle>[0-9.]+)\.exr$", re.IGNORECASE)


def read_exr_dir(path: str | Path) -> PredictionFile:
    """A directory of per-configuration spectral EXRs (pNN_s<angle>.exr); pixel means."""
    from normbox_lab.core.exr import read_spectral_exr

    path = Path(path)
    spectra = {}
    problems = []
    for f in sorted(path.iterdir()):
        m = _EXR_NAME.match(f.name)
        if not m:
            if f.suffix.lower() == ".exr":
                problems.append(f"{f.name}: not named pNN_s<angle>.exr")
            continue
        try:
            img = read_spectral_exr(f)
        except (OSError, RuntimeError, ValueError, KeyError) as exc:
            problems.append(f"{f.name}: not a spectral EXR ({exc})")
            continue
        rad = np.asarray(img.get("radiance"), dtype=np.float64)
        wl = np.asarray(img.get("wavelength_nm"), dtype=np.float64)
        if rad.ndim != 3 or wl.size != rad.shape[-1]:
            problems.append(f"{f.name}: no S0.<λ>nm radiance channels")
            continue
        spectra[(int(m["patch"]), float(m["angle"]))] = (wl, rad.reshape(-1, wl.size).mean(0),
                                                         None)
    if not spectra and not problems:
        problems.append(f"{path}: no pNN_s<angle>.exr files")
    return PredictionFile(str(path), spectra, {}, problems)


def read_prediction(path: str | Path) -> PredictionFile:
    p = Path(path)
    if p.is_dir():
        return read_exr_dir(p)
    if p.suffix.lower() == ".exr":
        raise PredictionFileError(str(p), [
            "a single EXR: give the directory with one pNN_s<angle>.exr per configuration"])
    return read_csv(p)


def _unit_hint(lo: float, hi: float) -> str:
    if hi < 10.0:
        return " (µm? wavelengths must be in nm)" if hi > 0.1 else " (metres? wavelengths " \
                                                                     "must be in nm)"
    if lo > PLAUSIBLE_NM[1]:
        return " (ångström? wavelengths must be in nm)" if lo < 10_000 else \
            " (not nm: wavelengths must be in nm)"
    return ""


def check_prediction(pf: PredictionFile, patches: list[int], angle_deg: Any,
                     wavelength_nm: Any, run_id: int) -> list[str]:
    """Every problem of `pf` against the reference run's configurations and grid, one line
    each ([] = fine)."""
    problems = list(pf.problems)
    want = {(int(p), float(a)) for p in patches for a in np.asarray(angle_deg, dtype=float)}
    have = set(pf.spectra)
    missing = sorted(want - have, key=lambda k: (k[1], k[0]))
    extra = sorted(have - want, key=lambda k: (k[1], k[0]))
    if missing:
        listed = ", ".join(_where(*k) for k in missing[:4])
        problems.append(f"{len(missing)} configuration{'s' if len(missing) > 1 else ''} of run "
                        f"{run_id} missing: {listed}{', …' if len(missing) > 4 else ''}")
    if extra:
        listed = ", ".join(_where(*k) for k in extra[:4])
        problems.append(f"{len(extra)} configuration{'s' if len(extra) > 1 else ''} not in run "
                        f"{run_id}: {listed}{', …' if len(extra) > 4 else ''}")
    ref_lo, ref_hi = float(np.min(wavelength_nm)), float(np.max(wavelength_nm))
    grid_faults: dict[str, list[tuple[int, float]]] = {}
    for (p, a), (wl, rad, se) in sorted(pf.spectra.items(), key=lambda kv: (kv[0][1],
                                                                          kv[0][0])):
        if (p, a) not in want:
            continue
        if not np.all(np.isfinite(wl)):
            grid_faults.setdefault("wavelength not finite", []).append((p, a))
            continue
        lo, hi = float(wl.min()), float(wl.max())
        if np.any(np.diff(wl) == 0):
            grid_faults.setdefault("a wavelength twice", []).append((p, a))
        if lo > ref_lo + 1e-6 or hi < ref_hi - 1e-6:
            key = (f"wavelength_nm {lo:g}–{hi:g} does not cover the reference's "
                   f"{ref_lo:g}–{ref_hi:g} nm{_unit_hint(lo, hi)}")
            grid_faults.setdefault(key, []).append((p, a))
        bad = ~np.isfinite(rad)
        if bad.any():
            k = int(np.argmax(bad))
            problems.append(f"radiance not finite ({rad[k]}) for {_where(p, a)} at "
                            f"{wl[k]:g} nm ({int(bad.sum())} value{'s' if bad.sum() > 1 else ''})")
        neg = np.isfinite(rad) & (rad < 0)
        if neg.any():
            k = int(np.argmin(np.where(neg, rad, np.inf)))
            problems.append(f"negative radiance {rad[k]:.3g} W·sr⁻¹·m⁻²·nm⁻¹ for {_where(p, a)}"
                            f" at {wl[k]:g} nm ({int(neg.sum())} value{'s' if neg.sum() > 1 else ''})")
        if se is not None:
            present = ~np.isnan(se)
            bad_se = present & (~np.isfinite(se) | (se < 0))
            if bad_se.any():
                k = int(np.argmax(bad_se))
                problems.append(f"std_error {se[k]} (must be finite and ≥ 0) for "
                                f"{_where(p, a)} at {wl[k]:g} nm")
    for text, where in grid_faults.items():
        more = f" and {len(where) - 1} more configurations" if len(where) > 1 else ""
        problems.append(f"{text}: {_where(*where[0])}{more}")
    return problems
