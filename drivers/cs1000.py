"""Konica Minolta CS-1000 / CS-1000A spectroradiometer over RS-232C (pyserial).

References: [KM-CS1000] in docs/references.md.  No official
CS-1000 communication document is public: the command set below is what three independent
drivers agree on; what is *assumed* is said so (docs/radiometers.md has the full table).

Line: 8N1, no flow control, 4800/9600/19200 baud (must match the instrument), LF after each
command, replies read up to LF (a CR before it is dropped).

    RMT,1 / RMT,0        → OK                      remote mode on / off
    MES,1                → OK,<t>   (after the pre-measurement, ≤ ~10 s; t = integration s)
                         → OK       (≈ 2·t later, end of the measurement)
    MES,0                → OK                      cancel
    MMS,<m>,<t>          → OK                      time mode (0 auto, 1 multi t %.2f, 2 auto
                                                   long, 3 manual t %.3f in 0.04–60 s)
    SPS,<0|1> / SPR      → OK / OK,<s>             speed normal / fast
    STR                  → OK,<time mode>,<speed>,<manual time>   (layout assumed)
    BDR,<k>,<o>,<f>      → OK                      select data (k 0 spectral / 1 colorimetric,
                                                   o 0 = 2° / 1 = 10°, f 0 ASCII / 1 binary)
    &                    → next block: colorimetry 1 line of 11 values (Le, Lv, X, Y, Z, x, y,
                           u′, v′, T, Δuv); spectrum 15 lines of ≤ 28 values (401, 380–780 nm);
                           binary spectrum (unconfirmed): 7 blocks of little-endian float32,
                           6 × 60 + 41, no terminator
    ERnn                 → `DeviceError` (codes as the CS-2000's; *unconfirmed* for this model)

While measuring the instrument refuses everything but MES,0.  Replies that are neither ``OK…``
nor ``ERnn`` raise `ProtocolError` with the raw bytes.

Timing model for ETAs (assumed, identical to the emulator's; docs/radiometers.md):
pre-measurement clamp(1 + 2·log10(100/Lv), 1, 10) s; integration t = clamp(K/Lv, 0.05, 60) s
(K = 100 normal, 25 fast; or the manual/multi time); main phase 2·t; plus the data transfer
at 10 bits per byte.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from typing import Any

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    ConfigError,
    DeviceError,
    InstrumentTimeout,
    ProtocolError,
)
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import SpectralReading
from normbox_lab.drivers.radiometer_common import (
    TRANSFER_READS,
    KonicaMinoltaRadiometer,
    Transfer,
    check_spectrum,
    colorimetry_from,
    pre_measurement_s,
)

BAUD_RATES = (4800, 9600, 19200)
SPEEDS = {"normal": 0, "fast": 1}
TIME_MODES = {"auto": 0, "multi": 1, "auto-long": 2, "manual": 3}
SPECTRAL_LINES = 15
SPECTRAL_LINE_VALUES = 28
BINARY_BLOCKS = (60, 60, 60, 60, 60, 60, 41)
FIRST_REPLY_TIMEOUT_S = 15.0        # pre-measurement is "about 1–10 s"
STR_REPLY = re.compile(rb"^OK,\d,\d,[0-9.]+$")

#: error codes (CS-2000 2008 texts; a VB CS-1000A driver uses the same list — unconfirmed)
ERRORS = {
    "ER00": "invalid command or parameters, not in remote mode, or command refused",
    "ER02": "measurement in progress (busy)",
    "ER05": "no compensation values",
    "ER10": "over measurement range",
    "ER17": "parameter out of range",
    "ER20": "no measurement data",
    "ER30": "memory error",
    "ER51": "CCD Peltier abnormality",
    "ER52": "temperature count abnormality",
    "ER71": "outside synchronisation range",
    "ER81": "shutter malfunction",
    "ER82": "internal ND filter malfunction",
    "ER83": "measurement angle abnormality",
    "ER99": "program abnormality",
}


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: blank line, RMT,1, STR, RMT,0): the
    CS-1000A has no identification command, so an ``OK`` to RMT,1 and STR's three-field
    status identify the model; serial number and firmware stay unknown."""
    if len(replies) < 3 or replies[1] != b"OK" or STR_REPLY.match(replies[2]) is None:
        return None
    return InstrumentIdentity("spectroradiometer", "CS-1000A",
                              extra={"note": "the CS-1000A has no identification command"})


def integration_time_s(luminance_cd_m2: float, speed: str = "normal", time_mode: str = "auto",
                       time_s: float = 1.0) -> float:
    if time_mode in ("multi", "manual"):
        return float(time_s)
    k = 25.0 if speed == "fast" else 100.0
    return min(60.0, max(0.05, k / max(float(luminance_cd_m2), 1e-6)))


class CS1000A(KonicaMinoltaRadiometer):
    model = "CS-1000A"
    ok_head = "OK"
    errors = ERRORS
    remote_prefix = "RMT,"
    cancel_command = "MES,0"
    sync_command = b"STR"

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "radiometer",
                 baud: int = 9600, data_format: str = "ascii", observer_deg: int = 2,
                 **options: Any) -> None:
        super().__init__(port, clock, instrument_id=instrument_id, **options)
        if data_format not in ("ascii", "binary"):
            raise ConfigError("<driver options>", 0, "data_format", "must be ascii or binary")
        if int(observer_deg) not in (2, 10):
            raise ConfigError("<driver options>", 0, "observer_deg", "must be 2 or 10")
        self.baud = int(baud)
        self.data_format = data_format
        self.observer_deg = int(observer_deg)
        self.speed = "normal"
        self.time_mode = "auto"
        self.time_s = 1.0

    @classmethod
    def open(cls, url: str, clock: Clock, *, baud: int = 9600, instrument_id: str = "radiometer",
             data_format: str = "ascii", observer_deg: int = 2, command_timeout_s: float = 10.0,
             attempts: int = 3, reconnect_timeout_s: float = 10.0) -> CS1000A:
        """Open `url` (a device path, socket://, sim://cs1000a?…) at 8N1 without flow control.
        Explicit keywords: any other option in the lab config is a ConfigError (lab.py)."""
        if int(baud) not in BAUD_RATES:
            raise ConfigError("<driver options>", 0, "baud",
                              f"CS-1000A baud must be one of {BAUD_RATES}, not {baud}")
        port = transport.open_port(url, baudrate=int(baud), bytesize=8, parity="N", stopbits=1,
                                   rtscts=False, timeout=1.0, instrument_id=instrument_id)
        return cls(port, clock, instrument_id=instrument_id, baud=int(baud),
                   data_format=data_format, observer_deg=observer_deg,
                   command_timeout_s=command_timeout_s, attempts=attempts,
                   reconnect_timeout_s=reconnect_timeout_s)

    # --- the Spectroradiometer role ---------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        url = str(self.port.port or "")
        return InstrumentIdentity("spectroradiometer", self.model, serial_number="",
                                  firmware="", simulated=url.startswith("sim://"),
                                  extra={"port": url, "baud": str(self.baud),
                                         "note": "the CS-1000A has no identification command"})

    def is_sync_reply(self, raw: bytes) -> bool:
        """STR's ``OK,<time mode>,<speed>,<time>``: no other command answers three fields."""
        return STR_REPLY.match(raw) is not None

    def _enter_remote(self) -> None:
        self.parse_reply(self.exchange(b"RMT,1"))
        self.remote = True

    def set_remote(self, on: bool) -> None:
        self._no_fields("RMT", self.command("RMT,1" if on else "RMT,0"))
        self.remote = bool(on)

    def set_speed(self, mode: str) -> None:
        """"normal" or "fast" (SPS)."""
        if mode not in SPEEDS:
            raise ConfigError("<driver call>", 0, "speed", f"must be one of {', '.join(SPEEDS)}")
        self._ensure_remote()
        self._no_fields("SPS", self.command(f"SPS,{SPEEDS[mode]}"))
        self.speed = mode

    def read_speed(self) -> str:
        def parse(fields: list[str]) -> str:
            if fields not in (["0"], ["1"]):
                raise self._protocol("SPR: expected OK,0 or OK,1",
                                     ",".join(["OK", *fields]).encode())
            return "fast" if fields == ["1"] else "normal"

        self._ensure_remote()
        return str(self.command("SPR", parse=parse))

    def set_time_mode(self, mode: str, time_s: float | None = None) -> None:
        """MMS: "auto", "auto-long", "multi" (time_s, %.2f) or "manual" (0.04–60 s, %.3f)."""
        if mode not in TIME_MODES:
            raise ConfigError("<driver call>", 0, "time_mode",
                              f"must be one of {', '.join(TIME_MODES)}")
        if mode == "manual" and (time_s is None or not 0.04 <= time_s <= 60.0):
            raise ConfigError("<driver call>", 0, "time_s", "manual time must be 0.04–60 s")
        if mode == "multi" and (time_s is None or not 1.0 <= time_s <= 60.0):
            raise ConfigError("<driver call>", 0, "time_s", "multi time must be 1–60 s")
        if mode == "multi":
            arg = f"{time_s:.2f}"
        elif mode == "manual":
            arg = f"{time_s:.3f}"
        else:
            arg = ""
        self._ensure_remote()
        self._no_fields("MMS", self.command(f"MMS,{TIME_MODES[mode]},{arg}"))
        self.time_mode = mode
        if time_s is not None:
            self.time_s = float(time_s)

    def status(self) -> dict[str, object]:
        def parse(fields: list[str]) -> dict[str, object]:
            raw = ",".join(["OK", *fields]).encode()
            if len(fields) < 3:
                raise self._protocol("STR: expected OK,<time mode>,<speed>,<time>", raw)
            modes = {str(v): k for k, v in TIME_MODES.items()}
            speeds = {str(v): k for k, v in SPEEDS.items()}
            if fields[0] not in modes or fields[1] not in speeds:
                raise self._protocol("STR: unknown time mode or speed", raw)
            return {"model": self.model, "remote": self.remote, "time_mode": modes[fields[0]],
                    "speed": speeds[fields[1]], "time_s": self.parse_number(fields[2], raw),
                    "raw": fields}

        self._ensure_remote()
        return dict(self.command("STR", parse=parse))

    def estimate_measure_time_s(self, luminance_cd_m2: float) -> float:
        """Pre-measurement + 2·t + command and data transfer time at this baud rate."""
        t = integration_time_s(luminance_cd_m2, self.speed, self.time_mode, self.time_s)
        # bytes on the line: MES,1 + 2 replies; twice (every block is read until two reads
        # agree): BDR + colorimetry, BDR + 15 spectral lines
        transfer_bytes = 10 + 3 + 2 + 90 + 10 + 3 + SPECTRAL_LINES * 2 + 401 * 10 + 2 * 15
        n_bytes = 6 + 12 + TRANSFER_READS * transfer_bytes
        exchanges = 2 + TRANSFER_READS * (2 + 1 + SPECTRAL_LINES)
        return pre_measurement_s(luminance_cd_m2) + 2 * t + n_bytes * 10.0 / self.baud \
            + exchanges * 0.02

    # --- measuring ---------------------------------------------------------------------------------
    def _run_measurement(self) -> float:
        try:
            self._write(b"MES,1")
            first = self.read_reply(FIRST_REPLY_TIMEOUT_S)
            assert first is not None
            fields = self.parse_reply(first)
            if len(fields) != 1:
                raise self._protocol("MES,1: expected OK,<t>", first)
            t_s = self.parse_number(fields[0], first)
            if not 0 < t_s <= 600:
                raise self._protocol("MES,1: integration time out of range", first)
            wait_s = 2 * t_s * 1.2 + 10.0
            final = self.read_reply(wait_s, watch_abort=True)
            if final is None:                            # abort() from another thread
                self._cancel_quietly()
                raise self._aborted()
            if self.parse_reply(final):
                raise self._protocol("MES,1: expected a bare OK at the end", final)
            return t_s
        except InstrumentTimeout:
            self._cancel_quietly()       # the instrument may still be measuring
            self._resync(late=True)      # a reply may still be on its way
            raise
        except ProtocolError:
            self._cancel_quietly()       # the instrument may still be measuring
            raise
        except DeviceError as exc:
            if exc.code == "ER00":       # dropped to local mode: enter remote, then retry
                self._enter_remote()
                raise self._timeout("instrument was in local mode; remote mode re-entered") \
                    from exc
            raise

    def _read_data(self) -> Transfer:
        """The colorimetric line, then the spectrum, each block read until two reads agree.
        `&` serves the selected blocks in order (it is not idempotent), so a pass selects the
        data with BDR and sends `&` up to the last block still in doubt."""
        obs = 1 if self.observer_deg == 10 else 0
        [(colour_block, raw_colour)] = self.agreed_blocks(
            "colorimetry", 1, lambda pending, got: self._line_pass(f"BDR,1,{obs},0", [11],
                                                                   pending, got))
        if self.data_format == "binary":
            blocks = self.agreed_blocks("binary spectrum", len(BINARY_BLOCKS),
                                        lambda pending, got: self._binary_pass(obs, pending, got))
        else:
            counts = [SPECTRAL_LINE_VALUES] * (SPECTRAL_LINES - 1) \
                + [401 - (SPECTRAL_LINES - 1) * SPECTRAL_LINE_VALUES]
            blocks = self.agreed_blocks(
                "spectrum", SPECTRAL_LINES,
                lambda pending, got: self._line_pass(f"BDR,0,{obs},0", counts, pending, got))
        raw_spectrum = b"\n".join(raw for _, raw in blocks)
        spectrum = check_spectrum([v for values, _ in blocks for v in values], raw_spectrum,
                                  self.instrument_id)
        return Transfer(spectrum, colour_block, raw=raw_colour + b"\n" + raw_spectrum)

    def _reading(self, trigger: float, data: Transfer) -> SpectralReading:
        return SpectralReading(RADIOMETER_WAVELENGTHS_NM.copy(), data.spectrum,
                               colorimetry_from(data.colorimetry_values), trigger,
                               self.clock.wall_time_s(), self.instrument_id,
                               {"model": self.model, "speed": self.speed,
                                "time_mode": self.time_mode, "observer_deg": self.observer_deg,
                                "data_format": self.data_format})

    def _select(self, command: str) -> None:
        """BDR: select the data `&` serves next (fields after OK, seen in one driver, are
        ignored)."""
        self.parse_reply(self.exchange(command.encode("ascii")))

    def _line_pass(self, select: str, counts: list[int], pending: list[int],
                   got: Callable[[int, Any, bytes], None]) -> None:
        """Select, then one `&` per line up to the last pending one.  A line whose content
        does not parse, or that did not come, is left for the next pass; a status reply (OK…, ERnn) where a data line
        belongs means the line is out of step: `ProtocolError` (or the `DeviceError`)."""
        self._select(select)
        timeouts = 0
        for i in range(max(pending) + 1):
            try:
                raw = self.exchange(b"&")
            except (InstrumentTimeout, ProtocolError):
                # `&` was received and its block sent (late, cut short or lost): find where
                # the line stands, go on with the next block; two in a row, or the line not
                # found: end the pass
                timeouts += 1
                if timeouts == 2 or not self._resync(late=True):
                    raise
                continue
            timeouts = 0
            if raw.startswith((b"OK", b"ER")):
                self.parse_reply(raw)          # ERnn raises DeviceError
                raise self._protocol("a status reply where a data line belongs", raw)
            try:
                got(i, self._data_values(raw, counts[i]), raw)
            except ProtocolError:
                continue                       # garbled: read again in the next pass

    def _binary_pass(self, obs: int, pending: list[int],
                     got: Callable[[int, Any, bytes], None]) -> None:
        self._select(f"BDR,0,{obs},1")
        for i in range(max(pending) + 1):
            n = BINARY_BLOCKS[i]
            self._write(b"&")
            raw = self._read_exact(4 * n, self.command_timeout_s)
            values = list(struct.unpack(f"<{n}f", raw))
            if all(math.isfinite(v) for v in values):
                got(i, values, raw)

    def _data_values(self, raw: bytes, expected: int) -> list[float]:
        try:
            parts = raw.decode("ascii").split(",")
        except UnicodeDecodeError:
            raise self._protocol("data block is not ASCII", raw) from None
        if len(parts) != expected:
            raise self._protocol(f"data block has {len(parts)} values, expected {expected}", raw)
        return [self.parse_number(p, raw) for p in parts]


CS1000 = CS1000A
__all__ = [
    "BAUD_RATES",
    "CS1000",
    "CS1000A",
    "ERRORS",
    "integration_time_s",
]
