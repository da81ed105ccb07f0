"""Imports into the store: measured BRDF data, and other renderers' predictions (at the end).

Format (the layout of the TH Köln group's later in-plane data, read by vgonio's `clausen.rs`;
see [LOW12] in docs/references.md): a JSON array whose element 0 is
``{"wavelengths": [nm, ...]}`` and every later element is one geometry
``{"thetaIn": deg, "phiIn": deg, "thetaOut": deg, "phiOut": deg, "spectrum": [...]}`` with
``spectrum`` as long as ``wavelengths``.  Values are BRDF in sr⁻¹.

In-plane angles are signed for the store: a direction at azimuth φ ≈ 180° (±90°) gets a
negative θ, so (θ, φ=180) ≡ (−θ, φ=0).

Hostile files: the size is checked before reading, the geometry count before decoding (a
cheap count of ``"spectrum"`` keys) and again while decoding element by element; geometries
that coincide at the store's 0.1° key resolution are refused as near-duplicates before
anything is written; the run and all its readings are written in one transaction, so a failed
import leaves nothing behind.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from normbox_lab.acquire.store_api import Store
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
    try:
        v = float(value)
    except OverflowError:
        raise DataError(file, where, "number out of range") from None
    if not math.isfinite(v):
        raise DataError(file, where, "must be finite")
    return v


def geometry_key(theta_i_deg: float, theta_o_deg: float) -> str:
    """The store key part of one geometry (0.1° resolution)."""
    return f"ti{theta_i_deg + 0.0:+.1f}/to{theta_o_deg + 0.0:+.1f}"


def _decode_stream(raw: bytes, file: str) -> list[object]:
    """The top-level JSON array, decoded element by element with the count checked as it
    grows (and a cheap upper bound checked before any decoding)."""
    if raw.count(b'"spectrum"') > MAX_GEOMETRIES + 1:
        raise DataError(file, "top level", f"more than {MAX_GEOMETRIES} geometries "
                        f"({raw.count(b'{')} objects); refused before decoding")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(file, "JSON", f"not UTF-8: {exc}") from None
    decoder = json.JSONDecoder()
    ws = " \t\n\r"
    i = len(text) - len(text.lstrip(ws))
    if not text.startswith("[", i):
        raise DataError(file, "top level", "must be a non-empty JSON array")
    i += 1
    out: list[object] = []
    while True:
        while i < len(text) and text[i] in ws:
            i += 1
        if i < len(text) and text[i] == "]" and not out:
            i += 1
            break
        try:
            item, i = decoder.raw_decode(text, i)
        except (ValueError, RecursionError) as exc:
            raise DataError(file, f"element {len(out)}", f"not valid JSON: {exc}") from None
        out.append(item)
        if len(out) - 1 > MAX_GEOMETRIES:
            raise DataError(file, "top level", f"more than {MAX_GEOMETRIES} geometries")
        while i < len(text) and text[i] in ws:
            i += 1
        if i < len(text) and text[i] == ",":
            i += 1
            continue
        if i < len(text) and text[i] == "]":
            i += 1
            break
        raise DataError(file, f"after element {len(out) - 1}", "expected ',' or ']'")
    if text[i:].strip(ws):
        raise DataError(file, "end", "extra data after the top-level array")
    return out


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
    seen: dict[str, int] = {}
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
        key = geometry_key(*geom)
        if key in seen:
            raise DataError(file, where, f"geometry θi={geom[0]}°, θo={geom[1]}° duplicates "
                            f"element {seen[key]} at the store's 0.1° resolution ({key})")
        seen[key] = n
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
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(str(path), "file", f"cannot read: {exc}") from None
    return parse_brdf_json(_decode_stream(raw, str(path)), str(path), material or path.stem)


def store_brdf(store, imported: ImportedBrdf, tilt_deg: float = 0.0) -> int:
    """Store as a run of protocol `import-brdf-json`, one `brdf` reading per geometry, all in
    one transaction (a failure leaves no run behind)."""
    readings = [
        (f"{imported.material}/{geometry_key(t_in, t_out)}", "brdf",
         {"wavelength_nm": imported.wavelength_nm, "brdf_per_sr": values},
         {"material": imported.material, "theta_i_deg": float(t_in),
          "theta_o_deg": float(t_out), "tilt_deg": tilt_deg, "blocked": False})
        for t_in, t_out, values in zip(imported.theta_i_deg, imported.theta_o_deg,
                                       imported.brdf_per_sr, strict=True)]
    run = store.create_complete_run(
        "import-brdf-json", parameters={"material": imported.material, "tilt_deg": tilt_deg},
        readings=readings, instrument="import")
    return run.id


# --- another renderer's prediction of a reference run (`normbox-lab import prediction`) -------

def import_prediction(store: Store, path: str | Path, ref_run: int | str, renderer: str, *,
                      renderer_version: str | None = None) -> tuple[int, int]:
    """Check `path` against `ref_run` and store it; (import run id, prediction artifact id).
    Raises `PredictionFileError` (every problem, nothing stored)."""
    from normbox_lab.acquire.queries import reference_data
    from normbox_lab.predict.renderers import (
        IMPORT_PROTOCOL,
        RENDERER_NAME_RE,
        PredictionFileError,
        artifact_name,
        check_prediction,
        read_prediction,
    )

    if not RENDERER_NAME_RE.match(renderer or ""):
        raise PredictionFileError(str(path), [
            f"renderer name {renderer!r}: letters, digits and . _ + - only (≤ 64)"])
    run = store.get_run(ref_run)
    ref = reference_data(store, run.id)
    pf = read_prediction(path)
    problems = check_prediction(pf, ref.patches, ref.angle_deg, ref.wavelength_nm, run.id)
    if problems:
        raise PredictionFileError(str(path), problems)
    n_p, n_a = len(ref.patches), ref.angle_deg.size
    rad = np.zeros((n_p, n_a, ref.wavelength_nm.size))
    err = np.full_like(rad, np.nan)
    for pi, p in enumerate(ref.patches):
        for ai, a in enumerate(ref.angle_deg):
            wl, r, se = pf.spectra[(int(p), float(a))]
            rad[pi, ai] = np.interp(ref.wavelength_nm, wl, r)
            if se is not None and np.isfinite(se).all():
                err[pi, ai] = np.interp(ref.wavelength_nm, wl, se)
    version = renderer_version or pf.header.get("renderer_version") or "unknown"
    digest = hashlib.sha256()
    p = Path(path)
    for f in ([p] if p.is_file() else sorted(p.glob("*.exr"))):
        digest.update(f.read_bytes())
    params = {"renderer": renderer, "renderer_version": version, "reference_run": run.id,
              "file": str(path), "sha256": digest.hexdigest(),
              "header": pf.header, "configurations": len(pf.spectra),
              "std_error": bool(np.isfinite(err).all())}
    imp = store.create_complete_run(IMPORT_PROTOCOL, parameters=params, readings=[])
    arrays = {"wavelength_nm": ref.wavelength_nm, "angle_deg": ref.angle_deg,
              "patches": np.array(ref.patches, dtype=float), "radiance": rad,
              "std_error": err}
    ours = store.artifacts("prediction", artifact_name(run.id))
    shares_from = None
    if ours and "direct_white" in ours[-1].arrays:
        arrays["direct_white"] = ours[-1].arrays["direct_white"]
        arrays["full_white"] = ours[-1].arrays["full_white"]
        shares_from = ours[-1].id
    aid = store.add_artifact(
        "prediction", artifact_name(run.id, renderer), arrays,
        metadata={"renderer": renderer, "renderer_version": version, "import_run": imp.id,
                  "quality": f"imported ({renderer})", "light_shares_from": shares_from,
                  "white_patch": 19 if 19 in ref.patches else ref.patches[0]},
        run_ref=run.id)
    return imp.id, aid
