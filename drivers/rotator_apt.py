"""Thorlabs APT rotation stage, K10CR1 profile, over a USB-serial port (pyserial).

References: Thorlabs, *APT Communications Protocol* (K10CR1 message subset) — [APT] in
docs/references.md.  Frames are encoded with `thorlabs-apt-protocol`
(MIT; ``thorlabs_apt_protocol.<message>(dest, source, …)``) and replies decoded with its
`Unpacker`.  Line: 115200 baud 8N1, RTS/CTS flow control; host 0x01, device 0x50, channel 1.

    connect   HW_REQ_INFO 0x0005                → HW_GET_INFO 0x0006 (serial, model, firmware)
              MOD_SET_CHANENABLESTATE 0x0210 (chan 1, 0x01)             (no reply)
              MOT_SET_VELPARAMS 0x0413 (min 0, acc, max v)                (no reply)
              MOT_REQ_VELPARAMS 0x0414          → MOT_GET_VELPARAMS 0x0415
              [HW_START_UPDATEMSGS 0x0011 when update_messages=True]
    identify  MOD_IDENTIFY 0x0223 (front-panel LED flashes)               (no reply)
    status    MOT_REQ_STATUSUPDATE 0x0480       → MOT_GET_STATUSUPDATE 0x0481
              (chan, position counter, encoder count, 32 status bits)
    home      MOT_MOVE_HOME 0x0443              → MOT_MOVE_HOMED 0x0444 when done
    move      MOT_MOVE_ABSOLUTE 0x0453 (chan, position) → MOT_MOVE_COMPLETED 0x0464
              (long form with the status block), or MOT_MOVE_STOPPED 0x0466 when a limit
              switch or a stop ended it
    stop      MOT_MOVE_STOP 0x0465 (chan, 0x01 immediate; 0x02 profiled with
              ``stop(profiled=True)``) → MOT_MOVE_STOPPED 0x0466 (profiled: once the rotor has
              decelerated, up to v/a later)
    push      with HW_START_UPDATEMSGS the controller pushes 0x0481 every 100 ms; the host
              sends MOT_ACK_DCSTATUSUPDATE 0x0492 at least every 0.9 s as keep-alive
    close     HW_STOP_UPDATEMSGS 0x0012 (push mode), HW_DISCONNECT 0x0002

Units: K10CR1 409600/3 = 136533.33 microsteps per degree; velocity in APT units =
µsteps/s × 53.68, acceleration = µsteps/s² / 90.9 (the KST101/K10CR1 scale factors as
tabulated by pylablib; *assumed*, not re-checked against the PDF).
Status bits used: 0x1/0x2 forward/reverse hardware limit, 0x10/0x20 moving, 0x200 homing,
0x400 homed, 0x4000 motion error, 0x80000000 channel enabled.

A lost connection (USB re-enumeration, power blip) raises `InstrumentError`; the next call
reopens the port and re-initialises the controller, and a controller that lost its reference
makes moves raise `NotReady` until it is homed again.
"""

from __future__ import annotations

import struct
from typing import Any

import thorlabs_apt_protocol as apt
from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import DeviceError, InstrumentError, InstrumentTimeout, ProtocolError
from normbox_lab.drivers.rotation import RotationStageBase

HOST = 0x01
DEVICE = 0x50
CHANNEL = 1
K10CR1_STEPS_PER_DEG = 409600.0 / 3.0
VELOCITY_SCALE = 53.68          # APT velocity units per µstep/s (K10CR1 / KST101)
ACCELERATION_SCALE = 1.0 / 90.9  # APT acceleration units per µstep/s²
STOP_IMMEDIATE = 0x01
STOP_PROFILED = 0x02
UPDATE_PERIOD_S = 0.1
KEEPALIVE_S = 0.9

MSG_GET_INFO = 0x0006
MSG_GET_VELPARAMS = 0x0415
MSG_HOMED = 0x0444
MSG_COMPLETED = 0x0464
MSG_STOPPED = 0x0466
MSG_GET_STATUS = 0x0481


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: HW_REQ_INFO): the HW_GET_INFO frame's
    serial number, model and firmware, decoded as `identify` decodes them."""
    if not replies or len(replies[0]) != 90 or replies[0][:2] != b"\x06\x00":
        return None
    unpacker = apt.Unpacker()
    unpacker.feed(replies[0])
    try:
        info = next(unpacker)._asdict()
    except (StopIteration, KeyError, ValueError, AssertionError, TypeError, struct.error):
        return None
    model = bytes(info.get("model_number", b"")).split(b"\0", 1)[0].decode("ascii", "replace")
    fw = ".".join(str(x) for x in info.get("firmware_version", []))
    return InstrumentIdentity("rotation-stage", model or "APT device",
                              str(info.get("serial_number", "")), fw,
                              extra={"protocol": "thorlabs-apt"})


class AptRotationStage(RotationStageBase):
    """A K10CR1 (or any APT stepper rotation stage with `steps_per_deg`)."""

    model = "K10CR1"
    move_overhead_s = 0.0

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "rotator",
                 steps_per_deg: float = K10CR1_STEPS_PER_DEG, min_angle_deg: float = -170.0,
                 max_angle_deg: float = 170.0, max_velocity_deg_s: float = 10.0,
                 acceleration_deg_s2: float = 10.0, home_velocity_deg_s: float = 5.0,
                 position_tolerance_deg: float = 0.05, update_messages: bool = False,
                 auto_home: bool = False, command_timeout_s: float = 1.0,
                 reconnect_timeout_s: float = 10.0, connect: bool = True,
                 attempts: int = 3) -> None:
        super().__init__(port, clock, instrument_id=instrument_id, min_angle_deg=min_angle_deg,
                         max_angle_deg=max_angle_deg, max_velocity_deg_s=max_velocity_deg_s,
                         acceleration_deg_s2=acceleration_deg_s2,
                         home_velocity_deg_s=home_velocity_deg_s,
                         position_tolerance_deg=position_tolerance_deg, auto_home=auto_home)
        self.steps_per_deg = float(steps_per_deg)
        self.update_messages = bool(update_messages)
        self.command_timeout_s = float(command_timeout_s)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.attempts = max(1, int(attempts))
        #: undecodable frames seen since opening (each followed by a drain)
        self.line_faults = 0
        self._unpacker = apt.Unpacker()
        self._status: dict[str, Any] = {}
        self._last_ack_s = -1e9
        self._done_msg: Any = None
        self._waiting_for: tuple[int, ...] = ()
        self._info: dict[str, Any] = {}
        self._lost = False
        self._updates_started = False
        if connect:
            self._connect_with_retries()

    @classmethod
    def open(cls, url: str, clock: Clock, **options: Any) -> AptRotationStage:
        port = transport.open_port(url, baudrate=115200, bytesize=8, parity="N", stopbits=1,
                                   rtscts=True, timeout=0.05,
                                   instrument_id=str(options.get("instrument_id", "")))
        return cls(port, clock, **options)

    # --- framing ------------------------------------------------------------------------------
    def _send(self, frame: bytes) -> None:
        try:
            self.port.write(frame)
        except (SerialException, OSError) as exc:
            self._lost = True
            raise InstrumentError(f"link lost: {exc}", instrument=self.instrument_id) from exc

    def _next_frame(self, deadline_s: float) -> Any:
        """The next decoded frame, or None at the deadline.  Keeps the keep-alive going."""
        while True:
            try:
                return next(self._unpacker)
            except StopIteration:
                pass
            except (KeyError, ValueError, AssertionError, TypeError, struct.error,
                    IndexError, OverflowError) as exc:
                raw = bytes(getattr(self._unpacker, "buf", b""))
                self._resync()
                raise ProtocolError(f"undecodable APT frame: {exc}", raw=raw[:64],
                                    instrument=self.instrument_id) from None
            now = self.clock.now_s()
            if now >= deadline_s:
                return None
            if self._updates_started and now - self._last_ack_s >= KEEPALIVE_S:
                self._send(apt.mot_ack_dcstatusupdate(DEVICE, HOST))
                self._last_ack_s = now
            try:
                waiting = self.port.in_waiting
                chunk = self.port.read(max(1, waiting))
            except (SerialException, OSError) as exc:
                self._lost = True
                raise InstrumentError(f"link lost: {exc}",
                                      instrument=self.instrument_id) from exc
            if chunk:
                self._unpacker.feed(chunk)
            elif self.clock.now_s() == now:
                self.clock.sleep(min(0.01, max(0.0, deadline_s - now)))

    def _resync(self) -> None:
        """After an undecodable frame: drop the unpacker's buffer and whatever is on the line
        (frames carry their message id, so later replies are matched by id, not position)."""
        self.line_faults += 1
        self._unpacker = apt.Unpacker()
        try:
            self.port.reset_input_buffer()
        except (SerialException, OSError):
            pass

    def _connect_with_retries(self) -> None:
        """`connect`, retried on transport faults (lost, late or undecodable replies, a link
        that blips while connecting) up to `attempts` times."""
        deadline = self.clock.now_s() + self.reconnect_timeout_s
        attempt = 0
        while True:
            attempt += 1
            try:
                if attempt > 1:
                    self._resync()
                    if hasattr(self.port, "is_open") and not self.port.is_open:
                        self.port.open()
                self.connect()
                self._lost = False
                return
            except (InstrumentTimeout, ProtocolError, SerialException, OSError):
                if attempt >= self.attempts:
                    raise
            except InstrumentError:            # the link is down: wait for it (bounded)
                if not self._lost or self.clock.now_s() >= deadline:
                    raise
            self.clock.sleep(0.5)

    def _handle(self, msg: Any) -> None:
        """Book-keeping for every frame that arrives (pushed status, end-of-move)."""
        if msg.msgid in (MSG_GET_STATUS, MSG_COMPLETED, MSG_STOPPED) and hasattr(msg, "position"):
            self._status = msg._asdict()
        if msg.msgid in self._waiting_for and self._done_msg is None:
            self._done_msg = msg

    def _expect(self, msgid: int, timeout_s: float | None = None) -> Any:
        deadline = self.clock.now_s() + (timeout_s if timeout_s is not None
                                         else self.command_timeout_s)
        while True:
            msg = self._next_frame(deadline)
            if msg is None:
                raise InstrumentTimeout(f"no {msgid:#06x} reply", instrument=self.instrument_id)
            self._handle(msg)
            if msg.msgid == msgid:
                return msg

    def _ensure_link(self) -> None:
        """After a lost link: reopen the port and re-initialise (`core.transport.recover_link`
        within `reconnect_timeout_s`), or raise InstrumentError."""
        if not self._lost:
            return

        def attempt() -> None:
            self._lost = True
            if not self.port.is_open:
                self.port.open()
            self.port.reset_input_buffer()
            self._unpacker = apt.Unpacker()
            self._lost = False
            self.connect()

        def close_half_open(_exc: BaseException) -> None:
            self._lost = True
            try:
                self.port.close()
            except (SerialException, OSError):
                pass                    # the port is gone already

        transport.recover_link(self.clock, self.reconnect_timeout_s, attempt,
                               retry_on=(SerialException, OSError, InstrumentError),
                               instrument_id=self.instrument_id, what="APT link lost",
                               on_failure=close_half_open)

    # --- conversions --------------------------------------------------------------------------
    def _steps(self, angle_deg: float) -> int:
        return round(angle_deg * self.steps_per_deg)

    def _deg(self, steps: int) -> float:
        return steps / self.steps_per_deg

    # --- connection ---------------------------------------------------------------------------
    def connect(self) -> None:
        self._updates_started = False
        self._send(apt.hw_req_info(DEVICE, HOST))
        info = self._expect(MSG_GET_INFO)
        self._info = info._asdict()
        self._send(apt.mod_set_chanenablestate(DEVICE, HOST, CHANNEL, 1))
        v = round(self.max_velocity_deg_s * self.steps_per_deg * VELOCITY_SCALE)
        a = round(self.acceleration_deg_s2 * self.steps_per_deg * ACCELERATION_SCALE)
        self._send(apt.mot_set_velparams(DEVICE, HOST, CHANNEL, 0, a, v))
        self._send(apt.mot_req_velparams(DEVICE, HOST, CHANNEL))
        vel = self._expect(MSG_GET_VELPARAMS)
        # the device's own numbers drive the timing model
        self.max_velocity_deg_s = vel.max_velocity / (self.steps_per_deg * VELOCITY_SCALE)
        self.acceleration_deg_s2 = vel.acceleration / (self.steps_per_deg * ACCELERATION_SCALE)
        if self.update_messages:
            self._send(apt.hw_start_updatemsgs(DEVICE, HOST))
            self._last_ack_s = self.clock.now_s()
            self._updates_started = True

    def identify(self) -> InstrumentIdentity:
        model = self._info.get("model_number", b"")
        model = model.split(b"\0", 1)[0].decode("ascii", "replace") if model else self.model
        fw = ".".join(str(x) for x in self._info.get("firmware_version", []))
        return InstrumentIdentity("rotation-stage", model or self.model,
                                  str(self._info.get("serial_number", "")), fw,
                                  extra={"protocol": "thorlabs-apt"})

    def flash_led(self) -> None:
        self._ensure_link()
        self._send(apt.mod_identify(DEVICE, HOST, CHANNEL))

    def close(self) -> None:
        try:
            if self.update_messages:
                self.port.write(apt.hw_stop_updatemsgs(DEVICE, HOST))
            self.port.write(apt.hw_disconnect(DEVICE, HOST))
        except (SerialException, OSError):
            pass
        try:
            self.port.close()
        except (SerialException, OSError):
            pass

    # --- status -------------------------------------------------------------------------------
    def _request_status(self) -> dict[str, Any]:
        self._ensure_link()
        self._send(apt.mot_req_statusupdate(DEVICE, HOST, CHANNEL))
        msg = self._expect(MSG_GET_STATUS)
        return msg._asdict()

    def status(self) -> dict[str, Any]:
        s = self._request_status()
        errors = []
        if s.get("forward_limit_switch"):
            errors.append("forward limit switch")
        if s.get("reverse_limit_switch"):
            errors.append("reverse limit switch")
        if s.get("motion_error"):
            errors.append("motion error")
        return {
            "position_deg": self._deg(s["position"]),
            "encoder_deg": self._deg(s["enc_count"]),
            "homed": bool(s["homed"]),
            "homing": bool(s["homing"]),
            "moving": bool(s["moving_forward"] or s["moving_reverse"]),
            "limit_forward": bool(s["forward_limit_switch"]),
            "limit_reverse": bool(s["reverse_limit_switch"]),
            "channel_enabled": bool(s["channel_enabled"]),
            "soft_limits_deg": (self.min_angle_deg, self.max_angle_deg),
            "errors": errors,
        }

    def is_homed(self) -> bool:
        return bool(self._request_status()["homed"])

    def is_moving(self) -> bool:
        s = self._request_status()
        return bool(s["moving_forward"] or s["moving_reverse"] or s["homing"])

    def position_deg(self) -> float:
        return self._deg(self._request_status()["position"])

    def _readback_deg(self) -> float:
        """Encoder readback after the move (what the rotor really did)."""
        return self._deg(self._request_status()["enc_count"])

    # --- motion -------------------------------------------------------------------------------
    def _begin_move(self, angle_deg: float) -> None:
        self._done_msg = None
        self._waiting_for = (MSG_COMPLETED, MSG_STOPPED)
        self._send(apt.mot_move_absolute(DEVICE, HOST, CHANNEL, self._steps(angle_deg)))

    def _begin_home(self) -> None:
        self._ensure_link()
        self._done_msg = None
        self._waiting_for = (MSG_HOMED, MSG_STOPPED)
        self._send(apt.mot_move_home(DEVICE, HOST, CHANNEL))

    def _wait_done(self, timeout_s: float) -> None:
        deadline = self.clock.now_s() + timeout_s
        while self._done_msg is None and self._waiting_for:
            msg = self._next_frame(deadline)
            if msg is None:
                raise InstrumentTimeout(f"motion not finished after {timeout_s:.1f} s",
                                        instrument=self.instrument_id)
            self._handle(msg)
        done, self._done_msg, self._waiting_for = self._done_msg, None, ()
        if done is None:
            return
        if done.msgid == MSG_STOPPED:
            s = self._request_status()
            if s["forward_limit_switch"] or s["reverse_limit_switch"]:
                side = "forward" if s["forward_limit_switch"] else "reverse"
                self._commanded_deg = None
                raise DeviceError("LIMIT", f"{side} limit switch hit at "
                                  f"{self._deg(s['enc_count']):.3f}°",
                                  instrument=self.instrument_id)
            self._commanded_deg = None        # stopped on request: no position check

    def stop(self, profiled: bool = False) -> None:
        """Halt now (MOT_MOVE_STOP immediate: the emergency stop and aborts), or with
        `profiled` decelerate first (MOVE_STOPPED up to v/a later)."""
        self._ensure_link()
        self._waiting_for = (MSG_STOPPED,)
        self._done_msg = None
        mode = STOP_PROFILED if profiled else STOP_IMMEDIATE
        self._send(apt.mot_move_stop(DEVICE, HOST, CHANNEL, mode))
        try:
            slack = self.max_velocity_deg_s / self.acceleration_deg_s2 if profiled else 0.0
            self._expect(MSG_STOPPED, self.command_timeout_s + slack)
        finally:
            self._waiting_for = ()
            self._done_msg = None
            self._commanded_deg = None


K10CR1 = AptRotationStage

__all__ = ["K10CR1", "K10CR1_STEPS_PER_DEG", "AptRotationStage"]
