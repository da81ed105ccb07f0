"""Small in-test fakes of the instrument roles, on a VirtualClock (no sleeping).

Their timing models are exact on purpose (each action sleeps the clock for what its
`estimate_*` says), so the engine's dry-run ETA can be checked against executed virtual time.
Faults and lamp glitches are scripted by call number.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.acquire.registry import DRIVERS, DriverEntry
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import VirtualClock
from normbox_lab.core.errors import DeviceError, InstrumentTimeout
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import Location, SpectralReading


class FakeWorld:
    def __init__(self) -> None:
        self.patch: int | None = None
        self.angle_deg = 0.0
        self.placed: list[int] = []

    def place_patch(self, n: int) -> None:
        self.patch = int(n)
        self.placed.append(int(n))

    def luminance_cd_m2(self, patch: int | None, angle_deg: float) -> float:
        if patch is None:
            return 0.5
        return 2.0 + 3.0 * patch * (1.0 + np.cos(np.radians(angle_deg)))


class FakeStage:
    speed_deg_s = 10.0
    overhead_s = 0.5
    home_s = 5.0

    def __init__(self, clock: VirtualClock, world: FakeWorld, name: str = "rotator") -> None:
        self.clock, self.world, self.name = clock, world, name
        self.homed = False
        self.pos = 0.0
        self.moves: list[float] = []
        self.stops = 0

    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("rotation-stage", "FAKE", "1", simulated=True)

    def close(self) -> None: ...
    def is_homed(self) -> bool: return self.homed
    def estimate_home_time_s(self) -> float: return self.home_s

    def home(self, wait: bool = True) -> None:
        self.clock.sleep(self.home_s)
        self.homed, self.pos = True, 0.0
        self.world.angle_deg = 0.0

    def estimate_move_time_s(self, from_deg: float, to_deg: float) -> float:
        d = abs(to_deg - from_deg)
        return 0.0 if d == 0 else self.overhead_s + d / self.speed_deg_s

    def move_to(self, angle_deg: float, wait: bool = True) -> None:
        self.clock.sleep(self.estimate_move_time_s(self.pos, angle_deg))
        self.setpoint = float(angle_deg)
        self.pos = float(angle_deg)
        self.world.angle_deg = self.pos
        self.moves.append(self.pos)

    def position_deg(self) -> float: return self.pos

    def locate(self) -> Location:
        return Location(getattr(self, "setpoint", None), self.pos, "deg", 0.05)
    def is_moving(self) -> bool: return False
    def stop(self) -> None: self.stops += 1


class FakeLamp:
    settle_s = 120.0

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock
        self.on = False
        self.stable_at_s = float("inf")
        self.switch_ons = 0

    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("light-source", "FAKE-SPHERE", simulated=True)

    def close(self) -> None: ...

    def set_output(self, on: bool) -> None:
        self.on = on
        if on:
            self.switch_ons += 1
            self.stable_at_s = self.clock.now_s() + self.settle_s

    def set_level_percent(self, level_percent: float) -> None: ...

    def state(self) -> str:
        if not self.on:
            return "off"
        return "stable" if self.clock.now_s() >= self.stable_at_s else "settling"

    def is_stable(self) -> bool: return self.state() == "stable"

    def estimate_settle_time_s(self) -> float:
        return self.settle_s

    def glitch(self, duration_s: float) -> None:
        """The lamp drifts out of regulation for `duration_s`."""
        self.stable_at_s = self.clock.now_s() + duration_s


@dataclass
class FakeRadiometer:
    clock: VirtualClock
    world: FakeWorld
    #: call number (1-based) → list of exceptions to raise on that call and its retries
    faults: dict[int, list[BaseException]] = field(default_factory=dict)
    #: call number → callback run in the middle of that measurement
    during: dict[int, Callable[[], None]] = field(default_factory=dict)
    calls: int = 0
    aborted: int = 0
    remote: bool = False
    _abort_flag: bool = False

    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("spectroradiometer", "FAKE-CS", "42", simulated=True)

    def close(self) -> None: ...
    def set_remote(self, on: bool) -> None: self.remote = on
    def set_speed(self, mode: str) -> None: ...
    def status(self) -> dict[str, object]: return {}

    def estimate_measure_time_s(self, luminance_cd_m2: float) -> float:
        return 2.0 + 40.0 / max(luminance_cd_m2, 0.1)

    def abort(self) -> None:
        self.aborted += 1
        self._abort_flag = True

    def measure(self) -> SpectralReading:
        self.calls += 1
        pending = self.faults.get(self.calls)
        if pending:
            exc = pending.pop(0)
            self.calls -= 1          # the retry is the same reading
            self.clock.sleep(1.0)
            raise exc
        lum = self.world.luminance_cd_m2(self.world.patch, self.world.angle_deg)
        duration = self.estimate_measure_time_s(lum)
        self.clock.sleep(duration / 2)
        hook = self.during.pop(self.calls, None)
        if hook is not None:
            hook()
        if self._abort_flag:
            self._abort_flag = False
            raise DeviceError("ER10", "measurement aborted")
        self.clock.sleep(duration / 2)
        rad = np.full(RADIOMETER_WAVELENGTHS_NM.shape, lum / 683.0 / 100.0)
        return SpectralReading(RADIOMETER_WAVELENGTHS_NM, rad, None, duration,
                               self.clock.wall_time_s(), "FAKE-CS",
                               {"patch_seen": self.world.patch, "angle_seen": self.world.angle_deg})


class FakeOperator:
    expected_response_s = 3.0

    def __init__(self, clock: VirtualClock, world: FakeWorld, fault_answers: list[str] | None = None):
        self.clock, self.world = clock, world
        self.fault_answers = list(fault_answers or [])
        self.asked: list[Any] = []

    def __call__(self, req: Any) -> str:
        self.asked.append(req)
        if req.kind == "fault":
            return self.fault_answers.pop(0) if self.fault_answers else "abort"
        self.clock.sleep(self.expected_response_s)
        if req.data.get("action") == "place_patch":
            self.world.place_patch(req.data["patch"])
        return "ok"


class FakeLab:
    def __init__(self, *, lamp_on: bool = False, fault_answers: list[str] | None = None,
                 clock: VirtualClock | None = None) -> None:
        self.clock = clock or VirtualClock(time_scale=0.0)
        self.world = FakeWorld()
        self.rotator = FakeStage(self.clock, self.world)
        self.sphere = FakeLamp(self.clock)
        if lamp_on:
            self.sphere.set_output(True)
            self.clock.sleep(self.sphere.settle_s)
        self.radiometer = FakeRadiometer(self.clock, self.world)
        self.instruments = {"rotator": self.rotator, "sphere": self.sphere,
                            "radiometer": self.radiometer}
        self.operator = FakeOperator(self.clock, self.world, fault_answers)

    def instrument(self, role: str) -> Any:
        return self.instruments[role]

    def light_sources(self) -> tuple[str, ...]:
        return ("sphere",)

    def luminance_hint_cd_m2(self, step: Any) -> float:
        return self.world.luminance_cd_m2(step.params.get("patch"),
                                          float(step.params.get("angle_deg", 0.0)))

    def provenance(self) -> dict[str, Any]:
        return {"lab_config": "", "seeds": {"lab": 0}}

    def record_identities(self, store: Store, run_id: int, segment: int = 1,
                          roles: Any = None) -> None:
        for role, inst in self.instruments.items():
            if roles is not None and role not in roles:
                continue
            ident = inst.identify()
            store.add_instrument(run_id, role, {"model": ident.model, "segment": segment})


def timeout(msg: str = "no reply") -> InstrumentTimeout:
    return InstrumentTimeout(msg, instrument="radiometer")


class FakeGonio:
    """In-plane gonioreflectometer fake: Lambertian ρ = 0.5 (patch) or 0.34 (wall)."""

    measure_s = 4.0
    calibrate_s = 30.0

    def __init__(self, clock: VirtualClock, world: FakeWorld) -> None:
        self.clock, self.world = clock, world
        self.material: Any = None
        self.calibrated_for: Any = None
        self.calibrations = 0

    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("gonioreflectometer", "FAKE-GONIO", simulated=True)

    def close(self) -> None: ...

    def estimate_calibrate_time_s(self) -> float:
        return self.calibrate_s

    def estimate_measure_time_s(self, theta_i_deg: float, theta_o_deg: float, *,
                                from_geometry_deg: tuple[float, float] | None = None) -> float:
        return self.measure_s

    def calibrate(self) -> dict[str, np.ndarray]:
        self.clock.sleep(self.calibrate_s)
        self.calibrations += 1
        self.calibrated_for = self.material
        return {"dark_counts": np.zeros(5), "white_counts": np.full(5, 1000.0)}

    def measure_brdf(self, theta_i_deg: float, theta_o_deg: float):
        from normbox_lab.core.types import BrdfReading

        self.clock.sleep(self.measure_s)
        wl = np.arange(400.0, 701.0, 100.0)
        rho = 0.34 if self.material == "wall" else 0.5
        return BrdfReading(theta_i_deg, theta_o_deg, 4.0, wl, np.full(wl.shape, rho / np.pi),
                           timestamp_s=self.clock.wall_time_s(), instrument_id="FAKE-GONIO",
                           metadata={"material_seen": self.material,
                                     "calibrated_for": self.calibrated_for})


def add_gonio(lab: FakeLab) -> FakeGonio:
    gonio = FakeGonio(lab.clock, lab.world)
    lab.instruments["gonio"] = gonio
    op = lab.operator
    original = op.__call__

    def operator(req: Any) -> str:
        if req.data.get("action") == "mount_gonio_material":
            gonio.material = req.data["material"]
        return original(req)
    lab.operator = operator
    operator.expected_response_s = op.expected_response_s  # type: ignore[attr-defined]
    operator.asked = op.asked  # type: ignore[attr-defined]
    return gonio


# --- fake *drivers* (Driver.open(url, clock, **options)) over the sim context's world ----------

class _WorldView:
    """FakeWorld's interface on top of the lab's world (AnalyticWorld)."""

    def __init__(self, world: Any) -> None:
        self._w = world

    @property
    def patch(self) -> Any:
        return self._w.patch

    @property
    def angle_deg(self) -> float:
        return self._w.sample_angle_deg

    @angle_deg.setter
    def angle_deg(self, value: float) -> None:
        self._w.set_sample_angle(value)

    def luminance_cd_m2(self, patch: Any, angle_deg: float) -> float:
        return self._w.luminance_cd_m2(patch, angle_deg)


def _world() -> _WorldView:
    from normbox_lab.sim import core

    return _WorldView(core.CONTEXT.world)


# The fakes declare the lab-config options they take as keywords, as real drivers do (the
# registry derives a driver's options from its signature): those the simulated-lab template uses.

class RadiometerDriver(FakeRadiometer):
    @classmethod
    def open(cls, url: str, clock: Any, *, baud: int = 9600, instrument_id: str = "radiometer",
             command_timeout_s: float = 10.0) -> RadiometerDriver:
        return cls(clock, _world())


class StageDriver(FakeStage):
    @classmethod
    def open(cls, url: str, clock: Any, *, instrument_id: str = "rotator",
             min_angle_deg: float = -170.0, max_angle_deg: float = 170.0) -> StageDriver:
        return cls(clock, _world())


class LampDriver(FakeLamp):
    @classmethod
    def open(cls, url: str, clock: Any, *, instrument_id: str = "sphere") -> LampDriver:
        return cls(clock)


def _fake(cls: str, real: str) -> DriverEntry:
    return dataclasses.replace(DRIVERS[real], module="engine_fakes", cls=cls)


#: registry entries with fake classes (``monkeypatch.setattr(registry, "DRIVERS", ...)``)
FAKE_DRIVERS = {
    "cs1000a": _fake("RadiometerDriver", "cs1000a"),
    "apt-k10cr1": _fake("StageDriver", "apt-k10cr1"),
    "zaber": _fake("StageDriver", "zaber"),
    "sphere-scpi": _fake("LampDriver", "sphere-scpi"),
}
