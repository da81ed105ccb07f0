"""Integrating-sphere light source (Image Engineering LE7-4x stand-in), emulated at the wire.

PLACEHOLDER PROTOCOL.  Image Engineering publish no remote-control protocol for the LE7; this
emulator speaks a SCPI-like command set of our own ([LE7], [SCPI] in docs/references.md;
every name is invented), so the app, its tests and outside programs have something
real to talk to.  The real adapter is written when the vendor document arrives, behind the same
`LightSource` interface (drivers/sphere.py).

Line: ASCII, commands end in LF (CR tolerated), every command gets exactly one reply line
ending in LF (two for ``MEAS:SPEC?``): ``OK``, a value, or ``ERR <code>`` (the error is also
queued for ``SYST:ERR?``).

    *IDN?                vendor,model,serial,firmware
    *RST / *CLS          OK (reset: output off, level 100, preset D65, queue cleared / clear queue)
    SYST:ERR?            <code>,"<text>"  (0,"No error" when empty)
    OUTP ON|OFF / OUTP?  OK / 1|0
    INT <0..100> / INT?  OK / level in %
    SPEC:PRES <D65|A> / SPEC:PRES?
    STAT?                OFF | SETTLING | STABLE | ERROR
    STAB:TIME?           seconds since the output became stable (0 when not stable)
    STAB:REM?            estimated seconds until stable (full warm-up when off, 0 when stable)
    MEAS:SPEC?           "380,1,401,REL" then 401 comma-separated relative values (internal
                         spectrometer: preset spectrum × relative output, 0.2 % noise)
    MEAS:LUM?            panel luminance, cd/m² (nominal × relative output)
    PANEL:MAP?           25 relative radiances of the opal panel, row-major 5 × 5, mean 1
    PANEL:MAP? r,c       the one at row r, column c (0-based)
    TEMP? / HOUR?        LED board °C / lamp hours
    ABOR                 OK
Errors: -100 "Command error", -222 "Data out of range", -224 "Illegal parameter value",
-350 "Queue overflow" (queue of 10), 201 "Lamp failure".

Behaviour (all on the injected clock):
- switch-on: output starts at 80 % of the set level and rises as 1 − 0.2·exp(−t/τ), τ = 60 s;
  STABLE once within 0.1 % (t = τ·ln 200 ≈ 318 s); a level change re-settles for 30 s;
- slow drift −0.05 %/h while on, noise 0.02 % rms per reading;
- the opal panel's 25-point map (`normbox_lab.predict.scene.panel_map`, ±3 % homogeneity).

Device faults: ``unstable`` (at a command: the regulation loses lock, a 2 % dip and SETTLING
for `parameter` s, default 60), ``lamp-fail`` (at a command: output 0, state ERROR, error 201
queued; cleared by OUTP OFF then ON).  Conditions that the regulation does *not* see (STAT?
stays STABLE; only the output, hence the radiometer and the sphere's own monitor ``MEAS:LUM?``,
show them), latched from the command at which they fire: ``lamp-drift`` (the output drifts by
`parameter` %/h, default −10), ``flicker`` (output noise of `parameter` % rms, default 2).
"""

from __future__ import annotations

import math
import random
from typing import Any

import numpy as np

from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.predict.scene import panel_map as truth_panel_map
from normbox_lab.sim import colour_tables, core

WARMUP_TAU_S = 60.0
WARMUP_DEFICIT = 0.2
STABLE_TOLERANCE = 0.001
WARMUP_S = WARMUP_TAU_S * math.log(WARMUP_DEFICIT / STABLE_TOLERANCE)
LEVEL_SETTLE_S = 30.0
DRIFT_PER_H = -0.0005
NOISE_RMS = 0.0002
NOMINAL_LUMINANCE_CD_M2 = 2000.0
WAVELENGTHS_NM = RADIOMETER_WAVELENGTHS_NM
ERRORS = {-100: "Command error", -222: "Data out of range", -224: "Illegal parameter value",
          -350: "Queue overflow", 201: "Lamp failure"}


def preset_spectrum(name: str) -> np.ndarray:
    """Relative spectral power of a preset on 380–780 nm (1 at 560 nm)."""
    if name == "A":
        c2 = 1.4388e7  # nm·K
        s = WAVELENGTHS_NM ** -5 / (np.exp(c2 / (WAVELENGTHS_NM * 2856.0)) - 1.0)
    else:              # CIE D65 (colour-science's table, shipped: no import at serve time)
        s = colour_tables.d65()
    return s / np.interp(560.0, WAVELENGTHS_NM, s)


class SphereEmulator(core.LineEmulator):
    device_name = "sphere"
    fault_kinds: tuple[core.FaultKind, ...] = (
        core.FaultKind("unstable", "@", (1, 12), (1.0, 3600.0), "log", unit="s",
                       means="a 2 % dip, then not stable for this long",
                       detector="stability check → suspend, wait, retake; prompt",
                       param_is_wait_s=True),
        core.FaultKind("lamp-fail", "@", (1, 12), means="the lamp goes out (ERROR state)",
                       detector="typed DeviceError(LAMP) → prompt"),
        core.FaultKind("lamp-drift", "@", (1, 12), (-100.0, 100.0), "linear", unit="%/h",
                       means="the output drifts at this rate (the monitor follows it)",
                       detector="lamp-drift gate (monitor vs reference, 0.5 %)"),
        core.FaultKind("flicker", "@", (1, 12), (0.01, 20.0), "log", unit="% rms",
                       means="output noise of this size",
                       detector="lamp-unstable gate (monitor scatter, 0.25 %)"),
        core.FaultKind("monitor-stuck", "@", (1, 12), (-100.0, 100.0), "linear", unit="%/h",
                       means="from the n-th command the monitor (MEAS:LUM?) keeps its value "
                             "while the output drifts at this rate",
                       detector="undetectable by the lab as built (one light sensor, no "
                                "reference re-measured): docs/fault-behaviour.md bounds it",
                       campaign=False),
    )
    device_faults = tuple(k.kind for k in fault_kinds)
    terminators = (b"\n", b"\r")
    presets = ("D65", "A")

    def __init__(self, clock: Any = None, faults: str = "", seed: int = 0, *,
                 homogeneity_percent: float = 3.0, serial: str = "LE7-SIM-0001") -> None:
        super().__init__(clock, faults, seed)
        self.rng = random.Random(seed)
        self.serial = serial
        self.map = truth_panel_map(homogeneity_percent)
        self.reset()

    def prepare(self) -> None:
        """Read the D65 table now, so the first ``MEAS:SPEC?`` answers as fast as the next."""
        for name in self.presets:
            preset_spectrum(name)

    def reset(self) -> None:
        self.on = False
        self.failed = False
        self.level_percent = 100.0
        self.preset = "D65"
        self.on_since_s = 0.0
        self.settle_until_s = 0.0      # extra settling (level change, lost lock)
        self.dip = 0.0
        self.dip_since_s = 0.0
        self.errors: list[int] = []
        self.hours = 412.0
        self.drift_since_s: float | None = None     # lamp-drift latched at
        self.flicker_rms = 0.0
        #: monitor-stuck: (time it latched, the value MEAS:LUM? keeps answering)
        self.stuck: tuple[float, float] | None = None

    # --- physics the world reads -------------------------------------------------------------
    def _warm(self, now_s: float) -> float:
        return 1.0 - WARMUP_DEFICIT * math.exp(-(now_s - self.on_since_s) / WARMUP_TAU_S)

    def state(self) -> str:
        """"off", "settling", "stable" (or "error" after a lamp failure)."""
        if self.failed:
            return "error"
        if not self.on:
            return "off"
        now = self.clock.now_s()
        if now - self.on_since_s < WARMUP_S or now < self.settle_until_s:
            return "settling"
        return "stable"

    def relative_output(self) -> float:
        """Output relative to the nominal stable output (1.0), drift and noise included."""
        if not self.on or self.failed:
            return 0.0
        now = self.clock.now_s()
        hours_on = (now - self.on_since_s) / 3600.0
        dip = self.dip * math.exp(-(now - self.dip_since_s) / 20.0) if self.dip else 0.0
        fault_drift = 0.0
        if self.drift_since_s is not None:
            fault_drift = (self.faults.parameter("lamp-drift", -10.0) / 100.0
                           * (now - self.drift_since_s) / 3600.0)
        if self.stuck is not None:       # the output drifts, the monitor does not see it
            fault_drift += (self.faults.parameter("monitor-stuck", -10.0) / 100.0
                            * (now - self.stuck[0]) / 3600.0)
        return (self.level_percent / 100.0 * self._warm(now) * (1.0 + DRIFT_PER_H * hours_on)
                * (1.0 + fault_drift) * (1.0 - dip)
                * (1.0 + self.rng.gauss(0.0, math.hypot(NOISE_RMS, self.flicker_rms))))

    def panel_map(self) -> np.ndarray:
        """(5, 5) relative radiance of the opal panel (mean 1)."""
        return self.map.copy()

    def stable_for_s(self) -> float:
        if self.state() != "stable":
            return 0.0
        return self.clock.now_s() - max(self.on_since_s + WARMUP_S, self.settle_until_s)

    def remaining_s(self) -> float:
        st = self.state()
        if st in ("off", "error"):
            return WARMUP_S
        now = self.clock.now_s()
        return max(0.0, self.on_since_s + WARMUP_S - now, self.settle_until_s - now)

    # --- protocol ------------------------------------------------------------------------------
    def _error(self, code: int) -> None:
        if len(self.errors) >= 10:
            self.errors[-1] = -350
        else:
            self.errors.append(code)
        self.emit(f"ERR {code}\n".encode())

    def _ok(self, text: str = "OK") -> None:
        self.emit(f"{text}\n".encode())

    def on_line(self, line: bytes, terminator: bytes) -> None:
        text = line.decode("ascii", "replace").strip()
        if not text:
            return
        now = self.clock.now_s()
        self._fire_faults(now)
        head, _, arg = text.partition(" ")
        head = head.upper()
        arg = arg.strip()
        if head == "*IDN?":
            self._ok(f"Image Engineering (placeholder protocol),LE7-4x,{self.serial},0.1-sim")
        elif head == "*RST":
            self.reset()
            self._ok()
        elif head == "*CLS":
            self.errors.clear()
            self._ok()
        elif head == "SYST:ERR?":
            code = self.errors.pop(0) if self.errors else 0
            self._ok(f'{code},"{ERRORS.get(code, "No error")}"')
        elif head == "OUTP":
            self._output(arg, now)
        elif head == "OUTP?":
            self._ok("1" if self.on else "0")
        elif head == "INT":
            self._intensity(arg, now)
        elif head == "INT?":
            self._ok(f"{self.level_percent:.2f}")
        elif head == "SPEC:PRES":
            self._preset(arg, now)
        elif head == "SPEC:PRES?":
            self._ok(self.preset)
        elif head == "STAT?":
            self._ok(self.state().upper())
        elif head == "STAB:TIME?":
            self._ok(f"{self.stable_for_s():.1f}")
        elif head == "STAB:REM?":
            self._ok(f"{self.remaining_s():.1f}")
        elif head == "MEAS:SPEC?":
            rel = self.relative_output()
            spd = preset_spectrum(self.preset) * rel
            spd = spd * (1.0 + np.array([self.rng.gauss(0.0, 0.002) for _ in spd]))
            self.emit(b"380,1,401,REL\n" + ",".join(f"{v:.5f}" for v in spd).encode() + b"\n")
        elif head == "MEAS:LUM?":
            lum = NOMINAL_LUMINANCE_CD_M2 * self.relative_output()
            self._ok(f"{lum if self.stuck is None else self.stuck[1]:.2f}")
        elif head == "PANEL:MAP?":
            self._panel_map(arg)
        elif head == "TEMP?":
            warm = 0.0 if not self.on else 1.0 - math.exp(-(now - self.on_since_s) / 300.0)
            self._ok(f"{25.0 + 10.0 * warm:.1f}")
        elif head == "HOUR?":
            self._ok(f"{self.hours:.1f}")
        elif head == "ABOR":
            self._ok()
        else:
            self._error(-100)

    def _fire_faults(self, now: float) -> None:
        """The seeded faults that may start at this command (each draws in this order)."""
        if self.on and not self.failed and self.faults.fires("lamp-fail"):
            self.failed = True
            self.errors.append(201)
        if self.on and not self.failed and self.faults.fires("unstable"):
            self.settle_until_s = now + self.faults.parameter("unstable", 60.0)
            self.dip, self.dip_since_s = 0.02, now
        if self.drift_since_s is None and self.faults.fires("lamp-drift"):
            self.drift_since_s = now
        if not self.flicker_rms and self.faults.fires("flicker"):
            self.flicker_rms = self.faults.parameter("flicker", 2.0) / 100.0
        if self.stuck is None and self.on and self.faults.fires("monitor-stuck"):
            self.stuck = (now, NOMINAL_LUMINANCE_CD_M2 * self.relative_output())

    def _output(self, arg: str, now: float) -> None:
        """OUTP ON|OFF|1|0: the lamp on (warm-up starts) or off (a failure clears)."""
        if arg.upper() not in ("ON", "OFF", "1", "0"):
            self._error(-224)
            return
        want = arg.upper() in ("ON", "1")
        if want and not self.on:
            self.on_since_s = now
            self.dip = 0.0
        if not want:
            self.failed = False
        self.on = want
        self._ok()

    def _intensity(self, arg: str, now: float) -> None:
        """INT <0–100>: the level in percent; a change while on settles again."""
        try:
            level = float(arg)
        except ValueError:
            self._error(-224)
            return
        if not 0.0 <= level <= 100.0:
            self._error(-222)
            return
        if level != self.level_percent and self.on:
            self.settle_until_s = now + LEVEL_SETTLE_S
        self.level_percent = level
        self._ok()

    def _preset(self, arg: str, now: float) -> None:
        """SPEC:PRES <name>: a spectral preset; a change while on settles again."""
        if arg.upper() not in self.presets:
            self._error(-224)
            return
        self.preset = arg.upper()
        if self.on:
            self.settle_until_s = now + LEVEL_SETTLE_S
        self._ok()

    def _panel_map(self, arg: str) -> None:
        """PANEL:MAP? [row,col]: the whole 5 × 5 map, or one point of it."""
        if not arg:
            self._ok(",".join(f"{v:.5f}" for v in self.map.ravel()))
            return
        try:
            r, c = (int(x) for x in arg.split(","))
        except ValueError:
            self._error(-224)
            return
        if not (0 <= r < 5 and 0 <= c < 5):
            self._error(-222)
            return
        self._ok(f"{self.map[r, c]:.5f}")

    def next_state_s(self) -> float | None:
        """When the state changes next by itself (the end of settling)."""
        if not self.on or self.failed:
            return None
        t = max(self.on_since_s + WARMUP_S, self.settle_until_s)
        return t if t > self.clock.now_s() else None


def _factory(clock: Any = None, faults: str = "", seed: int = 0, world: Any = None,
             **options: Any) -> SphereEmulator:
    kw: dict[str, Any] = {}
    if "homogeneity_percent" in options:
        kw["homogeneity_percent"] = float(options["homogeneity_percent"])
    elif world is not None and hasattr(world, "geometry"):
        kw["homogeneity_percent"] = float(getattr(world.geometry, "panel_homogeneity_percent",
                                                  3.0))
    if "serial" in options:
        kw["serial"] = str(options["serial"])
    return SphereEmulator(clock, faults, seed, **kw)


core.register("sphere", _factory, faults=SphereEmulator.known_faults())
