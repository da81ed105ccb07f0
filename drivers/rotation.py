"""What every rotation-stage driver shares: soft limits, the position check, the timing model.

Each concrete driver (Thorlabs APT, Zaber ASCII) talks its own protocol and implements
`_begin_move`, `_begin_home`, `_wait_done`, `_readback_deg` …; this base class adds the rules:

- **soft limits** (`min_angle_deg` … `max_angle_deg`, from the lab config): a target outside
  them is refused before anything is sent (`DeviceError("SOFT_LIMIT", …)`);
- **homing**: a move on a stage without a reference raises `NotReady` (or homes first when
  `auto_home=True`);
- **position check** after every completed move: the readback (encoder where the device has
  one) is kept with the commanded angle (`locate()` → `Location(setpoint, readback)`, stored
  with every reading).  A readback more than `stall_limit_deg` from the setpoint is a failed
  move, `DeviceError("POSITION", …)` (a stall the controller did not notice; the engine moves
  again); within it the stage stopped where it stopped, and a readback beyond
  `position_tolerance_deg` flags the reading (quality gate ``position``) instead of losing it;
- **timing model** (for ETAs): a trapezoidal velocity profile with the stage's maximum
  velocity v and acceleration a, plus a fixed command overhead:

      d ≥ v²/a:  T = d/v + v/a        d < v²/a:  T = 2·√(d/a)
"""

from __future__ import annotations

import math
from typing import Any

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import DeviceError, NotReady
from normbox_lab.core.types import Location

#: homing ends with the switch approach: off the switch by this much and back (the emulators
#: model it as time at the switch; *assumed* 1°)
HOME_BACKOFF_DEG = 1.0

def trapezoid_time_s(distance_deg: float, max_velocity_deg_s: float,
                     acceleration_deg_s2: float) -> float:
    d = abs(float(distance_deg))
    v, a = float(max_velocity_deg_s), float(acceleration_deg_s2)
    if d == 0.0:
        return 0.0
    if d >= v * v / a:
        return d / v + v / a
    return 2.0 * math.sqrt(d / a)


class RotationStageBase:
    """Shared logic.  Subclasses set `model` and implement the protocol hooks."""

    model = "rotation stage"
    #: command round trips around a move (request + status check), seconds, for ETAs
    move_overhead_s = 0.0

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "rotator",
                 min_angle_deg: float = -170.0, max_angle_deg: float = 170.0,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 10.0,
                 home_velocity_deg_s: float = 5.0, position_tolerance_deg: float = 0.05,
                 stall_limit_deg: float = 1.0, auto_home: bool = False) -> None:
        if not min_angle_deg < max_angle_deg:
            raise ValueError(f"min_angle_deg {min_angle_deg} must be below max_angle_deg "
                             f"{max_angle_deg}")
        self.port = port
        self.clock = clock
        self.instrument_id = instrument_id
        self.min_angle_deg = float(min_angle_deg)
        self.max_angle_deg = float(max_angle_deg)
        self.max_velocity_deg_s = float(max_velocity_deg_s)
        self.acceleration_deg_s2 = float(acceleration_deg_s2)
        self.home_velocity_deg_s = float(home_velocity_deg_s)
        self.position_tolerance_deg = float(position_tolerance_deg)
        self.stall_limit_deg = max(float(stall_limit_deg), self.position_tolerance_deg)
        self.auto_home = bool(auto_home)
        self._commanded_deg: float | None = None
        self._readback_at_stop_deg: float | None = None
        self._move_start_deg = 0.0

    # --- timing model -------------------------------------------------------------------------
    def estimate_move_time_s(self, from_deg: float, to_deg: float) -> float:
        t = trapezoid_time_s(to_deg - from_deg, self.max_velocity_deg_s,
                             self.acceleration_deg_s2)
        return t + self.move_overhead_s if t > 0 else 0.0

    def estimate_home_time_s(self) -> float:
        """Worst case: from the farthest soft limit to the home switch at 0°, then the switch
        approach (off the switch by `HOME_BACKOFF_DEG` and back at the homing speed)."""
        far = max(abs(self.min_angle_deg), abs(self.max_angle_deg))
        approach = 2.0 * trapezoid_time_s(HOME_BACKOFF_DEG, self.home_velocity_deg_s,
                                          self.acceleration_deg_s2)
        return trapezoid_time_s(far, self.home_velocity_deg_s, self.acceleration_deg_s2) \
            + approach + self.move_overhead_s

    def _timeout_for(self, duration_s: float) -> float:
        return 1.5 * duration_s + 3.0

    # --- rules --------------------------------------------------------------------------------
    def check_target(self, angle_deg: float) -> None:
        if not (self.min_angle_deg <= angle_deg <= self.max_angle_deg):
            raise DeviceError("SOFT_LIMIT", f"{angle_deg:.3f}° is outside the soft limits "
                              f"{self.min_angle_deg:g}…{self.max_angle_deg:g}°",
                              instrument=self.instrument_id)

    def check_position(self, commanded_deg: float, readback_deg: float) -> None:
        """Keep the readback; a readback beyond `stall_limit_deg` is a failed move."""
        self._readback_at_stop_deg = float(readback_deg)
        if abs(readback_deg - commanded_deg) > self.stall_limit_deg:
            raise DeviceError("POSITION", f"readback {readback_deg:.4f}° differs from the "
                              f"commanded {commanded_deg:.4f}° by more than "
                              f"{self.stall_limit_deg:g}° (stall or lost steps?)",
                              instrument=self.instrument_id)

    def locate(self) -> Location:
        """Setpoint (the last commanded angle) and readback (where the stage reported itself
        when that move ended; read now when no move has ended yet), in degrees, with the
        stated `position_tolerance_deg`."""
        readback = self._readback_at_stop_deg
        if readback is None:
            readback = float(self._readback_deg())
        return Location(self._commanded_deg, readback, "deg", self.position_tolerance_deg)

    def _require_homed(self) -> None:
        if self.is_homed():
            return
        if self.auto_home:
            self.home(wait=True)
            return
        raise NotReady("stage has no reference (power-up or power blip): home it first",
                       instrument=self.instrument_id)

    # --- the RotationStage role ----------------------------------------------------------------
    def move_to(self, angle_deg: float, wait: bool = True) -> None:
        angle_deg = float(angle_deg)
        self.check_target(angle_deg)
        self._require_homed()
        start = self.position_deg()
        self._move_start_deg = start
        self._commanded_deg = None          # a refused move leaves nothing to check
        self._readback_at_stop_deg = None
        self._begin_move(angle_deg)
        self._commanded_deg = angle_deg
        self._move_started_s = self.clock.now_s()
        self._move_timeout_s = self._timeout_for(self.estimate_move_time_s(start, angle_deg))
        if wait:
            self.wait_idle(self._move_timeout_s)

    def move_by(self, delta_deg: float, wait: bool = True) -> None:
        base = self._commanded_deg if self._commanded_deg is not None else self.position_deg()
        self.move_to(base + float(delta_deg), wait=wait)

    def home(self, wait: bool = True) -> None:
        self._commanded_deg = 0.0
        self._readback_at_stop_deg = None
        self._begin_home()
        self._move_timeout_s = self._timeout_for(self.estimate_home_time_s())
        if wait:
            self.wait_idle(self._move_timeout_s)

    def wait_idle(self, timeout_s: float) -> None:
        """Wait for the running move / homing to end, then check where the stage is."""
        self._wait_done(float(timeout_s))
        if self._commanded_deg is not None:
            self.check_position(self._commanded_deg, self._readback_deg())

    # --- hooks ----------------------------------------------------------------------------------
    def _begin_move(self, angle_deg: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _begin_home(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _wait_done(self, timeout_s: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _readback_deg(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def is_homed(self) -> bool:  # pragma: no cover - abstract
        raise NotImplementedError

    def position_deg(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError
