"""Konica Minolta CS-1000A spectroradiometer, emulated at the wire.

Written from the instrument facts, not from the driver.  References: [KM-CS1000] in
docs/references.md.
No official CS-1000 communication document is public: where the sources disagree or are
silent, the choices below are marked *assumed* and listed in docs/radiometers.md.

Line: 8N1, commands end in LF (a trailing CR is tolerated), replies end in LF.  Bytes take
10 bits each at `baud` (default 9600) to cross the line.

States:  local ──RMT,1──▶ remote ──MES,1──▶ pre-measuring ──t_pre──▶ measuring ──2·t──▶ remote
                                                 (OK,<t> on entering measuring; OK at the end)

Commands (reply ``OK`` unless said otherwise):
  RMT,1 / RMT,0      remote mode on / off; in local mode everything else → ER00 (*assumed*)
  MES,1              measure: after the pre-measurement ``OK,<t>`` (integration time, s,
                     ``%.2f``), 2·t later ``OK``; ER10 instead of ``OK,<t>`` when the luminance
                     is above `max_luminance_cd_m2` (*assumed* code)
  MES,0              cancel a running measurement (no final ``OK`` follows; buffer emptied);
                     when idle just ``OK`` (*assumed*)
  MMS,<m>,<t>        time mode: 0 auto, 1 fixed multi-time t s (%.2f), 2 auto (long),
                     3 manual t = 0.04–60 s (%.3f); m = 0/2 send an empty t field
  SPS,<s> / SPR      speed 0 normal / 1 fast; SPR → ``OK,<s>``
  STR                ``OK,<time mode>,<speed>,<manual time %.3f>`` (*assumed* layout; VB reads
                     field 1 as the time mode and field 3 as the manual time)
  BDR,<k>,<o>,<f>    select data: k 0 spectral / 1 colorimetric, o 0 = 2° / 1 = 10°,
                     f 0 ASCII / 1 binary (spectral only; colorimetric binary → ER17)
  &                  next block of the selected data; nothing selected or all sent → ER00
  while measuring    anything but MES,0 → ER02 (*assumed*)
  no data yet        BDR → ER20 (*assumed*); bad parameters → ER17; unknown command → ER00

Data blocks (no status prefix): colorimetry one line of 11 values Le, Lv, X, Y, Z, x, y, u′,
v′, T, Δuv; spectrum 15 lines of ≤ 28 values (14 × 28 + 9 = 401, 380–780 nm).  ASCII numbers use
``#.####e±#`` for radiances and tristimulus values, ``0.####`` for chromaticities, an integer
for T (``-9999`` when undefined) and ``±0.####`` for Δuv (*assumed*; the reference gives no
number format).  Binary spectrum (MesCol, *unconfirmed*): 7 blocks of little-endian float32,
6 × 60 + 41 values, no terminator.

Device faults (besides the transport kinds of `sim.core`): ``device-error`` (reply
``ER<nn>``, nn = the fault parameter, default 51), ``busy`` (ER02 to a command),
``over-range`` (the next measurement ends in ER10 whatever the luminance).

A disconnect models a power blip: the instrument comes back in local mode with no data.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np

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

SPECTRAL_BLOCK_VALUES = 28
BINARY_BLOCK_VALUES = 60
K_NORMAL_CD_S_M2 = 100.0
K_FAST_CD_S_M2 = 25.0
MIN_INTEGRATION_S = 0.05
MAX_INTEGRATION_S = 60.0
COMMAND_DELAY_S = 0.02


def integration_time_s(luminance_cd_m2: float, speed: int = 0, time_mode: int = 0,
                       manual_time_s: float = 1.0) -> float:
    """Integration time t (the ``OK,<t>`` value); the main phase lasts 2·t."""
    if time_mode in (1, 3):
        return float(manual_time_s)
    k = K_FAST_CD_S_M2 if speed == 1 else K_NORMAL_CD_S_M2
    lv = max(float(luminance_cd_m2), 1e-6)
    return round(min(MAX_INTEGRATION_S, max(MIN_INTEGRATION_S, k / lv)), 2)


class CS1000AEmulator(KonicaMinoltaCommands, core.LineEmulator):
    device_name = "cs1000a"
    replies_in_order = True         # one command at a time: a late reply holds back the next
    remote_command = "RMT"
    fault_kinds = RADIOMETER_FAULT_KINDS + DATA_FAULT_KINDS
    device_faults = tuple(k.kind for k in fault_kinds)
    #: `sim latency`: (take the line, its reply's end, start a measurement, the end of its
    #: first reply, its last reply)
    latency_script = (b"RMT,1\n", b"\n", b"MES,1\n", b"\n", b"OK\n")
    terminators = (b"\n",)

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 scene: Scene | None = None, world: Any = None, noise: str | bool = "on",
                 baud: int | str = 9600, time_factor: float | str | None = None,
                 max_luminance_cd_m2: float | str = 80_000.0) -> None:
        super().__init__(clock, faults, seed)
        self.optics = RadiometerOptics(scene=scene, world=world, noise=noise, seed=seed)
        self.baud = int(baud)
        self.time_factor = float(time_factor) if time_factor is not None else env_time_factor()
        self.max_luminance_cd_m2 = float(max_luminance_cd_m2)
        self.commands: list[bytes] = []        # every line received, for tests
        self._power_on()

    def prepare(self) -> None:
        self.optics.prepare()

    def _power_on(self) -> None:
        self.remote = False
        self.phase = "idle"                    # idle | pre | measuring
        self.phase_end_s: float | None = None
        self.speed = 0
        self.time_mode = 0
        self.manual_time_s = 1.0
        self._pending: dict[str, Any] | None = None
        self.data: dict[str, Any] | None = None      # the last completed measurement
        self._blocks: list[bytes] = []               # what `&` sends next

    # --- the timing model (public: ETAs come from here) -------------------------------------
    def measure_time_s(self, luminance_cd_m2: float) -> float:
        """Pre-measurement + 2 × integration time, for the current speed and time mode."""
        t = integration_time_s(luminance_cd_m2, self.speed, self.time_mode, self.manual_time_s)
        return (pre_measurement_s(luminance_cd_m2) + 2 * t) * self.time_factor

    def line_time_s(self, n_bytes: int) -> float:
        return n_bytes * 10.0 / self.baud * self.time_factor

    # --- wire ---------------------------------------------------------------------------------
    def reply(self, text: str | bytes, *, extra_delay_s: float = 0.0) -> None:
        data = (text.encode("ascii") if isinstance(text, str) else text)
        if isinstance(text, str):
            data += b"\n"
        self.emit(data, COMMAND_DELAY_S * self.time_factor + self.line_time_s(len(data))
                  + extra_delay_s)

    def on_line(self, line: bytes, terminator: bytes) -> None:
        line = line.rstrip(b"\r")
        if not line:
            return
        self.commands.append(line)
        parts = self.split_command(line)
        if parts is None:
            return
        text, cmd, args = parts
        if self.phase != "idle":
            if text == "MES,0":
                self._cancel()
                self.reply("OK")
            else:
                self.reply("ER02")
            return
        self.run_command(cmd, args, "next" if cmd == "&" else None)

    # --- commands -----------------------------------------------------------------------------
    def _cmd_RMT(self, args: list[str]) -> None:
        if args not in (["0"], ["1"]):
            self.reply("ER17" if len(args) == 1 else "ER00")
            return
        self.remote = args == ["1"]
        self.reply("OK")

    def _cmd_MES(self, args: list[str]) -> None:
        if args == ["0"]:
            self.reply("OK")
        elif args == ["1"]:
            self._start()
        else:
            self.reply("ER17" if len(args) == 1 else "ER00")

    def _cmd_MMS(self, args: list[str]) -> None:
        if len(args) != 2 or args[0] not in ("0", "1", "2", "3"):
            self.reply("ER00" if len(args) != 2 else "ER17")
            return
        mode = int(args[0])
        if mode in (1, 3):
            try:
                t = float(args[1])
            except ValueError:
                self.reply("ER17")
                return
            lo, hi = (0.04, 60.0) if mode == 3 else (1.0, 60.0)
            if not lo <= t <= hi:
                self.reply("ER17")
                return
            self.manual_time_s = t
        elif args[1] != "":
            self.reply("ER17")
            return
        self.time_mode = mode
        self.reply("OK")

    def _cmd_SPS(self, args: list[str]) -> None:
        if args not in (["0"], ["1"]):
            self.reply("ER17" if len(args) == 1 else "ER00")
            return
        self.speed = int(args[0])
        self.reply("OK")

    def _cmd_SPR(self, args: list[str]) -> None:
        self.reply(f"OK,{self.speed}" if not args else "ER00")

    def _cmd_STR(self, args: list[str]) -> None:
        if args:
            self.reply("ER00")
            return
        self.reply(f"OK,{self.time_mode},{self.speed},{self.manual_time_s:.3f}")

    def _cmd_BDR(self, args: list[str]) -> None:
        if len(args) != 3:
            self.reply("ER00")
            return
        if args[0] not in ("0", "1") or args[1] not in ("0", "1") or args[2] not in ("0", "1"):
            self.reply("ER17")
            return
        kind, observer, binary = (int(a) for a in args)
        if self.data is None:
            self.reply("ER20")
            return
        if kind == 1 and binary:
            self.reply("ER17")
            return
        spectrum = self.data["spectrum"]
        if kind == 1:
            c = self.data["colorimetry"] if observer == 0 else colorimetry(spectrum, 10)
            self._blocks = [format_colorimetry(c).encode("ascii") + b"\n"]
        elif binary:
            self._blocks = [struct.pack(f"<{len(chunk)}f", *chunk) for chunk in
                            _chunks(spectrum, BINARY_BLOCK_VALUES)]
        else:
            self._blocks = [",".join(fmt_e(v) for v in chunk).encode("ascii") + b"\n"
                            for chunk in _chunks(spectrum, SPECTRAL_BLOCK_VALUES)]
        self.reply("OK")

    def _cmd_next(self, args: list[str]) -> None:
        if args or not self._blocks:
            self.reply("ER00")
            return
        self.reply(self._blocks.pop(0))

    # --- the measurement ----------------------------------------------------------------------
    def _start(self) -> None:
        spectrum, colour_block = self.optics.observe(self.faults)
        lv = colour_block["Lv"]
        over = lv > self.max_luminance_cd_m2 or self.faults.fires("over-range")
        t = integration_time_s(lv, self.speed, self.time_mode, self.manual_time_s)
        self.data = None                        # the buffer empties when a measurement starts
        self._blocks = []
        self._pending = {"spectrum": spectrum, "colorimetry": colour_block,
                         "integration_time_s": t, "over_range": over}
        self.phase = "pre"
        self.phase_end_s = self.clock.now_s() + pre_measurement_s(lv) * self.time_factor

    def _cancel(self) -> None:
        self.cancel_output()
        self.phase, self.phase_end_s, self._pending = "idle", None, None

    def on_time(self, now_s: float) -> None:
        self.advance_measurement(
            now_s, lambda p: 2 * p["integration_time_s"] * self.time_factor,
            lambda p: f"OK,{p['integration_time_s']:.2f}", "OK")

    def next_state_s(self) -> float | None:
        return self.phase_end_s

    def on_disconnect(self) -> None:
        self._power_on()


def _chunks(values: np.ndarray, n: int) -> list[np.ndarray]:
    return [values[i:i + n] for i in range(0, len(values), n)]


def format_colorimetry(c: dict[str, float]) -> str:
    """One ASCII line: Le, Lv, X, Y, Z, x, y, u′, v′, T, Δuv."""
    def chroma(v: float) -> str:
        return "-9.999" if not math.isfinite(v) else f"{v:.4f}"

    T = "-9999" if not math.isfinite(c["T"]) else f"{round(c['T'])}"
    duv = "-9.9999" if not math.isfinite(c["duv"]) else f"{c['duv']:+.4f}"
    return ",".join([fmt_e(c["Le"]), fmt_e(c["Lv"]), fmt_e(c["X"]), fmt_e(c["Y"]),
                     fmt_e(c["Z"]), chroma(c["x"]), chroma(c["y"]), chroma(c["u_prime"]),
                     chroma(c["v_prime"]), T, duv])


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> CS1000AEmulator:
    return CS1000AEmulator(clock, faults, int(seed), world=world, **options)


core.register("cs1000a", _factory, faults=CS1000AEmulator.known_faults())
