"""Core data types.  Units are in every name (DESIGN §4).

Radiance: W·sr⁻¹·m⁻²·nm⁻¹.  BRDF: sr⁻¹.  Angles: degrees.  Times: seconds.
"""

from __future__ import annotations

from collections.abc import Mapping
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


# --- where a reading was taken: setpoint and readback ------------------------------------------

@dataclass(frozen=True)
class Location:
    """What an instrument was told (`setpoint`) and what it reported back (`readback`) at the
    moment of a reading, in `unit` — bluesky's ``locate()`` {setpoint, readback}.

    A stage's angle (deg), the lamp monitor's luminance (cd/m², no setpoint: the lamp is not
    servoed to a luminance) and the radiometer's integration time (s; no setpoint when the
    instrument chooses it).  ``readback is None``: not recorded (a reading stored before the
    readback was kept).  `tolerance`: the largest |readback − setpoint| the instrument states
    as in place (None: none stated)."""

    setpoint: float | None
    readback: float | None
    unit: str
    tolerance: float | None = None

    @property
    def recorded(self) -> bool:
        return self.readback is not None

    @property
    def deviation(self) -> float | None:
        """readback − setpoint, or None when either is missing."""
        if self.setpoint is None or self.readback is None:
            return None
        return self.readback - self.setpoint

    @property
    def value(self) -> float | None:
        """The best value of the quantity: the readback where recorded, else the setpoint."""
        return self.readback if self.readback is not None else self.setpoint

    def out_of_tolerance(self) -> bool:
        """True when the readback differs from the setpoint by more than the tolerance."""
        d = self.deviation
        return d is not None and self.tolerance is not None and abs(d) > self.tolerance

    def describe(self) -> str:
        rb = "not recorded" if self.readback is None else f"{self.readback:.4g} {self.unit}"
        sp = "none" if self.setpoint is None else f"{self.setpoint:.4g} {self.unit}"
        return f"setpoint {sp}, readback {rb}"

    def to_dict(self) -> dict[str, Any]:
        return {"setpoint": self.setpoint, "readback": self.readback, "unit": self.unit,
                "tolerance": self.tolerance}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Location:
        def num(v: Any) -> float | None:
            return None if v is None else float(v)

        return cls(num(d.get("setpoint")), num(d.get("readback")), str(d.get("unit", "")),
                   num(d.get("tolerance")))


#: a reading's metadata keys for its geometry — the one place they are spelled
ANGLE_DEG = "angle_deg"                 # the sample angle (reference sweep), deg
THETA_I_DEG = "theta_i_deg"             # the gonio's incidence angle, deg
THETA_O_DEG = "theta_o_deg"             # the gonio's viewing angle, deg
PATCH = "patch"                         # ColorChecker patch number (1 … 24)
LAMP_MONITOR_CD_M2 = "lamp_monitor_cd_m2"
#: role or quantity → `Location.to_dict()`: what each instrument did at the reading
LOCATIONS = "locations"
#: the roles whose locations a reading's geometry reads (the registry's role names)
ROTATOR_ROLE, LIGHT_ARM_ROLE, DETECTOR_ARM_ROLE = ("rotator", "gonio_light_arm",
                                                   "gonio_detector_arm")
LAMP_MONITOR, INTEGRATION_TIME = "lamp_monitor", "integration_time"


@dataclass(frozen=True)
class ReadingGeometry:
    """The typed geometry of one reading (a step's sample angle, patch, gonio angles) with
    what the instruments did: readers take this, not ``metadata["angle_deg"]``.

    Built from a stored reading's metadata by `of`; a reading stored before readbacks were
    kept migrates on read: its angles have the step's setpoint and a readback that is "not
    recorded" (``Location.readback is None``)."""

    patch: int | None = None
    sample_angle: Location | None = None        # deg (the rotator)
    theta_i: Location | None = None             # deg (the gonio's light arm)
    theta_o: Location | None = None             # deg (the gonio's detector arm)
    lamp_monitor: Location | None = None        # cd/m²
    integration_time: Location | None = None    # s
    locations: Mapping[str, Location] = field(default_factory=dict)

    @property
    def angle_deg(self) -> float | None:
        """The sample angle's setpoint (the step's angle: the key readings are grouped by)."""
        return None if self.sample_angle is None else self.sample_angle.setpoint

    def out_of_tolerance(self) -> dict[str, Location]:
        """The locations whose readback is beyond their stated tolerance, by name."""
        return {name: loc for name, loc in self.locations.items() if loc.out_of_tolerance()}

    @classmethod
    def of(cls, metadata: Mapping[str, Any]) -> ReadingGeometry:
        stored = {k: Location.from_dict(v) for k, v in (metadata.get(LOCATIONS) or {}).items()}

        def axis(role: str, key: str) -> Location | None:
            if role in stored:
                return stored[role]
            if key in metadata:                  # a store from before: the setpoint only
                return Location(float(metadata[key]), None, "deg")
            return None

        lamp = stored.get(LAMP_MONITOR)
        if lamp is None and metadata.get(LAMP_MONITOR_CD_M2) is not None:
            lamp = Location(None, float(metadata[LAMP_MONITOR_CD_M2]), "cd/m2")
        patch = metadata.get(PATCH)
        return cls(patch=int(patch) if isinstance(patch, (int, float)) or str(patch).isdigit()
                   else None,
                   sample_angle=axis(ROTATOR_ROLE, ANGLE_DEG),
                   theta_i=axis(LIGHT_ARM_ROLE, THETA_I_DEG),
                   theta_o=axis(DETECTOR_ARM_ROLE, THETA_O_DEG),
                   lamp_monitor=lamp, integration_time=stored.get(INTEGRATION_TIME),
                   locations=stored)
