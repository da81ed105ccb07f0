"""In-plane gonioreflectometer: two rotation stages (light arm θi, detector arm θo), a QE Pro,
arms tilted ±`tilt_deg` out of plane (DESIGN §1), calibrated against a white standard.

Angles are signed, in the plane of incidence, from the sample normal; both arms use the same
axis, so the specular direction is θo = −θi and backscatter is θo = θi.  The arms cannot pass
each other: where the in-plane separation |θo − θi| is below `arm_clearance_deg` (default 10°)
one arm shadows the other.  Those geometries stay in the set, flagged ``blocked`` (their
readings are taken and stored with ``blocked=True``, never silently dropped).

Calibration (`calibrate`, once per mounted material):
  0. the QE Pro's TEC must be at its set point (± `tec_tolerance_c`) and have stayed there for
     `tec_stable_s`; a detector still cooling has a dark current that changes by a factor of two
     every 6 °C, so darks and whites taken then do not match the readings that follow.  If the
     TEC does not get there within `tec_timeout_s`, `NotReady` (the engine asks the operator);
  1. arms to the reference geometry (θi, θo) = (0°, 45°), white standard (Spectralon,
     reflectance ρ_w(λ), treated as Lambertian) into the sample plane;
  2. integration time t_w chosen so the white peak is ≈ 60 % of full scale; white counts C_w;
  3. lamp off (QE Pro lamp-enable line = shutter): dark counts D_w at t_w; lamp on; a dark is
     also taken just before the white, and the two must agree (a dark current that jumped
     between C_w and D_w would bias every BRDF, most in the blue): else both again, once;
  4. white standard out.
Measurement (`measure_brdf(θi, θo)`): arms to (θi, θo); integration time t_s auto-ranged
(starting at t_w / max(cos θi, 0.1), divided by 4 while saturated, multiplied by 4 while the
peak is below 5 % of full scale, within 8 ms … 64·t_w); counts C_s; a dark D_s at t_s.
Every reading takes its own dark D_s right after C_s (`dark_every_reading`, default on): a
dark current that changes with the TEC at its set point (a light leak, a drifting detector) is
subtracted, not carried over from an older dark; the ``dark-drift`` gate still reports the
change.  Without it (``dark_every_reading=False``) a dark frame is reused while it is valid:
for its integration time, for the TEC temperature it was taken at (± `dark_tec_tolerance_c`)
and for `dark_max_age_s`; a stale one is taken again.  The calibration and the lamp checks
use the held darks under the same rules.  A reading's dark that moved by more than
`DARK_RETAKE_COUNTS_S` (+ 3σ) since the previous dark (the dark current may have jumped
between the spectrum and its dark) is taken again together with the spectrum.  A white
reference that needs more than `MAX_WHITE_INTEGRATION_S` is `DeviceError("WHITE")` (a lamp
that is out, not dim).
Each reading records the TEC temperature and the ids of the dark and white references it used
(``dark_id``, ``white_id`` in its metadata; the calibration artifact carries the same ids).  Then, per pixel λ:

    f_r(θi, θo; λ) = [(C_s − D_s)/t_s] / [(C_w − D_w)/t_w] · ρ_w(λ)/π · cos θi,ref / cos θi

(cos of the in-plane angles; the common cos(tilt) factor cancels.)  This assumes the detector's
field of view lies inside the illuminated spot at every geometry, so the projected-area factors
cancel, and a Lambertian white standard.  Counts are dark-pixel and nonlinearity corrected
(seabreeze); the BRDF is resampled from the QE Pro's pixel grid to 380–780 nm at 1 nm (linear
interpolation); the raw counts (C_s, uncorrected, native grid) are kept in the reading.

Lamp drift (the lamp is the one light of every reading, and it may dim after the white
reference was taken): with a motorised white standard (``white_standard.motorised``, the
simulated gonio's slide) every unblocked reading is bracketed by a *lamp check*: the white
standard goes into the sample plane at the reading's own geometry (no arm move), one spectrum
at t_w / max(cos θi, 0.1), and its dark-corrected rate is compared with the calibration white
scaled as a Lambertian standard (cos θi / cos θi,ref).  The median ratio over the pixels where
the white is above 10 % of its peak is the lamp's output relative to the white reference
(``lamp_ratio`` in the reading's metadata).  Beyond ±`lamp_drift_limit_percent` (default 2 %:
the lab's radiometric accuracy class; the check itself scatters 0.015 % sd on the simulated
gonio) the references are taken again (a new white and
dark, `recalibrations` counts them) and the reading is repeated; still beyond the limit after
that (the lamp is changing during the reading), the reading is stored with its ``lamp_ratio``
and the acquisition gate ``lamp-drift`` flags it as an *error* (never an unflagged value).
Cost: one integration time (+ a dark when new) per reading (153-geometry sweep: 430.3 s
instead of 400.5 s of virtual lab time).  With an operator-placed standard (or ``sim://qepro?slide=manual``) there is no
per-reading check (``lamp_ratio`` absent): drift between calibrations is not seen
(docs/motion-and-light.md).

Timing model for ETAs: both arms move at once (the longer of the two trapezoids), plus the
integration times (sample + dark when t_s is new).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from normbox_lab.core.capabilities import InstrumentIdentity, Movable
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import DeviceError, NotReady
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import DETECTOR_ARM_ROLE, LIGHT_ARM_ROLE, LOCATIONS, BrdfReading

THETA_I_DEG = tuple(range(-80, 1, 10))
THETA_O_DEG = tuple(range(-80, 81, 10))
REFERENCE_GEOMETRY_DEG = (0.0, 45.0)
WHITE_TARGET_FRACTION = 0.6
#: auto-ranging keeps the peak below this fraction of full scale where it can (the CCD is
#: nonlinear beyond the stored correction near full scale)
RANGE_CEILING_FRACTION = 0.95
#: electrically dark pixels the dark-pixel (offset) correction averages (QE Pro: 0–3, 1040–1043)
OFFSET_PIXELS = 8

#: calibration-validity defaults (overridable per lab: ``[instruments.spectrometer]`` options
#: are the QE Pro's; these are the gonio's).  The QE Pro data sheet gives the TEC set point
#: (−10 °C default, cseabreeze) but no settling figure; ±0.5 °C held for 30 s is the usual
#: CCD practice, and dark current doubling every ~6 °C makes 0.2 °C ≈ 2 % of the dark current.
TEC_TOLERANCE_C = 0.5
TEC_STABLE_S = 30.0
TEC_TIMEOUT_S = 600.0
#: the cooler's time constant for ETAs (*assumed*: the QE Pro data sheet gives none; the
#: emulator cools with 30 s)
TEC_TAU_S = 30.0
DARK_TEC_TOLERANCE_C = 0.2
DARK_MAX_AGE_S = 600.0
#: lamp check: the largest change of the lamp's output since the white reference, in percent
LAMP_DRIFT_LIMIT_PERCENT = 2.0
#: a reading's dark that moved more than this (+ 3σ of the change) since the previous dark is
#: taken again with the spectrum (the acquisition gate's dark_drift_counts_s default)
DARK_RETAKE_COUNTS_S = 100.0
#: a white reference that needs longer than this means the lamp is out (nominal t_w ≈ 0.1 s;
#: *assumed* 100×)
MAX_WHITE_INTEGRATION_S = 10.0


@runtime_checkable
class TecCooled(Protocol):
    """A spectrometer with a thermo-electric cooler it can report and wait for."""

    has_tec: bool

    def tec_temperature_c(self) -> float: ...

    def wait_tec_stable(self, tolerance_c: float = 0.5, timeout_s: float = 600.0,
                        poll_s: float = 5.0, stable_for_s: float = 30.0) -> float: ...


@dataclass(frozen=True)
class DarkFrame:
    """One dark reference and the conditions it is valid for."""

    dark_id: int
    counts: np.ndarray
    integration_time_s: float
    tec_temperature_c: float
    taken_s: float                  # clock.now_s() when taken
    drift_counts_s: float | None = None   # dark-current change since the previous dark
    drift_sigma_counts_s: float | None = None   # its standard uncertainty (frame noise)

    @property
    def rate_counts_s(self) -> float:
        return float(np.mean(self.counts)) / self.integration_time_s

    @property
    def rate_sigma_counts_s(self) -> float:
        """Standard error of `rate_counts_s` from the frame's own pixel scatter: the mean of
        its pixels, and the electrical offset subtracted from all of them, estimated from the
        QE Pro's 8 electrically dark pixels (common to the whole frame, and dominant)."""
        n = max(int(np.size(self.counts)), 1)
        sd = float(np.std(self.counts))
        return sd * math.sqrt(1.0 / n + 1.0 / OFFSET_PIXELS) / self.integration_time_s

    def valid_for(self, integration_time_s: float, tec_temperature_c: float, now_s: float,
                  tec_tolerance_c: float, max_age_s: float) -> bool:
        if round(self.integration_time_s, 6) != round(integration_time_s, 6):
            return False
        if now_s - self.taken_s > max_age_s:
            return False
        if math.isfinite(self.tec_temperature_c) and math.isfinite(tec_temperature_c):
            return abs(self.tec_temperature_c - tec_temperature_c) <= tec_tolerance_c
        return True


class OperatorWhiteStandard:
    """A white standard placed by hand: `prompt(message)` must return once it is done."""

    def __init__(self, prompt: Callable[[str], Any], reflectance: float | np.ndarray = 0.99,
                 wavelength_nm: np.ndarray | None = None) -> None:
        self.prompt = prompt
        self._rho = reflectance
        self._wl = wavelength_nm

    def reflectance(self, wavelength_nm: np.ndarray) -> np.ndarray:
        if self._wl is None:
            return np.full(np.shape(wavelength_nm), float(self._rho))
        return np.interp(wavelength_nm, self._wl, self._rho)

    def insert(self) -> None:
        self.prompt("place the white standard (Spectralon) in the sample plane")

    def remove(self) -> None:
        self.prompt("remove the white standard; put the sample back")


class Gonioreflectometer:
    model = "in-plane gonioreflectometer (QE Pro)"

    def __init__(self, light_arm: Any, detector_arm: Any, spectrometer: Any, clock: Clock, *,
                 instrument_id: str = "gonio", tilt_deg: float = 4.0,
                 arm_clearance_deg: float = 10.0, white_standard: Any = None,
                 shutter: Callable[[bool], None] | None = None,
                 output_wavelength_nm: np.ndarray = RADIOMETER_WAVELENGTHS_NM,
                 tec_tolerance_c: float = TEC_TOLERANCE_C, tec_stable_s: float = TEC_STABLE_S,
                 tec_timeout_s: float = TEC_TIMEOUT_S,
                 dark_tec_tolerance_c: float = DARK_TEC_TOLERANCE_C,
                 dark_max_age_s: float = DARK_MAX_AGE_S,
                 lamp_drift_limit_percent: float = LAMP_DRIFT_LIMIT_PERCENT,
                 dark_every_reading: bool = True) -> None:
        self.light_arm = light_arm
        self.detector_arm = detector_arm
        self.spectrometer = spectrometer
        self.clock = clock
        self.instrument_id = instrument_id
        self.tilt_deg = float(tilt_deg)
        self.arm_clearance_deg = float(arm_clearance_deg)
        if white_standard is None and hasattr(spectrometer, "white_standard"):
            white_standard = spectrometer.white_standard()
        self.white_standard = white_standard
        self.shutter = shutter or getattr(spectrometer, "set_lamp_enabled", None)
        self.output_wavelength_nm = np.asarray(output_wavelength_nm, dtype=float)
        self.tec_tolerance_c = float(tec_tolerance_c)
        self.tec_stable_s = float(tec_stable_s)
        self.tec_timeout_s = float(tec_timeout_s)
        self.dark_tec_tolerance_c = float(dark_tec_tolerance_c)
        self.dark_max_age_s = float(dark_max_age_s)
        self.lamp_drift_limit_percent = float(lamp_drift_limit_percent)
        self.dark_every_reading = bool(dark_every_reading)
        self.recalibrations = 0
        self._cal: dict[str, Any] | None = None
        self._darks: dict[float, DarkFrame] = {}
        self._next_id = 1
        self._last_dark: DarkFrame | None = None
        self.darks_taken = 0
        self._geometry = (0.0, 0.0)

    @classmethod
    def from_parts(cls, *, spectrometer: Any, light_arm: Any, detector_arm: Any, clock: Clock,
                   **options: Any) -> Gonioreflectometer:
        return cls(light_arm, detector_arm, spectrometer, clock, **options)

    # --- identity -----------------------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        spec = self.spectrometer.identify()
        return InstrumentIdentity("gonioreflectometer", self.model, spec.serial_number, "",
                                  simulated=spec.simulated,
                                  extra={"tilt_deg": f"{self.tilt_deg:g}",
                                         "spectrometer": spec.model})

    def close(self) -> None:
        for part in (self.spectrometer, self.light_arm, self.detector_arm):
            part.close()

    # --- geometry -----------------------------------------------------------------------------
    def blocked(self, theta_i_deg: float, theta_o_deg: float) -> bool:
        return abs(float(theta_o_deg) - float(theta_i_deg)) < self.arm_clearance_deg

    def geometries(self) -> list[tuple[float, float, bool]]:
        """The 153 in-plane geometries (θi, θo, blocked), θi-major."""
        return [(float(ti), float(to), self.blocked(ti, to))
                for ti in THETA_I_DEG for to in THETA_O_DEG]

    def _move_arms(self, theta_i_deg: float, theta_o_deg: float) -> None:
        for arm in (self.light_arm, self.detector_arm):
            if not arm.is_homed():
                arm.home(wait=True)
        self.light_arm.move_to(theta_i_deg, wait=False)
        self.detector_arm.move_to(theta_o_deg, wait=False)
        ti0, to0 = self._geometry
        self.light_arm.wait_idle(1.5 * self.light_arm.estimate_move_time_s(ti0, theta_i_deg) + 5)
        self.detector_arm.wait_idle(1.5 * self.detector_arm.estimate_move_time_s(
            to0, theta_o_deg) + 5)
        self._geometry = (theta_i_deg, theta_o_deg)

    # --- acquisition --------------------------------------------------------------------------
    def _lamp(self, on: bool) -> None:
        if self.shutter is None:
            raise NotReady("no lamp shutter / lamp-enable line configured",
                           instrument=self.instrument_id)
        self.shutter(on)

    def _acquire(self, integration_time_s: float) -> Any:
        self.spectrometer.set_integration_time_s(integration_time_s)
        return self.spectrometer.acquire(correct_dark=True, correct_nonlinearity=True)

    def _new_id(self) -> int:
        n = self._next_id
        self._next_id += 1
        return n

    def _tec_now_c(self) -> float:
        sp = self.spectrometer
        if isinstance(sp, TecCooled) and sp.has_tec:
            return float(sp.tec_temperature_c())
        return float("nan")

    def _dark(self, integration_time_s: float, tec_temperature_c: float, *,
              fresh: bool = False) -> DarkFrame:
        """A valid dark frame for these conditions: the held one, or a new one (shutter);
        `fresh`: always a new one."""
        key = round(integration_time_s, 6)
        held = None if fresh else self._darks.get(key)
        if held is not None and held.valid_for(integration_time_s, tec_temperature_c,
                                               self.clock.now_s(), self.dark_tec_tolerance_c,
                                               self.dark_max_age_s):
            return held
        self._lamp(False)
        try:
            acq = self._acquire(integration_time_s)
        finally:
            self._lamp(True)
        frame = DarkFrame(self._new_id(), acq.counts, float(integration_time_s),
                          float(acq.tec_temperature_c), self.clock.now_s())
        if self._last_dark is not None:
            prev = self._last_dark
            frame = DarkFrame(frame.dark_id, frame.counts, frame.integration_time_s,
                              frame.tec_temperature_c, frame.taken_s,
                              frame.rate_counts_s - prev.rate_counts_s,
                              math.hypot(frame.rate_sigma_counts_s, prev.rate_sigma_counts_s))
        self._last_dark = frame
        self._darks[key] = frame
        self.darks_taken += 1
        return frame

    def wait_tec(self) -> float:
        """The TEC at its set point and stable (NotReady after `tec_timeout_s`); NaN when the
        spectrometer has no TEC control."""
        sp = self.spectrometer
        if not (isinstance(sp, TecCooled) and sp.has_tec):
            return float("nan")
        return float(sp.wait_tec_stable(self.tec_tolerance_c, self.tec_timeout_s,
                                        poll_s=5.0, stable_for_s=self.tec_stable_s))

    @staticmethod
    def _clamp_t(t: float) -> float:
        return min(1600.0, max(8e-3, t))

    def calibrate(self) -> dict[str, np.ndarray]:
        """Dark and white references at the reference geometry (see the module docstring)."""
        if self.white_standard is None:
            raise NotReady("no white standard handler: pass white_standard=... "
                           "(e.g. OperatorWhiteStandard(prompt))", instrument=self.instrument_id)
        self._darks.clear()
        self.wait_tec()
        ti, to = REFERENCE_GEOMETRY_DEG
        self._move_arms(ti, to)
        self._lamp(True)
        self.white_standard.insert()
        try:
            full = self.spectrometer.max_counts
            t = 0.1
            for _ in range(8):
                acq = self._acquire(t)
                peak = float(np.max(acq.counts))
                if not acq.saturated and peak > 0.05 * full:
                    t = self._clamp_t(t * WHITE_TARGET_FRACTION * full / peak)
                    break
                t = self._clamp_t(t / 4 if acq.saturated else t * 8)
                if t > MAX_WHITE_INTEGRATION_S:
                    break                  # a lamp this dark is out, not dim: stop ranging
            if t > MAX_WHITE_INTEGRATION_S:
                raise DeviceError("WHITE", f"the white reference needs {t:g} s (more than "
                                  f"{MAX_WHITE_INTEGRATION_S:g} s): is the lamp on?",
                                  instrument=self.instrument_id)
            white, dark = self._bracketed_white(t)
            if white.saturated or float(np.max(white.counts)) < 0.05 * full:
                raise DeviceError("WHITE", "white reference saturated or too dark "
                                  f"(peak {np.max(white.raw_counts):.0f} counts at {t:g} s)",
                                  instrument=self.instrument_id)
        finally:
            self.white_standard.remove()
        wl = self.spectrometer.wavelengths_nm()
        rho = np.asarray(self.white_standard.reflectance(wl), dtype=float)
        self._cal = {"wavelength_nm": wl, "white_counts": white.counts,
                     "white_raw_counts": white.raw_counts, "dark_counts": dark.counts,
                     "white_reflectance": rho, "integration_time_s": t,
                     "theta_i_ref_deg": ti, "tec_temperature_c": white.tec_temperature_c,
                     "tec_setpoint_c": float(getattr(self.spectrometer, "tec_setpoint_c",
                                                     float("nan"))),
                     "white_id": self._new_id(), "dark_id": dark.dark_id,
                     "timestamp_s": self.clock.wall_time_s()}
        return self.references()

    def _bracketed_white(self, t: float) -> tuple[Any, DarkFrame]:
        """The white reference between two darks (shutter closed, standard in place) whose
        dark currents agree within `DARK_RETAKE_COUNTS_S` + 3σ: a dark current that jumps
        between the white and its dark would bias every BRDF by (jump × t) / white counts, most
        where the white is weak (the blue end).  Taken again once; a dark that keeps moving is
        `DeviceError("WHITE")`, never a reference."""
        change = limit = 0.0
        for _ in range(2):
            before = self._dark(t, float("nan"), fresh=True)
            white = self._acquire(t)
            after = self._dark(t, white.tec_temperature_c, fresh=True)
            change = after.rate_counts_s - before.rate_counts_s
            limit = DARK_RETAKE_COUNTS_S + 3.0 * math.hypot(after.rate_sigma_counts_s,
                                                             before.rate_sigma_counts_s)
            if abs(change) <= limit:
                return white, after
        raise DeviceError("WHITE", f"the dark current moved by {change:+.0f} counts/s across "
                          f"the white reference (limit ±{limit:.0f}), twice: no reference",
                          instrument=self.instrument_id)

    def references(self) -> dict[str, np.ndarray]:
        if self._cal is None:
            return {}
        return {k: (v if isinstance(v, np.ndarray) else np.array([v]))
                for k, v in self._cal.items()}

    def measure_brdf(self, theta_i_deg: float, theta_o_deg: float) -> BrdfReading:
        if self._cal is None:
            raise NotReady("not calibrated: run calibrate() after mounting the sample",
                           instrument=self.instrument_id)
        reading, ratio = self._measure_once(theta_i_deg, theta_o_deg)
        if ratio is not None and not self._lamp_ok(ratio):
            self.calibrate()                       # the lamp changed: new white reference
            self.recalibrations += 1
            reading, ratio = self._measure_once(theta_i_deg, theta_o_deg)
            # still beyond the limit (a lamp changing during the reading, or a check that
            # cannot be trusted): stored with its lamp_ratio, which the quality gate
            # `lamp-drift` flags as an error (acquire/quality.py)
        if ratio is not None:
            reading.metadata["lamp_ratio"] = ratio
            reading.metadata["lamp_drift_limit_percent"] = self.lamp_drift_limit_percent
            reading.metadata["recalibrations"] = self.recalibrations
        reading.metadata[LOCATIONS] = self.arm_locations()
        return reading

    def arm_locations(self) -> dict[str, dict[str, Any]]:
        """Setpoint and readback of each arm (`Movable.locate()`), by role, as stored with
        every BRDF reading."""
        arms = ((LIGHT_ARM_ROLE, self.light_arm), (DETECTOR_ARM_ROLE, self.detector_arm))
        return {role: arm.locate().to_dict() for role, arm in arms if isinstance(arm, Movable)}

    def _lamp_ok(self, ratio: float) -> bool:
        return abs(100.0 * (ratio - 1.0)) <= self.lamp_drift_limit_percent

    def _motorised_white(self) -> bool:
        return bool(getattr(self.white_standard, "motorised", False))

    def _lamp_check(self, theta_i_deg: float) -> float:
        """The lamp's output relative to the white reference: the white standard at this
        geometry against the calibration white scaled as a Lambertian (see the module doc)."""
        cal = self._cal
        assert cal is not None
        t_w = cal["integration_time_s"]
        cos_i = math.cos(math.radians(theta_i_deg))
        cos_ref = math.cos(math.radians(cal["theta_i_ref_deg"]))
        t = self._clamp_t(t_w / max(cos_i, 0.1))
        self.white_standard.insert()
        try:
            acq = self._acquire(t)
            while acq.saturated and t > 8e-3:
                t = self._clamp_t(t / 4)
                acq = self._acquire(t)
        finally:
            self.white_standard.remove()
        dark = self._dark(t, acq.tec_temperature_c)
        ref_rate = (cal["white_counts"] - cal["dark_counts"]) / t_w * cos_i / cos_ref
        rate = (acq.counts - dark.counts) / t
        use = ref_rate > 0.1 * float(np.max(ref_rate))
        if not np.any(use):
            return float("nan")
        return float(np.median(rate[use] / ref_rate[use]))

    def _measure_once(self, theta_i_deg: float, theta_o_deg: float
                      ) -> tuple[BrdfReading, float | None]:
        ti, to = float(theta_i_deg), float(theta_o_deg)
        blocked = self.blocked(ti, to)
        self._move_arms(ti, to)
        cal = self._cal
        t_w = cal["integration_time_s"]
        cos_i = math.cos(math.radians(ti))
        t = self._clamp_t(t_w / max(cos_i, 0.1))
        full = self.spectrometer.max_counts
        for _ in range(12):
            acq = self._acquire(t)
            peak = float(np.max(acq.counts))
            too_high = acq.saturated or \
                float(np.max(acq.raw_counts)) > RANGE_CEILING_FRACTION * full
            if too_high and t > 8e-3:
                t = self._clamp_t(t / 4)
                continue
            if not acq.saturated and peak < 0.05 * full and t < 64 * t_w and not blocked:
                t = self._clamp_t(min(t * 4, 64 * t_w))
                continue
            break
        if acq.saturated:
            raise DeviceError("SATURATED", f"saturated even at {t:g} s",
                              instrument=self.instrument_id)
        darks_before = self.darks_taken
        dark = self._dark(t, acq.tec_temperature_c, fresh=self.dark_every_reading)
        if self.dark_every_reading and dark.drift_counts_s is not None and \
                abs(dark.drift_counts_s) > DARK_RETAKE_COUNTS_S + 3.0 * float(
                    dark.drift_sigma_counts_s or 0.0):
            # the dark current moved since the last dark, maybe between this spectrum and its
            # dark: take both again so they see the same dark current
            first = dark
            acq = self._acquire(t)
            dark = self._dark(t, acq.tec_temperature_c, fresh=True)
            # the change since the previous reading's dark stays on record (dark-drift gate)
            dark = replace(dark, drift_counts_s=first.drift_counts_s + (dark.drift_counts_s or 0.0),
                           drift_sigma_counts_s=math.hypot(first.drift_sigma_counts_s or 0.0,
                                                           dark.drift_sigma_counts_s or 0.0))
        white_rate = (cal["white_counts"] - cal["dark_counts"]) / t_w
        sample_rate = (acq.counts - dark.counts) / t
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(white_rate > 0, sample_rate / white_rate, 0.0)
        cos_ref = math.cos(math.radians(cal["theta_i_ref_deg"]))
        brdf_native = ratio * cal["white_reflectance"] / math.pi * cos_ref / max(cos_i, 1e-6)
        wl = cal["wavelength_nm"]
        brdf = np.interp(self.output_wavelength_nm, wl, brdf_native)
        ratio = self._lamp_check(ti) if self._motorised_white() and not blocked else None
        return BrdfReading(
            theta_i_deg=ti, theta_o_deg=to, tilt_deg=self.tilt_deg,
            wavelength_nm=self.output_wavelength_nm, brdf_per_sr=brdf,
            raw_counts=acq.raw_counts, integration_time_s=t,
            timestamp_s=self.clock.wall_time_s(), instrument_id=self.instrument_id,
            blocked=blocked,
            metadata={"white_integration_time_s": t_w,
                      "tec_temperature_c": acq.tec_temperature_c,
                      "tec_setpoint_c": cal["tec_setpoint_c"],
                      "white_id": cal["white_id"], "white_dark_id": cal["dark_id"],
                      "white_tec_temperature_c": cal["tec_temperature_c"],
                      "dark_id": dark.dark_id,
                      "dark_tec_temperature_c": dark.tec_temperature_c,
                      "dark_age_s": self.clock.now_s() - dark.taken_s,
                      "dark_new": self.darks_taken > darks_before,
                      "dark_drift_counts_s": dark.drift_counts_s,
                      "dark_drift_sigma_counts_s": dark.drift_sigma_counts_s,
                      "dark_rate_counts_s": dark.rate_counts_s,
                      "peak_signal_counts": float(np.max(acq.counts - dark.counts)),
                      "peak_counts": float(np.max(acq.raw_counts)),
                      "full_scale_counts": float(full)}), ratio

    # --- timing -------------------------------------------------------------------------------
    def estimate_measure_time_s(self, theta_i_deg: float, theta_o_deg: float, *,
                                from_geometry_deg: tuple[float, float] | None = None) -> float:
        """Arm moves (from `from_geometry_deg`, default where the arms are) + integration."""
        ti0, to0 = self._geometry if from_geometry_deg is None else from_geometry_deg
        move = max(self.light_arm.estimate_move_time_s(ti0, theta_i_deg),
                   self.detector_arm.estimate_move_time_s(to0, theta_o_deg))
        t_w = self._cal["integration_time_s"] if self._cal else 0.1
        t = self._clamp_t(t_w / max(math.cos(math.radians(theta_i_deg)), 0.1))
        return move + t + (t if round(t, 6) not in self._darks else 0.0)  # darks may age

    def estimate_calibrate_time_s(self) -> float:
        ti, to = REFERENCE_GEOMETRY_DEG
        ti0, to0 = self._geometry
        move = max(self.light_arm.estimate_move_time_s(ti0, ti),
                   self.detector_arm.estimate_move_time_s(to0, to))
        return move + 4 * 0.1 + (self._tec_settle_estimate_s() + self.tec_stable_s
                                  if self._cal is None else 0.0)

    def _tec_settle_estimate_s(self) -> float:
        """Time for the detector to come within `tec_tolerance_c` of its set point, from its
        temperature now: a first-order cooler with `TEC_TAU_S` (*assumed*)."""
        sp = self.spectrometer
        if not (isinstance(sp, TecCooled) and sp.has_tec):
            return 0.0
        setpoint = float(getattr(sp, "tec_setpoint_c", float("nan")))
        off = abs(float(sp.tec_temperature_c()) - setpoint)
        if not math.isfinite(off) or off <= self.tec_tolerance_c:
            return 0.0
        return TEC_TAU_S * math.log(off / self.tec_tolerance_c)

    def stop(self) -> None:
        """Stop both arms (abort)."""
        for arm in (self.light_arm, self.detector_arm):
            arm.stop()

    def is_moving(self) -> bool:
        return bool(self.light_arm.is_moving() or self.detector_arm.is_moving())

    def status(self) -> dict[str, Any]:
        return {"calibrated": self._cal is not None, "geometry_deg": self._geometry,
                "tilt_deg": self.tilt_deg, "cached_darks": len(self._darks)}


InPlaneGonio = Gonioreflectometer


def compose(parts: Mapping[str, Any], clock: Clock,
            ask_operator: Callable[..., str] | None = None) -> Gonioreflectometer:
    """The lab's gonioreflectometer from its opened parts (the registry's composite ``gonio``:
    ``gonio_light_arm``, ``gonio_detector_arm``, ``spectrometer``).  A spectrometer without a
    white standard of its own (a real QE Pro) gets one the operator places during `calibrate`,
    through ``ask_operator(key, message, **data)``."""
    white = parts["spectrometer"].white_standard()
    if white is None and ask_operator is not None:
        white = OperatorWhiteStandard(lambda message: ask_operator(
            "gonio/white-standard", message, action="white_standard"))
    return Gonioreflectometer.from_parts(
        spectrometer=parts["spectrometer"], light_arm=parts["gonio_light_arm"],
        detector_arm=parts["gonio_detector_arm"], clock=clock, white_standard=white)


__all__ = [
    "THETA_I_DEG",
    "THETA_O_DEG",
    "Gonioreflectometer",
    "InPlaneGonio",
    "OperatorWhiteStandard",
    "compose",
]
