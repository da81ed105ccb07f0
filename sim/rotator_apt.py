"""Thorlabs K10CR1 rotation mount (integrated APT stepper controller), emulated at the wire.

Written from Thorlabs' *APT Communications Protocol* ([APT] in docs/references.md) with its own
small frame codec (struct), independently of the driver (which uses thorlabs-apt-protocol).

Frames: 6-byte header ``<H id><B p1><B p2><B dest><B src>`` (short) or
``<H id><H len><B dest|0x80><B src>`` + data (long); little-endian.  The controller answers as
0x50 (generic USB device) to requests addressed to 0x50, 0x11 (rack) or 0x21 (bay 0); the host
is 0x01.  Channel 1.  Messages (request → reply; "set" messages have no reply):

    0x0223 MOD_IDENTIFY                   LED flash
    0x0005 HW_REQ_INFO                    → 0x0006 HW_GET_INFO (84 data bytes)
    0x0210 / 0x0211 CHANENABLESTATE       set / → 0x0212 (short: chan, 0x01 on / 0x02 off)
    0x0011 / 0x0012 HW_START/STOP_UPDATEMSGS  push 0x0481 every 100 ms while 0x0492
                                          MOT_ACK_DCSTATUSUPDATE keep-alives come (stop 5 s
                                          after the last one, *assumed*)
    0x0002 HW_DISCONNECT                  stops the pushes
    0x0410 / 0x0411 POSCOUNTER            set (redefines the counter) / → 0x0412 (chan, pos)
    0x0409 / 0x040A ENCCOUNTER            set / → 0x040B (chan, encoder count)
    0x0413 / 0x0414 VELPARAMS             (chan, min v, acc, max v) / → 0x0415
    0x0416 / 0x0417 JOGPARAMS             (chan, mode, step, min v, acc, max v, stop mode)
                                          / → 0x0418
    0x0426 / 0x0427 POWERPARAMS           (chan, rest %, move %) / → 0x0428
    0x043A / 0x043B GENMOVEPARAMS         (chan, backlash) / → 0x043C
    0x0440 / 0x0441 HOMEPARAMS            (chan, dir, limit switch, velocity, offset) / → 0x0442
    0x0423 / 0x0424 LIMSWITCHPARAMS       (chan, cw hard, ccw hard, cw soft, ccw soft, mode)
                                          / → 0x0425
    0x0445 / 0x0446 MOVERELPARAMS         (chan, distance) / → 0x0447
    0x0450 / 0x0451 MOVEABSPARAMS         (chan, position) / → 0x0452
    0x0429 MOT_REQ_STATUSBITS             → 0x042A (chan, status bits)
    0x0480 MOT_REQ_STATUSUPDATE           → 0x0481 (chan, position, encoder, status bits)
    0x0490 MOT_REQ_DCSTATUSUPDATE         → 0x0491 (chan, position, velocity, 0, status bits)
    0x0443 MOT_MOVE_HOME                  → 0x0444 MOT_MOVE_HOMED at the home switch
    0x0453 MOT_MOVE_ABSOLUTE              long form (chan, position), or short form: the
                                          stored MOVEABSPARAMS position
    0x0448 MOT_MOVE_RELATIVE              long form (chan, distance), or short form: the stored
                                          MOVERELPARAMS distance
    0x0457 MOT_MOVE_VELOCITY              short (chan, direction): runs at the VELPARAMS maximum
                                          until MOVE_STOP (or a limit switch, if configured)
    0x046A MOT_MOVE_JOG                   short (chan, direction): one jog step (JOGPARAMS mode
                                          2) or a continuous jog (mode 1) at the jog velocity
    moves end with 0x0464 MOT_MOVE_COMPLETED, or 0x0466 MOT_MOVE_STOPPED (stop, limit switch)
    0x0465 MOT_MOVE_STOP                  short (chan, 0x01 immediate / 0x02 profiled): immediate
                                          → 0x0466 at once where the rotor is; profiled → the
                                          rotor decelerates (v²/2a), 0x0466 when at rest
    0x04F4 / 0x04F5 BOWINDEX              set (chan, bow index) / → 0x04F6 MOT_GET_BOWINDEX
                                          (0 = trapezoidal profile, the one modelled)

Direction codes (MOVE_VELOCITY, MOVE_JOG): the protocol calls 0x01 "forward" and 0x02
"reverse" without saying which way the position counter goes.  On Kinesis motor controllers
(K10CR1 among the stages its author tested) code 0x02 moves towards *increasing* position
counts: pylablib's ``KinesisMotor`` sends 2 for a "+" jog or velocity move
(``_forward_positive = False``), and thorlabs-apt-device documents that on some devices
"forward" moves towards negative counts (its ``invert_direction_logic``).  So here 0x02 ("reverse")
increases the counter and 0x01 ("forward") decreases it, and the status bits follow the
protocol's names: 0x10 "moving forward" (0x40 jogging forward) while the counter decreases,
0x20 / 0x80 while it increases ([APT], [PYLABLIB] in docs/references.md).
    0x04B9 MOT_SET_EEPROMPARAMS           accepted (parameters are kept in memory only)
Anything else is ignored, as the controller ignores messages it does not implement.

MOVE_COMPLETED, MOVE_STOPPED and GET_DCSTATUSUPDATE carry the 14-byte status structure the
protocol defines for them: ``<H chan><l position><h velocity><H reserved><L status bits>``
(velocity 0 once a move has ended; while moving, counts/s ÷ 2048, *assumed* scale).
GET_STATUSUPDATE carries ``<H chan><l position><l encoder count><L status bits>``.

Power-up: the channel is **enabled** (a K10CR1 energises its motor at power-up, as the Kinesis
software shows); not homed, counter 0 wherever the rotor is (`power_up_angle_deg`).  A channel
disabled with 0x0210 ignores motion commands, as the controller does.

Mechanics (`sim.motion.Axis`): K10CR1 409600/3 µsteps/°, default 10 °/s and 10 °/s²
(velocity APT units = µsteps/s × 53.68, acceleration = µsteps/s² / 90.9), homing at 5 °/s to
the home switch at 0° plus the switch approach (so homing from 0° takes ~0.6 s); the status
clears "homed" (0x400) while homing and sets 0x200.  A K10CR1 rotates continuously: no limit
switches (``limit_min_deg`` / ``limit_max_deg`` options add them for tests); the ±170° range of
the Normbox sample holder is the lab's configuration (the driver's ``min_angle_deg`` /
``max_angle_deg``), not the controller's.  The stepper is open loop: after a stall the
position counter still reaches the target while the encoder tells the truth.

Device faults: ``stall`` (the next move stalls half-way; parameter = fraction, default 0.5),
``power-blip`` (at the next command the controller resets: link down 1 s, reference lost).
"""

from __future__ import annotations

import math
import struct
from typing import Any, ClassVar

from normbox_lab.sim import core
from normbox_lab.sim.motion import ROTATOR_FAULT_KINDS, Axis, PowerCycled, Trapezoid

HOST = 0x01
CONTROLLER = 0x50
ADDRESSES = (CONTROLLER, 0x11, 0x21)
CHANNEL = 1
STEPS_PER_DEG = 409600.0 / 3.0
VELOCITY_SCALE = 53.68
ACCELERATION_SCALE = 1.0 / 90.9
DC_VELOCITY_DIVISOR = 2048.0
INT32_MAX = 2**31 - 1
UPDATE_PERIOD_S = 0.1
KEEPALIVE_TIMEOUT_S = 5.0
#: an endless run (velocity move, continuous jog) aims this far; a limit switch stops it first
RUN_DEG = 1.0e6

BIT_FWD_LIMIT = 0x1
BIT_REV_LIMIT = 0x2
BIT_MOVING_FWD = 0x10
BIT_MOVING_REV = 0x20
BIT_JOGGING_FWD = 0x40
BIT_JOGGING_REV = 0x80
BIT_CONNECTED = 0x100
BIT_HOMING = 0x200
BIT_HOMED = 0x400
BIT_MOTION_ERROR = 0x4000
BIT_ENABLED = 0x80000000


def direction_sign(code: int) -> int:
    """MOVE_VELOCITY / MOVE_JOG direction code → counter direction (0x02 increases it)."""
    return +1 if code == 0x02 else -1


def short_frame(msg_id: int, p1: int = 0, p2: int = 0) -> bytes:
    return struct.pack("<HBBBB", msg_id, p1 & 0xFF, p2 & 0xFF, HOST, CONTROLLER)


def long_frame(msg_id: int, data: bytes) -> bytes:
    return struct.pack("<HHBB", msg_id, len(data), HOST | 0x80, CONTROLLER) + data


class AptRotatorEmulator(PowerCycled, core.Emulator):
    device_name = "rotator-apt"
    fault_kinds = ROTATOR_FAULT_KINDS
    device_faults = tuple(k.kind for k in ROTATOR_FAULT_KINDS)

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 serial_number: int = 55123456, power_up_angle_deg: float = 0.0,
                 limit_min_deg: float = -math.inf, limit_max_deg: float = math.inf,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 10.0,
                 home_velocity_deg_s: float = 5.0) -> None:
        super().__init__(clock, faults, seed)
        self.serial_number = int(serial_number)
        self.home_velocity_deg_s = float(home_velocity_deg_s)
        self.move_trapezoid = Trapezoid(float(max_velocity_deg_s), float(acceleration_deg_s2))
        self.axis = Axis(self.move_trapezoid,
                         home_trapezoid=Trapezoid(self.home_velocity_deg_s,
                                                  float(acceleration_deg_s2)),
                         limit_min_deg=float(limit_min_deg), limit_max_deg=float(limit_max_deg),
                         power_up_angle_deg=float(power_up_angle_deg),
                         stall_stops_controller=False)
        self.motion_error = False
        self.updates_on = False
        self.next_update_s: float | None = None
        self.last_ack_s = 0.0
        self.identify_count = 0
        self.motion_kind = ""                 # "move", "velocity", "jog" (status bits)
        self._inbuf = bytearray()
        self._power_up_parameters()

    def _power_up_parameters(self) -> None:
        self.enabled = True
        self.abs_position_steps = 0
        self.rel_distance_steps = 0
        self.backlash_steps = 0
        self.rest_factor_pct, self.move_factor_pct = 50, 100        # *assumed* defaults
        self.jog_mode, self.jog_stop_mode = 2, 2                     # single step, profiled
        self.jog_step_steps = round(5.0 * STEPS_PER_DEG)
        self.jog_trapezoid = self.move_trapezoid
        self.home_dir, self.home_limit_switch, self.home_offset_steps = 2, 1, 0
        self.limit_params = (2, 2, 0, 0, 1)   # hard limits make on contact; soft limits off
        self.bow_index = 0                     # trapezoidal velocity profile

    # --- what the world reads ----------------------------------------------------------------
    def angle_deg(self) -> float:
        """The physical angle of the rotor now (the virtual Normbox reads the sample angle)."""
        return self.axis.physical_deg(self.clock.now_s())

    # --- units -----------------------------------------------------------------------------------
    @staticmethod
    def _v_apt(trap: Trapezoid) -> int:
        """APT velocity units (a 32-bit field: ≈ 293 °/s at most)."""
        return min(INT32_MAX, round(trap.max_velocity_deg_s * STEPS_PER_DEG * VELOCITY_SCALE))

    @staticmethod
    def _a_apt(trap: Trapezoid) -> int:
        return min(INT32_MAX, round(trap.acceleration_deg_s2 * STEPS_PER_DEG
                                    * ACCELERATION_SCALE))

    @staticmethod
    def _trapezoid(v_apt: int, a_apt: int) -> Trapezoid:
        return Trapezoid(v_apt / (STEPS_PER_DEG * VELOCITY_SCALE),
                         a_apt / (STEPS_PER_DEG * ACCELERATION_SCALE))

    # --- bytes in ------------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        self._inbuf += data
        while len(self._inbuf) >= 6:
            msg_id, word, dest, _source = struct.unpack_from("<HHBB", self._inbuf)
            is_long = bool(dest & 0x80)
            length = word if is_long else 0
            if len(self._inbuf) < 6 + length:
                return
            frame = bytes(self._inbuf[: 6 + length])
            del self._inbuf[: 6 + length]
            if (dest & 0x7F) not in ADDRESSES:
                continue                      # not for us
            p1, p2 = frame[2], frame[3]
            self.on_frame(msg_id, p1, p2, frame[6:] if is_long else None)

    def on_frame(self, msg_id: int, p1: int, p2: int, data: bytes | None) -> None:
        """One message; `data` is None for a short (header-only) frame."""
        now = self.clock.now_s()
        if self.faults.fires("power-blip"):
            self.power_blip()
            return
        body = data or b""

        def fields(fmt: str) -> tuple | None:
            return struct.unpack_from(fmt, body) if len(body) >= struct.calcsize(fmt) else None

        if msg_id == 0x0223:
            self.identify_count += 1
        elif msg_id == 0x0005:
            self.emit(long_frame(0x0006, self._info_block()))
        elif msg_id == 0x0210:
            self.enabled = p2 == 0x01
        elif msg_id == 0x0211:
            self.emit(short_frame(0x0212, CHANNEL, 0x01 if self.enabled else 0x02))
        elif msg_id == 0x0011:
            self.updates_on = True
            self.last_ack_s = now
            self.next_update_s = now + UPDATE_PERIOD_S
        elif msg_id in (0x0012, 0x0002):
            self.updates_on = False
            self.next_update_s = None
        elif msg_id == 0x0492:
            self.last_ack_s = now
            if self.updates_on and self.next_update_s is None:
                self.next_update_s = now + UPDATE_PERIOD_S
        elif msg_id in self._REQUESTS:
            reply_id, block = self._REQUESTS[msg_id](self, now)
            self.emit(long_frame(reply_id, block))
        elif msg_id in self._SETTERS:
            fmt, apply = self._SETTERS[msg_id]
            values = fields(fmt)
            if values is not None:
                apply(self, values[1:], now)
        elif msg_id == 0x04B9:
            pass                                   # save to EEPROM: kept in memory anyway
        elif msg_id == 0x0443:
            if self.enabled:
                self.motion_error = False
                self.motion_kind = "move"
                self.axis.start_home(now)
        elif msg_id in (0x0453, 0x0448):
            self._move(msg_id, fields("<Hl"), now)
        elif msg_id == 0x0457:
            if self.enabled:
                self._run(direction_sign(p2), self.move_trapezoid, "velocity", now)
        elif msg_id == 0x046A:
            if self.enabled:
                sign = direction_sign(p2)
                if self.jog_mode == 1:
                    self._run(sign, self.jog_trapezoid, "jog", now)
                else:
                    self.axis.trapezoid = self.jog_trapezoid
                    self._start(self.axis.counter_deg(now)
                                + sign * self.jog_step_steps / STEPS_PER_DEG, "jog", now)
        elif msg_id == 0x0465:
            if self.axis.moving and p2 == 0x02:
                self.axis.stop(now, profiled=True)     # MOVE_STOPPED once at rest
                if self.axis.moving:
                    return
            self.axis.stop(now)
            self.axis.trapezoid = self.move_trapezoid
            self.emit(long_frame(0x0466, self._dc_status_block(now)))

    def _move(self, msg_id: int, values: tuple | None, now: float) -> None:
        if not self.enabled:
            return
        counter = self.axis.counter_deg(now)
        if msg_id == 0x0453:
            steps = values[1] if values is not None else self.abs_position_steps
            target = steps / STEPS_PER_DEG
        else:
            steps = values[1] if values is not None else self.rel_distance_steps
            target = counter + steps / STEPS_PER_DEG
        self.axis.trapezoid = self.move_trapezoid
        self._start(target, "move", now)

    def _start(self, target_deg: float, kind: str, now: float) -> None:
        stall = None
        if self.faults.fires("stall"):
            stall = self.faults.parameter("stall", 0.5)
            self.motion_error = False
        self.motion_kind = kind
        slip = self.faults.parameter("slip", 0.5) if self.faults.fires("slip") else None
        self.axis.start_move(target_deg, now, stall_fraction=stall, slip_deg=slip)

    def _run(self, sign: int, trap: Trapezoid, kind: str, now: float) -> None:
        self.axis.trapezoid = trap
        self._start(self.axis.counter_deg(now) + sign * RUN_DEG, kind, now)

    # --- parameter messages ----------------------------------------------------------------------
    def _set_velparams(self, values: tuple, now: float) -> None:
        _vmin, acc, vmax = values
        if vmax > 0 and acc > 0:
            self.move_trapezoid = self._trapezoid(vmax, acc)
            self.axis.trapezoid = self.move_trapezoid
            self.axis.home_trapezoid = Trapezoid(self.home_velocity_deg_s,
                                                 self.move_trapezoid.acceleration_deg_s2)

    def _set_jogparams(self, values: tuple, now: float) -> None:
        mode, step, _vmin, acc, vmax, stop_mode = values
        if mode in (1, 2) and vmax > 0 and acc > 0:
            self.jog_mode, self.jog_step_steps, self.jog_stop_mode = mode, step, stop_mode
            self.jog_trapezoid = self._trapezoid(vmax, acc)

    def _set_homeparams(self, values: tuple, now: float) -> None:
        self.home_dir, self.home_limit_switch, v_apt, self.home_offset_steps = values
        if v_apt > 0:
            self.home_velocity_deg_s = v_apt / (STEPS_PER_DEG * VELOCITY_SCALE)
            self.axis.home_trapezoid = Trapezoid(self.home_velocity_deg_s,
                                                 self.move_trapezoid.acceleration_deg_s2)

    def _set_poscounter(self, values: tuple, now: float) -> None:
        if not self.axis.moving:
            self.axis.offset_deg = self.axis.physical_deg(now) - values[0] / STEPS_PER_DEG

    def _set_enccounter(self, values: tuple, now: float) -> None:
        if not self.axis.moving:
            self.axis.encoder_zero_deg = self.axis.physical_deg(now) - values[0] / STEPS_PER_DEG

    #: set messages: id → (data layout, apply(emulator, values after the channel, now))
    _SETTERS: ClassVar[dict[int, tuple[str, Any]]] = {}
    #: requests: id → handler(emulator, now) → (reply id, data)
    _REQUESTS: ClassVar[dict[int, Any]] = {}

    # --- time ----------------------------------------------------------------------------------
    def on_time(self, now_s: float) -> None:
        while True:
            end = self.axis.next_event_s()
            upd = self.next_update_s
            if end is not None and end <= now_s and (upd is None or end <= upd):
                self._finish(end)
            elif upd is not None and upd <= now_s:
                if upd - self.last_ack_s > KEEPALIVE_TIMEOUT_S:
                    self.next_update_s = None          # no keep-alive: stop pushing
                else:
                    self._emit_at(upd, long_frame(0x0481, self._status_block(upd)))
                    self.next_update_s = upd + UPDATE_PERIOD_S
            else:
                return

    def _emit_at(self, when_s: float, frame: bytes) -> None:
        self.emit(frame, max(0.0, when_s - self.clock.now_s()), reply=False)

    def _finish(self, when_s: float) -> None:
        end = self.axis.poll(when_s)
        if end is None:
            return
        self.axis.trapezoid = self.move_trapezoid
        if end.kind == "home":
            if end.reason == "done":
                self._emit_at(when_s, short_frame(0x0444, CHANNEL, 0))
            else:
                self._emit_at(when_s, long_frame(0x0466, self._dc_status_block(when_s)))
        elif end.reason in ("done", "stall"):
            # open loop: a stall goes unnoticed by the controller; only the encoder knows
            self._emit_at(when_s, long_frame(0x0464, self._dc_status_block(when_s)))
        else:
            self._emit_at(when_s, long_frame(0x0466, self._dc_status_block(when_s)))

    def next_state_s(self) -> float | None:
        times = [t for t in (self.axis.next_event_s(), self.next_update_s) if t is not None]
        return min(times) if times else None

    def restart(self) -> None:
        """After a power blip (`PowerCycled`): pushes off, motion gone, reference lost,
        parameters at their power-up values."""
        self.updates_on = False
        self.next_update_s = None
        self.axis.stop(self.clock.now_s())
        self.axis.power_up()
        self._power_up_parameters()

    # --- blocks --------------------------------------------------------------------------------
    def _info_block(self) -> bytes:
        return struct.pack("<l8sH4B60sHHH", self.serial_number, b"K10CR1\0\0", 16,
                           0, 3, 1, 0,  # firmware bytes (minor, interim, major, unused)
                           b"APT Stepper Motor Controller".ljust(60, b"\0"), 1, 0, 1)

    def _status_bits(self, now_s: float) -> int:
        bits = BIT_CONNECTED
        m = self.axis.motion
        if m is not None and now_s < m.end_s:
            if m.kind == "home":
                bits |= BIT_HOMING
            # the protocol's "forward" (code 0x01) decreases the counter (module docstring)
            if self.motion_kind == "jog":
                bits |= BIT_JOGGING_FWD if m.sign < 0 else BIT_JOGGING_REV
            bits |= BIT_MOVING_FWD if m.sign < 0 else BIT_MOVING_REV
        if self.axis.homed:
            bits |= BIT_HOMED
        if self.axis.at_limit == "min":
            bits |= BIT_FWD_LIMIT
        if self.axis.at_limit == "max":
            bits |= BIT_REV_LIMIT
        if self.motion_error:
            bits |= BIT_MOTION_ERROR
        if self.enabled:
            bits |= BIT_ENABLED
        return bits

    def _position(self, now_s: float) -> int:
        return round(self.axis.counter_deg(now_s) * STEPS_PER_DEG)

    def _encoder(self, now_s: float) -> int:
        return round(self.axis.encoder_deg(now_s) * STEPS_PER_DEG)

    def _status_block(self, now_s: float) -> bytes:
        """GET_STATUSUPDATE: chan, position, encoder count, status bits."""
        return struct.pack("<HllL", CHANNEL, self._position(now_s), self._encoder(now_s),
                           self._status_bits(now_s))

    def _dc_status_block(self, now_s: float) -> bytes:
        """MOVE_COMPLETED / MOVE_STOPPED / GET_DCSTATUSUPDATE: chan, position, velocity,
        reserved, status bits."""
        v = self.axis.velocity_deg_s(now_s) * STEPS_PER_DEG / DC_VELOCITY_DIVISOR
        velocity = max(-32768, min(32767, round(v)))
        return struct.pack("<HlhHL", CHANNEL, self._position(now_s), velocity, 0,
                           self._status_bits(now_s))


def _chan(fmt: str, *getters: Any) -> Any:
    """A request handler that packs (channel, *values) with `fmt`."""
    def reply(emu: AptRotatorEmulator, now: float) -> bytes:
        return struct.pack(fmt, CHANNEL, *(g(emu, now) for g in getters))
    return reply


AptRotatorEmulator._REQUESTS = {
    0x0411: lambda e, now: (0x0412, _chan("<Hl", AptRotatorEmulator._position)(e, now)),
    0x040A: lambda e, now: (0x040B, _chan("<Hl", AptRotatorEmulator._encoder)(e, now)),
    0x0414: lambda e, now: (0x0415, _chan(
        "<H3l", lambda e, n: 0, lambda e, n: e._a_apt(e.move_trapezoid),
        lambda e, n: e._v_apt(e.move_trapezoid))(e, now)),
    0x0417: lambda e, now: (0x0418, _chan(
        "<HH4lH", lambda e, n: e.jog_mode, lambda e, n: e.jog_step_steps, lambda e, n: 0,
        lambda e, n: e._a_apt(e.jog_trapezoid), lambda e, n: e._v_apt(e.jog_trapezoid),
        lambda e, n: e.jog_stop_mode)(e, now)),
    0x0427: lambda e, now: (0x0428, _chan(
        "<3H", lambda e, n: e.rest_factor_pct, lambda e, n: e.move_factor_pct)(e, now)),
    0x043B: lambda e, now: (0x043C, _chan("<Hl", lambda e, n: e.backlash_steps)(e, now)),
    0x0441: lambda e, now: (0x0442, _chan(
        "<3Hll", lambda e, n: e.home_dir, lambda e, n: e.home_limit_switch,
        lambda e, n: e._v_apt(Trapezoid(e.home_velocity_deg_s, 1.0)),
        lambda e, n: e.home_offset_steps)(e, now)),
    0x0424: lambda e, now: (0x0425, struct.pack("<3HLLH", CHANNEL, *e.limit_params)),
    0x0446: lambda e, now: (0x0447, _chan("<Hl", lambda e, n: e.rel_distance_steps)(e, now)),
    0x0451: lambda e, now: (0x0452, _chan("<Hl", lambda e, n: e.abs_position_steps)(e, now)),
    0x0429: lambda e, now: (0x042A, _chan("<HL", AptRotatorEmulator._status_bits)(e, now)),
    0x0480: lambda e, now: (0x0481, e._status_block(now)),
    0x04F5: lambda e, now: (0x04F6, _chan("<HH", lambda e, n: e.bow_index)(e, now)),
    0x0490: lambda e, now: (0x0491, e._dc_status_block(now)),
}

AptRotatorEmulator._SETTERS = {
    0x0410: ("<Hl", AptRotatorEmulator._set_poscounter),
    0x0409: ("<Hl", AptRotatorEmulator._set_enccounter),
    0x0413: ("<H3l", AptRotatorEmulator._set_velparams),
    0x0416: ("<HH4lH", AptRotatorEmulator._set_jogparams),
    0x0426: ("<3H", lambda e, v, now: setattr(e, "rest_factor_pct", v[0])
             or setattr(e, "move_factor_pct", v[1])),
    0x043A: ("<Hl", lambda e, v, now: setattr(e, "backlash_steps", v[0])),
    0x0440: ("<3Hll", AptRotatorEmulator._set_homeparams),
    0x0423: ("<3HLLH", lambda e, v, now: setattr(e, "limit_params", tuple(v))),
    0x0445: ("<Hl", lambda e, v, now: setattr(e, "rel_distance_steps", v[0])),
    0x0450: ("<Hl", lambda e, v, now: setattr(e, "abs_position_steps", v[0])),
    0x04F4: ("<HH", lambda e, v, now: setattr(e, "bow_index", v[0])),
}


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> AptRotatorEmulator:
    kw = {k: float(v) for k, v in options.items()
          if k in ("power_up_angle_deg", "limit_min_deg", "limit_max_deg",
                   "max_velocity_deg_s", "acceleration_deg_s2", "home_velocity_deg_s")}
    if "serial_number" in options:        # two stages of one model differ by it (lab discover)
        kw["serial_number"] = int(options["serial_number"])
    return AptRotatorEmulator(clock, faults, seed, **kw)


core.register("rotator-apt", _factory, faults=AptRotatorEmulator.known_faults())
