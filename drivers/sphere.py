"""Integrating-sphere light source (Image Engineering LE7-4x) — PLACEHOLDER protocol driver.

Image Engineering publish no remote-control protocol for the LE7 ([LE7] in docs/references.md).
This driver speaks a SCPI-like command set of our own ([SCPI]) — invented names,
implemented by the emulator in sim/sphere.py — so that the lab, the protocols and the tests run
end to end.  When the vendor document (or DLL / TCP service) arrives, write the real adapter as
another class with the same public methods; nothing above this module changes.

Line: ASCII, LF-terminated commands, one reply line per command (``OK``, a value, or
``ERR <code>``, after which the driver drains ``SYST:ERR?`` and raises `DeviceError`).
A lamp in its ``ERROR`` state (STAT?) is `DeviceError("LAMP")`, never an ``ERR`` reply.

Resynchronisation: the line has no message numbers, so after a timeout the driver drains the
line until it is quiet, then re-handshakes (``*IDN?``, discarding every line until the
identification comes back) before it trusts the line again; every command is idempotent, so
it is then repeated (bounded by `attempts`).  Replies are validated (ASCII, finite numbers,
value counts, increasing wavelengths); anything else is `ProtocolError` with the bytes.

    identify()                 *IDN?
    set_output(on)             OUTP ON | OUTP OFF
    set_level_percent(p)       INT <p>
    set_spectrum_preset(name)  SPEC:PRES <name>
    state()                    STAT?  → "off" | "settling" | "stable" ("error" → DeviceError)
    wait_stable(timeout_s)     STAT? polled every `poll_s` on the clock; NotReady on timeout
    estimate_settle_time_s()   STAB:REM?
    internal_spectrum()        MEAS:SPEC?  (header start,step,count,unit + CSV values)
    luminance_cd_m2()          MEAS:LUM?
    panel_map()                PANEL:MAP?       → (5, 5) relative radiance, mean 1
    radiance_factor(r, c)      PANEL:MAP? r,c   → one of the 25 points
    errors()                   SYST:ERR? until 0,"No error"
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np
from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    NotReady,
    ProtocolError,
)

STATES = ("off", "settling", "stable", "error")


class _LinkDown(InstrumentError):
    """The port went away; internal: the query reopens it and repeats."""


ERR_REPLY = re.compile(rb"^ERR[ \t]+([+-]?\d{1,6})$")
#: a drain after a lost reply stops after this long even if bytes keep coming
RESYNC_MAX_S = 5.0


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: blank line, ``*IDN?``): the placeholder
    protocol's ``vendor,model,serial,firmware`` with an LE7 model."""
    if len(replies) < 2:
        return None
    parts = replies[1].decode("ascii", "replace").split(",")
    if len(parts) != 4 or not parts[1].startswith("LE7"):
        return None
    return InstrumentIdentity("light-source", parts[1], parts[2], parts[3],
                              extra={"vendor": parts[0]})


class SphereLightSource:
    model = "LE7-4x (placeholder protocol)"

    def __init__(self, port: transport.Port, clock: Clock, *, instrument_id: str = "sphere",
                 command_timeout_s: float = 2.0, poll_s: float = 5.0, attempts: int = 3,
                 resync_quiet_s: float = 0.5, reconnect_wait_s: float = 2.0) -> None:
        self.port = port
        self.clock = clock
        self.instrument_id = instrument_id
        self.command_timeout_s = float(command_timeout_s)
        self.poll_s = float(poll_s)
        self.attempts = max(1, int(attempts))
        self.resync_quiet_s = float(resync_quiet_s)
        self.reconnect_wait_s = float(reconnect_wait_s)
        self._idn = ""
        #: timeouts seen since opening (each followed by a drain and a re-handshake)
        self.line_faults = 0

    @classmethod
    def open(cls, url: str, clock: Clock, **options: Any) -> SphereLightSource:
        port = transport.open_port(url, baudrate=115200, bytesize=8, parity="N", stopbits=1,
                                   timeout=0.05,
                                   instrument_id=str(options.get("instrument_id", "")))
        return cls(port, clock, **options)

    # --- lines --------------------------------------------------------------------------------
    def _readline(self) -> bytes:
        deadline = self.clock.now_s() + self.command_timeout_s
        buf = bytearray()
        while True:
            now = self.clock.now_s()
            chunk = self.port.read_until(b"\n")
            buf += chunk
            if buf.endswith(b"\n"):
                return bytes(buf).rstrip(b"\r\n")
            if self.clock.now_s() >= deadline:
                raise InstrumentTimeout(f"no reply (got {bytes(buf)!r})",
                                        instrument=self.instrument_id)
            if not chunk and self.clock.now_s() == now:
                self.clock.sleep(min(0.01, deadline - now))

    def query(self, command: str, lines: int = 1) -> list[str]:
        """Send one command, return its reply line(s); ``ERR <code>`` → DeviceError.  A
        timeout drains the line, re-handshakes and repeats the command (bounded)."""
        last: InstrumentError | None = None
        for _ in range(self.attempts):
            try:
                return self._query_once(command, lines)
            except InstrumentTimeout as exc:
                last = exc
                self.line_faults += 1
                self._resync()
            except _LinkDown as exc:
                last = exc
                self.line_faults += 1
                self._reopen()
        assert last is not None
        raise last

    def _reopen(self) -> None:
        """The link dropped (USB blip): wait, reopen the port (bounded: `reconnect_wait_s`
        more, then a typed error; the repeated command finds out whether the line is back)."""
        transport.recover_link(self.clock, self.reconnect_wait_s,
                               lambda: transport.reopen(self.port),
                               retry_on=(SerialException, OSError),
                               instrument_id=self.instrument_id,
                               first_wait_s=self.reconnect_wait_s)

    def _decode(self, raw: bytes) -> str:
        try:
            return raw.decode("ascii")
        except UnicodeDecodeError:
            raise ProtocolError("reply is not ASCII", raw=raw,
                                instrument=self.instrument_id) from None

    def _query_once(self, command: str, lines: int) -> list[str]:
        try:
            self.port.reset_input_buffer()
            self.port.write(command.encode("ascii") + b"\n")
            first = self._readline()
            m = ERR_REPLY.match(first)
            if m is not None:
                code = m.group(1).decode("ascii")
                meanings = self._drain_errors()
                raise DeviceError(code, "; ".join(meanings) or "command refused",
                                  instrument=self.instrument_id)
            out = [self._decode(first)]
            for _ in range(lines - 1):
                out.append(self._decode(self._readline()))
            return out
        except (SerialException, OSError) as exc:
            raise _LinkDown(f"link lost: {exc}", instrument=self.instrument_id) from exc

    def _resync(self) -> None:
        """Drain until quiet, then ``*IDN?`` until the identification comes back (lines
        before it are late replies to earlier commands)."""
        try:
            deadline_s = self.clock.now_s() + RESYNC_MAX_S
            while self.clock.now_s() < deadline_s:      # bytes that never stop: bounded
                self.port.timeout = self.resync_quiet_s
                if not self.port.read(65536):
                    break
            self.port.reset_input_buffer()
            self.port.write(b"*IDN?\n")
            for _ in range(8):
                line = self._readline()
                if line.startswith(b"ERR") or (self._idn and line.decode("ascii", "replace")
                                               != self._idn):
                    continue
                return
        except (InstrumentError, SerialException, OSError):
            return          # the repeated command finds out whether the line is back

    def _ask(self, command: str) -> str:
        return self.query(command)[0]

    def _command(self, command: str) -> None:
        reply = self._ask(command)
        if reply != "OK":
            raise ProtocolError(f"expected OK to {command!r}", raw=reply.encode(),
                                instrument=self.instrument_id)

    def _number(self, command: str) -> float:
        return self._finite(self._ask(command), f"expected a number to {command!r}")

    def _finite(self, text: str, what: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise ProtocolError(what, raw=text.encode(), instrument=self.instrument_id) from None
        if not math.isfinite(value):
            raise ProtocolError(f"{what} (not finite)", raw=text.encode(),
                                instrument=self.instrument_id)
        return value

    def _drain_errors(self) -> list[str]:
        out = []
        for _ in range(12):
            self.port.write(b"SYST:ERR?\n")
            line = self._decode(self._readline())
            code, _, text = line.partition(",")
            if code.strip() in ("0", "+0"):
                break
            out.append(f"{code.strip()} {text.strip().strip(chr(34))}")
        return out

    # --- the LightSource role ------------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        self._idn = self._ask("*IDN?")
        parts = [p.strip() for p in self._idn.split(",")] + ["", "", "", ""]
        return InstrumentIdentity("light-source", parts[1] or self.model, parts[2], parts[3],
                                  extra={"vendor": parts[0], "protocol": "placeholder-scpi"})

    def reset(self) -> None:
        self._command("*RST")

    def set_output(self, on: bool) -> None:
        self._command("OUTP ON" if on else "OUTP OFF")

    def output(self) -> bool:
        return self._ask("OUTP?") == "1"

    def set_level_percent(self, level_percent: float) -> None:
        self._command(f"INT {float(level_percent):.2f}")

    def level_percent(self) -> float:
        return self._number("INT?")

    def set_spectrum_preset(self, name: str) -> None:
        self._command(f"SPEC:PRES {name}")

    def state(self) -> str:
        reply = self._ask("STAT?").lower()
        if reply not in STATES:
            raise ProtocolError("unknown state", raw=reply.encode(), instrument=self.instrument_id)
        if reply == "error":
            problems = self._drain_errors()
            raise DeviceError("LAMP", "; ".join(problems) or "light source in error state",
                              instrument=self.instrument_id)
        return reply

    def is_stable(self) -> bool:
        return self.state() == "stable"

    def stable_for_s(self) -> float:
        return self._number("STAB:TIME?")

    def estimate_settle_time_s(self) -> float:
        return self._number("STAB:REM?")

    def wait_stable(self, timeout_s: float, min_stable_s: float = 0.0) -> None:
        """Poll until stable (for at least `min_stable_s`); NotReady after `timeout_s`."""
        deadline = self.clock.now_s() + float(timeout_s)
        while True:
            st = self.state()
            if st == "off":
                raise NotReady("light source is off", instrument=self.instrument_id)
            if st == "stable" and self.stable_for_s() >= min_stable_s:
                return
            if self.clock.now_s() >= deadline:
                raise NotReady(f"not stable after {timeout_s:g} s (state {st})",
                               instrument=self.instrument_id)
            self.clock.sleep(min(self.poll_s, max(0.0, deadline - self.clock.now_s())) or
                             self.poll_s)

    def internal_spectrum(self) -> tuple[np.ndarray, np.ndarray]:
        header, values = self.query("MEAS:SPEC?", lines=2)
        raw = (header + "\n" + values).encode()
        head = header.split(",")
        if len(head) < 3:
            raise ProtocolError("bad spectrum header", raw=raw, instrument=self.instrument_id)
        start, step, count = (self._finite(x, "bad spectrum header") for x in head[:3])
        rel = np.array([self._finite(v, "bad spectrum value") for v in values.split(",")])
        if not step > 0 or count != int(count) or rel.size != int(count):
            raise ProtocolError(f"spectrum has {rel.size} values, header says {count:g} "
                                f"(step {step:g} nm must be positive)", raw=raw,
                                instrument=self.instrument_id)
        return start + step * np.arange(rel.size), rel

    def luminance_cd_m2(self) -> float:
        return self._number("MEAS:LUM?")

    def panel_map(self) -> np.ndarray:
        reply = self._ask("PANEL:MAP?")
        values = np.array([self._finite(v, "bad panel map") for v in reply.split(",")])
        if values.size != 25:
            raise ProtocolError(f"panel map has {values.size} points, not 25",
                                raw=reply.encode(), instrument=self.instrument_id)
        return values.reshape(5, 5)

    def radiance_factor(self, row: int, column: int) -> float:
        """Relative radiance of the opal panel at grid point (row, column), 0-based."""
        return self._number(f"PANEL:MAP? {int(row)},{int(column)}")

    def errors(self) -> list[str]:
        try:
            return self._drain_errors()
        except (SerialException, OSError) as exc:
            raise InstrumentError(f"link lost: {exc}", instrument=self.instrument_id) from exc

    def status(self) -> dict[str, Any]:
        return {
            "state": self._ask("STAT?").lower(),
            "output": self.output(),
            "level_percent": self.level_percent(),
            "preset": self._ask("SPEC:PRES?"),
            "stable_for_s": self.stable_for_s(),
            "settle_remaining_s": self.estimate_settle_time_s(),
            "temperature_c": self._number("TEMP?"),
            "lamp_hours": self._number("HOUR?"),
        }

    def abort(self) -> None:
        self._command("ABOR")

    def close(self) -> None:
        try:
            self.port.close()
        except (SerialException, OSError):
            pass


Sphere = SphereLightSource

__all__ = ["Sphere", "SphereLightSource"]
