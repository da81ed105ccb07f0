"""Device capabilities: the one contract between instruments and the rest of the lab.

Small ``typing.Protocol``s, ``@runtime_checkable``, in the spirit of bluesky's
``protocols.py`` ([BLUESKY] in docs/references.md):
each names one thing an instrument can do, with units in its names.  The run engine and the
operator console ask ``isinstance(inst, Movable)`` — never ``hasattr`` — and a driver is
whatever set of capabilities its methods make it.  A capability carries the timing model of
what it does (``estimate_move_time_s``, ``estimate_measure_time_s`` …): that is how a dry run
gets an exact ETA without knowing any instrument.

The *roles* at the end (`Spectroradiometer`, `RotationStage`, `LightSource`, `Spectrometer`,
`Gonioreflectometer`) are named bundles of capabilities: the instrument interfaces of the design.

Which driver has which capabilities (tests check each claim, both ways):

=================================  =========================================================
driver                             capabilities
=================================  =========================================================
``drivers.cs1000.CS1000A``,        Identifiable, Closable, HealthPollable, RemoteControllable,
``drivers.cs2000.CS2000A``,        SpectrumReadable, Abortable, Recoverable
``drivers.specbos.Specbos1211``    (every radiometer of the registry)
``drivers.rotator_apt``,           Identifiable, Closable, HealthPollable, Movable, Homeable,
``drivers.rotator_zaber``          Stoppable
``drivers.sphere``                 Identifiable, Closable, HealthPollable, Switchable,
                                   LampLevel, LampMonitor, Settling, Abortable
``drivers.qepro.QEPro``            Identifiable, Closable, HealthPollable, TemperatureReadable
``drivers.gonio``                  Identifiable, Closable, HealthPollable, BrdfReadable,
                                   Calibratable, Stoppable
=================================  =========================================================
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from normbox_lab.core.types import BrdfReading, Location, SpectralReading


@dataclass(frozen=True)
class InstrumentIdentity:
    kind: str                    # "spectroradiometer", "rotation-stage", ...
    model: str                   # "CS-1000A", "K10CR1", ...
    serial_number: str = ""
    firmware: str = ""
    simulated: bool = False
    extra: dict[str, str] = field(default_factory=dict)


# --- fast isinstance ----------------------------------------------------------------------------

_ProtocolMeta = type(Protocol)
_MEMBERS: dict[type, tuple[str, ...]] = {}
_MISSING: dict[tuple[type, type], tuple[str, ...]] = {}


def _members(proto: type) -> tuple[str, ...]:
    names = _MEMBERS.get(proto)
    if names is None:
        names = set()
        for base in proto.__mro__[:-1]:
            if base.__name__ in ("Protocol", "Generic"):
                continue
            names.update(n for n in (*vars(base), *getattr(base, "__annotations__", {}))
                         if not n.startswith("_"))
        names = _MEMBERS[proto] = tuple(sorted(names))
    return names


class _CapabilityMeta(_ProtocolMeta):
    """`isinstance(inst, Capability)` as typing answers it, decided from the type where the
    type decides it (it has every member, or it has no ``__getattr__`` and the instance's own
    ``__dict__`` has none of the missing members) and then cached per type: the engine asks a
    few capabilities per reading, and typing's runtime check walks the MRO every time."""

    def __instancecheck__(cls, instance: Any) -> bool:
        if not cls.__dict__.get("_is_protocol", False):
            return super().__instancecheck__(instance)
        tp = type(instance)
        key = (tp, cls)
        missing = _MISSING.get(key)
        if missing is None:
            missing = _MISSING[key] = tuple(n for n in _members(cls) if not hasattr(tp, n))
        if not missing:
            return True
        own = getattr(instance, "__dict__", None) or {}
        if hasattr(tp, "__getattr__") or any(n in own for n in missing):
            return super().__instancecheck__(instance)
        return False


# --- every instrument ---------------------------------------------------------------------------

@runtime_checkable
class Identifiable(Protocol, metaclass=_CapabilityMeta):
    def identify(self) -> InstrumentIdentity:
        """Model, serial number, firmware (recorded with every run segment)."""
        ...


@runtime_checkable
class Closable(Protocol, metaclass=_CapabilityMeta):
    def close(self) -> None: ...


@runtime_checkable
class HealthPollable(Protocol, metaclass=_CapabilityMeta):
    def status(self) -> dict[str, Any]:
        """A cheap query of the instrument's state (the console's health poll)."""
        ...


@runtime_checkable
class RemoteControllable(Protocol, metaclass=_CapabilityMeta):
    def set_remote(self, on: bool) -> None:
        """Take (or give back) the front panel: the engine calls it before a run."""
        ...


@runtime_checkable
class Recoverable(Protocol, metaclass=_CapabilityMeta):
    def recover(self) -> None:
        """Bring the link back to a known state after a fault (resync, re-enter remote mode);
        the engine calls it before retrying a step that failed."""
        ...


# --- motion -------------------------------------------------------------------------------------

@runtime_checkable
class Movable(Protocol, metaclass=_CapabilityMeta):
    def move_to(self, angle_deg: float, wait: bool = True) -> None: ...
    def position_deg(self) -> float: ...
    def locate(self) -> Location:
        """The last commanded angle (setpoint) and where the stage reported itself when that
        move ended (readback), deg, with the stated position tolerance: stored with every
        reading taken there."""
        ...
    def is_moving(self) -> bool: ...
    def estimate_move_time_s(self, from_deg: float, to_deg: float) -> float: ...


@runtime_checkable
class Homeable(Protocol, metaclass=_CapabilityMeta):
    def home(self, wait: bool = True) -> None: ...
    def is_homed(self) -> bool: ...
    def estimate_home_time_s(self) -> float: ...


@runtime_checkable
class Stoppable(Protocol, metaclass=_CapabilityMeta):
    def stop(self) -> None:
        """Stop moving now (the engine's abort)."""
        ...


@runtime_checkable
class Abortable(Protocol, metaclass=_CapabilityMeta):
    def abort(self) -> None:
        """Abandon the measurement or action in progress (the engine's abort)."""
        ...


# --- readings -----------------------------------------------------------------------------------

@runtime_checkable
class SpectrumReadable(Protocol, metaclass=_CapabilityMeta):
    def measure(self) -> SpectralReading:
        """One spectral radiance reading (W·sr⁻¹·m⁻²·nm⁻¹) with its colorimetry."""
        ...

    def estimate_measure_time_s(self, luminance_cd_m2: float) -> float:
        """The timing model: how long `measure()` takes at this luminance."""
        ...


@runtime_checkable
class BrdfReadable(Protocol, metaclass=_CapabilityMeta):
    def measure_brdf(self, theta_i_deg: float, theta_o_deg: float) -> BrdfReading:
        """One BRDF reading (sr⁻¹) at an in-plane geometry."""
        ...

    def estimate_measure_time_s(self, theta_i_deg: float, theta_o_deg: float, *,
                                from_geometry_deg: tuple[float, float] | None = None) -> float:
        """The timing model; `from_geometry_deg` = where the arms start (default: now)."""
        ...


@runtime_checkable
class Calibratable(Protocol, metaclass=_CapabilityMeta):
    def calibrate(self) -> Mapping[str, np.ndarray] | None:
        """Take the instrument's references (e.g. dark and white); the arrays returned are
        stored with the run."""
        ...

    def estimate_calibrate_time_s(self) -> float: ...


@runtime_checkable
class TemperatureReadable(Protocol, metaclass=_CapabilityMeta):
    def tec_temperature_c(self) -> float:
        """Detector (TEC) temperature in °C."""
        ...


# --- light --------------------------------------------------------------------------------------

@runtime_checkable
class Switchable(Protocol, metaclass=_CapabilityMeta):
    def set_output(self, on: bool) -> None: ...
    def state(self) -> str:
        """"off", "settling" or "stable"."""
        ...


@runtime_checkable
class LampLevel(Protocol, metaclass=_CapabilityMeta):
    def set_level_percent(self, level_percent: float) -> None: ...


@runtime_checkable
class LampMonitor(Protocol, metaclass=_CapabilityMeta):
    def luminance_cd_m2(self) -> float:
        """The light source's own monitor of its output (the sphere's MEAS:LUM?), recorded
        with every reading that needs the lamp stable (the lamp-drift gate reads it)."""
        ...


@runtime_checkable
class Settling(Protocol, metaclass=_CapabilityMeta):
    def is_stable(self) -> bool:
        """The output is within its regulation band (readings may be taken)."""
        ...

    def estimate_settle_time_s(self) -> float:
        """Seconds until stable from now (0 when stable)."""
        ...


#: every capability, for tables and tests
CAPABILITIES: tuple[type, ...] = (
    Identifiable, Closable, HealthPollable, RemoteControllable, Recoverable,
    Movable, Homeable, Stoppable, Abortable,
    SpectrumReadable, BrdfReadable, Calibratable, TemperatureReadable,
    Switchable, LampLevel, LampMonitor, Settling,
)


def capabilities_of(inst: object) -> tuple[str, ...]:
    """Names of the capabilities `inst` (an instance or a driver class) has."""
    if isinstance(inst, type):
        return tuple(c.__name__ for c in CAPABILITIES if issubclass(inst, c))
    return tuple(c.__name__ for c in CAPABILITIES if isinstance(inst, c))


# --- roles: named bundles of capabilities --------------------------------------------------------

@runtime_checkable
class Instrument(Identifiable, Closable, Protocol):
    """Anything the lab opens."""


@runtime_checkable
class Spectroradiometer(Instrument, RemoteControllable, SpectrumReadable, Abortable,
                        HealthPollable, Protocol):
    def set_speed(self, mode: str) -> None:
        """Measurement speed / mode; accepted values are the model's (e.g. "normal", "fast")."""
        ...


@runtime_checkable
class RotationStage(Instrument, Movable, Homeable, Stoppable, HealthPollable, Protocol):
    def move_by(self, delta_deg: float, wait: bool = True) -> None: ...
    def wait_idle(self, timeout_s: float) -> None: ...


@runtime_checkable
class LightSource(Instrument, Switchable, LampLevel, Settling, HealthPollable, Protocol):
    def internal_spectrum(self) -> tuple[np.ndarray, np.ndarray]:
        """(wavelength_nm, relative spectral power) from the internal spectrometer."""
        ...

    def errors(self) -> list[str]: ...


@runtime_checkable
class Spectrometer(Instrument, TemperatureReadable, Protocol):
    def wavelengths_nm(self) -> np.ndarray: ...
    def set_integration_time_s(self, integration_time_s: float) -> None: ...
    def intensities_counts(self, correct_dark: bool = True,
                           correct_nonlinearity: bool = True) -> np.ndarray: ...
    def set_tec_setpoint_c(self, temperature_c: float) -> None: ...


@runtime_checkable
class Gonioreflectometer(Instrument, BrdfReadable, Calibratable, Protocol):
    def geometries(self) -> list[tuple[float, float, bool]]:
        """The in-plane set as (θi, θo, blocked)."""
        ...


__all__ = [
    "CAPABILITIES",
    "Abortable",
    "BrdfReadable",
    "Calibratable",
    "Closable",
    "Gonioreflectometer",
    "HealthPollable",
    "Homeable",
    "Identifiable",
    "Instrument",
    "InstrumentIdentity",
    "LampLevel",
    "LampMonitor",
    "LightSource",
    "Movable",
    "Recoverable",
    "RemoteControllable",
    "RotationStage",
    "Settling",
    "Spectrometer",
    "Spectroradiometer",
    "SpectrumReadable",
    "Stoppable",
    "Switchable",
    "TemperatureReadable",
    "capabilities_of",
]
