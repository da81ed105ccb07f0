"""The mechanics both rotator emulators share: a rotary axis moving along trapezoids.

A stepper controller accelerates at `acceleration_deg_s2` up to `max_velocity_deg_s`, cruises,
and decelerates to stop exactly at the target.  For a distance d:

    d ≥ v²/a  (reaches full speed):  T = d/v + v/a
    d <  v²/a  (triangle):            T = 2·√(d/a)

`Axis` keeps three angles apart, as real hardware does:

- the **physical** angle of the rotor (what the world sees, `angle_deg(now)`);
- the controller's **counter** (microsteps it has issued, what ``get pos`` / the APT position
  field reports); physical = counter + offset;
- the **encoder** (counts physical motion since the last homing or power-up).

At power-up the counter and the encoder read 0 wherever the rotor is, and `homed` is false.
Homing drives the rotor to the home switch (physical 0°) and zeroes counter and encoder; the
reference is lost (`homed` false) from the moment homing starts until it completes, and a
homing that is stopped leaves it lost.  Every homing ends with the switch approach (the rotor
backs off the switch by `home_backoff_deg` and comes back at the homing speed), so homing from
0° takes time too (modelled as time at the switch, *assumed* 1°).
Stopping: a *profiled* stop decelerates at the axis's acceleration from the speed it has (the
rotor runs on v²/2a), an *immediate* stop halts the rotor where it is.
A stall freezes the rotor part way; an open-loop controller (APT stepper) keeps counting to the
target (`stall_stops_controller=False`), a closed-loop one (Zaber) stops counting too.  Hardware
limit switches at `limit_min_deg` / `limit_max_deg` stop any motion that reaches them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from normbox_lab.sim.core import FaultKind


@dataclass(frozen=True)
class Trapezoid:
    max_velocity_deg_s: float
    acceleration_deg_s2: float

    def duration_s(self, distance_deg: float) -> float:
        d = abs(float(distance_deg))
        v, a = self.max_velocity_deg_s, self.acceleration_deg_s2
        if d == 0.0:
            return 0.0
        if d >= v * v / a:
            return d / v + v / a
        return 2.0 * math.sqrt(d / a)

    def travelled_deg(self, t_s: float, distance_deg: float) -> float:
        """Distance covered `t_s` after the start of a move of `distance_deg` (≥ 0)."""
        d = abs(float(distance_deg))
        v, a = self.max_velocity_deg_s, self.acceleration_deg_s2
        total = self.duration_s(d)
        if t_s <= 0.0:
            return 0.0
        if t_s >= total:
            return d
        t_acc = v / a if d >= v * v / a else math.sqrt(d / a)
        v_peak = a * t_acc
        if t_s <= t_acc:
            return 0.5 * a * t_s * t_s
        t_dec_start = total - t_acc
        d_acc = 0.5 * a * t_acc * t_acc
        if t_s <= t_dec_start:
            return d_acc + v_peak * (t_s - t_acc)
        left = total - t_s
        return d - 0.5 * a * left * left

    def velocity_deg_s(self, t_s: float, distance_deg: float) -> float:
        d = abs(float(distance_deg))
        total = self.duration_s(d)
        if t_s <= 0.0 or t_s >= total:
            return 0.0
        v, a = self.max_velocity_deg_s, self.acceleration_deg_s2
        return min(a * t_s, a * (total - t_s), v)


@dataclass
class Motion:
    kind: str                 # "move" or "home"
    t0_s: float
    start_counter_deg: float
    target_counter_deg: float
    trapezoid: Trapezoid
    end_s: float              # when the motion ends (reached, limit, stall)
    reason: str               # "done", "limit-max", "limit-min", "stall"
    stall_s: float | None = None   # physical rotor stops here (stall)
    stall_stops_controller: bool = True
    #: a profiled stop: the rotor decelerates from this speed at the trapezoid's acceleration
    v0_deg_s: float = 0.0
    #: time spent at the target after arriving (homing's switch approach)
    dwell_s: float = 0.0

    @property
    def distance_deg(self) -> float:
        return abs(self.target_counter_deg - self.start_counter_deg)

    @property
    def sign(self) -> float:
        return 1.0 if self.target_counter_deg >= self.start_counter_deg else -1.0

    def commanded_deg(self, now_s: float) -> float:
        t = min(now_s, self.end_s) - self.t0_s
        if self.v0_deg_s > 0:
            a = self.trapezoid.acceleration_deg_s2
            t = max(0.0, min(t, self.v0_deg_s / a))
            return self.start_counter_deg + self.sign * (self.v0_deg_s * t - 0.5 * a * t * t)
        return self.start_counter_deg + self.sign * self.trapezoid.travelled_deg(
            t, self.distance_deg)

    def speed_deg_s(self, now_s: float) -> float:
        t = now_s - self.t0_s
        if self.v0_deg_s > 0:
            return max(0.0, self.v0_deg_s - self.trapezoid.acceleration_deg_s2 * max(t, 0.0))
        return self.trapezoid.velocity_deg_s(t, self.distance_deg)


@dataclass
class MotionEnd:
    kind: str
    reason: str               # "done", "stopped", "limit-max", "limit-min", "stall"
    time_s: float


class Axis:
    def __init__(self, trapezoid: Trapezoid, *, home_trapezoid: Trapezoid | None = None,
                 limit_min_deg: float = -170.0, limit_max_deg: float = 170.0,
                 power_up_angle_deg: float = 0.0, stall_stops_controller: bool = True,
                 home_backoff_deg: float = 1.0) -> None:
        self.trapezoid = trapezoid
        self.home_trapezoid = home_trapezoid or trapezoid
        self.limit_min_deg = float(limit_min_deg)
        self.limit_max_deg = float(limit_max_deg)
        self.stall_stops_controller = stall_stops_controller
        self.home_backoff_deg = float(home_backoff_deg)
        self._physical_deg = float(power_up_angle_deg)   # at rest / at the last settle
        self.offset_deg = 0.0          # physical − counter
        self.encoder_zero_deg = 0.0    # physical angle where the encoder reads 0
        self.homed = False
        self.motion: Motion | None = None
        self.at_limit = ""             # "max", "min" or ""
        self.power_up()

    # --- power ---------------------------------------------------------------------------
    def power_up(self) -> None:
        """Counter and encoder read 0 wherever the rotor is; the reference is lost."""
        self.motion = None
        self.offset_deg = self._physical_deg
        self.encoder_zero_deg = self._physical_deg
        self.homed = False

    # --- readings ------------------------------------------------------------------------
    def physical_deg(self, now_s: float) -> float:
        m = self.motion
        if m is None:
            return self._physical_deg
        t = now_s if m.stall_s is None else min(now_s, m.stall_s)
        return m.commanded_deg(t) + self.offset_deg

    def counter_deg(self, now_s: float) -> float:
        m = self.motion
        if m is None:
            return self._physical_deg - self.offset_deg
        if m.stall_s is not None and m.stall_stops_controller:
            return m.commanded_deg(min(now_s, m.stall_s))
        return m.commanded_deg(now_s)

    def encoder_deg(self, now_s: float) -> float:
        return self.physical_deg(now_s) - self.encoder_zero_deg

    def velocity_deg_s(self, now_s: float) -> float:
        m = self.motion
        if m is None or (m.stall_s is not None and now_s >= m.stall_s):
            return 0.0
        return m.sign * m.speed_deg_s(now_s)

    @property
    def moving(self) -> bool:
        return self.motion is not None

    def next_event_s(self) -> float | None:
        return None if self.motion is None else self.motion.end_s

    # --- commands ------------------------------------------------------------------------
    def start_move(self, target_counter_deg: float, now_s: float, *,
                   stall_fraction: float | None = None, slip_deg: float | None = None) -> None:
        """`slip_deg`: the rotor loses this much of the move (steps lost: the counter still
        reaches the target, the rotor stops short of it by `slip_deg`)."""
        self._start("move", target_counter_deg, self.trapezoid, now_s, stall_fraction)
        if slip_deg and self.motion is not None:
            sign = 1.0 if target_counter_deg >= self.motion.start_counter_deg else -1.0
            self.offset_deg -= sign * float(slip_deg)

    def start_home(self, now_s: float) -> None:
        # drive the rotor to the home switch: physical 0° ⇔ counter −offset
        if self.motion is not None:
            self._settle(now_s)
        self.homed = False                 # the reference is being found again
        self._start("home", -self.offset_deg, self.home_trapezoid, now_s, None)
        m = self.motion
        assert m is not None
        if m.reason == "done":
            m.dwell_s = 2.0 * self.home_trapezoid.duration_s(self.home_backoff_deg)
            m.end_s += m.dwell_s

    def _start(self, kind: str, target_counter_deg: float, trap: Trapezoid, now_s: float,
               stall_fraction: float | None) -> None:
        if self.motion is not None:
            self._settle(now_s)           # a new command supersedes the running one
        start = self._physical_deg - self.offset_deg
        distance = abs(target_counter_deg - start)
        duration = trap.duration_s(distance)
        end_s, reason = now_s + duration, "done"
        sign = 1.0 if target_counter_deg >= start else -1.0
        # a hardware limit switch on the way stops the rotor there
        target_phys = target_counter_deg + self.offset_deg
        for limit, name in ((self.limit_max_deg, "limit-max"), (self.limit_min_deg, "limit-min")):
            crosses = (sign > 0 and name == "limit-max" and target_phys > limit) or \
                      (sign < 0 and name == "limit-min" and target_phys < limit)
            if crosses:
                need = abs(limit - self._physical_deg)
                end_s, reason = now_s + self._time_to(trap, distance, need), name
        m = Motion(kind, now_s, start, target_counter_deg, trap, end_s, reason,
                   stall_stops_controller=self.stall_stops_controller)
        if stall_fraction is not None and duration > 0:
            m.stall_s = now_s + stall_fraction * (end_s - now_s)
            m.reason = "stall"
            if self.stall_stops_controller:
                m.end_s = m.stall_s
        self.motion = m
        self.at_limit = ""

    @staticmethod
    def _time_to(trap: Trapezoid, distance: float, part: float) -> float:
        lo, hi = 0.0, trap.duration_s(distance)
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if trap.travelled_deg(mid, distance) < part:
                lo = mid
            else:
                hi = mid
        return hi

    def stop(self, now_s: float, *, profiled: bool = False) -> MotionEnd | None:
        """Immediate stop: the rotor stays where it is now; returns how the motion ended.
        Profiled stop: the rotor decelerates from its speed now; returns None, and the motion
        ends ("stopped") when it is at rest (`poll`)."""
        m = self.motion
        if m is None:
            return None
        kind = m.kind
        speed = abs(self.velocity_deg_s(now_s))
        sign = m.sign
        self._settle(now_s)
        if not profiled or speed <= 1e-9:
            return MotionEnd(kind, "stopped", now_s)
        trap = m.trapezoid
        start = self._physical_deg - self.offset_deg
        d = speed * speed / (2.0 * trap.acceleration_deg_s2)
        self.motion = Motion(kind, now_s, start, start + sign * d, trap,
                             now_s + speed / trap.acceleration_deg_s2, "stopped",
                             stall_stops_controller=self.stall_stops_controller, v0_deg_s=speed)
        return None

    def _settle(self, now_s: float) -> None:
        m = self.motion
        assert m is not None
        phys = self.physical_deg(now_s)
        counter = self.counter_deg(now_s)
        self.motion = None
        self._physical_deg = phys
        self.offset_deg = phys - counter

    def poll(self, now_s: float) -> MotionEnd | None:
        """Finish the motion when its end time has come; returns how it ended (once)."""
        m = self.motion
        if m is None or now_s < m.end_s:
            return None
        phys = self.physical_deg(m.end_s)
        counter = self.counter_deg(m.end_s)
        self.motion = None
        self._physical_deg = phys
        self.offset_deg = phys - counter
        if m.reason in ("limit-max", "limit-min"):
            self.at_limit = m.reason[6:]
        if m.reason == "stopped":
            return MotionEnd(m.kind, "stopped", m.end_s)
        if m.kind == "home" and m.reason == "done":
            self.offset_deg = self._physical_deg   # counter := 0 at the home switch
            self.encoder_zero_deg = self._physical_deg
            self.homed = True
        return MotionEnd(m.kind, m.reason, m.end_s)


#: the faults both rotator emulators inject besides the transport faults
ROTATOR_FAULT_KINDS: tuple[FaultKind, ...] = (
    FaultKind("stall", "@", (1, 12), (0.0, 1.0), "linear", unit="of the move",
              means="the n-th move stalls after this fraction of it (the controller sees it)",
              detector="controller stall / position error → typed DeviceError → prompt"),
    FaultKind("slip", "@", (1, 12), (0.01, 5.0), "log", unit="°",
              means="the n-th move loses steps: the rotor stops this far short of the "
                    "commanded angle (the controller's step counter reaches it)",
              detector="the readback (encoder) against the setpoint: beyond 1° DeviceError "
                       "POSITION, beyond 0.05° the position gate (error); a stage without an "
                       "independent encoder could not see it (docs/fault-behaviour.md)"),
    FaultKind("power-blip", "=", (1e-3, 1.0), (0.05, 60.0), "log", unit="s",
              means="the supply dips: controller reset, link down this long",
              detector="reconnect, re-home; typed InstrumentError beyond the window"),
)


class PowerCycled:
    """The ``power-blip`` fault both rotator emulators share: the supply dips, the controller
    resets (reference lost, parameters back to their power-up values) and the link drops for
    the fault's parameter in seconds (default `blip_s`).  A pulled cable (a plain disconnect)
    keeps the controller's state.  Subclasses (`core.Emulator`s) implement `restart()`."""

    blip_s = 1.0
    _powered_down = False

    def power_blip(self, duration_s: float | None = None) -> None:
        self._powered_down = True
        self.disconnect(duration_s if duration_s is not None   # type: ignore[attr-defined]
                        else self.faults.parameter("power-blip",  # type: ignore[attr-defined]
                                                   self.blip_s))

    def on_disconnect(self) -> None:
        self._inbuf.clear()                                      # type: ignore[attr-defined]
        if not self._powered_down:
            return
        self._powered_down = False
        self.restart()

    def restart(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

