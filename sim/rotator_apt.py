"""Thorlabs K10CR1 rotation mount (integrated APT stepper controller), emulated at the wire.

Written from Thorlabs' *APT Communications Protocol* ([APT] in docs/references.md) with its own
small frame codec (struct), independently of the driver (which uses thorlabs-apt-protocol).

Frames: 6-byte header ``<H id><B p1><B p2><B dest><B src>`` (short) or
``<H id><H len><B dest|0x80><B src>`` + data (long); little-endian.  The controller is 0x50,
the host 0x01.  Messages understood:

    0x0223 MOD_IDENTIFY            LED flash (no reply)
    0x0005 HW_REQ_INFO             → 0x0006 HW_GET_INFO (84 data bytes)
    0x0210 MOD_SET_CHANENABLESTATE enable (0x01) / disable (0x02) channel 1 (no reply)
    0x0211 MOD_REQ_CHANENABLESTATE → 0x0212
    0x0413 MOT_SET_VELPARAMS       (chan, min v, acc, max v) in APT units (no reply)
    0x0414 MOT_REQ_VELPARAMS       → 0x0415
    0x0480 MOT_REQ_STATUSUPDATE    → 0x0481 (chan, position, encoder, status bits)
    0x0443 MOT_MOVE_HOME           → 0x0444 MOT_MOVE_HOMED when the home switch is reached
    0x0453 MOT_MOVE_ABSOLUTE       → 0x0464 MOT_MOVE_COMPLETED (+ status block) at the end,
                                     or 0x0466 MOT_MOVE_STOPPED when a limit switch stops it
    0x0448 MOT_MOVE_RELATIVE       likewise
    0x0465 MOT_MOVE_STOP           → 0x0466 MOT_MOVE_STOPPED (stops at once; the profiled
                                     deceleration is not modelled)
    0x0011 / 0x0012 HW_START/STOP_UPDATEMSGS: push 0x0481 every 100 ms; the pushes stop when
                                     no 0x0492 MOT_ACK_DCSTATUSUPDATE came for 5 s (*assumed*)
    0x0492 MOT_ACK_DCSTATUSUPDATE  keep-alive
    0x0002 HW_DISCONNECT           stops the pushes
Anything else is ignored (as the controller does); a disabled channel ignores moves.

Mechanics (`sim.motion.Axis`): K10CR1 409600/3 µsteps/°, default 10 °/s and 10 °/s²
(velocity APT units = µsteps/s × 53.68, acceleration = µsteps/s² / 90.9), homing at 5 °/s to
the home switch at 0°; hardware limit switches at ±170° (the Normbox holder's cable wrap,
*assumed*).  Power-up: not homed, counter 0 wherever the rotor is (`power_up_angle_deg`).
The stepper is open loop: after a stall the position counter still reaches the target while
the encoder tells the truth.

Device faults: ``stall`` (the next move stalls half-way; parameter = fraction, default 0.5),
``power-blip`` (at the next command the controller resets: link down 1 s, reference lost).
"""

from __future__ import annotations

import struct
from typing import Any

from normbox_lab.sim import core
from normbox_lab.sim.motion import Axis, Trapezoid

HOST = 0x01
CONTROLLER = 0x50
STEPS_PER_DEG = 409600.0 / 3.0
VELOCITY_SCALE = 53.68
ACCELERATION_SCALE = 1.0 / 90.9
UPDATE_PERIOD_S = 0.1
KEEPALIVE_TIMEOUT_S = 5.0

BIT_FWD_LIMIT = 0x1
BIT_REV_LIMIT = 0x2
BIT_MOVING_FWD = 0x10
BIT_MOVING_REV = 0x20
BIT_CONNECTED = 0x100
BIT_HOMING = 0x200
BIT_HOMED = 0x400
BIT_MOTION_ERROR = 0x4000
BIT_ENABLED = 0x80000000


def short_frame(msg_id: int, p1: int = 0, p2: int = 0) -> bytes:
    return struct.pack("<HBBBB", msg_id, p1 & 0xFF, p2 & 0xFF, HOST, CONTROLLER)


def long_frame(msg_id: int, data: bytes) -> bytes:
    return struct.pack("<HHBB", msg_id, len(data), HOST | 0x80, CONTROLLER) + data


class AptRotatorEmulator(core.Emulator):
    device_name = "rotator-apt"
    device_faults = ("stall", "power-blip")

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 serial_number: int = 55123456, power_up_angle_deg: float = 0.0,
                 limit_min_deg: float = -170.0, limit_max_deg: float = 170.0,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 10.0,
                 home_velocity_deg_s: float = 5.0) -> None:
        super().__init__(clock, faults, seed)
        self.serial_number = int(serial_number)
        self.home_velocity_deg_s = float(home_velocity_deg_s)
        self.axis = Axis(Trapezoid(float(max_velocity_deg_s), float(acceleration_deg_s2)),
                         home_trapezoid=Trapezoid(self.home_velocity_deg_s,
                                                  float(acceleration_deg_s2)),
                         limit_min_deg=float(limit_min_deg), limit_max_deg=float(limit_max_deg),
                         power_up_angle_deg=float(power_up_angle_deg),
                         stall_stops_controller=False)
        self.enabled = False
        self.motion_error = False
        self.updates_on = False
        self.next_update_s: float | None = None
        self.last_ack_s = 0.0
        self.identify_count = 0
        self.blip_s = 1.0
        self._inbuf = bytearray()

    # --- what the world reads ----------------------------------------------------------------
    def angle_deg(self) -> float:
        """The physical angle of the rotor now (the virtual Normbox reads the sample angle)."""
        return self.axis.physical_deg(self.clock.now_s())

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
            if (dest & 0x7F) not in (CONTROLLER, 0x11, 0x21):
                continue                      # not for us
            p1, p2 = frame[2], frame[3]
            self.on_frame(msg_id, p1, p2, frame[6:] if is_long else b"")

    def on_frame(self, msg_id: int, p1: int, p2: int, data: bytes) -> None:
        now = self.clock.now_s()
        if self.faults.fires("power-blip"):
            self.power_blip()
            return
        if msg_id == 0x0223:
            self.identify_count += 1
        elif msg_id == 0x0005:
            self.emit(long_frame(0x0006, self._info_block()))
        elif msg_id == 0x0210:
            self.enabled = p2 == 0x01
        elif msg_id == 0x0211:
            self.emit(short_frame(0x0212, 1, 0x01 if self.enabled else 0x02))
        elif msg_id == 0x0413 and len(data) >= 14:
            _chan, _vmin, acc, vmax = struct.unpack_from("<H3l", data)
            if vmax > 0 and acc > 0:
                trap = Trapezoid(vmax / (STEPS_PER_DEG * VELOCITY_SCALE),
                                 acc / (STEPS_PER_DEG * ACCELERATION_SCALE))
                self.axis.trapezoid = trap
                self.axis.home_trapezoid = Trapezoid(self.home_velocity_deg_s,
                                                     trap.acceleration_deg_s2)
        elif msg_id == 0x0414:
            t = self.axis.trapezoid
            self.emit(long_frame(0x0415, struct.pack(
                "<H3l", 1, 0, round(t.acceleration_deg_s2 * STEPS_PER_DEG * ACCELERATION_SCALE),
                round(t.max_velocity_deg_s * STEPS_PER_DEG * VELOCITY_SCALE))))
        elif msg_id == 0x0480:
            self.emit(long_frame(0x0481, self._status_block(now)))
        elif msg_id == 0x0443:
            if self.enabled:
                self.motion_error = False
                self.axis.start_home(now)
        elif msg_id in (0x0453, 0x0448) and len(data) >= 6:
            _chan, steps = struct.unpack_from("<Hl", data)
            if self.enabled:
                counter = self.axis.counter_deg(now)
                target = steps / STEPS_PER_DEG if msg_id == 0x0453 else \
                    counter + steps / STEPS_PER_DEG
                stall = None
                if self.faults.fires("stall"):
                    stall = self.faults.parameter("stall", 0.5)
                    self.motion_error = False
                self.axis.start_move(target, now, stall_fraction=stall)
        elif msg_id == 0x0465:
            self.axis.stop(now)
            self.emit(long_frame(0x0466, self._status_block(now)))
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
        if end.kind == "home":
            if end.reason == "done":
                self._emit_at(when_s, short_frame(0x0444, 1, 0))
            else:
                self._emit_at(when_s, long_frame(0x0466, self._status_block(when_s)))
        elif end.reason in ("done", "stall"):
            # open loop: a stall goes unnoticed by the controller; only the encoder knows
            self._emit_at(when_s, long_frame(0x0464, self._status_block(when_s)))
        else:
            self._emit_at(when_s, long_frame(0x0466, self._status_block(when_s)))

    def next_state_s(self) -> float | None:
        times = [t for t in (self.axis.next_event_s(), self.next_update_s) if t is not None]
        return min(times) if times else None

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
        self.updates_on = False
        self.next_update_s = None
        self.enabled = False
        self.axis.stop(self.clock.now_s())
        self.axis.power_up()

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
            bits |= BIT_MOVING_FWD if m.sign > 0 else BIT_MOVING_REV
        if self.axis.homed:
            bits |= BIT_HOMED
        if self.axis.at_limit == "max":
            bits |= BIT_FWD_LIMIT
        if self.axis.at_limit == "min":
            bits |= BIT_REV_LIMIT
        if self.motion_error:
            bits |= BIT_MOTION_ERROR
        if self.enabled:
            bits |= BIT_ENABLED
        return bits

    def _status_block(self, now_s: float) -> bytes:
        pos = round(self.axis.counter_deg(now_s) * STEPS_PER_DEG)
        enc = round(self.axis.encoder_deg(now_s) * STEPS_PER_DEG)
        return struct.pack("<HllL", 1, pos, enc, self._status_bits(now_s))


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> AptRotatorEmulator:
    kw = {k: float(v) for k, v in options.items()
          if k in ("power_up_angle_deg", "limit_min_deg", "limit_max_deg",
                   "max_velocity_deg_s", "acceleration_deg_s2", "home_velocity_deg_s")}
    return AptRotatorEmulator(clock, faults, seed, **kw)


core.register("rotator-apt", _factory)
