"""Ocean Optics / Ocean Insight QE Pro, simulated at the seabreeze API boundary.

seabreeze ships no fake device, and `seabreeze.spectrometers.Spectrometer` type-checks its
backend device, so the simulation replaces the whole object: `SimulatedSpectrometer` has the
shape of `seabreeze.spectrometers.Spectrometer` (``from_serial_number``,
``integration_time_micros``, ``integration_time_micros_limits``, ``wavelengths()``,
``intensities(correct_dark_counts, correct_nonlinearity)``, ``max_intensity``, ``pixels``,
``serial_number``, ``model``, ``features[...]`` / ``f.<feature>``, ``open``/``close``).
Nothing here imports seabreeze.

The device (QE Pro facts from [QEPRO] in docs/references.md): 1044 pixels, electrically dark
pixels 0–3 and 1040–1043, 18-bit counts (max 262143), integration time 8 ms … 1600 s,
polynomial wavelength calibration λ(px) = 350 + 0.55·px − 3·10⁻⁵·px² nm (*assumed*
coefficients, ≈ 350–891 nm), TEC with a −10 °C default set point.

What it sees (the gonioreflectometer's detector arm): the radiance leaving the sample towards
the detector,

    L(λ) = f_r(θi, θo, tilt, λ) · E(λ) · cos θi · cos(tilt)

with f_r from ``world.brdf_truth(θi, θo, tilt, λ)`` (or the white standard ρ_w/π when the
reference slide is in), E the lamp's spectral irradiance at normal incidence (``lamp``
argument, ``world.gonio_lamp_irradiance(λ)`` if the world has one, else a 3000 K halogen with a
1 W·m⁻²·nm⁻¹ peak), θi/θo read from the arm emulators' `angle_deg()` (default keys
``gonio-light`` / ``gonio-detector`` in `sim.core.CONTEXT`), zero while the lamp is off
(``features['strobe_lamp'][0].enable_lamp(False)``, wired to the lamp shutter) or when the arms
block each other (in-plane separation < `arm_clearance_deg`) or no arm emulator is running.

Counts per pixel: counts = offset + [S + I_dark·t]·(1 − 0.005·S/262143) + noise, with
S = L·R(λ)·t (responsivity R peaking at 600 nm, scaled so the white standard at 0°/45° gives
≈ 150 000 counts in 100 ms), shot noise σ² = 0.262·S (SNR 1000:1 at full scale), read noise
15 counts, electrical offset 1500 counts (the only thing the electrically dark pixels see),
dark current 200 counts/s at −10 °C doubling every 6 °C, clipped at 262143.  The stored
nonlinearity coefficients [1, −0.005/262143] undo the 0.5 % nonlinearity the seabreeze way
(``counts / polyval(coeffs, counts)`` after the dark-pixel offset is removed).  TEC: first
order towards the set point, τ = 30 s, from 25 °C at power-up.  `intensities()` blocks for the
integration time on the injected clock.

Faults (`faults=` spec): ``disconnect``: the USB link drops for the parameter's seconds
(default 3): calls raise `SeaBreezeError`, and ``from_serial_number`` finds no device until it
is back.  Conditions, counted per acquisition and latched from the one at which they fire
(``kind@n`` = from the n-th spectrum on; ``kind`` alone = from the first):
``saturation`` (a light leak holds pixels 500–519 at `parameter` × full scale, default 0.97,
whatever the integration time), ``tec-drift`` (the detector warms by `parameter` °C, default
2, while the set point stays), ``dark-drift`` (`parameter` counts/s more dark current, default
1000), ``lamp-dim`` (the gonio lamp's output × `parameter`, default 1e-4).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from normbox_lab.core.clock import Clock, VirtualClock
from normbox_lab.sim import core

PIXELS = 1044
DARK_PIXELS = [0, 1, 2, 3, 1040, 1041, 1042, 1043]
MAX_COUNTS = 262143
INTEGRATION_LIMITS_US = (8_000, 1_600_000_000)
WAVELENGTH_COEFFS = (350.0, 0.55, -3.0e-5)
NONLINEARITY = 0.005
NONLINEARITY_COEFFS = [1.0, -NONLINEARITY / MAX_COUNTS]
OFFSET_COUNTS = 1500.0
READ_NOISE_COUNTS = 15.0
SHOT_VAR_PER_COUNT = 0.262
DARK_RATE_COUNTS_S = 200.0
TEC_TAU_S = 30.0
AMBIENT_C = 25.0
WHITE_TARGET_COUNTS = 150_000.0
#: condition faults and their default parameters
CONDITION_FAULTS = {"saturation": 0.97, "tec-drift": 2.0, "dark-drift": 1000.0,
                    "lamp-dim": 1e-4}


class SeaBreezeError(Exception):
    """What seabreeze raises (``seabreeze.spectrometers.SeaBreezeError``), simulated."""


def halogen_irradiance(wavelength_nm: np.ndarray, temperature_K: float = 3000.0) -> np.ndarray:
    wl = np.asarray(wavelength_nm, dtype=float)
    c2 = 1.4388e7  # nm·K
    s = wl ** -5 / np.expm1(c2 / (wl * temperature_K))
    peak_nm = 2.8978e6 / temperature_K
    return s / (peak_nm ** -5 / np.expm1(c2 / (peak_nm * temperature_K)))


def _angle_source(src: Any, default_key: str) -> Callable[[], float | None]:
    if callable(src):
        return src
    if src is not None and hasattr(src, "angle_deg"):
        return src.angle_deg
    key = src if isinstance(src, str) else default_key

    def read() -> float | None:
        emu = core.CONTEXT.instances.get(key)
        return None if emu is None else float(emu.angle_deg())

    return read


class _Feature:
    def __init__(self, dev: SimulatedQEProDevice) -> None:
        self._dev = dev


class ThermoElectricFeature(_Feature):
    def read_temperature_degrees_celsius(self) -> float:
        self._dev.check()
        return self._dev.tec_temperature_c()

    def set_temperature_setpoint_degrees_celsius(self, temperature: float) -> None:
        self._dev.check()
        self._dev.set_tec_setpoint(float(temperature))

    def enable_tec(self, state: bool) -> None:
        self._dev.check()
        self._dev.set_tec_enabled(bool(state))


class StrobeLampFeature(_Feature):
    def enable_lamp(self, state: bool) -> None:
        self._dev.check()
        self._dev.lamp_on = bool(state)


class NonlinearityCoefficientsFeature(_Feature):
    def get_nonlinearity_coefficients(self) -> list[float]:
        return list(NONLINEARITY_COEFFS)


class SpectrometerFeature(_Feature):
    def get_electric_dark_pixel_indices(self) -> list[int]:
        return list(DARK_PIXELS)

    def get_wavelengths(self) -> np.ndarray:
        return self._dev.wavelengths.copy()

    def get_maximum_intensity(self) -> float:
        return float(MAX_COUNTS)

    def get_integration_time_micros_limits(self) -> tuple[int, int]:
        return INTEGRATION_LIMITS_US

    def set_integration_time_micros(self, us: int) -> None:
        self._dev.check()
        lo, hi = INTEGRATION_LIMITS_US
        if not lo <= int(us) <= hi:
            raise SeaBreezeError("[Fix] Specified integration time is out of range.")
        self._dev.integration_time_us = int(us)

    def get_intensities(self) -> np.ndarray:
        return self._dev.acquire()


class _FeatureAccessor:
    def __init__(self, features: dict[str, list[Any]]) -> None:
        for name, items in features.items():
            setattr(self, name, items[0] if items else None)


class SimulatedQEProDevice:
    """The physical QE Pro on the detector arm (state persists across open/close)."""

    model = "QE-PRO"

    def __init__(self, clock: Clock | None = None, *, world: Any = None,
                 serial_number: str = "QEP-SIM-0001", light_arm: Any = None,
                 detector_arm: Any = None, tilt_deg: float = 4.0, arm_clearance_deg: float = 10.0,
                 lamp: Any = None, faults: str = "", seed: int = 0) -> None:
        self.clock = clock if clock is not None else VirtualClock()
        self.world = world
        self.serial_number = serial_number
        self.light_angle = _angle_source(light_arm, "gonio-light")
        self.detector_angle = _angle_source(detector_arm, "gonio-detector")
        self.tilt_deg = float(tilt_deg)
        self.arm_clearance_deg = float(arm_clearance_deg)
        self.faults = core.FaultInjector(faults, seed, ("disconnect", *CONDITION_FAULTS))
        self.conditions: dict[str, float] = {}      # latched condition faults → parameter
        self.rng = np.random.default_rng(seed)
        px = np.arange(PIXELS, dtype=float)
        c0, c1, c2 = WAVELENGTH_COEFFS
        self.wavelengths = c0 + c1 * px + c2 * px * px
        self._lamp = lamp
        self.lamp_on = True
        self.white_in_place = False
        self.white_reflectance = 0.99
        self.integration_time_us = 100_000
        self.is_open = False
        self.disconnected_until_s: float | None = None
        self._power_on_s = self.clock.now_s()
        self._tec_from_c, self._tec_since_s = AMBIENT_C, self._power_on_s
        self._tec_setpoint_c, self._tec_enabled = -10.0, True
        optical = self.wavelengths
        self.responsivity = np.exp(-((optical - 600.0) / 250.0) ** 2)
        white = (0.99 / math.pi * self.lamp_irradiance(optical) * math.cos(math.radians(tilt_deg))
                 * self.responsivity)
        self.responsivity *= WHITE_TARGET_COUNTS / (0.1 * float(white.max()))

    # --- link -------------------------------------------------------------------------------
    def check(self) -> None:
        now = self.clock.now_s()
        if self.disconnected_until_s is not None:
            if now < self.disconnected_until_s:
                raise SeaBreezeError("Data transfer error: device not found (USB)")
            self.disconnected_until_s = None
            self.is_open = False       # re-enumerated: the old handle is stale
        if not self.is_open:
            raise SeaBreezeError("Device is not open")
        if self.faults.fires("disconnect"):
            self.disconnected_until_s = now + self.faults.parameter("disconnect", 3.0)
            raise SeaBreezeError("Data transfer error")

    @property
    def present(self) -> bool:
        return self.disconnected_until_s is None or \
            self.clock.now_s() >= self.disconnected_until_s

    # --- TEC ----------------------------------------------------------------------------------
    def tec_temperature_c(self, at_s: float | None = None) -> float:
        target = self._tec_setpoint_c if self._tec_enabled else AMBIENT_C
        dt = (self.clock.now_s() if at_s is None else at_s) - self._tec_since_s
        return (target + (self._tec_from_c - target) * math.exp(-dt / TEC_TAU_S)
                + self.conditions.get("tec-drift", 0.0))

    def set_tec_setpoint(self, c: float) -> None:
        self._tec_from_c, self._tec_since_s = self.tec_temperature_c(), self.clock.now_s()
        self._tec_setpoint_c = c

    def set_tec_enabled(self, on: bool) -> None:
        self._tec_from_c, self._tec_since_s = self.tec_temperature_c(), self.clock.now_s()
        self._tec_enabled = on

    # --- optics -------------------------------------------------------------------------------
    def lamp_irradiance(self, wavelength_nm: np.ndarray) -> np.ndarray:
        if self._lamp is not None:
            return np.asarray(self._lamp(wavelength_nm) if callable(self._lamp) else
                              np.interp(wavelength_nm, *self._lamp), dtype=float)
        fn = getattr(self.world, "gonio_lamp_irradiance", None)
        if fn is not None:
            return np.asarray(fn(wavelength_nm), dtype=float)
        return halogen_irradiance(wavelength_nm)

    def blocked(self, theta_i_deg: float, theta_o_deg: float) -> bool:
        # physical arm angles carry microstep rounding: allow 0.001° before calling it blocked
        return abs(theta_o_deg - theta_i_deg) < self.arm_clearance_deg - 1e-3

    def radiance_at_detector(self) -> np.ndarray:
        """W·sr⁻¹·m⁻²·nm⁻¹ at each pixel's wavelength."""
        if not self.lamp_on:
            return np.zeros(PIXELS)
        ti, to = self.light_angle(), self.detector_angle()
        if ti is None or to is None:
            return np.zeros(PIXELS)                 # not on a (running) gonio: no light
        if self.blocked(ti, to):
            return np.zeros(PIXELS)
        wl = self.wavelengths
        if self.white_in_place:
            f = np.full(PIXELS, self.white_reflectance / math.pi)
        elif self.world is not None:
            f = np.asarray(self.world.brdf_truth(ti, to, self.tilt_deg, wl), dtype=float)
        else:
            f = np.zeros(PIXELS)
        cos_i = max(0.0, math.cos(math.radians(ti))) * math.cos(math.radians(self.tilt_deg))
        return f * self.lamp_irradiance(wl) * cos_i

    def acquire(self) -> np.ndarray:
        self.check()
        for kind, default in CONDITION_FAULTS.items():
            if kind not in self.conditions and self.faults.fires(kind):
                self.conditions[kind] = self.faults.parameter(kind, default)
        t = self.integration_time_us * 1e-6
        t0 = self.clock.now_s()
        self.clock.sleep(t)                         # the exposure
        signal = (self.radiance_at_detector() * self.responsivity * t
                  * self.conditions.get("lamp-dim", 1.0))
        # dark current integrated over the exposure (the TEC may still be cooling)
        temps = [self.tec_temperature_c(t0 + (k + 0.5) / 16 * t) for k in range(16)]
        dark = t * (float(np.mean([DARK_RATE_COUNTS_S * 2.0 ** ((c + 10.0) / 6.0)
                                   for c in temps]))
                    + self.conditions.get("dark-drift", 0.0))
        optical = signal + dark
        measured = optical * (1.0 - NONLINEARITY * optical / MAX_COUNTS)
        noise = self.rng.normal(0.0, 1.0, PIXELS) * np.sqrt(
            SHOT_VAR_PER_COUNT * np.maximum(measured, 0.0) + READ_NOISE_COUNTS ** 2)
        counts = OFFSET_COUNTS + measured + noise
        if "saturation" in self.conditions:
            counts[500:520] = np.maximum(counts[500:520],
                                         self.conditions["saturation"] * MAX_COUNTS)
        counts[DARK_PIXELS] = OFFSET_COUNTS + self.rng.normal(0.0, READ_NOISE_COUNTS,
                                                              len(DARK_PIXELS))
        return np.clip(np.round(counts), 0, MAX_COUNTS)


class WhiteStandardSlide:
    """The simulated gonio's reference slide: puts the Spectralon in the sample plane."""

    def __init__(self, device: SimulatedQEProDevice, reflectance: float = 0.99) -> None:
        self.device = device
        device.white_reflectance = float(reflectance)

    def reflectance(self, wavelength_nm: np.ndarray) -> np.ndarray:
        return np.full(np.shape(wavelength_nm), self.device.white_reflectance)

    def insert(self) -> None:
        self.device.white_in_place = True

    def remove(self) -> None:
        self.device.white_in_place = False


class SimulatedSpectrometer:
    """`seabreeze.spectrometers.Spectrometer`, simulated (same method names and behaviour)."""

    def __init__(self, device: SimulatedQEProDevice) -> None:
        self._dev = device
        self.open()
        nc = NonlinearityCoefficientsFeature(device).get_nonlinearity_coefficients()
        self._nc = np.poly1d(nc[::-1])
        self._dp = SpectrometerFeature(device).get_electric_dark_pixel_indices()
        self._wavelengths = SpectrometerFeature(device).get_wavelengths()
        self._features = {
            "spectrometer": [SpectrometerFeature(device)],
            "thermo_electric": [ThermoElectricFeature(device)],
            "strobe_lamp": [StrobeLampFeature(device)],
            "nonlinearity_coefficients": [NonlinearityCoefficientsFeature(device)],
        }

    # --- seabreeze's classmethods --------------------------------------------------------------
    @classmethod
    def from_serial_number(cls, serial: str | None = None) -> SimulatedSpectrometer:
        for dev in list_devices():
            if serial is None or dev.serial_number == str(serial):
                if dev.is_open:
                    raise SeaBreezeError("Device already opened.")
                return cls(dev)
        raise SeaBreezeError(f"No device attached with serial number '{serial}'.")

    @classmethod
    def from_first_available(cls) -> SimulatedSpectrometer:
        return cls.from_serial_number(None)

    # --- the Spectrometer API ------------------------------------------------------------------
    def wavelengths(self) -> np.ndarray:
        return self._wavelengths

    def intensities(self, correct_dark_counts: bool = False,
                    correct_nonlinearity: bool = False) -> np.ndarray:
        out = self._features["spectrometer"][0].get_intensities().astype(np.float64)
        dark_offset = float(np.mean(out[self._dp]))
        if correct_nonlinearity or correct_dark_counts:
            out -= dark_offset
        if correct_nonlinearity:
            out = out / np.polyval(self._nc, out)
        if correct_nonlinearity and not correct_dark_counts:
            out += dark_offset
        return out

    def spectrum(self, correct_dark_counts: bool = False,
                 correct_nonlinearity: bool = False) -> np.ndarray:
        return np.vstack((self._wavelengths,
                          self.intensities(correct_dark_counts, correct_nonlinearity)))

    def integration_time_micros(self, integration_time_micros: int) -> None:
        self._features["spectrometer"][0].set_integration_time_micros(integration_time_micros)

    @property
    def integration_time_micros_limits(self) -> tuple[int, int]:
        return INTEGRATION_LIMITS_US

    @property
    def max_intensity(self) -> float:
        return float(MAX_COUNTS)

    @property
    def serial_number(self) -> str:
        return self._dev.serial_number

    @property
    def model(self) -> str:
        return self._dev.model

    @property
    def pixels(self) -> int:
        return PIXELS

    @property
    def features(self) -> dict[str, list[Any]]:
        return self._features

    @property
    def f(self) -> _FeatureAccessor:
        return _FeatureAccessor(self._features)

    def open(self) -> None:
        if not self._dev.present:
            raise SeaBreezeError("No device attached")
        self._dev.disconnected_until_s = None
        self._dev.is_open = True

    def close(self) -> None:
        self._dev.is_open = False

    # --- simulation extras (not in seabreeze) --------------------------------------------------
    @property
    def simulated_device(self) -> SimulatedQEProDevice:
        return self._dev

    def __repr__(self) -> str:
        return f"<SimulatedSpectrometer {self.model}:{self.serial_number}>"


def list_devices() -> list[SimulatedQEProDevice]:
    """The simulated QE Pros that are plugged in now (`sim.core.CONTEXT` keys ``qepro*``)."""
    return [d for k, d in core.CONTEXT.instances.items()
            if isinstance(d, SimulatedQEProDevice) and d.present]


def device(key: str = "qepro", clock: Clock | None = None,
           **options: Any) -> SimulatedQEProDevice:
    """The live simulated QE Pro `key`, created on first use (on `clock`, default the
    CONTEXT clock, and the CONTEXT world)."""
    dev = core.CONTEXT.instances.get(key)
    if not isinstance(dev, SimulatedQEProDevice):
        options.setdefault("world", core.CONTEXT.world)
        dev = SimulatedQEProDevice(clock if clock is not None else core.CONTEXT.clock, **options)
        core.CONTEXT.instances[key] = dev  # type: ignore[assignment]
    return dev


__all__ = ["SeaBreezeError", "SimulatedQEProDevice", "SimulatedSpectrometer",
           "WhiteStandardSlide", "device", "halogen_irradiance", "list_devices"]
