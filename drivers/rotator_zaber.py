"""Zaber rotation stage over the Zaber ASCII protocol (pyserial).

References: Zaber Technologies, *Zaber ASCII Protocol Manual* — [ZABER] in docs/references.md.
Line: 115200 baud 8N1 (*assumed* default of current firmware), commands end in LF, replies
end in CR LF.

    command   /<device> <axis> <command> [args]\\n        e.g. ``/1 1 move abs 256000``
    reply     @<device> <axis> <OK|RJ> <IDLE|BUSY> <flag> <data>\\r\\n
              e.g. ``@01 1 OK BUSY -- 0``; RJ carries the reason in the data field
              (BADCOMMAND, BADDATA, BADAXIS, …) → `DeviceError(reason)`
    info      #… lines (ignored); alerts !… (ignored; alerts are off by default)

Commands sent:  ``/1 get deviceid``, ``/1 get system.serial``, ``/1 get version`` (identity);
``/1 1 get maxspeed``, ``/1 1 get accel`` (timing model); ``/1 1 warnings`` (flags, e.g.
``@01 1 OK IDLE WR 01 WR``); ``/1 1 warnings clear``; ``/1 1 home``; ``/1 1 move abs N``;
``/1 1 get pos``; ``/1 1 get encoder.pos``; ``/1 1`` (empty command = status poll);
``/1 1 stop``.

Warning flags acted on: ``WR`` no reference position (→ not homed), ``FS`` stalled and
stopped (→ `DeviceError("FS")`), ``WL`` unexpected limit trigger (→ `DeviceError("WL")`),
``NI`` command interrupted (after a stop; informative).

Units: positions in microsteps (`steps_per_deg`, default 4266.667 = 0.000234375 °/µstep, the
X-RSW60A rotary stage, *assumed* profile).  ``maxspeed`` native = µsteps/s × 1.6384,
``accel`` native = µsteps/s² × 1.6384 / 10000 (Zaber's ASCII unit conversions, *not
re-verified*).  Moves are followed by status polls: the driver sleeps until the estimated end
of the move, then polls every `poll_s`.
"""

from __future__ import annotations

import re
from typing import Any

from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import DeviceError, InstrumentError, InstrumentTimeout, ProtocolError
from normbox_lab.drivers.rotation import RotationStageBase

X_RSW60A_STEPS_PER_DEG = 1.0 / 0.000234375
SPEED_NATIVE_PER_STEP_S = 1.6384
ACCEL_NATIVE_PER_STEP_S2 = 1.6384 / 10000.0

REPLY = re.compile(rb"^@(\d{2}) (\d{1,3}) (OK|RJ) (IDLE|BUSY) ([A-Z-]{2}) ?([ -~]*)$")
#: a position or setting beyond this many microsteps is not a number the device can hold
MAX_NATIVE = 2**40

REJECTIONS = {
    "BADCOMMAND": "the command is not recognised",
    "BADDATA": "a parameter is out of range or malformed",
    "BADAXIS": "no such axis",
    "DEVICEONLY": "the command applies to the whole device, not an axis",
    "AGAIN": "the device is busy; try again",
    "PARKED": "the axis is parked",
    "STATUSBUSY": "the axis is busy",
}
FLAGS = {
    "FS": "stalled and stopped",
    "FQ": "encoder error",
    "WR": "no reference position (not homed)",
    "WL": "unexpected limit trigger",
    "NI": "command interrupted",
    "--": "no warning",
}


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: blank line, ``/1 get deviceid``,
    ``system.serial``, ``version``): three ``@01 0 OK <status> <flag> <value>`` replies."""
    values = []
    for raw in replies[1:4]:
        parts = raw.decode("ascii", "replace").split()
        if len(parts) != 6 or parts[0] != "@01" or parts[2] != "OK":
            return None
        values.append(parts[5])
    if len(values) != 3:
        return None
    deviceid, serial, version = values
    return InstrumentIdentity("rotation-stage", ZaberRotationStage.model if deviceid == "30342"
                              else f"Zaber device {deviceid}", serial, version,
                              extra={"protocol": "zaber-ascii", "deviceid": deviceid})


class ZaberReply:
    def __init__(self, device: int, axis: int, ok: bool, busy: bool, flag: str, data: str):
        self.device, self.axis, self.ok, self.busy, self.flag, self.data = (
            device, axis, ok, busy, flag, data)


class ZaberRotationStage(RotationStageBase):
    model = "X-RSW60A"

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "rotator",
                 device: int = 1, axis: int = 1, steps_per_deg: float = X_RSW60A_STEPS_PER_DEG,
                 min_angle_deg: float = -170.0, max_angle_deg: float = 170.0,
                 max_velocity_deg_s: float = 10.0, acceleration_deg_s2: float = 20.0,
                 home_velocity_deg_s: float | None = None, position_tolerance_deg: float = 0.05,
                 auto_home: bool = False, command_timeout_s: float = 1.0, poll_s: float = 0.1,
                 reconnect_timeout_s: float = 10.0, connect: bool = True, attempts: int = 3,
                 resync_quiet_s: float = 0.5) -> None:
        super().__init__(port, clock, instrument_id=instrument_id, min_angle_deg=min_angle_deg,
                         max_angle_deg=max_angle_deg, max_velocity_deg_s=max_velocity_deg_s,
                         acceleration_deg_s2=acceleration_deg_s2,
                         home_velocity_deg_s=home_velocity_deg_s or max_velocity_deg_s,
                         position_tolerance_deg=position_tolerance_deg, auto_home=auto_home)
        self.device = int(device)
        self.axis = int(axis)
        self.steps_per_deg = float(steps_per_deg)
        self.command_timeout_s = float(command_timeout_s)
        self.poll_s = float(poll_s)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.attempts = max(1, int(attempts))
        self.resync_quiet_s = float(resync_quiet_s)
        #: timeouts seen since opening (each followed by a drain and a re-handshake)
        self.line_faults = 0
        self._ident: dict[str, str] = {}
        self._lost = False
        self._expected_end_s = 0.0
        self._last_flag = "--"
        self._homing = False
        if connect:
            self._connect_with_retries()

    @classmethod
    def open(cls, url: str, clock: Clock, **options: Any) -> ZaberRotationStage:
        port = transport.open_port(url, baudrate=115200, bytesize=8, parity="N", stopbits=1,
                                   timeout=0.05,
                                   instrument_id=str(options.get("instrument_id", "")))
        return cls(port, clock, **options)

    # --- lines --------------------------------------------------------------------------------
    def _command(self, text: str, *, axis: bool = True, check: bool = True) -> ZaberReply:
        """Send one command and return its reply.  A timeout drains the line and
        re-handshakes (``get deviceid``) before the command is repeated (every command the
        driver sends is idempotent: absolute moves, gets, sets, home, stop), bounded."""
        self._ensure_link()
        prefix = f"/{self.device} {self.axis}" if axis else f"/{self.device}"
        line = f"{prefix} {text}".rstrip() + "\n"
        last: InstrumentTimeout | None = None
        for _ in range(self.attempts):
            try:
                self.port.reset_input_buffer()
                self.port.write(line.encode("ascii"))
                reply = self._read_reply(self.axis if axis else 0)
                break
            except (SerialException, OSError) as exc:
                self._lost = True
                raise InstrumentError(f"link lost: {exc}", instrument=self.instrument_id) from exc
            except InstrumentTimeout as exc:
                last = exc
                self.line_faults += 1
                self._resync()
        else:
            assert last is not None
            raise last
        self._last_flag = reply.flag
        if check and not reply.ok:
            raise DeviceError(reply.data, REJECTIONS.get(reply.data, "command rejected") +
                              f" ({text!r})", instrument=self.instrument_id)
        return reply

    def _resync(self) -> None:
        """Drain until quiet, then ``get deviceid`` until its reply comes back; replies to
        earlier commands that arrive before it are dropped."""
        try:
            while True:
                self.port.timeout = self.resync_quiet_s
                if not self.port.read(65536):
                    break
            self.port.timeout = 0.05
            self.port.reset_input_buffer()
            self.port.write(f"/{self.device} get deviceid\n".encode("ascii"))
            for _ in range(8):
                reply = self._read_reply(0)
                if not self._ident or reply.data == self._ident.get("deviceid"):
                    return
        except (InstrumentError, SerialException, OSError):
            return          # the repeated command finds out whether the line is back

    def _read_reply(self, axis: int) -> ZaberReply:
        """The next reply from this device and `axis` (0: device scope); info and alert
        lines, and replies of another scope (late replies to earlier commands), are skipped."""
        deadline = self.clock.now_s() + self.command_timeout_s
        buf = bytearray()
        while True:
            now = self.clock.now_s()
            if now >= deadline:
                raise InstrumentTimeout(f"no reply (got {bytes(buf)!r})",
                                        instrument=self.instrument_id)
            chunk = self.port.read_until(b"\n")
            buf += chunk
            if not buf.endswith(b"\n"):
                if not chunk and self.clock.now_s() == now:
                    self.clock.sleep(min(0.01, deadline - now))
                continue
            line = bytes(buf).rstrip(b"\r\n")
            buf.clear()
            if line.startswith((b"#", b"!")) or not line:
                continue                               # info / alert lines
            m = REPLY.match(line)
            if m is None:
                raise ProtocolError("not a Zaber reply", raw=line, instrument=self.instrument_id)
            dev, ax, flag_ok, status, flag, data = m.groups()
            if int(dev) != self.device or int(ax) != axis:
                continue
            return ZaberReply(int(dev), int(ax), flag_ok == b"OK", status == b"BUSY",
                              flag.decode("ascii"), data.decode("ascii").strip())

    def _ensure_link(self) -> None:
        """After a lost link: reopen and re-read the device (`core.transport.recover_link`
        within `reconnect_timeout_s`), or raise InstrumentError."""
        if not self._lost:
            return

        def attempt() -> None:
            self._lost = True
            if not self.port.is_open:
                self.port.open()
            self.port.reset_input_buffer()
            self._lost = False
            self.connect()

        def lost(_exc: BaseException) -> None:
            self._lost = True

        transport.recover_link(self.clock, self.reconnect_timeout_s, attempt,
                               retry_on=(SerialException, OSError, InstrumentError),
                               instrument_id=self.instrument_id, what="Zaber link lost",
                               on_failure=lost)

    def _int(self, reply: ZaberReply) -> int:
        text = reply.data.split()[0] if reply.data.split() else ""
        if not text.lstrip("+-").isdigit() or len(text) > 16 or abs(int(text)) > MAX_NATIVE:
            raise ProtocolError("expected a number of microsteps", raw=reply.data.encode(),
                                instrument=self.instrument_id)
        return int(text)

    # --- connection ---------------------------------------------------------------------------
    def _connect_with_retries(self) -> None:
        """`connect`, retried on transport faults (a lost, late or garbled reply, a link that
        blips while connecting) up to `attempts` times; device refusals raise at once."""
        deadline = self.clock.now_s() + self.reconnect_timeout_s
        attempt = 0
        while True:
            attempt += 1
            try:
                self.connect()
                return
            except (InstrumentTimeout, ProtocolError, SerialException, OSError):
                if attempt >= self.attempts:
                    raise
                self._resync()
            except InstrumentError:            # the link is down: wait for it (bounded)
                if not self._lost or self.clock.now_s() >= deadline:
                    raise
                self.clock.sleep(0.5)

    def connect(self) -> None:
        self._ident = {
            "deviceid": self._command("get deviceid", axis=False).data,
            "serial": self._command("get system.serial", axis=False).data,
            "version": self._command("get version", axis=False).data,
        }
        speed = self._int(self._command("get maxspeed"))
        accel = self._int(self._command("get accel"))
        self.max_velocity_deg_s = speed / SPEED_NATIVE_PER_STEP_S / self.steps_per_deg
        self.acceleration_deg_s2 = accel / ACCEL_NATIVE_PER_STEP_S2 / self.steps_per_deg
        self.home_velocity_deg_s = self.max_velocity_deg_s

    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("rotation-stage", self.model, self._ident.get("serial", ""),
                                  self._ident.get("version", ""),
                                  extra={"protocol": "zaber-ascii",
                                         "deviceid": self._ident.get("deviceid", "")})

    def close(self) -> None:
        try:
            self.port.close()
        except (SerialException, OSError):
            pass

    # --- status -------------------------------------------------------------------------------
    def warnings(self, clear: bool = False) -> list[str]:
        reply = self._command("warnings clear" if clear else "warnings")
        parts = reply.data.split()
        return parts[1:] if parts else []

    def status(self) -> dict[str, Any]:
        reply = self._command("")
        flags = self.warnings()
        pos = self._int(self._command("get pos"))
        return {
            "position_deg": pos / self.steps_per_deg,
            "homed": "WR" not in flags,
            "moving": reply.busy,
            "limit_hit": "WL" in flags,
            "stalled": "FS" in flags,
            "warnings": flags,
            "soft_limits_deg": (self.min_angle_deg, self.max_angle_deg),
            "errors": [f"{f}: {FLAGS.get(f, '?')}" for f in flags if f[0] in "FW"],
        }

    def is_homed(self) -> bool:
        return "WR" not in self.warnings()

    def is_moving(self) -> bool:
        return self._command("").busy

    def position_deg(self) -> float:
        return self._int(self._command("get pos")) / self.steps_per_deg

    def _readback_deg(self) -> float:
        return self._int(self._command("get encoder.pos")) / self.steps_per_deg

    # --- motion -------------------------------------------------------------------------------
    def _begin_move(self, angle_deg: float) -> None:
        self.warnings(clear=True)         # old NI / FS flags must not be read as this move's
        steps = round(angle_deg * self.steps_per_deg)
        self._command(f"move abs {steps}")
        self._expected_end_s = self.clock.now_s() + self.estimate_move_time_s(
            self._move_start_deg, angle_deg)

    def _begin_home(self) -> None:
        self.warnings(clear=True)
        self._command("home")
        self._expected_end_s = 0.0        # distance unknown until homed: poll from the start

    def _wait_done(self, timeout_s: float) -> None:
        deadline = self.clock.now_s() + timeout_s
        if self._expected_end_s > self.clock.now_s():
            self.clock.sleep(min(self._expected_end_s, deadline) - self.clock.now_s())
        while True:
            reply = self._command("")
            if not reply.busy:
                break
            if self.clock.now_s() >= deadline:
                raise InstrumentTimeout(f"still moving after {timeout_s:.1f} s",
                                        instrument=self.instrument_id)
            self.clock.sleep(self.poll_s)
        if reply.flag in ("FS", "FQ", "WL"):
            self.warnings(clear=True)
            self._commanded_deg = None
            raise DeviceError(reply.flag, FLAGS[reply.flag], instrument=self.instrument_id)

    def stop(self, profiled: bool = False) -> None:
        """Halt now (``estop``: the emergency stop and aborts), or with `profiled` the
        ``stop`` command, which decelerates at the axis's acceleration: wait until at rest."""
        self._command("stop" if profiled else "estop")
        self._commanded_deg = None
        self._expected_end_s = 0.0
        if not profiled:
            return
        deadline = self.clock.now_s() + self.command_timeout_s + \
            self.max_velocity_deg_s / self.acceleration_deg_s2
        while self._command("").busy:
            if self.clock.now_s() >= deadline:
                raise InstrumentTimeout("still moving after stop",
                                        instrument=self.instrument_id)
            self.clock.sleep(self.poll_s)


Zaber = ZaberRotationStage

__all__ = ["X_RSW60A_STEPS_PER_DEG", "Zaber", "ZaberRotationStage"]
