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
  SCMS,m[,f] / SCMR   sync 0 none / 1 internal (f = 2000–20000, Hz × 100) / 2 external;
                 SCMR → ``OK00,m`` (``OK00,1,fffff`` for internal)
  OBSS/OBSR, CSMS/CSMR, DIMS/DIMR, BALS/BALR   observer, display colour space, absolute /
                 difference display, backlight: kept and read back
  UCCS/UCCR, LNSS/LNSR, NDFS/NDFR   calibration channel 00–10, close-up lens, external ND;
                 ER05 when their compensation values are absent
  UCPS, ALFS, NFCS   compensation-factor writes (steps 1–2, committed with ``…,3``): accepted
                 and kept without interpreting the values (*simplified*); UCPR/ALFR/NFCR read
                 back presence (ER05 when absent); UCCD,cc deletes a user channel
  STDS,nn / STDR,nn,m,f,b / STDD,nn / STAD   memory 00–99 (STDR formats as MEDR; ER20 empty)
  TGSL/TGSR, TGDS,nn / TGDR,nn,m,f,b / TGDD,nn / TGAD   targets 01–20 (TGDR layout as STDR,
                 *assumed*)
  BPSS,b / BPSR  baud (fw ≥ 3.00.0000), reply at the old rate; BPSR right-aligned in 6 chars
  INIT,n         0 data + settings, 1 data, 2 settings → factory defaults (fw ≥ 3.00.9301)
Everything else → ER00.

Timing model (assumed; docs/radiometers.md): pre-measurement clamp(1 + 2·log10(100/Lv), 1,
10) s; ttt = clamp(ceil(K/Lv), 2, 242) s with K = 200 (Normal) / 50 (Fast), the measurement
ending ANNOUNCE_MARGIN_S = 0.15 s before the announced ttt (whole seconds rounded up); Multi-Integ
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
    DATA_FAULT_KINDS,
    RADIOMETER_FAULT_KINDS,
    KonicaMinoltaCommands,
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
#: the instrument announces whole seconds rounded up: it ends this long before the announced
#: time (*assumed* margin), so a client that waits the announced time finds it done
ANNOUNCE_MARGIN_S = 0.15
BAUD_RATES = (2400, 4800, 9600, 19200, 38400, 57600, 115200)
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


class CS2000AEmulator(KonicaMinoltaCommands, core.Emulator):
    device_name = "cs2000a"
    replies_in_order = True         # one command at a time: a late reply holds back the next
    remote_command = "RMTS"
    fault_kinds = RADIOMETER_FAULT_KINDS + DATA_FAULT_KINDS
    device_faults = tuple(k.kind for k in fault_kinds)
    #: `sim latency`: (take the line, its reply's end, start a measurement, the end of its
    #: first reply, its last reply)
    latency_script = (b"RMTS,1\n", b"\n", b"MEAS,1\n", b"\n", b"OK00\n")

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
        self._factory_settings()
        self._factory_data()
        self._power_on()

    def on_new_client(self) -> None:
        super().on_new_client()
        self._cr_hold_s = None

    def _factory_settings(self) -> None:
        """Settings kept in flash (they survive a power blip); INIT,0/2 restores these."""
        self.speed_mode, self.nd, self.multi_time_s, self.manual_time_us = 2, 2, 1, 33333
        self.button_enabled = False
        self.sync_mode, self.sync_frequency = 0, 6000          # no sync, 60.00 Hz
        self.cal_channel = 0
        self.lens = 0
        self.nd_filter = 0
        self.target = 1
        self.backlight = (1, 1)
        self.colour_space = 0
        self.display_mode = 0
        self.observer = 0
        self.line_baud = 115200

    def _factory_data(self) -> None:
        """Stored data (INIT,0/1 clears these): memory, targets, compensation factors."""
        self.memory: dict[int, dict[str, Any]] = {}
        self.targets: dict[int, dict[str, Any]] = {}
        self.user_channels: dict[int, str] = {}
        self.lens_factors = False
        self.nd_factors = False
        self._staged: dict[str, list[str]] = {}

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
        """Pre-measurement + ttt − the announcement margin, with the current speed mode (no
        data transfer)."""
        ttt = measurement_time_s(luminance_cd_m2, self.speed_mode, self.multi_time_s,
                                 self.manual_time_us)
        return (pre_measurement_s(luminance_cd_m2) + ttt - ANNOUNCE_MARGIN_S) * self.time_factor

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
        parts = self.split_command(line)
        if parts is None:
            return
        text, cmd, args = parts
        if self.phase == "measuring":
            if text == "MEAS,0":
                self.cancel_output()
                self.phase, self.phase_end_s, self._pending = "idle", None, None
                self.reply("OK00")
            else:
                self.reply("ER17" if text == "MEAS,1" else "ER00")
            return
        self.run_command(cmd, args)

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

    def _setting(self, args: list[str], name: str, allowed: tuple[int, ...]) -> None:
        """``XXXS,n``: one integer setting among `allowed`."""
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in allowed:
            self.reply("ER17")
            return
        setattr(self, name, v[0])
        self._settings_changed()
        self.reply("OK00")

    def _read(self, args: list[str], text: str) -> None:
        self.reply("ER00" if args else f"OK00,{text}")

    def _cmd_SCMS(self, args: list[str]) -> None:
        if not args or not args[0].isdigit():
            self.reply("ER00" if not args else "ER17")
            return
        mode = int(args[0])
        v = self._ints(args, 2 if mode == 1 else 1)
        if v is None:
            return
        if mode not in (0, 1, 2) or (mode == 1 and not 2000 <= v[1] <= 20000):
            self.reply("ER17")
            return
        self.sync_mode = mode
        if mode == 1:
            self.sync_frequency = v[1]
        self._settings_changed()
        self.reply("OK00")

    def _cmd_SCMR(self, args: list[str]) -> None:
        self._read(args, f"{self.sync_mode},{self.sync_frequency:05d}" if self.sync_mode == 1
                   else f"{self.sync_mode}")

    def _cmd_OBSS(self, args: list[str]) -> None:
        self._setting(args, "observer", (0, 1))

    def _cmd_OBSR(self, args: list[str]) -> None:
        self._read(args, str(self.observer))

    def _cmd_CSMS(self, args: list[str]) -> None:
        self._setting(args, "colour_space", (0, 1, 2, 3, 4, 5))

    def _cmd_CSMR(self, args: list[str]) -> None:
        self._read(args, str(self.colour_space))

    def _cmd_DIMS(self, args: list[str]) -> None:
        self._setting(args, "display_mode", (0, 1))

    def _cmd_DIMR(self, args: list[str]) -> None:
        self._read(args, str(self.display_mode))

    def _cmd_BALS(self, args: list[str]) -> None:
        v = self._ints(args, 2)
        if v is None:
            return
        if not set(v) <= {0, 1}:
            self.reply("ER17")
            return
        self.backlight = (v[0], v[1])
        self._settings_changed()
        self.reply("OK00")

    def _cmd_BALR(self, args: list[str]) -> None:
        self._read(args, f"{self.backlight[0]},{self.backlight[1]}")

    def _cmd_UCCS(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if not 0 <= v[0] <= 10:
            self.reply("ER17")
        elif v[0] and v[0] not in self.user_channels:
            self.reply("ER05")                       # no compensation values in that channel
        else:
            self.cal_channel = v[0]
            self._settings_changed()
            self.reply("OK00")

    def _cmd_UCCR(self, args: list[str]) -> None:
        self._read(args, f"{self.cal_channel:02d}")

    def _cmd_LNSS(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in (0, 1):
            self.reply("ER17")
        elif v[0] == 1 and not self.lens_factors:
            self.reply("ER05")
        else:
            self.lens = v[0]
            self._settings_changed()
            self.reply("OK00")

    def _cmd_LNSR(self, args: list[str]) -> None:
        self._read(args, str(self.lens))

    def _cmd_NDFS(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in (0, 1, 2):
            self.reply("ER17")
        elif v[0] and not self.nd_factors:
            self.reply("ER05")
        else:
            self.nd_filter = v[0]
            self._settings_changed()
            self.reply("OK00")

    def _cmd_NDFR(self, args: list[str]) -> None:
        self._read(args, str(self.nd_filter))

    # compensation factors: UCPS / ALFS / NFCS are multi-step writes ended by ``XXXS,3``.
    # The steps are accepted and kept without interpreting their values (*simplified*).
    def _staged_write(self, name: str, args: list[str]) -> str | None:
        """Stage one step; returns the commit argument (after ``3``) once committed."""
        if not args or args[0] not in ("1", "2", "3"):
            self.reply("ER17" if args else "ER00")
            return None
        if args[0] != "3":
            self._staged.setdefault(name, []).append(",".join(args))
            self.reply("OK00")
            return None
        if not self._staged.pop(name, None):
            self.reply("ER17")                       # nothing to commit
            return None
        self.flash_writes += 1
        self.reply("OK00")
        return ",".join(args[1:])

    def _cmd_UCPS(self, args: list[str]) -> None:
        if args and args[0] == "3" and not (len(args) == 2 and args[1].isdigit()
                                            and 1 <= int(args[1]) <= 10):
            self.reply("ER17")
            return
        committed = self._staged_write("UCPS", args)
        if committed is not None:
            self.user_channels[int(committed)] = "USER"

    def _cmd_UCPR(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if not 1 <= v[0] <= 10:
            self.reply("ER17")
        elif v[0] not in self.user_channels:
            self.reply("ER05")
        else:
            self.reply(f"OK00,{self.user_channels[v[0]]:<10}")

    def _cmd_UCCD(self, args: list[str]) -> None:
        v = self._ints(args, 1)
        if v is None:
            return
        if not 1 <= v[0] <= 10:
            self.reply("ER17")
            return
        self.user_channels.pop(v[0], None)
        if self.cal_channel == v[0]:
            self.cal_channel = 0
        self.reply("OK00")

    def _cmd_ALFS(self, args: list[str]) -> None:
        if self._staged_write("ALFS", args) is not None:
            self.lens_factors = True

    def _cmd_ALFR(self, args: list[str]) -> None:
        self.reply("OK00" if self.lens_factors else "ER05")

    def _cmd_NFCS(self, args: list[str]) -> None:
        if self._staged_write("NFCS", args) is not None:
            self.nd_factors = True

    def _cmd_NFCR(self, args: list[str]) -> None:
        self.reply("OK00" if self.nd_factors else "ER05")

    # stored measurements 00–99 and colour-difference targets 01–20
    def _slot(self, args: list[str], lo: int, hi: int, count: int = 1) -> list[int] | None:
        v = self._ints(args, count)
        if v is None:
            return None
        if not lo <= v[0] <= hi:
            self.reply("ER17")
            return None
        return v

    def _cmd_STDS(self, args: list[str]) -> None:
        v = self._slot(args, 0, 99)
        if v is None:
            return
        if self.data is None:
            self.reply("ER20")
            return
        self.memory[v[0]] = self.data
        self.reply("OK00")

    def _cmd_STDR(self, args: list[str]) -> None:
        v = self._slot(args, 0, 99, 4)
        if v is None:
            return
        if not self._valid_block(*v[1:]):
            self.reply("ER17")
        elif v[0] not in self.memory:
            self.reply("ER20")
        else:
            self.reply(self._data_reply(self.memory[v[0]], *v[1:]))

    def _cmd_STDD(self, args: list[str]) -> None:
        v = self._slot(args, 0, 99)
        if v is not None:
            self.memory.pop(v[0], None)
            self.reply("OK00")

    def _cmd_STAD(self, args: list[str]) -> None:
        if args:
            self.reply("ER00")
            return
        self.memory.clear()
        self.reply("OK00")

    def _cmd_TGSL(self, args: list[str]) -> None:
        v = self._slot(args, 1, 20)
        if v is not None:
            self.target = v[0]
            self._settings_changed()
            self.reply("OK00")

    def _cmd_TGSR(self, args: list[str]) -> None:
        self._read(args, f"{self.target:02d}")

    def _cmd_TGDS(self, args: list[str]) -> None:
        v = self._slot(args, 1, 20)
        if v is None:
            return
        if self.data is None:
            self.reply("ER20")
            return
        self.targets[v[0]] = self.data
        self.reply("OK00")

    def _cmd_TGDR(self, args: list[str]) -> None:
        v = self._slot(args, 1, 20, 4)           # TGDR,nn,m,f,b like STDR (*assumed*)
        if v is None:
            return
        if not self._valid_block(*v[1:]):
            self.reply("ER17")
        elif v[0] not in self.targets:
            self.reply("ER20")
        else:
            self.reply(self._data_reply(self.targets[v[0]], *v[1:]))

    def _cmd_TGDD(self, args: list[str]) -> None:
        v = self._slot(args, 1, 20)
        if v is not None:
            self.targets.pop(v[0], None)
            self.reply("OK00")

    def _cmd_TGAD(self, args: list[str]) -> None:
        if args:
            self.reply("ER00")
            return
        self.targets.clear()
        self.reply("OK00")

    def _cmd_BPSS(self, args: list[str]) -> None:
        if _firmware_tuple(self.firmware) < (3, 0, 0):
            self.reply("ER00")
            return
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in BAUD_RATES:
            self.reply("ER17")
            return
        self.reply("OK00")                         # still at the old rate
        self.line_baud = self.baud = v[0]
        self._settings_changed()

    def _cmd_BPSR(self, args: list[str]) -> None:
        if _firmware_tuple(self.firmware) < (3, 0, 0):
            self.reply("ER00")
            return
        self._read(args, f"{self.line_baud:>6}")

    def _cmd_INIT(self, args: list[str]) -> None:
        if _firmware_tuple(self.firmware) < (3, 0, 9301):
            self.reply("ER00")
            return
        v = self._ints(args, 1)
        if v is None:
            return
        if v[0] not in (0, 1, 2):
            self.reply("ER17")
            return
        if v[0] in (0, 2):
            self._factory_settings()
            self.flash_writes += 1
        if v[0] in (0, 1):
            self._factory_data()
            self.data = None
        self.reply("OK00")

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
        if not self._valid_block(*v):
            self.reply("ER17")
            return
        if self.data is None:
            self.reply("ER20")
            return
        kind, fmt, block = v
        self.reply(self._data_reply(self.data, kind, fmt, block))
        if kind == 1:
            self._spectral_read.add(block)
        if self.button_enabled and (kind == 2 or self._spectral_read == set(SPECTRAL_BLOCKS)):
            self.data = None                        # MSWE,1: the buffer is read once

    @staticmethod
    def _valid_block(kind: int, fmt: int, block: int) -> bool:
        return (fmt in (0, 1) and ((kind == 0 and block == 1)
                                   or (kind == 1 and block in SPECTRAL_BLOCKS)
                                   or (kind == 2 and block in COLORIMETRIC_BLOCKS)))

    def _data_reply(self, d: dict[str, Any], kind: int, fmt: int, block: int) -> str:
        if kind == 0:
            # speed, sync, integration µs, internal ND, lens, external ND, angle, cal channel
            return (f"OK00,{d['speed_mode']},{d['sync_mode']},{d['integration_time_us']:09d},"
                    f"{d['nd_used']},{d['lens']},{d['nd_filter']},0,{d['cal_channel']:02d}")
        if kind == 1:
            lo, hi = SPECTRAL_BLOCKS[block]
            values = d["spectrum"][lo:hi]
            return "OK00," + ",".join(fmt_hex(x) if fmt else fmt_e(x) for x in values)
        return "OK00," + ",".join(self._colorimetric(d, block, fmt))

    def _colorimetric(self, d: dict[str, Any], block: int, fmt: int) -> list[str]:
        c2, c10 = d["colorimetry"], d["colorimetry10"]
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
        spectrum, c2 = self.optics.observe(self.faults)
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
                         "integration_time_us": t_int_us, "over_range": over,
                         "speed_mode": self.speed_mode, "nd_used": int(self.nd == 1),
                         "sync_mode": self.sync_mode, "lens": self.lens,
                         "nd_filter": self.nd_filter, "cal_channel": self.cal_channel}
        self.phase = "pre"
        self.phase_end_s = self.clock.now_s() + pre_measurement_s(lv) * self.time_factor

    def on_time(self, now_s: float) -> None:
        if self._cr_hold_s is not None and now_s >= self._cr_hold_s:
            self._split_lines(final=True)       # a lone CR: the command ends there
        self.advance_measurement(
            now_s, lambda p: (p["ttt"] - ANNOUNCE_MARGIN_S) * self.time_factor,
            lambda p: f"OK00,{p['ttt']:03d}", "OK00")

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


core.register("cs2000a", _factory, faults=CS2000AEmulator.known_faults())

__all__ = ["CS2000AEmulator", "fmt_hex", "fmt_lv", "measurement_time_s"]
