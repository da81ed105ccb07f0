"""JETI specbos 1211 spectroradiometer over its virtual COM port (pyserial).

References: [JETI-SB1211] in docs/references.md.  What the sources leave open is marked
*assumed* (docs/radiometers.md has the table).

Line: 921600 baud 8N1 without flow control (115200 / 38400 after ``*PARA:BAUD``); CR after
each command.  Answers: a query or fetch gives text lines ending in CR; a setting gives ACK
(0x06) or NAK (0x15); ``*INIT`` gives ACK, then BEL (0x07) when the measurement has ended
(NAK when it failed).  After a NAK, ``*STAT:ERR?`` → ``Error Code: <n>`` names the reason
(`DeviceError` with the instrument's number).

    *CONF:WRAN 380 780 1 / *CONF:AVER n / *CONF:EXPO 1 / *CONF:MAXTIN ms / *CONF:FORM 4
                           → ACK            the measurement's configuration (temporary: the
                                            driver writes it before every measurement)
    *INIT                  → ACK … BEL      measure
    *FETCH:SPRAD           → tint[ms]: t / wran: 380 780 1 / 401 values / empty line
    *FETCH:XYZ             → X: … / Y: … / Z: …   (CIE 1931 2°; Y = Lv in cd/m²)
    *IDN?                  → JETI_SB1211   (the sync query: no other answer looks like it)
    *BREAK                 → ACK            stop a running measurement (*assumed* command)

The specbos has no remote mode: `set_remote(True)` writes the configuration.  The data are
re-readable (a fetch does not empty the buffer), so every transfer is read until two reads
agree byte for byte and is then checked for plausibility (the instrument's own Lv and x, y
against the spectrum's), as for the Konica Minolta models (`radiometer_common`).  The
colorimetric block's Le, u′, v′, T and Δuv are computed here from the spectrum and X, Y, Z
(the instrument is not asked for them).

Timing model for ETAs (*assumed*, identical to the emulator's; docs/radiometers.md):
adaptive integration time t = clamp(20 cd·s/m² / Lv, 1 ms, MAXTIN) after an adaptation of
1 s; averages × 2·t (light + dark) + 0.2 s; plus the commands and the data transfer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    ConfigError,
    DeviceError,
    ImplausibleData,
    InstrumentError,
    InstrumentTimeout,
    ProtocolError,
)
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import SpectralReading
from normbox_lab.drivers.radiometer_common import (
    TRANSFER_READS,
    LinkLost,
    SerialRadiometer,
    Transfer,
    check_spectrum,
    colorimetry_from,
    implausibility,
)

ACK, NAK, BEL = b"\x06", b"\x15", b"\x07"
CONTROL_BYTES = (ACK, NAK, BEL)
BAUD_RATES = (921600, 115200, 38400)
SPEEDS = ("normal", "fast")
#: the adaptive time's cap in "fast" (s): what a display-measuring client uses
FAST_MAX_INTEGRATION_S = 5.0
WAVELENGTH_RANGE = (380, 780, 1)
K_AUTO_CD_S_M2 = 20.0
ADAPT_S = 1.0
OVERHEAD_S = 0.2
COMMAND_DELAY_S = 0.01
#: error codes the instrument names after a NAK (its firmware's numbers)
ERRORS = {
    4: "unknown command, or refused while measuring",
    7: "password",
    8: "digit",
    10: "argument 1", 11: "argument 2", 12: "argument 3", 13: "argument 4",
    20: "parameter argument", 21: "configuration argument", 22: "control argument",
    24: "fetch argument", 25: "measuring argument",
    120: "overexposure", 121: "underexposure", 123: "adaptation of the integration time",
    131: "no dark measurement", 138: "no light measurement (no data)",
    147: "scan break (measurement stopped)", 170: "write parameter to flash",
    171: "read parameter from flash",
}
NO_DATA = 138


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: empty line, *IDN?, *PARA:SERNO?, *VERS?)."""
    if len(replies) < 4:
        return None
    name, serial, firmware = (r.rstrip(b"\r") for r in replies[1:4])
    if not name.startswith(b"JETI_SB") or not serial.startswith(b"serial number:"):
        return None
    try:
        return InstrumentIdentity("spectroradiometer", f"specbos {name[7:].decode('ascii')}",
                                  serial_number=serial[14:].decode("ascii").strip(),
                                  firmware=firmware.decode("ascii").strip())
    except UnicodeDecodeError:
        return None


def integration_time_s(luminance_cd_m2: float, max_integration_time_s: float = 60.0) -> float:
    """The adaptive integration time t (s)."""
    return min(max_integration_time_s, max(0.001, K_AUTO_CD_S_M2 / max(luminance_cd_m2, 1e-6)))


def colorimetry_values(spectrum: np.ndarray, X: float, Y: float, Z: float) -> list[float]:
    """The 11-value block (Le, Lv, X, Y, Z, x, y, u′, v′, T, Δuv) from the instrument's
    X, Y, Z and its spectrum (Le; T and Δuv by Ohno 2013 from colour-science)."""
    le = float(np.nansum(spectrum))
    s, d = X + Y + Z, X + 15 * Y + 3 * Z
    if s <= 0 or d <= 0:
        return [le, Y, X, Y, Z] + [math.nan] * 6
    up, vp = 4 * X / d, 9 * Y / d
    import colour

    try:
        T, duv = (float(v) for v in colour.temperature.uv_to_CCT_Ohno2013(
            np.array([up, vp * 2.0 / 3.0])))
    except (ValueError, ArithmeticError):
        T, duv = math.nan, math.nan
    if not (1000.0 <= T <= 99999.0 and abs(duv) <= 0.1):
        T, duv = math.nan, math.nan
    return [le, Y, X, Y, Z, X / s, Y / s, up, vp, T, duv]


class Specbos1211(SerialRadiometer):
    model = "specbos 1211"
    terminator = b"\r"
    sync_command = b"*IDN?"

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "radiometer",
                 baud: int = 921600, averages: int = 1, max_integration_time_s: float = 60.0,
                 **options: Any) -> None:
        super().__init__(port, clock, instrument_id=instrument_id, **options)
        if not 1 <= int(averages) <= 100:
            raise ConfigError("<driver options>", 0, "averages", "must be 1–100")
        if not 1.0 <= float(max_integration_time_s) <= 60.0:
            raise ConfigError("<driver options>", 0, "max_integration_time_s",
                              "must be 1–60 s")
        self.baud = int(baud)
        self.averages = int(averages)
        self.max_integration_time_s = float(max_integration_time_s)
        self.speed = "normal"
        self._identity: InstrumentIdentity | None = None

    @classmethod
    def open(cls, url: str, clock: Clock, *, baud: int = 921600, instrument_id: str = "radiometer",
             averages: int = 1, max_integration_time_s: float = 60.0,
             command_timeout_s: float = 5.0, attempts: int = 3,
             reconnect_timeout_s: float = 10.0) -> Specbos1211:
        """Open `url` (a device path, socket://, sim://specbos1211?…) at 8N1 without flow
        control."""
        if int(baud) not in BAUD_RATES:
            raise ConfigError("<driver options>", 0, "baud",
                              f"specbos 1211 baud must be one of {BAUD_RATES}, not {baud}")
        port = transport.open_port(url, baudrate=int(baud), bytesize=8, parity="N", stopbits=1,
                                   rtscts=False, timeout=1.0, instrument_id=instrument_id)
        return cls(port, clock, instrument_id=instrument_id, baud=int(baud), averages=averages,
                   max_integration_time_s=max_integration_time_s,
                   command_timeout_s=command_timeout_s, attempts=attempts,
                   reconnect_timeout_s=reconnect_timeout_s)

    # --- reading one answer -------------------------------------------------------------------
    def _read_line(self, timeout_s: float, *, watch_abort: bool = False) -> bytes | None:
        """One answer: a single ACK / NAK / BEL byte, or a line without its CR.  Where the
        outstanding command answers with a byte (a setting, *INIT), anything else is returned
        as it came once the line has been quiet for `resync_quiet_s` (the caller refuses it)."""
        deadline = self.clock.now_s() + timeout_s
        text_reply = _answers_text(self._outstanding)
        buf = bytearray()
        while True:
            if watch_abort and not buf and self._abort.is_set():
                return None
            remaining = deadline - self.clock.now_s()
            if remaining <= 1e-9:
                if buf and not text_reply:
                    return bytes(buf)
                if buf:
                    raise self._protocol("reply cut short (no CR)", bytes(buf))
                raise self._timeout(f"no reply within {timeout_s:g} s")
            try:
                self.port.timeout = min(remaining, self.poll_s)
                if buf:
                    buf += self.port.read_until(b"\r")
                else:
                    first = self.port.read(1)
                    if not first:
                        continue
                    if first in CONTROL_BYTES or first == b"\r":
                        return first if first != b"\r" else b""
                    buf += first
                    if not text_reply:
                        deadline = min(deadline, self.clock.now_s() + self.resync_quiet_s)
                    continue
            except (SerialException, OSError) as exc:
                raise LinkLost(f"read failed: {exc}", instrument=self.instrument_id) from exc
            if buf.endswith(b"\r"):
                return bytes(buf[:-1])

    def _enter_remote(self) -> None:
        """After a reconnect: the instrument answers *IDN? (it has no remote mode)."""
        reply = self.exchange(b"*IDN?")
        if not self.is_sync_reply(reply):
            raise self._protocol("*IDN?: expected JETI_SB…", reply)

    def is_sync_reply(self, raw: bytes) -> bool:
        """*IDN?'s ``JETI_SB…``: no other answer starts so."""
        return raw.startswith(b"JETI_SB")

    # --- commands -------------------------------------------------------------------------------
    def _device_error(self) -> DeviceError:
        """After a NAK: ask why (``*STAT:ERR?``)."""
        text = self._text(self.exchange(b"*STAT:ERR?"), "Error Code:")
        code = self.parse_int(text, text.encode(), 0, 999)
        return DeviceError(code, ERRORS.get(code, "unknown error code"),
                           instrument=self.instrument_id)

    def _text(self, raw: bytes, prefix: str) -> str:
        if raw == NAK:
            raise self._device_error()
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            raise self._protocol("reply is not ASCII", raw) from None
        if not text.startswith(prefix):
            raise self._protocol(f"expected {prefix!r}", raw)
        return text[len(prefix):].strip()

    def setting(self, cmd: str) -> None:
        """A command answered ACK (NAK → `DeviceError`); transport faults are retried."""
        def once() -> None:
            reply = self.exchange(cmd.encode("ascii"))
            if reply == NAK:
                raise self._device_error()
            if reply != ACK:
                raise self._protocol(f"{cmd}: expected ACK or NAK", reply)

        self.with_retries(once)

    def query(self, cmd: str, prefix: str = "") -> str:
        """A one-line query: the text after `prefix` (NAK → `DeviceError`)."""
        return str(self.with_retries(lambda: self._text(self.exchange(cmd.encode("ascii")),
                                                        prefix)))

    # --- the Spectroradiometer role ---------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        if self._identity is None:
            name = self.query("*IDN?", "JETI_SB")
            serial = self.query("*PARA:SERNO?", "serial number:")
            firmware = self.query("*VERS?")
            url = str(getattr(self.port, "port", "") or "")
            self._identity = InstrumentIdentity(
                "spectroradiometer", f"specbos {name}", serial_number=serial, firmware=firmware,
                simulated=url.startswith("sim://"), extra={"port": url, "baud": str(self.baud)})
        return self._identity

    def set_remote(self, on: bool) -> None:
        """The specbos has no local mode: on → write the measurement configuration."""
        if on:
            self._configure()
        self.remote = bool(on)

    def set_speed(self, mode: str) -> None:
        """"normal" (adaptive time up to `max_integration_time_s`) or "fast" (up to 5 s)."""
        if mode not in SPEEDS:
            raise ConfigError("<driver call>", 0, "speed", f"must be one of {', '.join(SPEEDS)}")
        self.speed = mode

    def _max_tint_s(self) -> float:
        return min(self.max_integration_time_s, FAST_MAX_INTEGRATION_S) \
            if self.speed == "fast" else self.max_integration_time_s

    def _configure(self) -> None:
        b, e, s = WAVELENGTH_RANGE
        for cmd in (f"*CONF:WRAN {b} {e} {s}", f"*CONF:AVER {self.averages}", "*CONF:EXPO 1",
                    f"*CONF:MAXTIN {round(self._max_tint_s() * 1000)}", "*CONF:FORM 4"):
            self.setting(cmd)

    def status(self) -> dict[str, object]:
        laser = self.query("*CONTR:LASER?", "laser:")
        return {"model": self.model, "remote": self.remote, "speed": self.speed,
                "averages": self.averages, "max_integration_time_s": self._max_tint_s(),
                "laser": laser == "1"}

    def estimate_measure_time_s(self, luminance_cd_m2: float) -> float:
        """Configuration + adaptation + averages × 2·t + overhead + the transfer (read twice)."""
        t = integration_time_s(luminance_cd_m2, self._max_tint_s())
        block_bytes = 20 + 16 + 401 * 12 + 1 + 45
        n_bytes = 5 * 22 + 8 + TRANSFER_READS * (26 + block_bytes)
        exchanges = 5 + 1 + TRANSFER_READS * 2
        return ADAPT_S + self.averages * 2 * t + OVERHEAD_S + n_bytes * 10.0 / self.baud \
            + exchanges * COMMAND_DELAY_S

    def abort(self) -> None:
        """Stop a running measurement (from any thread); idle → *BREAK anyway (harmless)."""
        if self.request_abort():
            return
        with self._lock:
            try:
                self.setting("*BREAK")
            except DeviceError:
                pass

    def _cancel_quietly(self) -> None:
        try:
            self._resync()
            self.exchange(b"*BREAK", timeout_s=3.0)
        except (InstrumentError, SerialException, OSError):
            pass
        self._resync()

    def recover(self) -> None:
        """Engine hook after a fault: drain, stop whatever runs, write the configuration."""
        with self._lock:
            self._cancel_quietly()
            self._configure()
            self.remote = True

    def close(self) -> None:
        try:
            self.port.close()
        except (SerialException, OSError):
            pass

    # --- measuring ---------------------------------------------------------------------------------
    def measure(self) -> SpectralReading:
        """Configure, trigger, then transfer.  Transport faults are retried (bounded); a lost
        buffer (error 138) measures again; every block is read until two reads agree; an
        implausible transfer is read again, then refused."""
        with self._lock:
            self._measuring = True
            self._abort.clear()
            try:
                for attempt in range(1, self.attempts + 1):
                    try:
                        return self._measure_once()
                    except DeviceError as exc:
                        if exc.code != NO_DATA or attempt == self.attempts:
                            raise
                raise AssertionError("unreachable")
            finally:
                self._measuring = False

    def _measure_once(self) -> SpectralReading:
        self._configure()
        self.remote = True
        self.with_retries(self._run_measurement)
        data = self._checked_transfer()
        return SpectralReading(RADIOMETER_WAVELENGTHS_NM.copy(), data.spectrum,
                               colorimetry_from(data.colorimetry_values),
                               data.extra["integration_time_s"], self.clock.wall_time_s(),
                               self.instrument_id,
                               {"model": self.model, "speed": self.speed,
                                "averages": self.averages})

    def _run_measurement(self) -> None:
        """*INIT: ACK, then BEL when the measurement has ended."""
        try:
            self._write(b"*INIT")
            first = self.read_reply(self.command_timeout_s)
            if first == NAK:
                raise self._device_error()
            if first != ACK:
                raise self._protocol("*INIT: expected ACK", first or b"")
            wait_s = ADAPT_S + self.averages * 2 * self._max_tint_s() * 1.2 + OVERHEAD_S + 10.0
            final = self.read_reply(wait_s, watch_abort=True)
            if final is None:                            # abort() from another thread
                self._cancel_quietly()
                raise self._aborted()
            if final == NAK:
                raise self._device_error()
            if final != BEL:
                raise self._protocol("*INIT: expected BEL at the end", final)
        except (InstrumentTimeout, ProtocolError):
            self._cancel_quietly()       # the instrument may still be measuring
            raise

    def _checked_transfer(self) -> Transfer:
        why = ""
        data: Transfer | None = None
        for _ in range(self.attempts):
            data = self._read_data()
            c = data.colorimetry_values
            why = implausibility(data.spectrum, c[1], c[5], c[6])
            if not why:
                return data
            self._count_line_fault()
        assert data is not None
        raise ImplausibleData(f"implausible data: {why}", raw=data.raw[:200],
                              instrument=self.instrument_id)

    def _read_data(self) -> Transfer:
        (spectral, raw_spectrum), (xyz, raw_xyz) = self.agreed_blocks(
            "specbos transfer", 2, self._transfer_pass)
        tint_s, values = spectral
        spectrum = check_spectrum(values, raw_spectrum, self.instrument_id)
        return Transfer(spectrum, colorimetry_values(spectrum, *xyz),
                        {"integration_time_s": tint_s}, raw=raw_spectrum + b"\r" + raw_xyz)

    def _transfer_pass(self, pending: list[int], got: Callable[[int, Any, bytes], None]) -> None:
        if 0 in pending:
            lines = self._fetch(b"*FETCH:SPRAD", 2 + 401 + 1)
            got(0, self._parse_spectrum(lines), b"\r".join(lines))
        if 1 in pending:
            lines = self._fetch(b"*FETCH:XYZ", 3)
            got(1, self._parse_xyz(lines), b"\r".join(lines))

    def _fetch(self, cmd: bytes, n_lines: int) -> list[bytes]:
        self._write(cmd)
        lines: list[bytes] = []
        for _ in range(n_lines):
            line = self.read_reply(self.command_timeout_s)
            assert line is not None
            if line == NAK:
                raise self._device_error()
            lines.append(line)
        self.history = (self.history + [(cmd, lines[0])])[-50:]
        return lines

    def _parse_spectrum(self, lines: list[bytes]) -> tuple[float, list[float]]:
        raw = b"\r".join(lines)
        head = [self._text(line, prefix) for line, prefix in
                zip(lines[:2], ("tint[ms]:", "wran:"), strict=True)]
        tint_ms = self.parse_number(head[0], raw)
        if not 0 < tint_ms <= 60_000 * 100:
            raise self._protocol("integration time out of range", lines[0])
        if head[1].split() != [str(v) for v in WAVELENGTH_RANGE]:
            raise self._protocol("the wavelength range is not the configured one", lines[1])
        if lines[-1] != b"":
            raise self._protocol("spectral block does not end in an empty line", lines[-1])
        values = []
        for wl, line in zip(RADIOMETER_WAVELENGTHS_NM, lines[2:-1], strict=True):
            text = line.decode("ascii", errors="replace")
            fields = text.split("\t")
            if len(fields) == 2:                 # "<nm><TAB><value>" (formats 7 and 10)
                if self.parse_number(fields[0], line) != wl:
                    raise self._protocol(f"wavelength {fields[0]!r} where {wl:g} belongs", line)
            elif len(fields) != 1:
                raise self._protocol("spectral line is neither a value nor nm<TAB>value", line)
            values.append(self.parse_number(fields[-1], line))
        return tint_ms / 1000.0, values

    def _parse_xyz(self, lines: list[bytes]) -> tuple[float, float, float]:
        raw = b"\r".join(lines)
        X, Y, Z = (self.parse_number(self._text(line, prefix), raw)
                   for line, prefix in zip(lines, ("X:", "Y:", "Z:"), strict=True))
        return X, Y, Z


def _answers_text(cmd: bytes) -> bool:
    """Queries and fetches answer with text lines; settings and *INIT with one byte."""
    return cmd.endswith(b"?") or cmd.upper().startswith(b"*FETCH")


__all__ = ["BAUD_RATES", "ERRORS", "Specbos1211", "colorimetry_values", "integration_time_s",
           "parse_identification"]
