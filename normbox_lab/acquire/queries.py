"""Queries on the store that the pipeline, the report, the budget, the scene package and the
commands share: the reference run's spectra, the latest fits, the prediction's lamp, the latest
run of a protocol, what the prediction of a reference run used (geometry, lamp) and the inputs
of its scene package.  Read-only; nothing here writes to the store.

They live in `acquire`, next to the store, so that the layers above (predict's callers, analyze,
the commands) read the store one way and `predict` itself never does: it gets plain inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import DataError
from normbox_lab.core.spectral import WHITE_PATCH
from normbox_lab.core.types import ReadingGeometry, fit_key

__all__ = ["WHITE_PATCH", "ReferenceData", "fit_key", "lamp_from_light_map", "latest_fits",
           "latest_run", "measured_light", "prediction_inputs", "reference_data",
           "scene_package_inputs", "white_index"]


def white_index(patches: list[int]) -> int:
    """Index of the white patch (19) in `patches`, or 0 when it was not measured."""
    return patches.index(WHITE_PATCH) if WHITE_PATCH in patches else 0


# --- the reference run ---------------------------------------------------------------------------

@dataclass
class ReferenceData:
    patches: list[int]
    angle_deg: np.ndarray             # the sweep's angles (the rotator's setpoints)
    wavelength_nm: np.ndarray
    radiance: np.ndarray              # [patch, angle, λ], W·sr⁻¹·m⁻²·nm⁻¹
    patch_names: list[str] = field(default_factory=list)
    #: [patch, angle]: the rotator's readback at each reading, deg (NaN: not recorded)
    angle_readback_deg: np.ndarray | None = None

    def readback_offset_deg(self) -> np.ndarray:
        """Per angle: the mean over patches of readback − setpoint, deg (NaN where no
        readback was recorded: a store from before readbacks were kept)."""
        if self.angle_readback_deg is None:
            return np.full(self.angle_deg.shape, np.nan)
        dev = self.angle_readback_deg - self.angle_deg[None, :]
        out = np.full(self.angle_deg.shape, np.nan)
        seen = np.isfinite(dev).any(axis=0)
        out[seen] = np.nanmean(dev[:, seen], axis=0)
        return out


def reference_data(store: Store, run_ref: int | str) -> ReferenceData:
    """The reference sweep's spectra as [patch, angle, λ] (grouped by the sweep's setpoints,
    with the rotator's readbacks); refuses holes (resume the run)."""
    rows = [(r, ReadingGeometry.of(r.metadata)) for r in store.readings(run_ref, kind="spectral")]
    rows = [(r, g) for r, g in rows if g.patch is not None and g.angle_deg is not None]
    if not rows:
        raise DataError(str(store.path), f"run {run_ref}", "no patch × angle readings")
    patches = sorted({g.patch for _, g in rows})
    angles = sorted({float(g.angle_deg) for _, g in rows})
    wl = rows[0][0].arrays["wavelength_nm"]
    rad = np.full((len(patches), len(angles), wl.size), np.nan)
    readback = np.full((len(patches), len(angles)), np.nan)
    names: dict[int, str] = {}
    for r, g in rows:
        p, a = patches.index(g.patch), angles.index(float(g.angle_deg))
        rad[p, a] = np.interp(wl, r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"])
        if g.sample_angle is not None and g.sample_angle.readback is not None:
            readback[p, a] = g.sample_angle.readback
        names[g.patch] = str(r.metadata.get("patch_name", g.patch))
    missing = np.isnan(rad).all(axis=-1)
    if missing.any():
        holes = [f"a{angles[a]:g}/p{patches[p]:02d}" for p, a in zip(*np.nonzero(missing))]
        raise DataError(str(store.path), f"run {run_ref}",
                        f"{len(holes)} readings missing (e.g. {holes[0]}); resume the run first")
    return ReferenceData(patches, np.array(angles), wl, rad, [names[p] for p in patches],
                         readback)


# --- fits, lamp, runs ----------------------------------------------------------------------------

def latest_fits(store: Store) -> dict[str, Any]:
    """The latest fit of every material in the store, by name (`p01`…, `wall`)."""
    from normbox_lab.predict.brdf_model import MaterialFit

    return {a.name: MaterialFit.from_artifact(a) for a in store.artifacts("fit")}


def lamp_from_light_map(store: Store, light_map_run: int | str | None) -> Any:
    """The prediction's lamp: nominal spectrum, luminance from the light-map run if given."""
    from normbox_lab.predict.render import Lamp, luminance_cd_m2

    if light_map_run is None:
        return Lamp()
    lv = [luminance_cd_m2(r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"])
          for r in store.readings(light_map_run, kind="spectral")]
    if not lv:
        raise DataError(str(store.path), f"run {light_map_run}", "light map has no readings")
    return Lamp(luminance_cd_m2=float(np.mean(lv)))


def latest_run(store: Store, protocol: str) -> Any:
    """The latest finished run of `protocol`, or None."""
    runs = [r for r in store.runs() if r.protocol == protocol and r.status == "done"]
    return runs[-1] if runs else None


# --- what a prediction of a reference run used, the scene package's inputs ---------------------

def prediction_inputs(store: Store, ref_run: int | str, *, light_map_run: int | str | None = None
                      ) -> tuple[Any, Any, dict[str, Any]]:
    """(geometry, lamp, provenance) our prediction of `ref_run` used: the prediction artifact's
    recorded lamp and geometry; else the light-map run (given, or the latest finished one) and
    the reference run's lab config; else the Normbox defaults."""
    from normbox_lab.predict.render import Lamp
    from normbox_lab.predict.scene import as_geometry

    run = store.get_run(ref_run)
    prov: dict[str, Any] = {}
    md: dict[str, Any] = {}
    found = store.artifacts("prediction", f"ref-run-{run.id}")
    if found:
        md = dict(found[-1].metadata)
        prov["prediction_artifact"] = found[-1].id
    geometry = None
    if isinstance(md.get("geometry"), dict):
        geometry = as_geometry(_Obj(md["geometry"]))
        prov["geometry_from"] = "prediction"
    elif run.lab_config:
        from normbox_lab.acquire.config import parse_config

        geometry = parse_config(run.lab_config, f"run {run.id} lab config").geometry
        prov["geometry_from"] = f"run {run.id} lab config"
    else:
        geometry = as_geometry(None)
        prov["geometry_from"] = "Normbox defaults"
    if isinstance(md.get("lamp"), dict):
        lamp = Lamp(**{k: float(v) for k, v in md["lamp"].items()})
        prov["lamp_from"] = "prediction"
    else:
        lm = light_map_run
        if lm is None:
            done = latest_run(store, "light-map")
            lm = done.id if done is not None else None
        lamp = lamp_from_light_map(store, lm)
        prov["lamp_from"] = f"light-map run {store.get_run(lm).id}" if lm is not None \
            else "nominal lamp"
    return geometry, lamp, prov


class _Obj:
    def __init__(self, d: dict[str, Any]) -> None:
        self.__dict__.update(d)


def measured_light(store: Store, light_map_run: int | str | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Mean measured panel spectrum of a light-map run (wavelength_nm, radiance)."""
    if light_map_run is None:
        return None
    rows = list(store.readings(light_map_run, kind="spectral"))
    if not rows:
        return None
    wl = rows[0].arrays["wavelength_nm"]
    rad = np.mean([np.interp(wl, r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"])
                   for r in rows], axis=0)
    return wl, rad


def scene_package_inputs(store: Store, ref_run: int | str, *,
                         light_map_run: int | str | None = None,
                         fits: dict[str, Any] | None = None) -> Any:
    """Everything `normbox_lab.predict.scene_package.write_scene_package` needs of the store
    for `ref_run`: the reference spectra, the fits of its patches and the wall (the latest, or
    `fits`), the geometry, the lamp and the measured light of the prediction."""
    from normbox_lab.core.errors import StoreError
    from normbox_lab.predict.scene_package import PackageInputs

    run = store.get_run(ref_run)
    ref = reference_data(store, run.id)
    fits = fits if fits is not None else latest_fits(store)
    need = [fit_key(p) for p in ref.patches] + ["wall"]
    missing = [n for n in need if n not in fits]
    if missing:
        raise StoreError(f"no fits for {', '.join(missing)}: run `normbox-lab fit` first")
    geometry, lamp, prov = prediction_inputs(store, run.id, light_map_run=light_map_run)
    lm = light_map_run if light_map_run is not None else (
        prov["lamp_from"].split()[-1] if prov.get("lamp_from", "").startswith("light-map run")
        else None)
    return PackageInputs(run_id=run.id, run_uuid=run.uuid, protocol=run.protocol,
                         code_version=run.code_version, ref=ref,
                         fits={k: fits[k] for k in need}, geometry=geometry, lamp=lamp,
                         provenance=prov, measured_light=measured_light(store, lm))


def renderers(store: Store, run_id: int, kind: str = "comparison") -> list[str | None]:
    """Renderers with a `kind` artifact for the run: None (ours) first, then by name."""
    from normbox_lab.predict.renderers import artifact_name, renderer_of

    base = artifact_name(run_id)
    names = {a.name for a in store.artifacts(kind) if a.name == base
             or a.name.startswith(base + "@")}
    return sorted({renderer_of(n) for n in names}, key=lambda r: (r is not None, r or ""))
