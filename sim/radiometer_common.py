"""What the CS-1000A and CS-2000A emulators share: the light they see, the instrument's
imperfections, colorimetry, and the timing model.

Light in view (first that applies):
  1. a ``scene`` callable → ``(wavelength_nm, radiance_W_sr_m2_nm)``;
  2. ``world.radiance_in_view()`` when a world is given;
  3. `default_spectrum()`: a Planckian 2856 K (CIE illuminant A's temperature) scaled to
     ``DEFAULT_LUMINANCE_CD_M2`` = 100 cd/m².
The spectrum is resampled (linear, zero outside its range) to 380–780 nm at 1 nm.

Instrument behaviour (``noise="on"``, the default; seeded, one draw per measurement):
  - wavelength-scale error: the instrument reports L(λ + δ) at λ, δ ~ U(−0.3, +0.3) nm;
  - radiometric error: one gain g ~ U(0.98, 1.02) on the whole spectrum (±2 %).
``noise="off"`` disables both (δ = 0, g = 1): the reported spectrum is the scene's.

Colorimetry: CIE 1931 2° (and 1964 10°) colour-matching functions, integrated explicitly at
1 nm: X = 683·Σ L·x̄·Δλ (so Y = Lv in cd/m²), Le = Σ L·Δλ, x, y, u′, v′ from XYZ, T and Δuv
by Ohno's (2013) method on CIE 1960 uv.  The tables (CMFs, the Planckian table) are
colour-science's, shipped as data (`normbox_lab.sim.colour_tables`): a served emulator never
imports colour-science, and its first measurement is as fast as the next.

Timing model (an assumption written for this lab — Konica Minolta publishes no
luminance-vs-time table; see docs/radiometers.md):
  pre-measurement  t_pre = clamp(1 + 2·log10(100 / Lv), 1, 10) s        (auto-exposure)
  CS-1000A         integration t = clamp(K / Lv, 0.05, 60) s with K = 100 cd·s/m² (normal),
                   25 (fast), or the manual time (MMS,3); main phase = 2·t (light + dark)
  CS-2000A         ttt = clamp(ceil(K / Lv), 2, 242) s with K = 200 (Normal) / 50 (Fast);
                   Multi-Integ: clamp(2·tt, 2, 242); Manual: clamp(ceil(2·t) + 1, 2, 242)
  serial transfer  10 bits per byte at the line's baud rate
`time_factor` (URL option, or the environment variable ``NORMBOX_LAB_SIM_TIME_FACTOR``)
multiplies every duration, e.g. 0.01 for a pty demo on the real clock.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np

from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.sim import colour_tables
from normbox_lab.sim.core import FaultKind

#: the faults both Konica Minolta emulators inject besides the transport faults
RADIOMETER_FAULT_KINDS: tuple[FaultKind, ...] = (
    FaultKind("device-error", "@", (1, 12), (0, 99), "choice",
              choices=(None, 0, 2, 5, 10, 17, 20, 30, 51, 52, 71, 81, 82, 83, 99),
              unit="ER code", means="the n-th command answers ERnn (default ER51; drawn "
                                    "from the codes the manuals list)",
              detector="typed DeviceError with its meaning → operator prompt"),
    FaultKind("busy", "=", (1e-3, 1.0), means="a command answers ER02 (busy)",
              detector="waited out; persistent → typed DeviceError"),
    FaultKind("over-range", "@", (1, 12), means="the n-th measurement is over range (ER10)",
              detector="typed DeviceError → retry / flag instrument-error"),
)
#: faults of the data a radiometer delivers (every emulator that measures through
#: `RadiometerOptics.observe(faults)`); counted per measurement, latched from the n-th on
DATA_FAULT_KINDS: tuple[FaultKind, ...] = (
    FaultKind("stale-data", "=", (1e-3, 1.0),
              means="a measurement's data block repeats the previous measurement's",
              detector="quality gate identical-spectrum (error): noise makes two "
                       "measurements differ"),
    FaultKind("lost-digit", "@", (1, 12), (380, 780), "int", unit="nm",
              means="from the n-th measurement on, this band's value loses its leading "
                    "digit in every transfer",
              detector="driver plausibility: a band off its neighbours by > 25 % of their "
                       "level (5 nm bandwidth) → re-read, ImplausibleData"),
    FaultKind("zero-block", "@", (1, 12), (1, 401), "log-int", unit="bands",
              means="from the n-th measurement on, this many adjacent bands read 0",
              detector="driver plausibility (a step to zero); all 401: radiometer-range "
                       "gate (Lv 0)"),
    FaultKind("negative", "@", (1, 12), (1e-5, 0.1), "log", unit="× peak",
              means="from the n-th measurement on, the dark is over-subtracted where the "
                    "signal is below this fraction of the peak: those bands read negative",
              detector="driver plausibility (the step where the over-subtraction starts); "
                       "quality gate radiance-negative (error): radiance is never < 0"),
)

KM_LM_W = 683.0
DEFAULT_CCT_K = 2856.0
DEFAULT_LUMINANCE_CD_M2 = 100.0
WAVELENGTH_ERROR_NM = 0.3
RADIOMETRIC_ERROR = 0.02

Scene = Callable[[], tuple[np.ndarray, np.ndarray]]

def cmfs(observer_deg: int = 2) -> np.ndarray:
    """(401, 3) x̄ ȳ z̄ at 380–780 nm, 1 nm: colour-science's MSDS_CMFS, from the shipped
    tables (read-only)."""
    return colour_tables.cmfs(observer_deg)


def planck_W_sr_m2_nm(wavelength_nm: np.ndarray, temperature_K: float) -> np.ndarray:
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    wl_m = np.asarray(wavelength_nm, dtype=float) * 1e-9
    return 2 * h * c**2 / wl_m**5 / np.expm1(h * c / (wl_m * k * temperature_K)) * 1e-9


def default_spectrum() -> tuple[np.ndarray, np.ndarray]:
    """Planckian 2856 K scaled to 100 cd/m² (CIE 1931 2°, 683 lm/W)."""
    wl = RADIOMETER_WAVELENGTHS_NM.copy()
    spd = planck_W_sr_m2_nm(wl, DEFAULT_CCT_K)
    lv = KM_LM_W * float(np.sum(spd * cmfs(2)[:, 1]))
    return wl, spd * (DEFAULT_LUMINANCE_CD_M2 / lv)


def colorimetry(radiance_W_sr_m2_nm: np.ndarray, observer_deg: int = 2) -> dict[str, float]:
    """The 11-value block (Le, Lv, X, Y, Z, x, y, u′, v′, T, Δuv) of a 380–780 nm spectrum.

    With the 10° observer X, Y, Z and what follows from them are the 10° values; Lv stays
    the (2°) luminance, as on the instruments' 10° blocks.
    """
    L = np.asarray(radiance_W_sr_m2_nm, dtype=float)
    X, Y, Z = (KM_LM_W * (L[:, None] * cmfs(observer_deg)).sum(axis=0)).tolist()
    lv = KM_LM_W * float((L * cmfs(2)[:, 1]).sum())
    le = float(L.sum())
    s = X + Y + Z
    d = X + 15 * Y + 3 * Z
    if s <= 0 or d <= 0:
        return {"Le": le, "Lv": lv, "X": X, "Y": Y, "Z": Z, "x": math.nan, "y": math.nan,
                "u_prime": math.nan, "v_prime": math.nan, "T": math.nan, "duv": math.nan}
    x, y = X / s, Y / s
    up, vp = 4 * X / d, 9 * Y / d
    try:
        T, duv = colour_tables.uv_to_cct_ohno2013(up, vp * 2.0 / 3.0)
    except (ValueError, ArithmeticError):
        T, duv = math.nan, math.nan
    if not (1000.0 <= T <= 99999.0 and abs(duv) <= 0.1):
        T, duv = math.nan, math.nan       # outside what the instrument reports
    return {"Le": le, "Lv": lv, "X": X, "Y": Y, "Z": Z, "x": x, "y": y, "u_prime": up,
            "v_prime": vp, "T": T, "duv": duv}


def resample(wavelength_nm: np.ndarray, radiance: np.ndarray, shift_nm: float = 0.0) -> np.ndarray:
    """Radiance at RADIOMETER_WAVELENGTHS_NM + shift_nm: linear, the edge value held up to
    1 nm beyond the data (so a ±0.3 nm shift does not zero 380/780 nm), 0 further out."""
    wl = np.asarray(wavelength_nm, dtype=float)
    L = np.asarray(radiance, dtype=float)
    if wl.shape != L.shape or wl.ndim != 1 or wl.size < 2:
        raise ValueError("scene must return two 1-D arrays of the same length")
    x = RADIOMETER_WAVELENGTHS_NM + shift_nm
    out = np.interp(x, wl, L)
    out[(x < wl[0] - 1.0) | (x > wl[-1] + 1.0)] = 0.0
    return out


def lose_leading_digit(value: float) -> float:
    """A value whose leading mantissa digit was lost on the wire: 4.5678e-03 → .5678e-03."""
    if value == 0.0 or not math.isfinite(value):
        return value
    exponent = math.floor(math.log10(abs(value)))
    mantissa = abs(value) / 10.0 ** exponent
    return math.copysign((mantissa - math.floor(mantissa)) * 10.0 ** exponent, value)


def env_time_factor(default: float = 1.0) -> float:
    value = os.environ.get("NORMBOX_LAB_SIM_TIME_FACTOR")
    return float(value) if value else default


def pre_measurement_s(luminance_cd_m2: float) -> float:
    lv = max(float(luminance_cd_m2), 1e-6)
    return min(10.0, max(1.0, 1.0 + 2.0 * math.log10(100.0 / lv)))


class RadiometerOptics:
    """The light path of an emulated radiometer: scene → instrument-affected spectrum."""

    def __init__(self, *, scene: Scene | None = None, world: Any = None, noise: str | bool = "on",
                 seed: int = 0) -> None:
        self.scene = scene
        self.world = world
        self.noise = _on_off(noise)
        self.rng = np.random.default_rng(seed)

    def light(self) -> tuple[np.ndarray, np.ndarray]:
        """(wavelength_nm, radiance) in view now: scene, else world, else the default."""
        if self.scene is not None:
            return self.scene()
        if self.world is not None and hasattr(self.world, "radiance_in_view"):
            return self.world.radiance_in_view()
        return default_spectrum()

    def prepare(self) -> None:
        """Read the colorimetric tables now (a few ms), so the first `observe()` is as fast
        as the next: colorimetry of the default light, 2° and 10°."""
        _, spd = default_spectrum()
        colorimetry(spd, 2)
        colorimetry(spd, 10)

    def observe(self, faults: Any = None) -> tuple[np.ndarray, dict[str, float]]:
        """One measurement: (reported spectrum, its 2° colorimetry) with the instrument's
        errors, and the data faults of `DATA_FAULT_KINDS` when `faults` (the emulator's
        `FaultInjector`) arms them.  Call `colorimetry(spectrum, 10)` for the 10° block."""
        wl, L = self.light()
        if self.noise:
            shift = float(self.rng.uniform(-WAVELENGTH_ERROR_NM, WAVELENGTH_ERROR_NM))
            gain = float(self.rng.uniform(1 - RADIOMETRIC_ERROR, 1 + RADIOMETRIC_ERROR))
        else:
            shift, gain = 0.0, 1.0
        spectrum = np.maximum(resample(wl, L, shift) * gain, 0.0)
        if faults is None:
            return spectrum, colorimetry(spectrum)
        return self._data_faults(faults, spectrum)

    def _data_faults(self, faults: Any, spectrum: np.ndarray
                     ) -> tuple[np.ndarray, dict[str, float]]:
        latched = self.__dict__.setdefault("_latched", {})
        for kind, default in (("lost-digit", 560.0), ("zero-block", 20.0),
                              ("negative", 1e-3)):
            if kind not in latched and faults.fires(kind):
                latched[kind] = faults.parameter(kind, default)
                if kind == "zero-block":
                    width = int(min(401, max(1, round(latched[kind]))))
                    latched["zero-start"] = int(self.rng.integers(0, 401 - width + 1))
        previous = self.__dict__.get("_previous")
        if faults.fires("stale-data") and previous is not None:
            return previous[0].copy(), dict(previous[1])       # the last block, again
        if "zero-block" in latched:                             # dead detector elements
            start = latched["zero-start"]
            spectrum[start:start + int(min(401, max(1, round(latched["zero-block"]))))] = 0.0
        if "negative" in latched:                               # dark over-subtracted
            floor = float(latched["negative"]) * float(np.max(spectrum))
            spectrum = np.where(spectrum < floor, spectrum - floor, spectrum)
        colour = colorimetry(spectrum)                          # the instrument's own
        self._previous = (spectrum.copy(), dict(colour))
        if "lost-digit" in latched:                             # lost on the wire
            i = round(latched["lost-digit"]) - int(RADIOMETER_WAVELENGTHS_NM[0])
            spectrum = spectrum.copy()
            spectrum[i] = lose_leading_digit(float(spectrum[i]))
        return spectrum, colour


class KonicaMinoltaCommands:
    """The command preamble both models share (a mixin for their emulators, which supply
    `remote`, `faults` and `reply(text)`): decoding a line, and running a command the current
    phase lets through — local mode refuses all but the remote command with ER00, the ``busy``
    and ``device-error`` faults answer ER02 / ERnn, an unknown command is ER00, else
    ``_cmd_<NAME>(args)`` runs."""

    #: the command that works in local (key) mode
    remote_command = ""

    def split_command(self, line: bytes) -> tuple[str, str, list[str]] | None:
        """``(text, command, args)`` of one line, or None after answering ER00 (not ASCII)."""
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            self.reply("ER00")  # type: ignore[attr-defined]
            return None
        cmd, *args = text.split(",")
        return text, cmd, args

    def run_command(self, cmd: str, args: list[str], handler: str | None = None) -> None:
        emu: Any = self
        if not emu.remote and cmd != self.remote_command:
            emu.reply("ER00")
        elif emu.faults.fires("busy"):
            emu.reply("ER02")
        elif emu.faults.fires("device-error"):
            emu.reply(f"ER{int(emu.faults.parameter('device-error', 51)):02d}")
        else:
            method = getattr(emu, f"_cmd_{handler or cmd}", None)
            if method is None:
                emu.reply("ER00")
            else:
                method(args)

    def on_new_client(self) -> None:
        """A new client (`sim serve`): the half-received command and a measurement the last
        client started are dropped (it would answer ``OK,<t>`` / ``OK`` to a client that
        never asked; the buffer stays empty).  Remote mode and settings stay."""
        emu: Any = self
        emu._inbuf.clear()
        if emu.phase != "idle":
            emu.phase, emu.phase_end_s, emu._pending = "idle", None, None

    def advance_measurement(self, now_s: float, main_phase_s: Callable[[dict[str, Any]], float],
                            announce: Callable[[dict[str, Any]], str], done: str) -> None:
        """The measurement's phases on the clock, as both models run them: at the end of the
        pre-measurement ER10 (over range; back to idle) or `announce(pending)` and the main
        phase of `main_phase_s(pending)`; at its end the data fill the buffer and `done` is
        sent.  (The emulator holds `phase`, `phase_end_s`, `_pending` and `data`.)"""
        emu: Any = self
        if emu.phase_end_s is None or now_s < emu.phase_end_s or emu._pending is None:
            return
        p = emu._pending
        if emu.phase == "pre":
            if p["over_range"]:
                emu.phase, emu.phase_end_s, emu._pending = "idle", None, None
                emu.reply("ER10")
                return
            emu.phase = "measuring"
            emu.phase_end_s += main_phase_s(p)
            emu.reply(announce(p))
        elif emu.phase == "measuring":
            emu.data = p
            emu.phase, emu.phase_end_s, emu._pending = "idle", None, None
            emu.reply(done)


def _on_off(value: str | bool) -> bool:
    if isinstance(value, bool):
        return value
    v = str(value).strip().lower()
    if v in ("on", "1", "true", "yes"):
        return True
    if v in ("off", "0", "false", "no"):
        return False
    raise ValueError(f"noise must be on or off, not {value!r}")


def fmt_e(value: float) -> str:
    """``#.####e±#`` (CS-2000 spectral/XYZ shape); tiny values print ``0.0000e-9``."""
    if not math.isfinite(value):
        return "-9.9999e9"
    if abs(value) < 1e-9:
        return "0.0000e-9"
    mant, exp = f"{value:.4e}".split("e")
    return f"{mant}e{int(exp)}"
