"""Zaber rotary stage (X-RSW60A-like) speaking the Zaber ASCII protocol, emulated at the wire.

Written from the *Zaber ASCII Protocol Manual* ([ZABER] in docs/references.md).

Line: commands ``/<device> <axis> <command…>`` end in LF or CR; replies
``@<dd> <axis> <OK|RJ> <IDLE|BUSY> <flag> <data>`` end in CR LF.  Device 1, one axis.
Device number 0 addresses all devices; a missing axis means 0 (the whole device).
Message ids and checksums are not supported (*simplification*).

Commands:
    (empty)                      status
    home                         BUSY; drives to the home switch (physical 0°), clears WR
    move abs N / move rel N      BUSY; N in microsteps; outside limit.min…limit.max → RJ BADDATA;
                                 before homing → RJ … WR BADDATA (*assumed* rejection)
    stop                         stops at once (deceleration not modelled); NI flag when it
                                 interrupted a motion
    get pos | encoder.pos | maxspeed | accel | limit.min | limit.max   (axis scope)
    get deviceid | system.serial | version                             (device scope)
    set maxspeed N | accel N | limit.min N | limit.max N
    warnings [clear]             ``OK IDLE <flag> <count> <flags…>`` (count two digits);
                                 clear drops everything but WR (a condition)
    anything else                RJ BADCOMMAND; axis other than 0/1 → RJ BADAXIS
Flag in every reply: the highest-priority warning, faults (F…) before warnings (W…) before
notices (N…), ``--`` when none.

Mechanics (`sim.motion.Axis`): 0.000234375 °/µstep (4266.67 µsteps/°); maxspeed native =
µsteps/s × 1.6384, accel native = µsteps/s² × 1.6384/10000; default 10 °/s, 20 °/s²; homing at
maxspeed.  Firmware travel range ±180°, hardware limit switches (the holder's cable stop) at
±170°: a move beyond them trips the switch → WL.  A stall stops the axis (closed loop): FS.
Power-up: not homed (WR), position 0 wherever the rotor is.

Device faults: ``stall`` (next move stalls at the fraction given, default 0.5),
``power-blip`` (the next command resets the device: link down 1 s, reference lost).
"""

from __future__ import annotations

from typing import Any

from normbox_lab.sim import core
from normbox_lab.sim.motion import Axis, Trapezoid

STEPS_PER_DEG = 1.0 / 0.000234375
SPEED_NATIVE = 1.6384
ACCEL_NATIVE = 1.6384 / 10000.0
PRIORITY = {"F": 0, "W": 1, "N": 2}


class ZaberRotatorEmulator(core.LineEmulator):
    device_name = "rotator-zaber"
    device_faults = ("stall", "power-blip")
    terminators = (b"\n", b"\r")

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 serial_number: int = 33456, power_up_angle_deg: float = 0.0,
                 limit_min_deg: float = -170.0, limit_max_deg: float = 170.0,
                 travel_min_deg: float = -180.0, travel_max_deg: float = 180.0,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 20.0) -> None:
        super().__init__(clock, faults, seed)
        self.serial_number = int(serial_number)
        self.maxspeed = round(max_velocity_deg_s * STEPS_PER_DEG * SPEED_NATIVE)
        self.accel = round(acceleration_deg_s2 * STEPS_PER_DEG * ACCEL_NATIVE)
        self.limit_min = round(travel_min_deg * STEPS_PER_DEG)
        self.limit_max = round(travel_max_deg * STEPS_PER_DEG)
        self.axis = Axis(self._trapezoid(), limit_min_deg=limit_min_deg,
                         limit_max_deg=limit_max_deg, power_up_angle_deg=power_up_angle_deg,
                         stall_stops_controller=True)
        self.flags: set[str] = set()
        self.blip_s = 1.0

    def _trapezoid(self) -> Trapezoid:
        return Trapezoid(self.maxspeed / SPEED_NATIVE / STEPS_PER_DEG,
                         self.accel / ACCEL_NATIVE / STEPS_PER_DEG)

    def angle_deg(self) -> float:
        """The physical angle of the rotor now (read by the virtual world / gonio)."""
        return self.axis.physical_deg(self.clock.now_s())

    # --- state -----------------------------------------------------------------------------
    def _all_flags(self) -> list[str]:
        flags = set(self.flags)
        if not self.axis.homed:
            flags.add("WR")
        return sorted(flags, key=lambda f: (PRIORITY.get(f[0], 3), f))

    def _flag(self) -> str:
        flags = self._all_flags()
        return flags[0] if flags else "--"

    def _busy(self) -> bool:
        return self.axis.moving

    def on_time(self, now_s: float) -> None:
        end = self.axis.poll(now_s)
        if end is None:
            return
        if end.reason == "stall":
            self.flags.add("FS")
        elif end.reason in ("limit-max", "limit-min"):
            self.flags.add("WL")

    def next_state_s(self) -> float | None:
        return self.axis.next_event_s()

    def power_blip(self, duration_s: float | None = None) -> None:
        """The supply dips: the controller resets (reference lost) and the link drops."""
        self._powered_down = True
        self.disconnect(duration_s if duration_s is not None
                        else self.faults.parameter("power-blip", self.blip_s))

    def on_disconnect(self) -> None:
        """A pulled cable keeps the controller's state; a power blip resets it."""
        self._inbuf.clear()
        if not getattr(self, "_powered_down", False):
            return
        self._powered_down = False
        self.axis.stop(self.clock.now_s())
        self.axis.power_up()
        self.flags.clear()

    # --- replies ---------------------------------------------------------------------------
    def _reply(self, axis: int, ok: bool, data: str | int = 0) -> None:
        status = "BUSY" if self._busy() else "IDLE"
        line = f"@01 {axis} {'OK' if ok else 'RJ'} {status} {self._flag()} {data}\r\n"
        self.emit(line.encode("ascii"))

    def on_line(self, line: bytes, terminator: bytes) -> None:
        text = line.decode("ascii", "replace").strip()
        if not text.startswith("/"):
            return                                   # not a command: ignored
        parts = text[1:].split()
        device = 0
        if parts and parts[0].isdigit():
            device = int(parts.pop(0))
        if device not in (0, 1):
            return                                   # another device's command
        axis = 0
        if parts and parts[0].isdigit():
            axis = int(parts.pop(0))
        if self.faults.fires("power-blip"):
            self.power_blip()
            return
        self.poll()
        if axis not in (0, 1):
            self._reply(axis, False, "BADAXIS")
            return
        self._command(axis, parts)

    def _command(self, axis: int, parts: list[str]) -> None:
        now = self.clock.now_s()
        words = [p.lower() for p in parts]
        if not words:
            self._reply(axis, True)
        elif words == ["home"]:
            self.flags.discard("FS")
            self.flags.discard("WL")
            self.axis.start_home(now)
            self._reply(axis, True)
        elif words[0] == "move" and len(words) == 3 and words[1] in ("abs", "rel"):
            try:
                n = int(words[2])
            except ValueError:
                self._reply(axis, False, "BADDATA")
                return
            counter = round(self.axis.counter_deg(now) * STEPS_PER_DEG)
            target = n if words[1] == "abs" else counter + n
            if not self.axis.homed or not self.limit_min <= target <= self.limit_max:
                self._reply(axis, False, "BADDATA")
                return
            if self.axis.moving:
                self.flags.add("NI")
            stall = self.faults.parameter("stall", 0.5) if self.faults.fires("stall") else None
            self.axis.start_move(target / STEPS_PER_DEG, now, stall_fraction=stall)
            self._reply(axis, True)
        elif words == ["stop"]:
            if self.axis.stop(now) is not None:
                self.flags.add("NI")
            self._reply(axis, True)
        elif words[0] == "warnings" and words[1:] in ([], ["clear"]):
            flags = self._all_flags()
            self._reply(axis, True, " ".join([f"{len(flags):02d}", *flags]))
            if words[1:] == ["clear"]:
                self.flags.clear()
        elif words[0] == "get" and len(words) == 2:
            value = self._get(axis, words[1], now)
            if value is None:
                self._reply(axis, False, "BADCOMMAND")
            else:
                self._reply(axis, True, value)
        elif words[0] == "set" and len(words) == 3:
            self._set(axis, words[1], words[2])
        else:
            self._reply(axis, False, "BADCOMMAND")

    def _get(self, axis: int, name: str, now: float) -> str | int | None:
        device_scope = {"deviceid": 30342, "system.serial": self.serial_number,
                        "version": "7.38"}
        axis_scope = {
            "pos": lambda: round(self.axis.counter_deg(now) * STEPS_PER_DEG),
            "encoder.pos": lambda: round(self.axis.encoder_deg(now) * STEPS_PER_DEG),
            "maxspeed": lambda: self.maxspeed,
            "accel": lambda: self.accel,
            "limit.min": lambda: self.limit_min,
            "limit.max": lambda: self.limit_max,
        }
        if name in device_scope:
            return device_scope[name]
        if name in axis_scope:
            return axis_scope[name]()
        return None

    def _set(self, axis: int, name: str, value: str) -> None:
        try:
            n = int(value)
        except ValueError:
            self._reply(axis, False, "BADDATA")
            return
        if name in ("maxspeed", "accel") and n > 0:
            setattr(self, name, n)
            self.axis.trapezoid = self.axis.home_trapezoid = self._trapezoid()
        elif name == "limit.min":
            self.limit_min = n
        elif name == "limit.max":
            self.limit_max = n
        else:
            self._reply(axis, False, "BADDATA" if name in ("maxspeed", "accel") else "BADCOMMAND")
            return
        self._reply(axis, True)


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> ZaberRotatorEmulator:
    kw = {k: float(v) for k, v in options.items()
          if k in ("power_up_angle_deg", "limit_min_deg", "limit_max_deg", "travel_min_deg",
                   "travel_max_deg", "max_velocity_deg_s", "acceleration_deg_s2")}
    return ZaberRotatorEmulator(clock, faults, seed, **kw)


core.register("rotator-zaber", _factory)
