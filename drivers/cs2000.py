"""Konica Minolta CS-2000 / CS-2000A spectroradiometer (pyserial).

References: Konica Minolta, *Spectroradiometer CS-2000/CS-2000A Communication
Specifications*, Rev. 7.00 (2020) — [KM-CS2000] in docs/references.md.

Line: 115200 baud (RS-232C default; ignored over USB), 8N1, RTS/CTS.  Commands end in LF
(`delimiter` option: LF or CR+LF); the reply ends in the same delimiter.  Every reply starts
with ``OK00`` or ``ERnn`` (→ `DeviceError` with the meaning from `ERRORS`).

    RMTS,2 (fw ≥ 3.00.9301; falls back to RMTS,1) / RMTS,0       remote on (no flash writes) / off
    IDDR            → OK00,<name 9>,<variation 1|2>,<serial 7>
    MSWE,0          → OK00     measure button off: the buffer survives until the next MEAS,1
    SPMS,m,… / SPMR → speed mode 0 Normal, 1 Fast, 2 Multi-Integ Normal (tt s), 3 Manual (µs),
                      4 Multi-Integ Fast, each with ND 0 off / 1 on / 2 auto
    MEAS,1          → OK00,ttt after the pre-measurement (1–10 s), → OK00 ttt s later
    MEAS,0          → OK00     cancel (after the pre-measurement)
    MEDR,1,f,1..4   → OK00,v1,…   spectral radiance 380–479, 480–579, 580–679, 680–780 nm
    MEDR,2,f,00     → OK00,24 values (Le, Lv, X, Y, Z, x, y, u′, v′, T, Δuv, λd, Pe, 10° …)
    MEDR,0,0,1      → OK00,speed,sync,integration µs,ND,lens,ext ND,angle,cal channel
  f = 0 ASCII (``#.####e±#`` …), 1 hex (8 hex digits, big-endian IEEE float).

Timing model for ETAs (assumed; the same as the emulator's, docs/radiometers.md):
pre-measurement clamp(1 + 2·log10(100/Lv), 1, 10) s + ttt = clamp(ceil(K/Lv), 2, 242) s (K = 200
Normal, 50 Fast; Multi-Integ 2·tt; Manual ceil(2·t) + 1) + data transfer at 10 bits per byte.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from typing import Any

from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    ConfigError,
    DeviceError,
    InstrumentError,
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

ERRORS = {
    "ER00": "invalid command or number of parameters (or not in remote mode, or a command "
            "other than MEAS,0 during a measurement)",
    "ER02": "measurement in progress",
    "ER05": "no compensation values (user calibration, lens or ND factors missing)",
    "ER10": "over measurement range (luminance too high or flicker too large)",
    "ER17": "parameter out of range or wrong length (or MEAS,0 when idle, MEAS,1 while "
            "measuring)",
    "ER20": "no data",
    "ER30": "internal memory (flash) error",
    "ER32": "internal memory (flash) error",
    "ER34": "internal memory (flash) error",
    "ER51": "temperature abnormality (CCD Peltier)",
    "ER52": "temperature abnormality (temperature count)",
    "ER71": "outside synchronisation range (20–200 Hz)",
    "ER81": "shutter malfunction",
    "ER82": "internal ND filter malfunction",
    "ER83": "measurement angle abnormality",
    "ER84": "cooling fan abnormality",
    "ER99": "program abnormality",
}
SPEED_MODES = {"normal": 0, "fast": 1, "multi-normal": 2, "manual": 3, "multi-fast": 4}
ND_MODES = {"off": 0, "on": 1, "auto": 2}
SPECTRAL_BLOCK_SIZES = {1: 100, 2: 100, 3: 100, 4: 101}
FIRST_REPLY_TIMEOUT_S = 15.0          # pre-measurement "about 1–10 s"
HEX_UNDEFINED = "D1BA43B6"
HEX_DIGITS = frozenset("0123456789ABCDEFabcdef")
#: the name holds a letter: SPMR's ``OK00,2,1,2`` (Multi-Integ Normal 1 s, ND auto) has the
#: same field layout in digits only
IDDR_REPLY = re.compile(rb"^OK00,(?=[^,]*[A-Za-z])[^,]{1,16},[12],\s*\d{1,12}$")


def parse_identification(replies: list[bytes]) -> InstrumentIdentity | None:
    """`lab discover`'s identification (registry: blank line, RMTS,2, IDDR, RMTS,0): IDDR's
    ``OK00,<name>,<variation>,<serial>``."""
    if len(replies) < 3 or IDDR_REPLY.match(replies[2]) is None:
        return None
    fields = replies[2].decode("ascii").split(",")
    return InstrumentIdentity("spectroradiometer", fields[1].strip(),
                              serial_number=fields[3].strip(),
                              extra={"variation": "CS-2000A" if fields[2] == "2"
                                     else "CS-2000"})


def measurement_time_s(luminance_cd_m2: float, speed: str = "normal", time_s: float = 1.0) -> int:
    """ttt of the timing model (2–242 s)."""
    lv = max(float(luminance_cd_m2), 1e-6)
    if speed in ("normal", "fast"):
        t = math.ceil((50.0 if speed == "fast" else 200.0) / lv)
    elif speed in ("multi-normal", "multi-fast"):
        t = 2 * round(time_s)
    else:
        t = math.ceil(2 * time_s) + 1
    return int(min(242, max(2, t)))


class CS2000A(KonicaMinoltaRadiometer):
    model = "CS-2000A"
    ok_head = "OK00"
    errors = ERRORS
    remote_prefix = "RMTS,"
    cancel_command = "MEAS,0"
    sync_command = b"IDDR"

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "radiometer",
                 data_format: str = "ascii", delimiter: str = "\n", baud: int = 115200,
                 **options: Any) -> None:
        super().__init__(port, clock, instrument_id=instrument_id, **options)
        if data_format not in ("ascii", "hex"):
            raise ConfigError("<driver options>", 0, "data_format", "must be ascii or hex")
        if delimiter not in ("\n", "\r\n"):
            raise ConfigError("<driver options>", 0, "delimiter", "must be LF or CR+LF")
        self.data_format = data_format
        self.terminator = delimiter.encode("ascii")
        self.baud = int(baud)
        self.remote_level = 0          # 0 off, 1 on (writes flash), 2 on without flash writes
        self.speed = "multi-normal"    # the factory default: Multi-Integ Normal 1 s, ND auto
        self.time_s = 1.0
        self.nd = "auto"
        self._button_off = False

    @classmethod
    def open(cls, url: str, clock: Clock, *, baud: int = 115200,
             instrument_id: str = "radiometer", data_format: str = "ascii",
             delimiter: str = "\n", command_timeout_s: float = 10.0, attempts: int = 3,
             reconnect_timeout_s: float = 10.0) -> CS2000A:
        """Open `url` (device path, socket://, sim://cs2000a?…) at 8N1 with RTS/CTS.
        Explicit keywords: any other option in the lab config is a ConfigError (lab.py)."""
        port = transport.open_port(url, baudrate=int(baud), bytesize=8, parity="N", stopbits=1,
                                   rtscts=True, timeout=1.0, instrument_id=instrument_id)
        return cls(port, clock, instrument_id=instrument_id, baud=int(baud),
                   data_format=data_format, delimiter=delimiter,
                   command_timeout_s=command_timeout_s, attempts=attempts,
                   reconnect_timeout_s=reconnect_timeout_s)

    def is_sync_reply(self, raw: bytes) -> bool:
        """IDDR's ``OK00,<name>,<variation>,<serial>``."""
        return IDDR_REPLY.match(raw) is not None

    # --- remote mode ---------------------------------------------------------------------------------
    def _enter_remote(self) -> None:
        """RMTS,2 (no flash writes, fw ≥ 3.00.9301); ER17/ER00 from older firmware → RMTS,1.
        Then MSWE,0 once, so the data buffer survives reading (spec §8.1)."""
        level = 2 if self.remote_level != 1 else 1
        try:
            self._no_fields("RMTS", self.parse_reply(self.exchange(f"RMTS,{level}".encode())))
        except DeviceError as exc:
            if level != 2 or exc.code not in ("ER17", "ER00"):
                raise
            level = 1
            self._no_fields("RMTS", self.parse_reply(self.exchange(b"RMTS,1")))
        self.remote_level = level
        self.remote = True
        if not self._button_off:
            self._no_fields("MSWE", self.parse_reply(self.exchange(b"MSWE,0")))
            self._button_off = True

    def set_remote(self, on: bool) -> None:
        if on:
            self.with_retries(self._enter_remote, retry_device=("ER02",))
        else:
            self._no_fields("RMTS", self.command("RMTS,0"))
            self.remote = False
            self.remote_level = 0

    # --- the Spectroradiometer role ---------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        def parse(fields: list[str]) -> list[str]:
            if len(fields) != 3 or fields[1] not in ("1", "2") \
                    or not fields[2].strip().isascii() or not fields[2].strip().isdigit():
                raise self._protocol("IDDR: expected OK00,<name>,<variation>,<serial>",
                                     ",".join(["OK00", *fields]).encode())
            return fields

        self._ensure_remote()
        fields = self.command("IDDR", parse=parse)
        url = str(self.port.port or "")
        return InstrumentIdentity("spectroradiometer", fields[0].strip(),
                                  serial_number=fields[2].strip(),
                                  simulated=url.startswith("sim://"),
                                  extra={"variation": "CS-2000A" if fields[1] == "2"
                                         else "CS-2000", "port": url})

    def set_speed(self, mode: str, *, time_s: float | None = None, nd: str = "auto") -> None:
        """SPMS: "normal", "fast", "multi-normal"/"multi-fast" (time_s 1–16 s) or "manual"
        (time_s 0.005–120 s); ND "off", "on", "auto" (not for manual)."""
        if mode not in SPEED_MODES:
            raise ConfigError("<driver call>", 0, "speed",
                              f"must be one of {', '.join(SPEED_MODES)}")
        if nd not in ND_MODES or (mode == "manual" and nd == "auto"):
            raise ConfigError("<driver call>", 0, "nd", "off, on or auto (manual: off or on)")
        m = SPEED_MODES[mode]
        if mode in ("normal", "fast"):
            cmd = f"SPMS,{m},{ND_MODES[nd]}"
        elif mode.startswith("multi"):
            if time_s is None or not 1 <= round(time_s) <= 16:
                raise ConfigError("<driver call>", 0, "time_s", "multi-integ time must be 1–16 s")
            cmd = f"SPMS,{m},{round(time_s)},{ND_MODES[nd]}"
        else:
            if time_s is None or not 0.005 <= time_s <= 120.0:
                raise ConfigError("<driver call>", 0, "time_s", "manual time must be 0.005–120 s")
            cmd = f"SPMS,{m},{round(time_s * 1e6)},{ND_MODES[nd]}"
        self._ensure_remote()
        self._no_fields("SPMS", self.command(cmd))
        self.speed, self.nd = mode, nd
        if time_s is not None:
            self.time_s = float(time_s)

    def read_speed(self) -> dict[str, object]:
        """SPMR → {"speed", "time_s" (multi/manual), "nd"}."""
        def parse(fields: list[str]) -> dict[str, object]:
            raw = ",".join(["OK00", *fields]).encode()
            names = {v: k for k, v in SPEED_MODES.items()}
            nds = {v: k for k, v in ND_MODES.items()}
            if not fields:
                raise self._protocol("SPMR: unexpected reply", raw)
            mode = names.get(self.parse_int(fields[0], raw, 0, 9), "")
            if not mode:
                raise self._protocol("SPMR: unknown speed mode", raw)
            if len(fields) != (2 if mode in ("normal", "fast") else 3):
                raise self._protocol("SPMR: wrong number of fields", raw)
            nd = nds.get(self.parse_int(fields[-1], raw, 0, 9), "")
            if not nd:
                raise self._protocol("SPMR: unknown ND mode", raw)
            out: dict[str, object] = {"speed": mode, "nd": nd}
            if mode.startswith("multi"):
                out["time_s"] = float(self.parse_int(fields[1], raw, 1, 16))
            elif mode == "manual":
                out["time_s"] = self.parse_int(fields[1], raw, 5_000, 120_000_000) / 1e6
            self.speed, self.nd = mode, str(out["nd"])
            if "time_s" in out:
                self.time_s = float(out["time_s"])  # type: ignore[arg-type]
            return out

        self._ensure_remote()
        return dict(self.command("SPMR", parse=parse))

    def status(self) -> dict[str, object]:
        out: dict[str, object] = {"model": self.model, "remote": self.remote,
                                  "remote_level": self.remote_level}
        out.update(self.read_speed())
        return out

    def measurement_conditions(self) -> dict[str, object]:
        """MEDR,0,0,1: the conditions of the measurement in the buffer."""
        self._ensure_remote()
        return self.with_retries(self.measurement_conditions_once, retry_device=("ER02",))

    def estimate_measure_time_s(self, luminance_cd_m2: float) -> float:
        ttt = measurement_time_s(luminance_cd_m2, self.speed, self.time_s)
        # MEAS,1 + 2 replies; twice (every block read until two reads agree): 4 spectral
        # blocks, the colorimetry, the conditions
        transfer_bytes = 4 * (11 + 5 + 100 * 10) + 11 + 5 + 24 * 10 + 11 + 40
        n_bytes = 7 + 9 + 5 + TRANSFER_READS * transfer_bytes
        exchanges = 1 + TRANSFER_READS * 6
        return pre_measurement_s(luminance_cd_m2) + ttt + n_bytes * 10.0 / self.baud \
            + exchanges * 0.02

    def _cancel_quietly(self) -> None:
        """MEAS,0 whatever the state.  During the pre-measurement the instrument ignores
        commands; the OK00,ttt that ends it then arrives instead, and MEAS,0 is sent again."""
        try:
            self._resync()
            reply = self.exchange(b"MEAS,0", timeout_s=FIRST_REPLY_TIMEOUT_S)
            if reply.startswith(b"OK00,"):
                self.exchange(b"MEAS,0", timeout_s=3.0)
        except (InstrumentError, SerialException, OSError):
            pass
        self._resync()

    # --- measuring -------------------------------------------------------------------------------------
    def _read_data(self) -> Transfer:
        """MEDR spectral blocks 1–4, colorimetry and conditions, each read until two reads
        agree (MEDR reads the buffer, which does not change: a garbled or stray reply does)."""
        f = 1 if self.data_format == "hex" else 0
        reads: list[tuple[str, int]] = [(f"MEDR,1,{f},{block}", n)
                                         for block, n in SPECTRAL_BLOCK_SIZES.items()]
        reads += [(f"MEDR,2,{f},00", 24), ("MEDR,0,0,1", 0)]

        def read_pass(pending: list[int], got: Callable[[int, Any, bytes], None]) -> None:
            for i in pending:
                cmd, n = reads[i]
                raw = self.exchange(cmd.encode("ascii"))
                got(i, self._values(cmd, raw, n) if n else self._conditions(raw), raw)

        blocks = self.agreed_blocks("MEDR", len(reads), read_pass)
        raws = b"\n".join(raw for _, raw in blocks[:4])
        spectrum = check_spectrum([v for values, _ in blocks[:4] for v in values], raws,
                                  self.instrument_id)
        colour_vals = blocks[4][0]
        return Transfer(spectrum, colour_vals[:11],
                        {"conditions": blocks[5][0], "colour_values": colour_vals},
                        raw=raws + b"\n" + blocks[4][1])

    def _reading(self, trigger: int, data: Transfer) -> SpectralReading:
        conditions = data.extra["conditions"]
        colour_vals = data.extra["colour_values"]
        return SpectralReading(
            RADIOMETER_WAVELENGTHS_NM.copy(), data.spectrum,
            colorimetry_from(data.colorimetry_values),
            conditions["integration_time_us"] / 1e6, self.clock.wall_time_s(),
            self.instrument_id,
            {"model": self.model, "measurement_time_s": trigger, "speed": self.speed,
             "data_format": self.data_format, "conditions": conditions,
             "colorimetry_10deg": dict(zip(("X10", "Y10", "Z10", "x10", "y10", "u10", "v10",
                                            "T10", "duv10"), colour_vals[13:22], strict=True))})

    def measurement_conditions_once(self) -> dict[str, Any]:
        return self._conditions(self.exchange(b"MEDR,0,0,1"))

    def _conditions(self, raw: bytes) -> dict[str, Any]:
        fields = self.parse_reply(raw)
        if len(fields) != 8:
            raise self._protocol("MEDR,0,0,1: expected 8 numeric fields", raw)
        keys = ("speed_mode", "sync_mode", "integration_time_us", "internal_nd", "close_up_lens",
                "external_nd", "angle", "calibration_channel")
        values = [self.parse_int(x, raw) for x in fields]
        if not 0 < values[2] <= 600_000_000:
            raise self._protocol("MEDR,0,0,1: integration time out of range", raw)
        return dict(zip(keys, values, strict=True))

    def _run_measurement(self) -> int:
        try:
            self._write(b"MEAS,1")
            first = self.read_reply(FIRST_REPLY_TIMEOUT_S)
            assert first is not None
            fields = self.parse_reply(first)
            if len(fields) != 1:
                raise self._protocol("MEAS,1: expected OK00,ttt", first)
            ttt = self.parse_int(fields[0], first, 1, 999)
            final = self.read_reply(ttt * 1.2 + 10.0, watch_abort=True)
            if final is None:
                self._cancel_quietly()
                raise self._aborted()
            self._no_fields("MEAS,1", self.parse_reply(final))
            return ttt
        except InstrumentTimeout:
            self._cancel_quietly()       # the instrument may still be measuring
            self._resync(late=True)      # a reply may still be on its way
            raise
        except ProtocolError:
            self._cancel_quietly()
            raise
        except DeviceError as exc:
            if exc.code == "ER00":
                self._enter_remote()
                raise self._timeout("instrument was in key mode; remote mode re-entered") \
                    from exc
            raise

    def _values(self, cmd: str, raw: bytes, expected: int) -> list[float]:
        """The numbers of a MEDR data reply: exactly `expected` fields, each ``#.####e±#``
        ASCII or exactly 8 hex digits (a big-endian float32); anything else `ProtocolError`."""
        fields = self.parse_reply(raw)
        if len(fields) != expected:
            raise self._protocol(f"{cmd}: {len(fields)} values, expected {expected}", raw)
        if self.data_format != "hex":
            return [self.parse_number(x, raw) for x in fields]
        out = []
        for x in fields:
            if len(x) != 8 or not all(c in HEX_DIGITS for c in x):
                raise self._protocol(f"{cmd}: hex value {x[:16]!r} is not 8 hex digits", raw)
            value = struct.unpack(">f", bytes.fromhex(x))[0]
            if not math.isfinite(value):
                raise self._protocol(f"{cmd}: non-finite value {x!r}", raw)
            out.append(value)
        return out


CS2000 = CS2000A
__all__ = ["CS2000", "CS2000A", "ERRORS", "HEX_UNDEFINED", "SPEED_MODES", "measurement_time_s"]
