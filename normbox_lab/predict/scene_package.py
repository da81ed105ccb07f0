"""A renderer-neutral scene package of a reference run (`normbox-lab scene export`).

Everything another renderer needs to predict what the radiometer saw, and nothing of
normbox-lab: the box geometry per sample angle (OBJ), the light (spectrum and 5×5 panel map,
CSV with units), every material's fitted BRDF parameters (JSON, the formula written out), the
radiometer's view (JSON), a Mitsuba 3 scene (XML) per patch × angle configuration, the fit
model as a stand-alone Mitsuba BSDF (``normbox_bsdf.py``, the source of
`normbox_lab.predict.standalone_bsdf`), ``render_mitsuba.py`` (the source of
`normbox_lab.predict.standalone_render`) and a README with the units, the conventions and what a
renderer must return (the CSV that `normbox-lab import prediction` reads).

The scene is the one our prediction renders: the shapes come from `scene.scene_dict` (the
shared builder) with 25 emitting panel cells, the materials from the latest fits, the lamp and
the geometry from the prediction's provenance (else the light-map run and the reference run's
lab config).  Mitsuba is imported (for the shared builder's transforms) only while exporting.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from normbox_lab.core.types import fit_key

PACKAGE_FORMAT = "normbox-scene-package/1"
#: every spectrum the scene uses is defined on 360–830 nm (Mitsuba's CIE range); the bands
#: a renderer returns are 380…780 nm every 5 nm, triangular hats of half-width 5 nm
SCENE_GRID_NM = (360.0, 830.0)
BAND_START_NM, BAND_STOP_NM, BAND_STEP_NM = 380.0, 780.0, 5.0
PIXELS = 10

FORMULA = (
    "f(λ, ωi, ωo) = kd(λ)/π + ks(λ) · D(h) · F(ωi·h) · G1(ωi) · G1(ωo) / (4 cosθi cosθo) − c   "
    "[sr⁻¹]; h = (ωi + ωo)/|ωi + ωo|; "
    "GGX: D(h) = α² / (π (cos²θh (α² − 1) + 1)²); "
    "Smith (separable): G1(ω) = 2 / (1 + √(1 + α² tan²θ)); "
    "Cook-Torrance Fresnel: F(b) = ½ (g − b)²/(g + b)² · (1 + [b(g + b) − 1]² / [b(g − b) + 1]²), "
    "g = √(η² − 1 + b²), b = ωi·h; one real η and one constant c for all wavelengths; "
    "two-sided; kd, ks linear between the listed wavelengths, constant beyond them")


@dataclass
class PackageSummary:
    out_dir: Path
    ref_run: int
    configurations: list[tuple[int, float, str]]      # (patch, angle_deg, scene file)
    files: list[str] = field(default_factory=list)
    lamp: dict[str, float] = field(default_factory=dict)
    geometry: dict[str, float] = field(default_factory=dict)


def config_name(patch: int, angle_deg: float) -> str:
    """p19_s30, p07_s62.5: a configuration's file stem."""
    return f"p{int(patch):02d}_s{float(angle_deg):g}"


# --- what the package is made of ---------------------------------------------------------------

@dataclass
class PackageInputs:
    """What a scene package is written from (read from the store by
    `normbox_lab.acquire.queries.scene_package_inputs`): the reference run, its spectra
    (`ref`: patches, angle_deg, wavelength_nm, patch_names), the fits of its patches (``p01``…)
    and the wall, the geometry, the lamp, where they came from (`provenance`) and the measured
    light-map spectrum (wavelength_nm, radiance) if any."""

    run_id: int
    run_uuid: str
    protocol: str
    code_version: str
    ref: Any
    fits: dict[str, Any]
    geometry: Any
    lamp: Any
    provenance: dict[str, Any] = field(default_factory=dict)
    measured_light: tuple[np.ndarray, np.ndarray] | None = None


# --- writers ----------------------------------------------------------------------------------

def _fmt(x: float) -> str:
    return f"{float(x):.9g}"


def _spectrum_attr(wavelength_nm: Any, values: Any) -> str:
    return ", ".join(f"{_fmt(w)}:{_fmt(v)}" for w, v in zip(wavelength_nm, values, strict=True))


def _material_spectra(mat: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """kd, ks on the material's own grid, extended to 360–830 nm with the end values (which is
    what every renderer of ours does: constant beyond the fitted range)."""
    wl = np.asarray(mat.wavelength_nm, dtype=np.float64)
    grid = np.unique(np.concatenate([[SCENE_GRID_NM[0]], wl, [SCENE_GRID_NM[1]]]))
    grid = grid[(grid >= SCENE_GRID_NM[0]) & (grid <= SCENE_GRID_NM[1])]
    kd, ks, _ = mat.spectra_at(grid)
    return grid, kd, ks


def _bsdf_xml(bsdf_id: str, mat: Any, indent: str = "    ") -> str:
    grid, kd, ks = _material_spectra(mat)

    def spectrum(name: str, values: np.ndarray) -> str:
        # a constant as <float> (Mitsuba refuses an all-zero tabulated spectrum)
        if np.all(values == values[0]):
            return f'{indent}    <float name="{name}" value="{_fmt(values[0])}"/>\n'
        return f'{indent}    <spectrum name="{name}" value="{_spectrum_attr(grid, values)}"/>\n'

    return (f'{indent}<bsdf type="normbox_fit" id="{bsdf_id}">\n'
            + spectrum("kd", kd) + spectrum("ks", ks) +
            f'{indent}    <float name="alpha" value="{_fmt(mat.alpha)}"/>\n'
            f'{indent}    <float name="eta" value="{_fmt(mat.eta)}"/>\n'
            f'{indent}    <float name="c" value="{_fmt(mat.c)}"/>\n'
            f'{indent}</bsdf>\n')


def _matrix(tr: Any) -> np.ndarray:
    """A transform's 4×4 matrix, rounded to float32's 7 significant digits."""
    m = np.array(tr.matrix, dtype=np.float64).reshape(4, 4)
    return np.array([float(f"{v:.7g}") for v in m.ravel()]).reshape(4, 4)


def _transform_xml(m: np.ndarray, indent: str) -> str:
    vals = " ".join(_fmt(v) for v in m.ravel())
    return (f'{indent}<transform name="to_world">\n{indent}    <matrix value="{vals}"/>\n'
            f'{indent}</transform>\n')


def _shape_xml(name: str, shape: dict[str, Any], bsdf_ref: str | None, indent: str = "    ",
               emitter: str = "") -> str:
    out = f'{indent}<shape type="{shape["type"]}" id="{name}">\n'
    out += _transform_xml(_matrix(shape["to_world"]), indent + "    ")
    if bsdf_ref is not None:
        out += f'{indent}    <ref id="{bsdf_ref}"/>\n'
    else:
        out += (f'{indent}    <bsdf type="diffuse">\n'
                f'{indent}        <float name="reflectance" value="0"/>\n{indent}    </bsdf>\n')
    out += emitter
    return out + f"{indent}</shape>\n"


# unit-square / unit-cube corners of Mitsuba's `rectangle` ([-1,1]² at z=0, normal +z) and
# `cube` ([-1,1]³)
_RECT_V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
_RECT_F = [(0, 1, 2), (0, 2, 3)]
_CUBE_V = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)],
                   dtype=np.float64)
_CUBE_F = [(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
           (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)]


def _obj_text(shapes: dict[str, tuple[dict[str, Any], str]], angle_deg: float,
              geometry: Any) -> str:
    lines = [(f"# Normbox at sample angle s = {float(angle_deg):g} deg (0 = sample faces the light,"
             " 90 = faces the radiometer)"),
             ("# units: metres; x along the sample's rotation axis, y into the box (open side at"
             " y = -L/2), z up (floor z = 0)"),
             "# faces are counter-clockwise seen from the side they reflect (normals into the box)",
             f"# geometry (mm / deg): {json.dumps(asdict(geometry), sort_keys=True)}",
             "mtllib materials.mtl"]
    base = 1
    for name, (shape, material) in shapes.items():
        m = _matrix(shape["to_world"])
        corners, faces = (_RECT_V, _RECT_F) if shape["type"] == "rectangle" else (_CUBE_V,
                                                                                   _CUBE_F)
        v = corners @ m[:3, :3].T + m[:3, 3]
        lines.append(f"o {name}")
        lines.append(f"usemtl {material}")
        lines.extend(f"v {_fmt(p[0])} {_fmt(p[1])} {_fmt(p[2])}" for p in v)
        lines.extend(f"f {a + base} {b + base} {c + base}" for a, b, c in faces)
        base += len(corners)
    return "\n".join(lines) + "\n"


def _csv(path: Path, header: list[str], rows: list[list[Any]], comments: list[str]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.writelines(f"# {c}\n" for c in comments)
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            w.writerow([_fmt(x) if isinstance(x, (float, np.floating)) else x for x in r])


def _material_json(mat: Any, role: str, fit: Any = None) -> dict[str, Any]:
    grid, kd, ks = _material_spectra(mat)
    d: dict[str, Any] = {
        "name": mat.name, "role": role, "model": "cook-torrance-ggx-smith-ctfresnel-minus-c",
        "formula": FORMULA,
        "units": {"wavelength": "nm", "kd": "1 (albedo; kd/π in sr⁻¹)",
                  "ks": "1 (specular albedo)", "alpha": "1 (GGX roughness)",
                  "eta": "1 (relative refractive index)", "c": "sr⁻¹"},
        "alpha": float(mat.alpha), "eta": float(mat.eta), "c_per_sr": float(mat.c),
        "wavelength_nm": [float(x) for x in grid], "kd": [float(x) for x in kd],
        "ks": [float(x) for x in ks]}
    if fit is not None:
        d["fit"] = {"fit_error_pct": float(fit.fit_error_pct), "cost_weight_exponent_w": float(fit.w),
                    "gonio_tilt_deg": float(fit.tilt_deg),
                    "fitted_wavelength_nm": [float(np.min(fit.wavelength_nm)),
                                             float(np.max(fit.wavelength_nm))]}
    return d


def _package_source(module: str) -> str:
    import importlib

    mod = importlib.import_module(f"normbox_lab.predict.{module}")
    return Path(mod.__file__).read_text(encoding="utf-8")


# --- the export -------------------------------------------------------------------------------

def write_scene_package(inputs: PackageInputs, out_dir: str | Path, *,
                        max_depth: int = 12) -> PackageSummary:
    """Write the scene package of `inputs` (`normbox_lab.acquire.queries.scene_package_inputs`)
    into `out_dir` (created; existing files replaced): materials, light, the radiometer's view,
    the Mitsuba scenes and OBJ geometry, the stand-alone BSDF and renderer, manifest, README and
    the SHA256 of every file."""
    import mitsuba as mi

    if not mi.variant():
        mi.set_variant("scalar_spectral")
    out = Path(out_dir)
    for sub in ("geometry", "light", "materials", "scenes/common"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    files: list[str] = []

    def write(rel: str, text: str) -> None:
        (out / rel).write_text(text, encoding="utf-8")
        files.append(rel)

    materials = _write_materials(inputs, write)
    lamp_wl, lamp_values = _write_light(inputs, out, files)
    write("radiometer.json", json.dumps(_radiometer_view(inputs), indent=1) + "\n")
    configs = _write_scenes(inputs, materials, lamp_wl, lamp_values, max_depth, write)
    _csv(out / "configurations.csv", ["patch", "angle_deg", "scene"],
         [[p, a, s] for p, a, s in configs],
         [("one row per patch × sample angle of the reference run; a renderer returns the "
          "band radiance of each (README.md)")])
    files.append("configurations.csv")
    write("normbox_bsdf.py", _package_source("standalone_bsdf"))
    write("render_mitsuba.py", _package_source("standalone_render"))
    write("manifest.json", json.dumps(_manifest(inputs, max_depth), indent=1) + "\n")
    write("README.md", _readme(inputs.run_id, inputs.ref, inputs.geometry, inputs.lamp,
                               inputs.provenance, len(configs)))
    digest = hashlib.sha256()
    for rel in sorted(files):
        digest.update(rel.encode() + b"\0" + (out / rel).read_bytes())
    (out / "SHA256").write_text(digest.hexdigest() + "\n", encoding="utf-8")
    return PackageSummary(out, inputs.run_id, configs, sorted(files), asdict(inputs.lamp),
                          asdict(inputs.geometry))


def _write_materials(inputs: PackageInputs, write: Any) -> dict[str, Any]:
    """materials/*.json and geometry/materials.mtl; the patches' materials by fit name."""
    from normbox_lab.predict.materials import Material, holder_material

    ref, fits = inputs.ref, inputs.fits
    materials = {fit_key(p): Material.from_fit(fits[fit_key(p)]) for p in ref.patches}
    wall = Material.from_fit(fits["wall"])
    for p in ref.patches:
        k = fit_key(p)
        write(f"materials/{k}.json", json.dumps(_material_json(materials[k], f"patch {p}",
                                                               fits[k]), indent=1) + "\n")
    write("materials/wall.json", json.dumps(_material_json(wall, "wall", fits["wall"]),
                                            indent=1) + "\n")
    write("materials/holder.json", json.dumps(_material_json(holder_material(), "holder (black "
                                                             "paint, not fitted: flat kd 0.04, "
                                                             "ks 0)"),
                                              indent=1) + "\n")
    mtl = ["# material names used by the OBJ files; the BRDFs are in materials/*.json"]
    for name in ["wall", "holder", "panel", *materials]:
        mtl += [f"newmtl {name}", "Kd 0.5 0.5 0.5" if name != "panel" else "Ke 1 1 1"]
    write("geometry/materials.mtl", "\n".join(mtl) + "\n")
    return {**materials, "wall": wall, "holder": holder_material()}


def _write_light(inputs: PackageInputs, out: Path, files: list[str]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """light/spectrum.csv and light/panel_map.csv; the lamp's grid and values."""
    from normbox_lab.predict.render import LAMP_GRID_NM
    from normbox_lab.predict.scene import panel_map

    lamp, geometry, prov = inputs.lamp, inputs.geometry, inputs.provenance
    lamp_wl = np.asarray(LAMP_GRID_NM, dtype=np.float64)
    lamp_values = lamp.radiance(lamp_wl)
    measured = inputs.measured_light
    header = ["wavelength_nm", "radiance_W_sr_m2_nm"]
    rows: list[list[Any]] = [[float(w), float(v)] for w, v in zip(lamp_wl, lamp_values)]
    comments = [("the opal panel's mean spectral radiance, W·sr⁻¹·m⁻²·nm⁻¹, as the scene uses "
                "it (linear between the rows); each of the 25 panel cells emits it times its "
                "map factor (panel_map.csv)"),
                (f"lamp: Planckian {lamp.cct_K:g} K scaled to a mean panel luminance of "
                f"{lamp.luminance_cd_m2 * lamp.relative_output:.6g} cd/m² ({prov['lamp_from']})")]
    if measured is not None:
        header.append("measured_radiance_W_sr_m2_nm")
        m_at = np.interp(lamp_wl, measured[0], measured[1], left=np.nan, right=np.nan)
        rows = [r + [float(m) if np.isfinite(m) else ""] for r, m in zip(rows, m_at)]
        comments.append("measured_radiance: the mean of the light-map readings (the "
                        "radiometer's range only; empty outside it)")
    _csv(out / "light" / "spectrum.csv", header, rows, comments)
    files.append("light/spectrum.csv")
    pm = panel_map(geometry.panel_homogeneity_percent)
    ax, ay = geometry.aperture_x_mm, geometry.aperture_y_mm
    prow = []
    for j in range(5):
        for i in range(5):
            prow.append([j, i, float((i + 0.5) / 5 * ax - ax / 2), float((j + 0.5) / 5 * ay
                                                                         - ay / 2),
                         float(ax / 5), float(ay / 5), float(pm[j, i])])
    _csv(out / "light" / "panel_map.csv",
         ["row_j", "column_i", "centre_x_mm", "centre_y_mm", "size_x_mm", "size_y_mm",
          "relative_radiance"], prow,
         [("the opal panel (the ceiling aperture, emitting downwards at z = "
          f"{(geometry.box_inner_mm + geometry.ceiling_thickness_mm) / 1000:g} m) as 5×5 "
          "cells; centres in mm from the aperture centre (x along the rotation axis, y into "
          "the box); radiance = relative_radiance × spectrum.csv (mean factor 1)")])
    files.append("light/panel_map.csv")
    return lamp_wl, lamp_values


def _radiometer_view(inputs: PackageInputs) -> dict[str, Any]:
    """radiometer.json: where the radiometer stands, what it sees and how bands are formed."""
    from normbox_lab.predict.scene import radiometer_position_m, sample_centre_m, sample_normal

    geometry, angles = inputs.geometry, inputs.ref.angle_deg
    origin = radiometer_position_m(geometry)
    target = sample_centre_m(geometry)
    direction = (target - origin) / np.linalg.norm(target - origin)
    dist = float(np.linalg.norm(target - origin))
    spot = 2 * dist * math.tan(math.radians(geometry.radiometer_view_deg / 2))
    return {
        "instrument": "spectroradiometer (Konica Minolta CS-1000A class), 1° acceptance",
        "position_m": [float(x) for x in origin], "target_m": [float(x) for x in target],
        "direction": [float(x) for x in direction], "up": [0.0, 0.0, 1.0],
        "field_of_view_deg": float(geometry.radiometer_view_deg),
        "field_shape": "square, fov along x (Mitsuba perspective fov_axis x); the instrument's "
                       "is a 1° circle",
        "pixels": [PIXELS, PIXELS],
        "averaging": "the prediction is the mean radiance of the 10 × 10 pixels",
        "spot_diameter_on_sample_mm_at_normal_view": spot * 1000.0,
        "spot_length_on_sample_mm": {f"{a:g}": spot * 1000.0 / max(math.sin(math.radians(a)),
                                                                   1e-9)
                                     for a in angles},
        "view_angle_from_sample_normal_deg": {f"{a:g}": 90.0 - float(a) for a in angles},
        "bands": {"centres_nm": [BAND_START_NM, BAND_STOP_NM, BAND_STEP_NM],
                  "shape": "triangular, unit height, half-width 5 nm: band value = ∫ hat(λ) L(λ) "
                           "dλ / 5 nm (the band-averaged radiance)"},
        "sample_normal_at_angle": {f"{a:g}": [float(x) for x in sample_normal(a)]
                                   for a in angles}}


def _write_scenes(inputs: PackageInputs, materials: dict[str, Any], lamp_wl: np.ndarray,
                  lamp_values: np.ndarray, max_depth: int, write: Any
                  ) -> list[tuple[int, float, str]]:
    """scenes/common/*.xml, geometry/normbox_s*.obj and one scenes/pNN_sA.xml per
    configuration; the configurations (patch, angle_deg, scene file)."""
    from normbox_lab.predict.render import BAND_CENTRES_NM, BAND_WIDTH_NM
    from normbox_lab.predict.scene import band_film, scene_dict

    geometry, ref = inputs.geometry, inputs.ref
    film = band_film(BAND_CENTRES_NM, BAND_WIDTH_NM, PIXELS)
    d0 = scene_dict(geometry, angle_deg=0.0, patch_bsdf="PATCH",
                    wall_bsdf="wall", holder_bsdf="holder", lamp_values=lamp_values,
                    lamp_grid_nm=lamp_wl, film=film, max_depth=max_depth, post_bsdf="holder")
    write("scenes/common/box.xml", _common_box_xml(d0, materials, max_depth))
    for name, text in _sensor_xml(d0["sensor"]).items():
        write(f"scenes/common/{name}.xml", text)
    configs: list[tuple[int, float, str]] = []
    for a in ref.angle_deg:
        d = scene_dict(geometry, angle_deg=float(a), patch_bsdf="PATCH", wall_bsdf="wall",
                       holder_bsdf="holder", lamp_values=lamp_values, lamp_grid_nm=lamp_wl,
                       film=film, max_depth=max_depth, post_bsdf="holder")
        shapes = {k: (d[k], d[k]["bsdf"] if isinstance(d[k]["bsdf"], str) else "panel")
                  for k in d if k not in ("type", "integrator", "sensor")}
        shapes = {k: (s, "panel" if k.startswith("panel_") else ("patch" if m == "PATCH" else m))
                  for k, (s, m) in shapes.items()}
        write(f"geometry/normbox_s{float(a):g}.obj", _obj_text(shapes, float(a), geometry))
        for p in ref.patches:
            name = config_name(p, float(a))
            text = ['<?xml version="1.0" encoding="utf-8"?>',
                    (f"<!-- patch {p} ({ref.patch_names[ref.patches.index(p)]}) at sample angle "
                    f"{float(a):g}°: the radiometer sees it at {90 - float(a):g}° from its "
                    "normal. Render with the normbox_fit BSDF registered (normbox_bsdf.py); "
                    "sensor=sensor_rgb for an RGB variant. -->"),
                    '<scene version="3.0.0">',
                    '    <default name="sensor" value="sensor_spectral"/>',
                    '    <include filename="common/box.xml"/>',
                    '    <include filename="common/$sensor.xml"/>',
                    _bsdf_xml("patch_bsdf", materials[fit_key(p)]).rstrip("\n"),
                    _shape_xml("patch", d["patch"], "patch_bsdf").rstrip("\n"),
                    _shape_xml("holder_plate", d["holder_plate"], "holder").rstrip("\n"),
                    "</scene>"]
            write(f"scenes/{name}.xml", "\n".join(text) + "\n")
            configs.append((int(p), float(a), f"scenes/{name}.xml"))
    return configs


def _common_box_xml(d0: dict[str, Any], materials: dict[str, Any], max_depth: int) -> str:
    """The box without the sample (walls, ceiling, the 25 emitting panel cells, the post) and
    the integrator, included by every configuration's scene."""
    fixed = [k for k in d0 if k not in ("type", "integrator", "sensor", "patch", "holder_plate")]
    common = ['<?xml version="1.0" encoding="utf-8"?>',
              ("<!-- The Normbox without the sample: walls, ceiling with aperture, the opal panel "
              "(25 emitting cells), the holder post; the integrator. Units: metres, "
              "W·sr⁻¹·m⁻²·nm⁻¹. Included by every configuration's scene. -->"),
              '<scene version="3.0.0">',
              (f'    <integrator type="path">\n        <integer name="max_depth" value="'
              f'{int(max_depth)}"/>\n        <integer name="rr_depth" value="6"/>\n'
              '        <boolean name="hide_emitters" value="false"/>\n    </integrator>'),
              _bsdf_xml("wall", materials["wall"]).rstrip("\n"),
              _bsdf_xml("holder", materials["holder"]).rstrip("\n")]
    for k in fixed:
        shape = d0[k]
        if "emitter" in shape:
            rad = shape["emitter"]["radiance"]
            vals = [float(x) for x in rad["values"].split(",")]
            grid = np.linspace(rad["wavelength_min"], rad["wavelength_max"], len(vals))
            emitter = ('        <emitter type="area">\n            <spectrum name="radiance" '
                       f'value="{_spectrum_attr(grid, vals)}"/>\n        </emitter>\n')
            common.append(_shape_xml(k, shape, None, emitter=emitter).rstrip("\n"))
        else:
            common.append(_shape_xml(k, shape, shape["bsdf"]).rstrip("\n"))
    common.append("</scene>")
    return "\n".join(common) + "\n"


def _sensor_xml(sensor: dict[str, Any]) -> dict[str, str]:
    """The two sensors (``sensor_spectral``: one band per film channel; ``sensor_rgb``)."""
    from normbox_lab.predict.render import BAND_CENTRES_NM, BAND_WIDTH_NM

    sens_tr = _transform_xml(_matrix(sensor["to_world"]), "        ")
    sens_head = ('<?xml version="1.0" encoding="utf-8"?>\n<scene version="3.0.0">\n'
                 '    <sensor type="perspective">\n'
                 f'        <float name="fov" value="{_fmt(sensor["fov"])}"/>\n'
                 '        <string name="fov_axis" value="x"/>\n'
                 '        <float name="near_clip" value="0.01"/>\n'
                 '        <float name="far_clip" value="10"/>\n' + sens_tr +
                 '        <sampler type="independent">\n'
                 '            <integer name="sample_count" value="64"/>\n'
                 '        </sampler>\n')
    bands = "".join(f'            <spectrum name="b{k:04d}" value="{_fmt(lam - BAND_WIDTH_NM)}:0,'
                    f' {_fmt(lam)}:1, {_fmt(lam + BAND_WIDTH_NM)}:0"/>\n'
                    for k, lam in enumerate(BAND_CENTRES_NM))
    return {
        "sensor_spectral": sens_head + '        <film type="specfilm">\n'
        f'            <integer name="width" value="{PIXELS}"/>\n'
        f'            <integer name="height" value="{PIXELS}"/>\n'
        '            <string name="component_format" value="float32"/>\n'
        '            <rfilter type="box"/>\n' + bands +
        "        </film>\n    </sensor>\n</scene>\n",
        "sensor_rgb": sens_head + '        <film type="hdrfilm">\n'
        f'            <integer name="width" value="{PIXELS}"/>\n'
        f'            <integer name="height" value="{PIXELS}"/>\n'
        '            <string name="pixel_format" value="rgb"/>\n'
        '            <string name="component_format" value="float32"/>\n'
        '            <rfilter type="box"/>\n'
        "        </film>\n    </sensor>\n</scene>\n"}


def _manifest(inputs: PackageInputs, max_depth: int) -> dict[str, Any]:
    from normbox_lab.core.spectral import WHITE_PATCH

    ref, lamp = inputs.ref, inputs.lamp
    wp = WHITE_PATCH if WHITE_PATCH in ref.patches else ref.patches[0]
    return {
        "format": PACKAGE_FORMAT, "reference_run": inputs.run_id,
        "reference_run_uuid": inputs.run_uuid,
        "protocol": inputs.protocol, "code_version": inputs.code_version,
        "patches": ref.patches, "angle_deg": [float(a) for a in ref.angle_deg],
        "reference_wavelength_nm": [float(ref.wavelength_nm.min()),
                                    float(ref.wavelength_nm.max())],
        "white_patch": wp, "units": {"length": "m", "radiance": "W·sr⁻¹·m⁻²·nm⁻¹",
                                     "wavelength": "nm", "angle": "deg", "brdf": "sr⁻¹"},
        "geometry_mm_deg": asdict(inputs.geometry),
        "lamp": {"cct_K": lamp.cct_K, "luminance_cd_m2": lamp.luminance_cd_m2,
                 "relative_output": lamp.relative_output},
        "provenance": inputs.provenance, "max_depth": int(max_depth)}


def _readme(run_id: int, ref: Any, geometry: Any, lamp: Any, prov: dict[str, Any],
            n_configs: int) -> str:
    angles = ", ".join(f"{a:g}" for a in ref.angle_deg)
    patches = ", ".join(str(p) for p in ref.patches)
    return f"""# Normbox scene package — reference run {run_id}

A renderer-neutral description of a Normbox measurement campaign: render each configuration
(patch × sample angle, {n_configs} in all) and return the radiance the radiometer would see.
`normbox-lab import prediction FILE --ref-run {run_id} --renderer NAME` then compares your
renderer with the measurement exactly as it compares its own prediction.

Patches: {patches}. Sample angles (deg): {angles}.

## Units and conventions
- Lengths in metres (the manifest's geometry in mm and degrees); wavelengths in nm; spectral
  radiance in W·sr⁻¹·m⁻²·nm⁻¹; BRDFs in sr⁻¹; angles in degrees.
- World frame: x along the sample's rotation axis (parallel to the open side), y into the box
  (the open side at y = −0.3 m, the back wall at +0.3 m), z up (floor at z = 0, the ceiling's
  inner face at z = 0.6 m).  The sample (a square patch in a black holder) is centred at
  (0, 0, {geometry.sample_height_mm / 1000:g}) m and turned about x: its normal at sample angle
  s is (0, −sin s, cos s), so s = 0° faces the light in the ceiling and s = 90° the radiometer.
- Walls are their inner faces; all surfaces are one-sided in the OBJ (normals into the box) but
  the BRDF is two-sided.  Outside the box the lab is dark.

## Files
- `geometry/normbox_s<angle>.obj`: every surface at that sample angle (triangles, metres),
  grouped (`o`) by surface and tagged (`usemtl`) wall / holder / panel / patch.
- `light/spectrum.csv`: the panel's mean spectral radiance (W·sr⁻¹·m⁻²·nm⁻¹), linear
  between rows; `light/panel_map.csv`: its 5×5 relative map (each cell emits spectrum × factor,
  a Lambertian emitter facing down).  Lamp: {prov.get('lamp_from', '')}.
- `materials/*.json`: per patch (`pNN`), the wall and the holder: the fitted BRDF with the
  formula written out (Cook-Torrance with GGX, separable Smith G1, the Cook-Torrance Fresnel
  with one real η, spectral kd and ks, minus a constant c); kd and ks are linear between the
  listed wavelengths.
- `radiometer.json`: position, direction, field of view (1°), 10 × 10 pixels averaged, the
  spot on the sample per angle, and the band definition.
- `scenes/pNN_s<angle>.xml`: a Mitsuba 3 scene per configuration (includes `scenes/common/`).
- `normbox_bsdf.py`: the fit model as a stand-alone Mitsuba BSDF plugin (`normbox_fit`).
- `render_mitsuba.py`: renders every configuration with stock Mitsuba 3 and writes the CSV
  below: `python render_mitsuba.py --variant llvm_ad_spectral --spp 256 --out predictions.csv`
  (`--variant llvm_ad_rgb` renders RGB and writes spectra upsampled from it, as a triplet
  renderer would hand them back; `--only p19_s30,...` a subset).

## What a renderer must return
A CSV with the header `patch,angle_deg,wavelength_nm,radiance_W_sr_m2_nm[,std_error]`, one row
per configuration and wavelength (lines starting with `#` are comments; `# renderer_version: X`
is recorded).  Every configuration of `configurations.csv` exactly once, no others; wavelengths
in nm covering {ref.wavelength_nm.min():g}–{ref.wavelength_nm.max():g} nm (any grid, e.g. the
5 nm bands of `radiometer.json`); radiance finite and ≥ 0, the mean over the radiometer's 1°
field; `std_error` the Monte-Carlo standard error of that mean (same unit), if known.
Alternatively a directory with one spectral OpenEXR per configuration, named like its scene
(`p19_s30.exr`), channels `S0.<λ>nm` (the spectral EXR layout of Fichet, Pacanowski & Wilkie),
values in W·sr⁻¹·m⁻²·nm⁻¹; the pixels are averaged.
"""
