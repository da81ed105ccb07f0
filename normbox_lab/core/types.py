"""Core data types.  Units are in every name (DESIGN §4).

Radiance: W·sr⁻¹·m⁻²·nm⁻¹.  BRDF: sr⁻¹.  Angles: degrees.  Times: seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np


def fit_key(patch: int | str) -> str:
    """The name of a material's fit (the store's fit artifact, the brdf-inplane protocol's
    material key): ``p01``…``p24`` for a patch number, any other name (``wall``) as it is."""
    return f"p{int(patch):02d}" if str(patch).isdigit() else str(patch)


def _as_1d_float(name: str, value: Any) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    return arr


@dataclass(frozen=True)
class Colorimetry:
    """The colorimetric block the radiometers report with each measurement."""

    Le_W_sr_m2: float          # radiance, integrated 380–780 nm
    Lv_cd_m2: float            # luminance
    X: float                   # tristimulus (CIE 1931 2°, absolute, cd/m² scale)
    Y: float
    Z: float
    x: float                   # chromaticity
    y: float
    u_prime: float             # CIE 1976 UCS
    v_prime: float
    cct_K: float               # correlated colour temperature (nan when undefined)
    duv: float                 # distance from the Planckian locus

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, float]) -> Colorimetry:
        return cls(**{f.name: float(d[f.name]) for f in fields(cls)})


@dataclass(frozen=True)
class SpectralReading:
    """One spectroradiometer measurement."""

    wavelength_nm: np.ndarray
    radiance_W_sr_m2_nm: np.ndarray
    colorimetry: Colorimetry | None
    integration_time_s: float
    timestamp_s: float          # seconds since the Unix epoch (from the injected clock)
    instrument_id: str
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl = _as_1d_float("wavelength_nm", self.wavelength_nm)
        rad = _as_1d_float("radiance_W_sr_m2_nm", self.radiance_W_sr_m2_nm)
        if wl.shape != rad.shape:
            raise ValueError(f"wavelength_nm {wl.shape} and radiance {rad.shape} differ in shape")
        if wl.size > 1 and np.any(np.diff(wl) <= 0):
            raise ValueError("wavelength_nm must be strictly increasing")
        object.__setattr__(self, "wavelength_nm", wl)
        object.__setattr__(self, "radiance_W_sr_m2_nm", rad)


@dataclass(frozen=True)
class BrdfReading:
    """One gonioreflectometer geometry: in-plane angles, out-of-plane tilt, spectral BRDF."""

    theta_i_deg: float
    theta_o_deg: float
    tilt_deg: float              # out-of-plane tilt of the arms (±4° in the Normbox gonio)
    wavelength_nm: np.ndarray
    brdf_per_sr: np.ndarray
    raw_counts: np.ndarray | None = None
    integration_time_s: float = 0.0
    timestamp_s: float = 0.0
    instrument_id: str = ""
    blocked: bool = False         # an arm shadows the other at this geometry
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl = _as_1d_float("wavelength_nm", self.wavelength_nm)
        f = _as_1d_float("brdf_per_sr", self.brdf_per_sr)
        if wl.shape != f.shape:
            raise ValueError(f"wavelength_nm {wl.shape} and brdf {f.shape} differ in shape")
        object.__setattr__(self, "wavelength_nm", wl)
        object.__setattr__(self, "brdf_per_sr", f)
        if self.raw_counts is not None:
            object.__setattr__(self, "raw_counts", np.asarray(self.raw_counts, dtype=np.float64))
