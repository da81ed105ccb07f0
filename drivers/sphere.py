"""Integrating-sphere light source (Image Engineering LE7-4x) — PLACEHOLDER protocol driver.

Image Engineering publish no remote-control protocol for the LE7 ([LE7] in docs/references.md).
This driver speaks a SCPI-like command set of our own ([SCPI]) — invented names,
implemented by the emulator in sim/sphere.py — so that the lab, the protocols and the tests run
end to end.  When the vendor document (or DLL / TCP service) arrives, write the real adapter as
another class with the same public methods; nothing above this module changes.

Line: ASCII, LF-terminated commands, one reply line per command (``OK``, a value, or
``ERR <code>``, after which the driver drains ``SYST:ERR?`` and raises `DeviceError`).

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

from typing import Any

import numpy as np
from serial import SerialException

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    NotReady,
    ProtocolError,
)
from normbox_lab.core.interfaces import InstrumentIdentity

STATES = ("off", "settling", "stable", "error")


class SphereLightSource:
    model = "LE7-4x (placeholder protocol)"

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "sphere",
                 command_timeout_s: float = 2.0, poll_s: float = 5.0) -> None:
        self.port = port
        self.clock = clock
        self.instrument_id = instrument_id
        self.command_timeout_s = float(command_timeout_s)
        self.poll_s = float(poll_s)
        self._idn = ""

    @classmethod
    def open(cls, url: str, clock: Clock, **options: Any) -> SphereLightSource:
        from normbox_lab.sim.transport import open_port

        port = open_port(url, baudrate=115200, bytesize=8, parity="N", stopbits=1, timeout=0.05)
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
        """Send one command, return its reply line(s); ``ERR <code>`` → DeviceError."""
        try:
            self.port.write(command.encode("ascii") + b"\n")
            first = self._readline()
            if first.startswith(b"ERR"):
                code = first[3:].strip().decode("ascii", "replace")
                meanings = self._drain_errors()
                raise DeviceError(code, "; ".join(meanings) or "command refused",
                                  instrument=self.instrument_id)
            out = [first.decode("ascii", "replace")]
            for _ in range(lines - 1):
                out.append(self._readline().decode("ascii", "replace"))
            return out
        except (SerialException, OSError) as exc:
            raise InstrumentError(f"link lost: {exc}", instrument=self.instrument_id) from exc

    def _ask(self, command: str) -> str:
        return self.query(command)[0]

    def _command(self, command: str) -> None:
        reply = self._ask(command)
        if reply != "OK":
            raise ProtocolError(f"expected OK to {command!r}", raw=reply.encode(),
                                instrument=self.instrument_id)

    def _number(self, command: str) -> float:
        reply = self._ask(command)
        try:
            return float(reply)
        except ValueError:
            raise ProtocolError(f"expected a number to {command!r}", raw=reply.encode(),
                                instrument=self.instrument_id) from None

    def _drain_errors(self) -> list[str]:
        out = []
        for _ in range(12):
            self.port.write(b"SYST:ERR?\n")
            line = self._readline().decode("ascii", "replace")
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
        try:
            start, step, count = (float(x) for x in header.split(",")[:3])
            rel = np.array([float(v) for v in values.split(",")])
        except ValueError:
            raise ProtocolError("bad spectrum block", raw=(header + values).encode(),
                                instrument=self.instrument_id) from None
        if rel.size != int(count):
            raise ProtocolError(f"spectrum has {rel.size} values, header says {int(count)}",
                                raw=header.encode(), instrument=self.instrument_id)
        return start + step * np.arange(rel.size), rel

    def luminance_cd_m2(self) -> float:
        return self._number("MEAS:LUM?")

    def panel_map(self) -> np.ndarray:
        reply = self._ask("PANEL:MAP?")
        try:
            values = np.array([float(v) for v in reply.split(",")])
        except ValueError:
            raise ProtocolError("bad panel map", raw=reply.encode(),
                                instrument=self.instrument_id) from None
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
