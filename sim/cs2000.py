"""Konica Minolta CS-2000A spectroradiometer, emulated at the wire.

Written from Konica Minolta, *Spectroradiometer CS-2000/CS-2000A Communication
Specifications*, Rev. 7.00 (2020) — [KM-CS2000] in docs/references.md.

Line: 115200 baud 8N1 RTS/CTS (the emulator ignores the settings, as the instrument does over
USB).  A command ends in CR, LF or CR+LF; **the reply ends in the same delimiter**.  Replies are
``OK00[,…]`` or ``ERnn``.

States: key mode (RMTS,0: only RMTS accepted, others ER00) → remote (RMTS,1 writes settings to
flash; RMTS,2 does not, firmware ≥ 3.00.9301) → pre-measuring (commands get no reply) →
measuring (MEAS,0 cancels; MEAS,1 → ER17; anything else → ER00) → remote with data.

Commands emulated:
  RMTS,n         0 / 1 / 2 (2 → ER17 on firmware < 3.00.9301)
  IDDR           ``OK00,CS-2000A ,2,<serial 7 digits>`` (name space-padded to 9 chars)
  SPMS / SPMR    speed 0 Normal, 1 Fast, 2 Multi-Integ Normal (tt 1–16 s), 3 Manual
                 (5000–120000000 µs, ND 0/1), 4 Multi-Integ Fast; ND 0 off / 1 on / 2 auto
  MSWE,n         measure button; with 1 the buffer is cleared once all four spectral blocks or
                 one colorimetric set have been read
  MEAS,1         after the pre-measurement ``OK00,ttt`` (ttt 3 digits, s), ttt later ``OK00``;
                 ER10 (instead of OK00,ttt) above `max_luminance_cd_m2` or on ``over-range``
  MEAS,0         cancel (after the pre-measurement only): ``OK00``, no final reply of the
                 cancelled MEAS,1 (*assumed*: the spec leaves it open), buffer empty; idle → ER17
  MEDR,m,f,b     m 0 conditions (b 1), 1 spectral (b 1–4: 100/100/100/101 values), 2 colorimetric
                 (b 00 = 24 values, 01–05, 11–15, 100, 101); f 0 ASCII, 1 hex (big-endian float32);
                 ER20 before any measurement, ER17 bad parameters
  STSR, DTCR     aperture 0 (1°); calibration date/time
Everything else → ER00 (not emulated).

Timing model (assumed; docs/radiometers.md): pre-measurement clamp(1 + 2·log10(100/Lv), 1,
10) s; ttt = clamp(ceil(K/Lv), 2, 242) s with K = 200 (Normal) / 50 (Fast); Multi-Integ
clamp(2·tt, 2, 242); Manual clamp(ceil(2·t) + 1, 2, 242); replies cross the line at 10 bits per
byte at `baud`.

Device faults: ``device-error`` (reply ``ERnn``, nn = parameter, default 51), ``busy`` (ER02 to
a command), ``over-range`` (the next MEAS,1 ends in ER10).  A disconnect models a power blip: the
instrument comes back in key mode with an empty buffer.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from normbox_lab.sim import core
from normbox_lab.sim.radiometer_common import (
    RadiometerOptics,
    Scene,
    colorimetry,
    env_time_factor,
    fmt_e,
    pre_measurement_s,
)

SPECTRAL_BLOCKS = {1: (0, 100), 2: (100, 200), 3: (200, 300), 4: (300, 401)}
COLORIMETRIC_BLOCKS = {0, 1, 2, 3, 4, 5, 11, 12, 13, 14, 15, 100, 101}
COMMAND_DELAY_S = 0.02
CR_WAIT_S = 0.01                 # how long a trailing CR waits for its LF
K_NORMAL_CD_S_M2 = 200.0
K_FAST_CD_S_M2 = 50.0


def measurement_time_s(luminance_cd_m2: float, speed_mode: int = 0, multi_time_s: int = 1,
                       manual_time_us: int = 33333) -> int:
    """ttt, the remaining measurement time the instrument announces after pre-measuring."""
    lv = max(float(luminance_cd_m2), 1e-6)
    if speed_mode in (0, 1):
        t = math.ceil((K_FAST_CD_S_M2 if speed_mode == 1 else K_NORMAL_CD_S_M2) / lv)
    elif speed_mode in (2, 4):
        t = 2 * multi_time_s
    else:
        t = math.ceil(2 * manual_time_us / 1e6) + 1
    return int(min(242, max(2, t)))


def _firmware_tuple(version: str) -> tuple[int, ...]:
    return tuple(int(p) for p in version.split("."))


def fmt_lv(lv: float) -> str:
    """Lv: 6 characters (``######``, ``####.#`` … ``#.####``); ``#.##e+#`` above 999 999.5;
    ``0.0000`` below 0.00005."""
    if not math.isfinite(lv):
        return "-9.9e9"
    if lv < 0.00005:
        return "0.0000"
    if lv >= 999_999.5:
        mant, exp = f"{lv:.2e}".split("e")
        return f"{mant}e+{int(exp)}"
    digits = max(1, math.floor(math.log10(lv)) + 1) if lv >= 1 else 1
    return f"{lv:.{max(0, 5 - digits)}f}"


def fmt_hex(value: float) -> str:
    return "D1BA43B6" if not math.isfinite(value) else struct.pack(">f", value).hex().upper()


class CS2000AEmulator(core.Emulator):
    device_name = "cs2000a"
    device_faults = ("device-error", "busy", "over-range")

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 scene: Scene | None = None, world: Any = None, noise: str | bool = "on",
                 baud: int | str = 115200, time_factor: float | str | None = None,
                 max_luminance_cd_m2: float | str = 500_000.0, firmware: str = "3.10.0000",
                 serial_number: str = "2000123") -> None:
        super().__init__(clock, faults, seed)
        self.optics = RadiometerOptics(scene=scene, world=world, noise=noise, seed=seed)
        self.baud = int(baud)
        self.time_factor = float(time_factor) if time_factor is not None else env_time_factor()
        self.max_luminance_cd_m2 = float(max_luminance_cd_m2)
        self.firmware = firmware
        self.serial_number = serial_number
        self.commands: list[bytes] = []
        self.flash_writes = 0
        self._inbuf = bytearray()
        self._delim = b"\n"
        self._cr_hold_s: float | None = None
        # settings kept in flash survive a power blip
        self.speed_mode, self.nd, self.multi_time_s, self.manual_time_us = 2, 2, 1, 33333
        self.button_enabled = False
        self._power_on()

    def prepare(self) -> None:
        self.optics.prepare()

    def _power_on(self) -> None:
        self.remote = 0
        self.phase = "idle"                   # idle | pre | measuring
        self.phase_end_s: float | None = None
        self._pending: dict[str, Any] | None = None
        self.data: dict[str, Any] | None = None
        self._spectral_read: set[int] = set()

    # --- timing (public: ETAs come from here) ---------------------------------------------------
    def measure_time_s(self, luminance_cd_m2: float) -> float:
        """Pre-measurement + ttt with the current speed mode (no data transfer)."""
        ttt = measurement_time_s(luminance_cd_m2, self.speed_mode, self.multi_time_s,
                                 self.manual_time_us)
        return (pre_measurement_s(luminance_cd_m2) + ttt) * self.time_factor

    def line_time_s(self, n_bytes: int) -> float:
        return n_bytes * 10.0 / self.baud * self.time_factor

    # --- wire -------------------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        self._inbuf += data
        self._split_lines(final=False)

    def _split_lines(self, final: bool) -> None:
        """Cut the input at CR, LF or CR+LF.  A CR that ends the input so far is held for
        `CR_WAIT_S` in case its LF follows in the next write."""
        while True:
            ends = [i for i in (self._inbuf.find(b"\r"), self._inbuf.find(b"\n")) if i >= 0]
            if not ends:
                return
            i = min(ends)
            if self._inbuf[i:i + 1] == b"\r" and i == len(self._inbuf) - 1 and not final:
                self._cr_hold_s = self.clock.now_s() + CR_WAIT_S * self.time_factor
                return
            self._cr_hold_s = None
            delim = b"\r\n" if self._inbuf[i:i + 2] == b"\r\n" else bytes(self._inbuf[i:i + 1])
            line = bytes(self._inbuf[:i])
            del self._inbuf[:i + len(delim)]
            if line:
                self._delim = delim
                self.on_line(line)

    def reply(self, text: str) -> None:
        data = text.encode("ascii") + self._delim
        self.emit(data, COMMAND_DELAY_S * self.time_factor + self.line_time_s(len(data)))

    def on_line(self, line: bytes) -> None:
        self.commands.append(line)
        if self.phase == "pre":
            return                                   # nothing is accepted while pre-measuring
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            self.reply("ER00")
            return
        cmd, *args = text.split(",")
        if self.phase == "measuring":
            if text == "MEAS,0":
                self.cancel_output()
                self.phase, self.phase_end_s, self._pending = "idle", None, None
                self.reply("OK00")
            else:
                self.reply("ER17" if text == "MEAS,1" else "ER00")
            return
        if not self.remote and cmd != "RMTS":
            self.reply("ER00")
            return
        if self.faults.fires("busy"):
            self.reply("ER02")
            return
        if self.faults.fires("device-error"):
            self.reply(f"ER{int(self.faults.parameter('device-error', 51)):02d}")
            return
        handler = getattr(self, f"_cmd_{cmd}", None)
        if handler is None:
            self.reply("ER00")
            return
        handler(args)

    def _ints(self, args: list[str], count: int) -> list[int] | None:
        if len(args) != count:
            self.reply("ER00")
            return None
        if not all(a.isdigit() for a in args):
            self.reply("ER17")
            return None
        return [int(a) for a in args]

    def _settings_changed(self) -> None:
        if self.remote == 1:
            self.flash_writes += 1

    # --- commands ---------------------------------------------------------------------------------
    def _cmd_RMTS(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in (0, 1, 2) or (v[0] == 2 and _firmware_tuple(self.firmware)
                                     < (3, 0, 9301)):
            self.reply("ER17")
            return
        self.remote = v[0]
        self.reply("OK00")

    def _cmd_IDDR(self, args: list[str]) -> None:
        if args:
            self.reply("ER00")
            return
        self.reply(f"OK00,{'CS-2000A':<9},2,{self.serial_number}")

    def _cmd_SPMS(self, args: list[str]) -> None:
        if not args or not args[0].isdigit():
            self.reply("ER00" if not args else "ER17")
            return
        mode = int(args[0])
        count = {0: 2, 1: 2, 2: 3, 3: 3, 4: 3}.get(mode)
        if count is None:
            self.reply("ER17")
            return
        v = self._ints(args, count)
        if v is None:
            return
        nd = v[-1]
        if mode in (2, 4) and not 1 <= v[1] <= 16:
            self.reply("ER17")
            return
        if mode == 3 and not 5000 <= v[1] <= 120_000_000:
            self.reply("ER17")
            return
        if nd not in ((0, 1) if mode == 3 else (0, 1, 2)):
            self.reply("ER17")
            return
        self.speed_mode, self.nd = mode, nd
        if mode in (2, 4):
            self.multi_time_s = v[1]
        elif mode == 3:
            self.manual_time_us = v[1]
        self._settings_changed()
        self.reply("OK00")

    def _cmd_SPMR(self, args: list[str]) -> None:
        if args:
            self.reply("ER00")
            return
        m = self.speed_mode
        if m in (2, 4):
            self.reply(f"OK00,{m},{self.multi_time_s:02d},{self.nd}")
        elif m == 3:
            self.reply(f"OK00,{m},{self.manual_time_us:09d},{self.nd}")
        else:
            self.reply(f"OK00,{m},{self.nd}")

    def _cmd_MSWE(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in (0, 1):
            self.reply("ER17")
            return
        self.button_enabled = v[0] == 1
        self._settings_changed()
        self.reply("OK00")

    def _cmd_STSR(self, args: list[str]) -> None:
        self.reply("OK00,0" if not args else "ER00")

    def _cmd_DTCR(self, args: list[str]) -> None:
        self.reply("OK00,20200101,120000" if not args else "ER00")

    def _cmd_MEAS(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] == 0:
            self.reply("ER17")                     # nothing to cancel
        elif v[0] == 1:
            self._start()
        else:
            self.reply("ER17")

    def _cmd_MEDR(self, args: list[str]) -> None:
        v = self._ints(args, 3)
        if v is None:
            return
        kind, fmt, block = v
        valid = (fmt in (0, 1) and ((kind == 0 and block == 1)
                                    or (kind == 1 and block in SPECTRAL_BLOCKS)
                                    or (kind == 2 and block in COLORIMETRIC_BLOCKS)))
        if not valid:
            self.reply("ER17")
            return
        if self.data is None:
            self.reply("ER20")
            return
        d = self.data
        if kind == 0:
            self.reply(f"OK00,{self.speed_mode},0,{d['integration_time_us']:09d},"
                       f"{int(self.nd == 1)},0,0,0,00")
            return
        if kind == 1:
            lo, hi = SPECTRAL_BLOCKS[block]
            values = d["spectrum"][lo:hi]
            text = ",".join(fmt_hex(x) if fmt else fmt_e(x) for x in values)
            self._spectral_read.add(block)
        else:
            text = ",".join(self._colorimetric(block, fmt))
        self.reply(f"OK00,{text}")
        if self.button_enabled and (kind == 2 or self._spectral_read == set(SPECTRAL_BLOCKS)):
            self.data = None                        # MSWE,1: the buffer is read once

    def _colorimetric(self, block: int, fmt: int) -> list[str]:
        c2, c10 = self.data["colorimetry"], self.data["colorimetry10"]
        nan = math.nan
        full = [("e", c2["Le"]), ("lv", c2["Lv"]), ("e", c2["X"]), ("e", c2["Y"]),
                ("e", c2["Z"]), ("c", c2["x"]), ("c", c2["y"]), ("c", c2["u_prime"]),
                ("c", c2["v_prime"]), ("T", c2["T"]), ("duv", c2["duv"]), ("f6", nan),
                ("f6", nan),
                ("e", c10["X"]), ("e", c10["Y"]), ("e", c10["Z"]), ("c", c10["x"]),
                ("c", c10["y"]), ("c", c10["u_prime"]), ("c", c10["v_prime"]),
                ("T", c10["T"]), ("duv", c10["duv"]), ("f6", nan), ("f6", nan)]
        lv = ("lv", c2["Lv"])
        pick = {0: full, 1: full[2:5], 2: [full[5], full[6], lv], 3: [full[7], full[8], lv],
                4: [full[9], full[10], lv], 5: [full[11], full[12], lv],
                11: full[13:16], 12: [full[16], full[17], lv], 13: [full[18], full[19], lv],
                14: [full[20], full[21], lv], 15: [full[22], full[23], lv],
                100: [full[0]], 101: [lv]}[block]
        if fmt == 1:
            return [fmt_hex(v) for _, v in pick]
        out = []
        for shape, v in pick:
            if shape == "e":
                out.append(fmt_e(v))
            elif shape == "lv":
                out.append(fmt_lv(v))
            elif shape == "c":
                out.append("-9.999" if not math.isfinite(v) else f"{v:.4f}")
            elif shape == "T":
                out.append("-9999" if not math.isfinite(v) else f"{round(v)}")
            elif shape == "duv":
                out.append("-9.9999" if not math.isfinite(v) else f"{v:+.4f}")
            else:
                out.append("-9.9e9")                  # λd, Pe: not computed by the emulator
        return out

    # --- the measurement ---------------------------------------------------------------------------
    def _start(self) -> None:
        spectrum, c2 = self.optics.observe()
        lv = c2["Lv"]
        over = lv > self.max_luminance_cd_m2 or self.faults.fires("over-range")
        ttt = measurement_time_s(lv, self.speed_mode, self.multi_time_s, self.manual_time_us)
        if self.speed_mode == 3:
            t_int_us = self.manual_time_us
        else:
            t_int_us = int(min(ttt / 2.0, 120.0) * 1e6)
        self.data = None
        self._spectral_read = set()
        self._pending = {"spectrum": spectrum, "colorimetry": c2,
                         "colorimetry10": colorimetry(spectrum, 10), "ttt": ttt,
                         "integration_time_us": t_int_us, "over_range": over}
        self.phase = "pre"
        self.phase_end_s = self.clock.now_s() + pre_measurement_s(lv) * self.time_factor

    def on_time(self, now_s: float) -> None:
        if self._cr_hold_s is not None and now_s >= self._cr_hold_s:
            self._split_lines(final=True)       # a lone CR: the command ends there
        if self.phase_end_s is None or now_s < self.phase_end_s or self._pending is None:
            return
        p = self._pending
        if self.phase == "pre":
            if p["over_range"]:
                self.phase, self.phase_end_s, self._pending = "idle", None, None
                self.reply("ER10")
                return
            self.phase = "measuring"
            self.phase_end_s += p["ttt"] * self.time_factor
            self.reply(f"OK00,{p['ttt']:03d}")
        elif self.phase == "measuring":
            self.data = p
            self.phase, self.phase_end_s, self._pending = "idle", None, None
            self.reply("OK00")

    def next_state_s(self) -> float | None:
        times = [t for t in (self.phase_end_s, self._cr_hold_s) if t is not None]
        return min(times) if times else None

    def on_disconnect(self) -> None:
        self._inbuf.clear()
        self._cr_hold_s = None
        self._power_on()


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> CS2000AEmulator:
    return CS2000AEmulator(clock, faults, int(seed), world=world, **options)


core.register("cs2000a", _factory)

__all__ = ["CS2000AEmulator", "fmt_hex", "fmt_lv", "measurement_time_s"]
