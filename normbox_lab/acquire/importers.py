"""Import of measured BRDF data.

Format (the layout of the TH Köln group's later in-plane data, read by vgonio's `clausen.rs`;
see [LOW12] in docs/references.md): a JSON array whose element 0 is
``{"wavelengths": [nm, ...]}`` and every later element is one geometry
``{"thetaIn": deg, "phiIn": deg, "thetaOut": deg, "phiOut": deg, "spectrum": [...]}`` with
``spectrum`` as long as ``wavelengths``.  Values are BRDF in sr⁻¹.

In-plane angles are signed for the store: a direction at azimuth φ ≈ 180° (±90°) gets a
negative θ, so (θ, φ=180) ≡ (−θ, φ=0).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from normbox_lab.core.errors import DataError

MAX_FILE_BYTES = 256 * 1024 * 1024
MAX_GEOMETRIES = 200_000
MAX_WAVELENGTHS = 10_000


@dataclass(frozen=True)
class ImportedBrdf:
    material: str
    wavelength_nm: np.ndarray           # (n_wavelengths,)
    theta_i_deg: np.ndarray             # (n_geometries,) signed in-plane
    theta_o_deg: np.ndarray             # (n_geometries,)
    brdf_per_sr: np.ndarray             # (n_geometries, n_wavelengths)


def _signed_theta(theta: float, phi: float) -> float:
    phi = phi % 360.0
    return -theta if 90.0 < phi < 270.0 else theta


def _number(file: str, where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DataError(file, where, f"must be a number, got {type(value).__name__}")
    v = float(value)
    if not math.isfinite(v):
        raise DataError(file, where, "must be finite")
    return v


def parse_brdf_json(data: object, file: str = "<json>", material: str = "") -> ImportedBrdf:
    """Validate the decoded JSON document and return it as arrays."""
    if not isinstance(data, list) or not data:
        raise DataError(file, "top level", "must be a non-empty JSON array")
    if len(data) - 1 > MAX_GEOMETRIES:
        raise DataError(file, "top level", f"more than {MAX_GEOMETRIES} geometries")
    head = data[0]
    if not isinstance(head, dict) or "wavelengths" not in head:
        raise DataError(file, "element 0", "must be an object with a 'wavelengths' list")
    wl = head["wavelengths"]
    if not isinstance(wl, list) or not wl:
        raise DataError(file, "element 0: wavelengths", "must be a non-empty list")
    if len(wl) > MAX_WAVELENGTHS:
        raise DataError(file, "element 0: wavelengths", f"more than {MAX_WAVELENGTHS} values")
    wavelength_nm = np.array([_number(file, f"element 0: wavelengths[{i}]", v)
                              for i, v in enumerate(wl)])
    if np.any(np.diff(wavelength_nm) <= 0):
        raise DataError(file, "element 0: wavelengths", "must be strictly increasing")
    if wavelength_nm[0] <= 0 or wavelength_nm[-1] > 100_000:
        raise DataError(file, "element 0: wavelengths", "must be positive nanometres")
    if len(data) < 2:
        raise DataError(file, "top level", "no measurements after the wavelengths element")

    ti, to, spectra = [], [], []
    seen: set[tuple[float, float]] = set()
    for n, item in enumerate(data[1:], start=1):
        where = f"element {n}"
        if not isinstance(item, dict):
            raise DataError(file, where, "must be an object")
        for k in ("thetaIn", "phiIn", "thetaOut", "phiOut", "spectrum"):
            if k not in item:
                raise DataError(file, where, f"missing field '{k}'")
        t_in = _number(file, f"{where}: thetaIn", item["thetaIn"])
        t_out = _number(file, f"{where}: thetaOut", item["thetaOut"])
        p_in = _number(file, f"{where}: phiIn", item["phiIn"])
        p_out = _number(file, f"{where}: phiOut", item["phiOut"])
        for name, t in (("thetaIn", t_in), ("thetaOut", t_out)):
            if not 0.0 <= t <= 90.0:
                raise DataError(file, f"{where}: {name}", f"must be within 0…90°, got {t}")
        spec = item["spectrum"]
        if not isinstance(spec, list) or len(spec) != len(wavelength_nm):
            raise DataError(file, f"{where}: spectrum",
                            f"must be a list of {len(wavelength_nm)} numbers")
        values = np.array([_number(file, f"{where}: spectrum[{i}]", v)
                           for i, v in enumerate(spec)])
        geom = (_signed_theta(t_in, p_in) + 0.0, _signed_theta(t_out, p_out) + 0.0)
        if geom in seen:
            raise DataError(file, where, f"duplicate geometry θi={geom[0]}°, θo={geom[1]}°")
        seen.add(geom)
        ti.append(geom[0])
        to.append(geom[1])
        spectra.append(values)
    return ImportedBrdf(material, wavelength_nm, np.array(ti), np.array(to), np.vstack(spectra))


def load_brdf_json(path: str | Path, material: str | None = None) -> ImportedBrdf:
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DataError(str(path), "file", f"cannot read: {exc}") from None
    if size > MAX_FILE_BYTES:
        raise DataError(str(path), "file", f"{size} bytes is over the {MAX_FILE_BYTES} limit")
    try:
        data = json.loads(path.read_bytes())
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise DataError(str(path), "JSON", f"not valid JSON: {exc}") from None
    return parse_brdf_json(data, str(path), material or path.stem)


def store_brdf(store, imported: ImportedBrdf, tilt_deg: float = 0.0) -> int:
    """Store as a run of protocol `import-brdf-json`, one `brdf` reading per geometry."""
    run = store.create_run("import-brdf-json",
                           parameters={"material": imported.material, "tilt_deg": tilt_deg},
                           planned=len(imported.theta_i_deg), status="running")
    for t_in, t_out, values in zip(imported.theta_i_deg, imported.theta_o_deg,
                                   imported.brdf_per_sr):
        store.add_reading(run.id, f"{imported.material}/ti{t_in:+.1f}/to{t_out:+.1f}", "brdf",
                          {"wavelength_nm": imported.wavelength_nm, "brdf_per_sr": values},
                          instrument="import", metadata={
                              "material": imported.material, "theta_i_deg": float(t_in),
                              "theta_o_deg": float(t_out), "tilt_deg": tilt_deg,
                              "blocked": False})
    store.set_run_status(run.id, "done")
    return run.id
