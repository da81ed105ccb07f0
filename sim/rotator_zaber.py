"""Zaber rotary stage (X-RSW60A-like) speaking the Zaber ASCII protocol, emulated at the wire.

Written from the *Zaber ASCII Protocol Manual* ([ZABER] in docs/references.md): message format,
reply/alert/info message types, message ids, checksums, reply and warning flags, commands, settings.

Line: ``/[device] [axis] [id] command [args][:CC]`` ending in LF, CR or CR LF.  Device 0 (or a
missing number) addresses every device; a missing axis means 0 (the whole device).  A third
leading number is the **message id** (0–99), echoed in the reply; ``:CC`` is an optional
LRC checksum (two hex digits: the byte sum of everything between ``/`` and ``:`` plus CC is 0
mod 256).  A command with a wrong checksum is dropped without a reply (*assumed*: the device
cannot trust any of its fields, the address included).

Replies ``@dd a [id ]OK|RJ IDLE|BUSY FLAG data[:CC]`` end in CR LF; ``:CC`` is appended when
``comm.checksum`` is 1.  With ``comm.alert`` 1 the device sends ``!dd a IDLE FLAG`` when a
motion ends.  Device 1, one axis (``system.axiscount`` 1), peripheral id 0 (integrated).

Commands (reply data in brackets; BUSY while the axis moves):
    (empty)                          status [0]
    home                             drives to the home switch (physical 0°), clears WR
    move abs|rel N                   N in microsteps; beyond limit.min…limit.max → RJ BADDATA;
                                     before homing → RJ … WR BADDATA (absolute moves need a
                                     reference; *assumed* rejection)
    move max | move min              to limit.max / limit.min (needs a reference)
    move vel V                       constant velocity V (native speed units, signed, |V| ≤
                                     maxspeed) until stop / a limit; allowed before homing
    stop                             decelerates at accel (BUSY until at rest); NI when it
                                     interrupted a motion
    estop                            stops at once; NI when it interrupted a motion
    identify                         OK (the device flashes its LEDs)
    warnings [clear]                 [count two digits, flags…]; clear drops all but WR
    get SETTING | set SETTING V      see SETTINGS below; unknown setting → RJ BADCOMMAND,
                                     read-only or bad value → RJ BADDATA
    tools echo TEXT                  [TEXT]
    system reset                     OK, then the device restarts (reference lost)
    anything else                    RJ BADCOMMAND; axis other than 0/1 → RJ BADAXIS;
                                     an id that is not 0–99 → RJ BADMESSAGEID
Flag in every reply: the highest-priority warning, faults (F…) before warnings (W…) before
notices (N…), ``--`` when none.  An axis-scope ``get`` at axis 0 answers the single axis'
value, as for a one-axis device.

Settings answered besides the motion ones: ``comm.packet.size.max`` 80, ``system.current``
0.32 A, ``driver.current.run`` 25 and ``driver.current.hold`` 10 (the manual's current units,
*assumed* values), ``knob.enable`` (0/1, settable) — what zaber-motion asks when it opens a
device.

Mechanics (`sim.motion.Axis`): 0.000234375 °/µstep (resolution 64 µsteps per step); maxspeed
native = µsteps/s × 1.6384, accel native = µsteps/s² × 1.6384/10000; default 10 °/s,
20 °/s²; homing at maxspeed, then the switch approach.  Hardware limit switches (the holder's
cable stop) at ±170°, and the firmware travel range ``limit.min`` / ``limit.max`` ends there
(``move min`` / ``move max`` reach them); a ``set limit.max`` beyond a switch lets a move trip
it → WL.  A stall stops the axis (closed
loop): FS.  Power-up: not homed (WR), position 0 wherever the rotor is.

Device faults: ``stall`` (next move stalls at the fraction given, default 0.5),
``power-blip`` (the next command resets the device: link down 1 s, reference lost).
"""

from __future__ import annotations

from typing import Any

from normbox_lab.sim import core
from normbox_lab.sim.motion import ROTATOR_FAULT_KINDS, Axis, PowerCycled, Trapezoid

STEPS_PER_DEG = 1.0 / 0.000234375
SPEED_NATIVE = 1.6384
ACCEL_NATIVE = 1.6384 / 10000.0
PRIORITY = {"F": 0, "W": 1, "N": 2}
DEVICE_ID = 30342
PERIPHERAL_ID = 0
RESOLUTION = 64
VERSION = "7.38"
VERSION_BUILD = 17220
#: the endless motion of ``move vel`` runs to this counter distance (the limit stops it first)
VELOCITY_RUN_DEG = 1.0e6


def lrc(text: str) -> str:
    """Zaber's message checksum: two hex digits that bring the byte sum to 0 mod 256."""
    return f"{(-sum(text.encode('ascii'))) & 0xFF:02X}"


class ZaberRotatorEmulator(PowerCycled, core.LineEmulator):
    device_name = "rotator-zaber"
    fault_kinds = ROTATOR_FAULT_KINDS
    device_faults = tuple(k.kind for k in ROTATOR_FAULT_KINDS)
    terminators = (b"\n", b"\r")

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 serial_number: int = 33456, power_up_angle_deg: float = 0.0,
                 limit_min_deg: float = -170.0, limit_max_deg: float = 170.0,
                 travel_min_deg: float | None = None, travel_max_deg: float | None = None,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 20.0) -> None:
        super().__init__(clock, faults, seed)
        self.serial_number = int(serial_number)
        self.maxspeed = round(max_velocity_deg_s * STEPS_PER_DEG * SPEED_NATIVE)
        self.accel = round(acceleration_deg_s2 * STEPS_PER_DEG * ACCEL_NATIVE)
        # the firmware's travel range (limit.min / limit.max) ends where the limit switches
        # are, unless given otherwise: move min / move max reach the switches' positions
        travel_min_deg = limit_min_deg if travel_min_deg is None else travel_min_deg
        travel_max_deg = limit_max_deg if travel_max_deg is None else travel_max_deg
        self.travel_min = self.limit_min = round(travel_min_deg * STEPS_PER_DEG)
        self.travel_max = self.limit_max = round(travel_max_deg * STEPS_PER_DEG)
        self.axis = Axis(self._trapezoid(), limit_min_deg=limit_min_deg,
                         limit_max_deg=limit_max_deg, power_up_angle_deg=power_up_angle_deg,
                         stall_stops_controller=True)
        self.flags: set[str] = set()
        self.comm_alert = 0
        self.comm_checksum = 0
        self.knob_enable = 1

    def _trapezoid(self, speed_native: int | None = None) -> Trapezoid:
        speed = self.maxspeed if speed_native is None else abs(speed_native)
        return Trapezoid(speed / SPEED_NATIVE / STEPS_PER_DEG,
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
        # a constant-velocity run keeps its own speed; later moves use maxspeed again
        self.axis.trapezoid = self._trapezoid()
        if end.reason == "stall":
            self.flags.add("FS")
        elif end.reason in ("limit-max", "limit-min"):
            self.flags.add("WL")
        if self.comm_alert:
            self._send(f"!01 1 IDLE {self._flag()}", reply=False,
                       delay_s=end.time_s - now_s)

    def next_state_s(self) -> float | None:
        return self.axis.next_event_s()

    def restart(self) -> None:
        """After a power blip (`PowerCycled`) or ``system reset``."""
        self.axis.stop(self.clock.now_s())
        self.axis.power_up()
        self.axis.trapezoid = self._trapezoid()
        self.flags.clear()
        self.comm_alert = 0

    # --- replies ---------------------------------------------------------------------------
    def _send(self, text: str, *, reply: bool = True, delay_s: float = 0.0) -> None:
        if self.comm_checksum:
            text += ":" + lrc(text[1:])
        self.emit((text + "\r\n").encode("ascii"), max(0.0, delay_s), reply=reply)

    def _reply(self, axis: int, ok: bool, data: str | int = 0) -> None:
        status = "BUSY" if self._busy() else "IDLE"
        msg_id = "" if self._msg_id is None else f"{self._msg_id} "
        self._send(f"@01 {axis} {msg_id}{'OK' if ok else 'RJ'} {status} {self._flag()} {data}")

    def on_line(self, line: bytes, terminator: bytes) -> None:
        text = line.decode("ascii", "replace").strip()
        if not text.startswith("/"):
            return                                   # not a command: ignored
        body = text[1:]
        if len(body) >= 3 and body[-3] == ":":
            given = body[-2:].upper()
            body = body[:-3]
            if lrc(body) != given:
                return                               # corrupted in transit: dropped
        parts = body.split()
        numbers: list[str] = []
        while parts and len(numbers) < 3 and parts[0].isdigit():
            numbers.append(parts.pop(0))
        device = int(numbers[0]) if numbers else 0
        axis = int(numbers[1]) if len(numbers) > 1 else 0
        self._msg_id = numbers[2] if len(numbers) > 2 else None
        if device not in (0, 1):
            return                                   # another device's command
        if self.faults.fires("power-blip"):
            self.power_blip()
            return
        self.poll()
        if self._msg_id is not None and int(self._msg_id) > 99:
            self._reply(axis, False, "BADMESSAGEID")
        elif axis not in (0, 1):
            self._reply(axis, False, "BADAXIS")
        else:
            self._command(axis, parts)

    def _command(self, axis: int, parts: list[str]) -> None:
        now = self.clock.now_s()
        words = [p.lower() for p in parts]
        if not words:
            self._reply(axis, True)
        elif words == ["home"]:
            self.flags.discard("FS")
            self.flags.discard("WL")
            self.axis.trapezoid = self._trapezoid()
            self.axis.start_home(now)
            self._reply(axis, True)
        elif words[0] == "move" and len(words) >= 2:
            self._move(axis, words[1:], now)
        elif words == ["stop"]:
            # decelerates at accel: BUSY until at rest (the alert, if on, comes then)
            if self.axis.moving:
                self.flags.add("NI")
                self.axis.stop(now, profiled=True)
            self._reply(axis, True)
        elif words == ["estop"]:
            stopped = self.axis.stop(now) is not None
            if stopped:
                self.flags.add("NI")
                self.axis.trapezoid = self._trapezoid()
            self._reply(axis, True)
            if stopped and self.comm_alert:
                self._send(f"!01 1 IDLE {self._flag()}", reply=False)
        elif words == ["identify"]:
            self._reply(axis, True)                  # the device flashes its LEDs
        elif words[0] == "warnings" and words[1:] in ([], ["clear"]):
            flags = self._all_flags()
            self._reply(axis, True, " ".join([f"{len(flags):02d}", *flags]))
            if words[1:] == ["clear"]:
                self.flags.clear()
        elif words[0] == "get" and len(words) == 2:
            value = self._get(words[1], now)
            if value is None:
                self._reply(axis, False, "BADCOMMAND")
            else:
                self._reply(axis, True, value)
        elif words[0] == "set" and len(words) == 3:
            self._set(axis, words[1], words[2])
        elif words[:2] == ["tools", "echo"]:
            self._reply(axis, True, " ".join(parts[2:]) or 0)
        elif words == ["system", "reset"]:
            self._reply(axis, True)
            self.restart()
        else:
            self._reply(axis, False, "BADCOMMAND")

    def _move(self, axis: int, args: list[str], now: float) -> None:
        kind = args[0]
        if kind in ("max", "min") and len(args) == 1:
            target: int | None = self.limit_max if kind == "max" else self.limit_min
        elif kind in ("abs", "rel", "vel") and len(args) == 2:
            try:
                n = int(args[1])
            except ValueError:
                self._reply(axis, False, "BADDATA")
                return
            counter = round(self.axis.counter_deg(now) * STEPS_PER_DEG)
            target = {"abs": n, "rel": counter + n, "vel": None}[kind]
        else:
            self._reply(axis, False, "BADCOMMAND")
            return
        if kind == "vel":
            if abs(n) > self.maxspeed:
                self._reply(axis, False, "BADDATA")
                return
            if n == 0:
                self.axis.stop(now)
                self._reply(axis, True)
                return
        elif not self.axis.homed or not self.limit_min <= target <= self.limit_max:
            self._reply(axis, False, "BADDATA")
            return
        if self.axis.moving:
            self.flags.add("NI")
        stall = self.faults.parameter("stall", 0.5) if self.faults.fires("stall") else None
        if kind == "vel":
            self.axis.trapezoid = self._trapezoid(n)
            current = self.axis.counter_deg(now)
            run_deg = VELOCITY_RUN_DEG if n > 0 else -VELOCITY_RUN_DEG
            self.axis.start_move(current + run_deg, now, stall_fraction=stall)
        else:
            self.axis.trapezoid = self._trapezoid()
            slip = self.faults.parameter("slip", 0.5) if self.faults.fires("slip") else None
            self.axis.start_move(target / STEPS_PER_DEG, now, stall_fraction=stall,
                                 slip_deg=slip)
        self._reply(axis, True)

    def _settings(self, now: float) -> dict[str, Any]:
        """name → (getter, setter or None for read-only)."""
        def counter() -> int:
            return round(self.axis.counter_deg(now) * STEPS_PER_DEG)

        def speed(value: int) -> bool:
            if value <= 0:
                return False
            self.maxspeed = value
            self.axis.trapezoid = self.axis.home_trapezoid = self._trapezoid()
            return True

        def accel(value: int) -> bool:
            if value <= 0:
                return False
            self.accel = value
            self.axis.trapezoid = self.axis.home_trapezoid = self._trapezoid()
            return True

        def limit(name: str) -> Any:
            def setter(value: int) -> bool:
                setattr(self, name, value)
                return True
            return setter

        def flag(name: str) -> Any:
            def setter(value: int) -> bool:
                if value not in (0, 1):
                    return False
                setattr(self, name, value)
                return True
            return setter

        def position(value: int) -> bool:
            if self.axis.moving:
                return False
            # redefine the counter: physical = counter + offset
            self.axis.offset_deg = self.axis.physical_deg(now) - value / STEPS_PER_DEG
            return True

        return {
            "deviceid": (lambda: DEVICE_ID, None),
            "system.serial": (lambda: self.serial_number, None),
            "version": (lambda: VERSION, None),
            "version.build": (lambda: VERSION_BUILD, None),
            "system.axiscount": (lambda: 1, None),
            "system.access": (lambda: 1, None),
            "system.voltage": (lambda: "24.1", None),
            "system.temperature": (lambda: "31.5", None),
            "driver.temperature": (lambda: "33.0", None),
            "comm.protocol": (lambda: 1, None),
            "comm.address": (lambda: 1, None),
            "comm.rs232.baud": (lambda: 115200, None),
            "comm.alert": (lambda: self.comm_alert, flag("comm_alert")),
            "comm.checksum": (lambda: self.comm_checksum, flag("comm_checksum")),
            "peripheralid": (lambda: PERIPHERAL_ID, None),
            "resolution": (lambda: RESOLUTION, None),
            "pos": (counter, position),
            "encoder.pos": (lambda: round(self.axis.encoder_deg(now) * STEPS_PER_DEG), None),
            "maxspeed": (lambda: self.maxspeed, speed),
            "accel": (lambda: self.accel, accel),
            "limit.min": (lambda: self.limit_min, limit("limit_min")),
            "limit.max": (lambda: self.limit_max, limit("limit_max")),
            "limit.home.pos": (lambda: 0, None),
            "limit.cycle.dist": (lambda: round(360 * STEPS_PER_DEG), None),
            "motion.index.dist": (lambda: round(360 * STEPS_PER_DEG), None),
            "limit.approach.maxspeed": (lambda: self.maxspeed, None),
            "comm.packet.size.max": (lambda: 80, None),
            "system.current": (lambda: "0.32", None),
            "driver.current.run": (lambda: 25, None),
            "driver.current.hold": (lambda: 10, None),
            "knob.enable": (lambda: self.knob_enable, flag("knob_enable")),
        }

    def _get(self, name: str, now: float) -> str | int | None:
        entry = self._settings(now).get(name)
        return None if entry is None else entry[0]()

    def _set(self, axis: int, name: str, value: str) -> None:
        entry = self._settings(self.clock.now_s()).get(name)
        if entry is None:
            self._reply(axis, False, "BADCOMMAND")
            return
        setter = entry[1]
        try:
            n = int(value)
        except ValueError:
            n = None
        if setter is None or n is None or not setter(n):
            self._reply(axis, False, "BADDATA")
            return
        self._reply(axis, True)

    _msg_id: str | None = None


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> ZaberRotatorEmulator:
    kw = {k: float(v) for k, v in options.items()
          if k in ("power_up_angle_deg", "limit_min_deg", "limit_max_deg", "travel_min_deg",
                   "travel_max_deg", "max_velocity_deg_s", "acceleration_deg_s2")}
    if "serial_number" in options:        # two stages of one model differ by it (lab discover)
        kw["serial_number"] = int(options["serial_number"])
    return ZaberRotatorEmulator(clock, faults, seed, **kw)


core.register("rotator-zaber", _factory, faults=ZaberRotatorEmulator.known_faults())
