"""JETI specbos 1211 spectroradiometer, emulated at the wire.

Written from the instrument facts, not from the driver.  References: [JETI-SB1211] in
docs/references.md (JETI's firmware command reference for the specbos 1201/1211, and the
public clients that agree on its answers).  What the sources leave open is marked *assumed*
here and in docs/radiometers.md.

Line: a virtual COM port (USB); 921600 baud 8N1 without flow control by default (115200 and
38400 are the other rates the clients try).  A command ends in CR (an LF after it is ignored);
command words are case-insensitive.  Answers (as the public clients read them):
  - a query (``…?``) and a fetch: text lines, each ending in CR;
  - a setting (``*PARA``, ``*CONF``, ``*CONTR`` with arguments): ACK (0x06) when accepted,
    NAK (0x15) when refused — no CR;
  - ``*INIT``: ACK when accepted, BEL (0x07) when the measurement has ended (NAK when it
    failed);
  - after a NAK, ``*STAT:ERR?`` answers ``Error Code: <n>`` (and clears it; *assumed*).
Bytes take 10 bits each at `baud` to cross the line.

Commands emulated:
  *IDN?                 ``JETI_SB1211``
  *VERS?                the firmware version (*assumed* layout: the bare version)
  *PARA:SERNO?          ``serial number: <n>``;  *PARA:SPNUM?  ``spectrometer number: <n>``
  *PARA:WAVBEG? / WAVEND?   ``Predefined start wave: 380`` / ``Predefined end wave: 780``
  *CONF:DEFAULT         the configuration's defaults (the configuration is temporary: a
                        power-up restores them too)
  *CONF:WRAN b e s      wavelength range and step, integer nm inside the predefined range
  *CONF:AVER n          averages, 1–100
  *CONF:EXPO m          1 adaptive (auto) integration time, 2 fixed (*CONF:TINT)
  *CONF:TINT t          fixed integration time, ms, 1–60000 (decimals allowed)
  *CONF:MAXTIN t        the adaptive time's upper limit, ms, 1000–60000
  *CONF:FUNC n          measuring function (6 = radiometric spectrum; kept, not interpreted)
  *CONF:FORM n          spectral output: 4 values only, 7 or 10 ``<nm><TAB><value>``
  *CONF:<name>?         ``<name>: <value(s)>`` for WRAN, AVER, EXPO, TINT, MAXTIN, FUNC, FORM
  *CONTR:LASER 0|1 / *CONTR:LASER?   the target laser; ``laser: <0|1>``
  *CONTR:MHEAD?         ``mhead: 0`` (measuring head: radiance optics, no diffuser)
  *INIT                 measure with the configuration: ACK, then BEL at the end
  *MEAS:SPRAD t a f     measure (t ms, 0 = adaptive; a averages; f format as *CONF:FORM) and
                        answer with the data: ACK, then BEL and the spectral block
  *FETCH:SPRAD          the last measurement's spectral block, in *CONF:FORM's format:
                          ``tint[ms]: <t>`` CR, ``wran: <b> <e> <s>`` CR (*assumed* header),
                          one line per wavelength, then an empty line (CR)
                        values in W·sr⁻¹·m⁻²·nm⁻¹, ``%.5e``
  *FETCH:XYZ            ``X: <X>`` CR ``Y: <Y>`` CR ``Z: <Z>`` CR (CIE 1931 2°, Y = Lv cd/m²)
  *STAT:ERR?            ``Error Code: <n>``
  *BREAK                stop a running measurement (its *INIT ends in NAK, error 147 "scan
                        break"); idle: ACK (*assumed* command)
  while measuring       *BREAK, *IDN? and *STAT:ERR? are answered; anything else is NAK with
                        error 4 (*assumed*)
Everything else → NAK, error 4; a bad argument → NAK, error 10–13 (argument 1–4).

Timing model (*assumed*; docs/radiometers.md): adaptive integration time
t = clamp(K / Lv, 1 ms, MAXTIN) with K = 20 cd·s/m², found in an adaptation phase of
ADAPT_S = 1 s; then `aver` × (light + dark) = aver × 2·t, plus OVERHEAD_S = 0.2 s.  A fixed
time skips the adaptation.  Above `max_luminance_cd_m2` the measurement ends in NAK, error 120
(overexposure).

Device faults (besides the transport kinds of `sim.core`): ``device-error`` (a command is
answered NAK; ``*STAT:ERR?`` then gives the fault parameter, default 171 "read parameter from
flash"), ``over-range`` (the next measurement ends in NAK, error 120).  A disconnect models a
power blip: the configuration is back at its defaults and the last measurement is gone.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from normbox_lab.sim import core
from normbox_lab.sim.radiometer_common import (
    DATA_FAULT_KINDS,
    RadiometerOptics,
    Scene,
    env_time_factor,
)

ACK, NAK, BEL = b"\x06", b"\x15", b"\x07"
IDENTITY = "JETI_SB1211"
#: the predefined wavelength range of the emulated unit (nm); the emulator's light is known there
PREDEFINED_RANGE_NM = (380, 780)
COMMAND_DELAY_S = 0.01
K_AUTO_CD_S_M2 = 20.0
MIN_TINT_MS = 1.0
MAX_TINT_MS = 60_000.0
ADAPT_S = 1.0
OVERHEAD_S = 0.2
#: error codes (the instrument's numbers)
ERR_COMMAND, ERR_ARG_1, ERR_OVEREXPOSED, ERR_NO_LIGHT_MEAS, ERR_SCAN_BREAK = 4, 10, 120, 138, 147
DEFAULTS: dict[str, Any] = {"wran": (380, 780, 1), "aver": 1, "expo": 1, "tint": 100.0,
                            "maxtin": 60_000.0, "func": 6, "form": 7}


def adaptive_tint_ms(luminance_cd_m2: float, maxtin_ms: float = MAX_TINT_MS) -> float:
    """The integration time the adaptation finds (ms)."""
    t_ms = 1000.0 * K_AUTO_CD_S_M2 / max(float(luminance_cd_m2), 1e-6)
    return round(min(maxtin_ms, max(MIN_TINT_MS, t_ms)), 3)


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if np.isfinite(value) else None


class SpecbosEmulator(core.LineEmulator):
    device_name = "specbos1211"
    replies_in_order = True         # one command at a time: a late reply holds back the next
    fault_kinds: tuple[core.FaultKind, ...] = (
        core.FaultKind("device-error", "@", (1, 12), (0, 999), "choice",
                       choices=(None, 4, 10, 120, 138, 147, 171), unit="error number",
                       means="the n-th command answers NAK with this error (default 171)",
                       detector="typed DeviceError with its meaning → operator prompt"),
        core.FaultKind("over-range", "@", (1, 12), means="the n-th measurement is over range",
                       detector="typed DeviceError → retry / flag instrument-error"),
        *DATA_FAULT_KINDS,
    )
    device_faults = tuple(k.kind for k in fault_kinds)
    terminators = (b"\r",)
    #: `sim latency`: (take the line, its reply's end, start a measurement, the end of its
    #: first reply, its last reply)
    latency_script = (b"*IDN?\r", b"\r", b"*INIT\r", ACK, BEL)

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 scene: Scene | None = None, world: Any = None, noise: str | bool = "on",
                 baud: int | str = 921600, time_factor: float | str | None = None,
                 max_luminance_cd_m2: float | str = 150_000.0, serial_number: str = "123456",
                 spectrometer_number: str = "7201234", firmware: str = "3.8.1") -> None:
        super().__init__(clock, faults, seed)
        self.optics = RadiometerOptics(scene=scene, world=world, noise=noise, seed=seed)
        self.baud = int(baud)
        self.time_factor = float(time_factor) if time_factor is not None else env_time_factor()
        self.max_luminance_cd_m2 = float(max_luminance_cd_m2)
        self.serial_number = str(serial_number)
        self.spectrometer_number = str(spectrometer_number)
        self.firmware = str(firmware)
        self.commands: list[bytes] = []        # every line received, for tests
        self.laser = 0
        self._power_on()

    def prepare(self) -> None:
        self.optics.prepare()

    @property
    def phase(self) -> str:
        """"measuring" while a measurement runs, else "idle" (as the other radiometers say)."""
        return "idle" if self._pending is None else "measuring"

    def _power_on(self) -> None:
        self.conf: dict[str, Any] = dict(DEFAULTS)
        self.error = 0
        self.phase_end_s: float | None = None
        self._pending: dict[str, Any] | None = None
        self.data: dict[str, Any] | None = None

    # --- the timing model (public: ETAs come from here) ---------------------------------------
    def measure_time_s(self, luminance_cd_m2: float) -> float:
        """Adaptation (adaptive time only) + averages × (light + dark) + overhead."""
        adaptive = self.conf["expo"] == 1
        t_ms = adaptive_tint_ms(luminance_cd_m2, self.conf["maxtin"]) if adaptive \
            else self.conf["tint"]
        return ((ADAPT_S if adaptive else 0.0) + self.conf["aver"] * 2 * t_ms / 1000.0
                + OVERHEAD_S) * self.time_factor

    def line_time_s(self, n_bytes: int) -> float:
        return n_bytes * 10.0 / self.baud * self.time_factor

    # --- wire ---------------------------------------------------------------------------------
    def send(self, data: bytes) -> None:
        self.emit(data, COMMAND_DELAY_S * self.time_factor + self.line_time_s(len(data)))

    def line(self, text: str) -> None:
        self.send(text.encode("ascii") + b"\r")

    def nak(self, code: int) -> None:
        self.error = code
        self.send(NAK)

    def on_line(self, line: bytes, terminator: bytes) -> None:
        line = line.lstrip(b"\n").strip()
        if not line:
            return
        self.commands.append(line)
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            self.nak(ERR_COMMAND)
            return
        head, *args = text.split()
        head = head.upper()
        if self._pending is not None:               # measuring
            if head == "*BREAK":
                self._finish(ERR_SCAN_BREAK)
                self.send(ACK)
            elif head in ("*IDN?", "*STAT:ERR?"):
                self._run(head, args)
            else:
                self.nak(ERR_COMMAND)
            return
        if head not in ("*STAT:ERR?",) and self.faults.fires("device-error"):
            self.nak(int(self.faults.parameter("device-error", 171)))
            return
        self._run(head, args)

    def _run(self, head: str, args: list[str]) -> None:
        name = head.lstrip("*").replace(":", "_").replace("?", "_Q")
        method = getattr(self, f"_cmd_{name}", None)
        if method is None:
            if head.startswith("*CONF:") and head.endswith("?") and not args \
                    and head[6:-1].lower() in self.conf:
                self._conf_query(head[6:-1].lower())
            elif head.startswith("*CONF:") and head[6:].lower() in self.conf:
                self._conf_set(head[6:].lower(), args)
            else:
                self.nak(ERR_COMMAND)
            return
        method(args)

    # --- general and parameters ----------------------------------------------------------------
    def _cmd_IDN_Q(self, args: list[str]) -> None:
        self.line(IDENTITY) if not args else self.nak(ERR_ARG_1)

    def _cmd_VERS_Q(self, args: list[str]) -> None:
        self.line(self.firmware) if not args else self.nak(ERR_ARG_1)

    def _cmd_STAT_ERR_Q(self, args: list[str]) -> None:
        code, self.error = self.error, 0
        self.line(f"Error Code: {code}")

    def _cmd_PARA_SERNO_Q(self, args: list[str]) -> None:
        self.line(f"serial number: {self.serial_number}")

    def _cmd_PARA_SPNUM_Q(self, args: list[str]) -> None:
        self.line(f"spectrometer number: {self.spectrometer_number}")

    def _cmd_PARA_WAVBEG_Q(self, args: list[str]) -> None:
        self.line(f"Predefined start wave: {PREDEFINED_RANGE_NM[0]}")

    def _cmd_PARA_WAVEND_Q(self, args: list[str]) -> None:
        self.line(f"Predefined end wave: {PREDEFINED_RANGE_NM[1]}")

    def _cmd_CONTR_LASER(self, args: list[str]) -> None:
        if args not in (["0"], ["1"]):
            self.nak(ERR_ARG_1)
            return
        self.laser = int(args[0])
        self.send(ACK)

    def _cmd_CONTR_LASER_Q(self, args: list[str]) -> None:
        self.line(f"laser: {self.laser}")

    def _cmd_CONTR_MHEAD_Q(self, args: list[str]) -> None:
        self.line("mhead: 0")

    def _cmd_BREAK(self, args: list[str]) -> None:
        self.send(ACK)

    # --- the configuration -----------------------------------------------------------------------
    def _cmd_CONF_DEFAULT(self, args: list[str]) -> None:
        self.conf = dict(DEFAULTS)
        self.send(ACK)

    def _conf_query(self, name: str) -> None:
        value = self.conf[name]
        shown = " ".join(str(v) for v in value) if isinstance(value, tuple) else f"{value:g}"
        self.line(f"{name}: {shown}")

    def _conf_set(self, name: str, args: list[str]) -> None:
        """Check every argument; NAK with the number of the first bad one."""
        wanted = 3 if name == "wran" else 1
        values = [_number(a) for a in args]
        if len(args) != wanted:
            self.nak(ERR_ARG_1 + min(len(args), wanted - 1) if args else ERR_ARG_1)
            return
        integer = name in ("wran", "aver", "expo", "func", "form")
        for i, v in enumerate(values):
            if v is None or (integer and v != int(v)):
                self.nak(ERR_ARG_1 + i)
                return
        bad = self._conf_check(name, values)  # type: ignore[arg-type]
        if bad is not None:
            self.nak(ERR_ARG_1 + bad)
            return
        self.conf[name] = tuple(int(v) for v in values) if name == "wran" else (
            int(values[0]) if integer else float(values[0]))   # type: ignore[arg-type]
        self.send(ACK)

    @staticmethod
    def _conf_check(name: str, v: list[float]) -> int | None:
        """Index of the first argument out of range, or None."""
        lo, hi = PREDEFINED_RANGE_NM
        if name == "wran":
            if not lo <= v[0] < hi:
                return 0
            if not v[0] < v[1] <= hi:
                return 1
            if not 1 <= v[2] <= 10 or (v[1] - v[0]) % v[2]:
                return 2
            return None
        ok = {"aver": 1 <= v[0] <= 100, "expo": v[0] in (1, 2),
              "tint": MIN_TINT_MS <= v[0] <= MAX_TINT_MS, "maxtin": 1000 <= v[0] <= MAX_TINT_MS,
              "func": 1 <= v[0] <= 9, "form": v[0] in (4, 7, 10)}[name]
        return None if ok else 0

    # --- measuring -------------------------------------------------------------------------------
    def _cmd_INIT(self, args: list[str]) -> None:
        if args:
            self.nak(ERR_ARG_1)
            return
        self._start(answer=None)

    def _cmd_MEAS_SPRAD(self, args: list[str]) -> None:
        values = [_number(a) for a in args]
        if len(args) != 3 or any(v is None for v in values):
            self.nak(ERR_ARG_1 + next((i for i, v in enumerate(values) if v is None),
                                      min(len(args), 2)))
            return
        t_ms, aver, form = values
        if not (t_ms == 0 or MIN_TINT_MS <= t_ms <= MAX_TINT_MS):      # type: ignore[operator]
            self.nak(ERR_ARG_1)
        elif aver != int(aver) or not 1 <= aver <= 100:                 # type: ignore[operator]
            self.nak(ERR_ARG_1 + 1)
        elif form not in (4, 7, 10):
            self.nak(ERR_ARG_1 + 2)
        else:
            conf = dict(self.conf, expo=1 if t_ms == 0 else 2, tint=float(t_ms or 0),  # type: ignore[arg-type]
                        aver=int(aver), form=int(form))                # type: ignore[arg-type]
            self._start(answer=conf)

    def _start(self, answer: dict[str, Any] | None) -> None:
        """ACK now; the measurement runs for the timing model's time on the configuration
        (`answer`: *MEAS's own, whose data follow the BEL)."""
        conf = answer if answer is not None else self.conf
        spectrum, colour = self.optics.observe(self.faults)
        lv = colour["Lv"]
        adaptive = conf["expo"] == 1
        t_ms = adaptive_tint_ms(lv, conf["maxtin"]) if adaptive else conf["tint"]
        over = lv > self.max_luminance_cd_m2 or self.faults.fires("over-range")
        saved, self.conf = self.conf, conf
        duration_s = self.measure_time_s(lv)
        self.conf = saved
        self.data = None                      # the buffer empties when a measurement starts
        self._pending = {"spectrum": spectrum, "colorimetry": colour, "tint_ms": t_ms,
                         "over": over, "answer": answer, "wran": conf["wran"]}
        self.phase_end_s = self.clock.now_s() + duration_s
        self.send(ACK)

    def _finish(self, error: int = 0) -> None:
        p = self._pending
        self._pending, self.phase_end_s = None, None
        if p is None:
            return
        if error or p["over"]:
            self.nak(error or ERR_OVEREXPOSED)
            return
        self.data = p
        tail = b"" if p["answer"] is None else self.spectral_block(p["answer"]["form"])
        self.send(BEL + tail)

    def on_time(self, now_s: float) -> None:
        if self.phase_end_s is not None and now_s >= self.phase_end_s:
            self._finish()

    def next_state_s(self) -> float | None:
        return self.phase_end_s

    # --- data --------------------------------------------------------------------------------------
    def spectral_block(self, form: int) -> bytes:
        """The last measurement's spectral block in format `form`."""
        assert self.data is not None
        b, e, s = self.data["wran"]
        grid = np.arange(b, e + 1, s)
        values = self.data["spectrum"][grid - PREDEFINED_RANGE_NM[0]]
        if form == 4:
            rows = [f"{v:.5e}" for v in values]
        else:
            rows = [f"{wl}\t{v:.5e}" for wl, v in zip(grid, values, strict=True)]
        text = [f"tint[ms]: {self.data['tint_ms']:.3f}", f"wran: {b} {e} {s}", *rows, ""]
        return "\r".join(text).encode("ascii") + b"\r"

    def _cmd_FETCH_SPRAD(self, args: list[str]) -> None:
        if args:
            self.nak(ERR_ARG_1)
        elif self.data is None:
            self.nak(ERR_NO_LIGHT_MEAS)
        else:
            self.send(self.spectral_block(self.conf["form"]))

    def _cmd_FETCH_XYZ(self, args: list[str]) -> None:
        if args:
            self.nak(ERR_ARG_1)
        elif self.data is None:
            self.nak(ERR_NO_LIGHT_MEAS)
        else:
            c = self.data["colorimetry"]
            self.send(f"X: {c['X']:.5e}\rY: {c['Y']:.5e}\rZ: {c['Z']:.5e}\r".encode("ascii"))

    # --- link -----------------------------------------------------------------------------------
    def on_disconnect(self) -> None:
        self._power_on()

    def on_new_client(self) -> None:
        """A new client: the half-received command and a measurement the last one started are
        dropped; the configuration stays."""
        self._inbuf.clear()
        self._pending, self.phase_end_s = None, None
