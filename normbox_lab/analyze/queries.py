"""Queries on the store that the pipeline, the report, the budget and the commands share: the
reference run's spectra, the latest fits, the prediction's lamp, the latest run of a protocol.
Read-only; nothing here writes to the store.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.core.errors import DataError
from normbox_lab.core.spectral import WHITE_PATCH

__all__ = ["WHITE_PATCH", "ReferenceData", "fit_key", "lamp_from_light_map", "latest_fits",
           "latest_run", "reference_data", "white_index"]


def fit_key(patch: int | str) -> str:
    """The fit artifact name of a patch number (the brdf-inplane protocol's material key)."""
    return f"p{int(patch):02d}" if str(patch).isdigit() else str(patch)


def white_index(patches: list[int]) -> int:
    """Index of the white patch (19) in `patches`, or 0 when it was not measured."""
    return patches.index(WHITE_PATCH) if WHITE_PATCH in patches else 0


# --- the reference run ---------------------------------------------------------------------------

@dataclass
class ReferenceData:
    patches: list[int]
    angle_deg: np.ndarray
    wavelength_nm: np.ndarray
    radiance: np.ndarray              # [patch, angle, λ], W·sr⁻¹·m⁻²·nm⁻¹
    patch_names: list[str] = field(default_factory=list)


def reference_data(store: Any, run_ref: int | str) -> ReferenceData:
    """The reference sweep's spectra as [patch, angle, λ]; refuses holes (resume the run)."""
    rows = [r for r in store.readings(run_ref, kind="spectral")
            if "patch" in r.metadata and "angle_deg" in r.metadata]
    if not rows:
        raise DataError(str(store.path), f"run {run_ref}", "no patch × angle readings")
    patches = sorted({int(r.metadata["patch"]) for r in rows})
    angles = sorted({float(r.metadata["angle_deg"]) for r in rows})
    wl = rows[0].arrays["wavelength_nm"]
    rad = np.full((len(patches), len(angles), wl.size), np.nan)
    names: dict[int, str] = {}
    for r in rows:
        p, a = patches.index(int(r.metadata["patch"])), angles.index(float(r.metadata["angle_deg"]))
        rad[p, a] = np.interp(wl, r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"])
        names[int(r.metadata["patch"])] = str(r.metadata.get("patch_name", r.metadata["patch"]))
    missing = np.isnan(rad).all(axis=-1)
    if missing.any():
        holes = [f"a{angles[a]:g}/p{patches[p]:02d}" for p, a in zip(*np.nonzero(missing))]
        raise DataError(str(store.path), f"run {run_ref}",
                        f"{len(holes)} readings missing (e.g. {holes[0]}); resume the run first")
    return ReferenceData(patches, np.array(angles), wl, rad, [names[p] for p in patches])


# --- fits, lamp, runs ----------------------------------------------------------------------------

def latest_fits(store: Any) -> dict[str, Any]:
    """The latest fit of every material in the store, by name (`p01`…, `wall`)."""
    from normbox_lab.predict.brdf_model import MaterialFit

    return {a.name: MaterialFit.from_artifact(a) for a in store.artifacts("fit")}


def lamp_from_light_map(store: Any, light_map_run: int | str | None) -> Any:
    """The prediction's lamp: nominal spectrum, luminance from the light-map run if given."""
    from normbox_lab.predict.render import Lamp, luminance_cd_m2

    if light_map_run is None:
        return Lamp()
    lv = [luminance_cd_m2(r.arrays["wavelength_nm"], r.arrays["radiance_W_sr_m2_nm"])
          for r in store.readings(light_map_run, kind="spectral")]
    if not lv:
        raise DataError(str(store.path), f"run {light_map_run}", "light map has no readings")
    return Lamp(luminance_cd_m2=float(np.mean(lv)))


def latest_run(store: Any, protocol: str) -> Any:
    """The latest finished run of `protocol`, or None."""
    runs = [r for r in store.runs() if r.protocol == protocol and r.status == "done"]
    return runs[-1] if runs else None
