"""Ocean Optics / Ocean Insight QE Pro spectrometer through python-seabreeze.

References: Ocean Insight, *QE Pro Installation and Operation Manual*; python-seabreeze
documentation (MIT) — [QEPRO] in docs/references.md.  The cseabreeze backend is the
default (it has the QE Pro's TEC and nonlinearity features); pyseabreeze is the fallback (no TEC,
no nonlinearity correction for the QE Pro — the driver then reports them as unavailable).
seabreeze is imported only when a real device is opened, never at module import.

    open("usb:") / open("usb:QEP01234") / open("QEP01234")    a real QE Pro (seabreeze)
    open("sim") / open("sim://qepro?seed=1&faults=disconnect@3")  the simulated one, through
                                          the backend a simulated lab registers with
                                          `normbox_lab.core.transport`

Device facts used: 1044 pixels, integration time 8 ms … 1600 s (`integration_time_micros`),
18-bit counts (max 262143), electrically dark pixels (dark correction = subtract their mean),
stored nonlinearity coefficients (``counts / polyval(c, counts)``), TEC set point
(``features['thermo_electric'][0]``, default −10 °C), lamp-enable line
(``features['strobe_lamp'][0].enable_lamp``) used by the gonioreflectometer as the shutter.

A saturated spectrum (any raw pixel at the maximum) raises `DeviceError("SATURATED")` from
`intensities_counts`; `acquire` returns it flagged instead.  A USB drop (seabreeze error)
closes the handle, reopens the device by serial number (until `reconnect_timeout_s`) and
retries the call once; if it stays away, `InstrumentError`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from normbox_lab.core import transport
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady, ProtocolError

MIN_INTEGRATION_S = 8e-3
MAX_INTEGRATION_S = 1600.0


@dataclass(frozen=True)
class Acquisition:
    counts: np.ndarray            # corrected as requested
    raw_counts: np.ndarray        # as read, 0 … max_counts
    integration_time_s: float
    saturated: bool
    tec_temperature_c: float


class QEPro:
    model = "QE Pro"

    def __init__(self, spectrometer: Any, clock: Clock, *, instrument_id: str = "spectrometer",
                 reopen: Callable[[], Any] | None = None, error_types: tuple[type, ...] = (),
                 tec_setpoint_c: float | None = -10.0, reconnect_timeout_s: float = 10.0,
                 simulated: bool = False) -> None:
        self.spec = spectrometer
        self.clock = clock
        self.instrument_id = instrument_id
        self._reopen = reopen
        self._errors = tuple(error_types) or (RuntimeError,)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.simulated = simulated
        self._white_standard: Any = None     # set by the backend that opened the device
        self.integration_time_s = 0.1
        try:
            self._wavelengths = np.asarray(self.spec.wavelengths(), dtype=float)
            self.max_counts = float(self.spec.max_intensity)
        except self._errors as exc:
            raise InstrumentError(f"seabreeze: {exc}", instrument=instrument_id) from exc
        except (TypeError, ValueError) as exc:
            raise ProtocolError(f"unreadable wavelength calibration: {exc}",
                                instrument=instrument_id) from None
        wl = self._wavelengths
        if wl.ndim != 1 or wl.size < 16 or not np.all(np.isfinite(wl)) \
                or np.any(np.diff(wl) <= 0) or not math.isfinite(self.max_counts) \
                or self.max_counts <= 0:
            raise ProtocolError(f"implausible device data: {wl.size} wavelengths (they must "
                                f"increase), max counts {self.max_counts:g}",
                                instrument=instrument_id)
        self.has_tec = "thermo_electric" in self._features() and \
            bool(self._features()["thermo_electric"])
        self.has_nonlinearity = bool(self._features().get("nonlinearity_coefficients"))
        self.set_integration_time_s(self.integration_time_s)
        if tec_setpoint_c is not None and self.has_tec:
            self.set_tec_setpoint_c(tec_setpoint_c)

    # --- opening ------------------------------------------------------------------------------
    @classmethod
    def open(cls, serial_or_url: str, clock: Clock, *, world: Any = None,
             backend: str = "cseabreeze", **options: Any) -> QEPro:
        target = str(serial_or_url)
        if transport.spectrometer_scheme(target) is not None:
            # a registered backend (the simulated lab's `sim`): no seabreeze here
            link = transport.open_spectrometer(target, clock, world=world)
            inst = cls(link.device, clock, reopen=link.reopen, error_types=link.error_types,
                       simulated=link.simulated, **options)
            inst._white_standard = link.white_standard
            return inst
        serial = target.removeprefix("usb:")
        serial = serial or None
        try:
            import seabreeze
            seabreeze.use(backend)
            from seabreeze.spectrometers import SeaBreezeError, Spectrometer
        except (ImportError, RuntimeError, ValueError) as exc:
            if backend == "pyseabreeze":
                raise InstrumentError(f"seabreeze unavailable: {exc}") from exc
            return cls.open(serial_or_url, clock, world=world, backend="pyseabreeze", **options)

        def reopen() -> Any:
            return Spectrometer.from_serial_number(serial)

        try:
            spec = reopen()
        except SeaBreezeError as exc:
            raise InstrumentError(f"cannot open QE Pro {serial or '(first)'}: {exc}",
                                  instrument=options.get("instrument_id", "spectrometer")) from exc
        return cls(spec, clock, reopen=reopen, error_types=(SeaBreezeError,), **options)

    # --- plumbing -----------------------------------------------------------------------------
    def _features(self) -> dict[str, list[Any]]:
        return dict(getattr(self.spec, "features", {}) or {})

    def _call(self, fn: Callable[[], Any]) -> Any:
        """Run one seabreeze call; on a USB drop reopen the device and try once more."""
        try:
            return fn()
        except self._errors as first:
            if self._reopen is None:
                raise InstrumentError(f"seabreeze: {first}", instrument=self.instrument_id) \
                    from first
            self._reconnect(first)
            try:
                return fn()
            except self._errors as exc:
                raise InstrumentError(f"seabreeze after reconnect: {exc}",
                                      instrument=self.instrument_id) from exc

    def _reconnect(self, cause: Exception) -> None:
        try:
            self.spec.close()
        except self._errors:
            pass
        deadline = self.clock.now_s() + self.reconnect_timeout_s
        while True:
            try:
                self.spec = self._reopen()  # type: ignore[misc]
                break
            except self._errors as exc:
                if self.clock.now_s() >= deadline:
                    raise InstrumentError(f"QE Pro gone ({cause}); not back after "
                                          f"{self.reconnect_timeout_s:g} s: {exc}",
                                          instrument=self.instrument_id) from exc
                self.clock.sleep(0.5)
        try:
            self.spec.integration_time_micros(round(self.integration_time_s * 1e6))
        except self._errors as exc:
            raise InstrumentError(f"QE Pro back but not answering: {exc}",
                                  instrument=self.instrument_id) from exc

    # --- the Spectrometer role -----------------------------------------------------------------
    def identify(self) -> InstrumentIdentity:
        return InstrumentIdentity("spectrometer", str(self.spec.model),
                                  str(self.spec.serial_number), "",
                                  simulated=self.simulated,
                                  extra={"pixels": str(len(self._wavelengths))})

    def close(self) -> None:
        try:
            self.spec.close()
        except self._errors:
            pass

    def wavelengths_nm(self) -> np.ndarray:
        return self._wavelengths.copy()

    def set_integration_time_s(self, integration_time_s: float) -> None:
        t = float(integration_time_s)
        if not MIN_INTEGRATION_S <= t <= MAX_INTEGRATION_S:
            raise DeviceError("INTEGRATION", f"{t:g} s is outside 8 ms … 1600 s",
                              instrument=self.instrument_id)
        us = round(t * 1e6)
        self._call(lambda: self.spec.integration_time_micros(us))
        self.integration_time_s = t

    def acquire(self, correct_dark: bool = True, correct_nonlinearity: bool = True) -> Acquisition:
        """One spectrum with its raw counts and the saturation flag (never raises on it)."""
        nl = correct_nonlinearity and self.has_nonlinearity
        raw = self._checked_counts(self._call(lambda: self.spec.intensities(False, False)))
        counts = raw.copy()
        dark_px = self._dark_pixels()
        offset = float(np.mean(raw[dark_px])) if dark_px else 0.0
        if correct_dark or nl:
            counts = counts - offset
        if nl:
            coeffs = self._features()["nonlinearity_coefficients"][0]
            c = np.poly1d(list(coeffs.get_nonlinearity_coefficients())[::-1])
            counts = counts / np.polyval(c, counts)
            if not correct_dark:
                counts = counts + offset
        saturated = bool(np.max(raw) >= self.max_counts - 0.5)
        tec = self.tec_temperature_c() if self.has_tec else float("nan")
        return Acquisition(counts, raw, self.integration_time_s, saturated, tec)

    def _checked_counts(self, values: Any) -> np.ndarray:
        """The device's counts as floats: one finite value per pixel, or ProtocolError."""
        try:
            raw = np.asarray(values, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ProtocolError(f"counts are not numbers: {exc}",
                                instrument=self.instrument_id) from None
        if raw.shape != self._wavelengths.shape or not np.all(np.isfinite(raw)):
            raise ProtocolError(f"counts: {raw.size} values (expected "
                                f"{self._wavelengths.size}), finite: "
                                f"{bool(np.all(np.isfinite(raw)))}",
                                instrument=self.instrument_id)
        return raw

    def _dark_pixels(self) -> list[int]:
        feats = self._features().get("spectrometer")
        if not feats:
            return []
        pixels = list(self._call(lambda: feats[0].get_electric_dark_pixel_indices()))
        if not all(isinstance(p, (int, np.integer)) and 0 <= p < self._wavelengths.size
                   for p in pixels):
            raise ProtocolError(f"electric dark pixel indices out of range: {pixels[:8]}",
                                instrument=self.instrument_id)
        return [int(p) for p in pixels]

    def intensities_counts(self, correct_dark: bool = True,
                           correct_nonlinearity: bool = True) -> np.ndarray:
        acq = self.acquire(correct_dark, correct_nonlinearity)
        if acq.saturated:
            raise DeviceError("SATURATED", f"counts reached {self.max_counts:.0f} at "
                              f"{acq.integration_time_s:g} s integration",
                              instrument=self.instrument_id)
        return acq.counts

    def _tec(self) -> Any:
        if not self.has_tec:
            raise NotReady("no TEC control with this seabreeze backend (use cseabreeze)",
                           instrument=self.instrument_id)
        return self._features()["thermo_electric"][0]

    def set_tec_setpoint_c(self, temperature_c: float) -> None:
        tec = self._tec()
        self._call(lambda: tec.set_temperature_setpoint_degrees_celsius(float(temperature_c)))
        self._call(lambda: self._tec().enable_tec(True))
        self.tec_setpoint_c = float(temperature_c)

    def tec_temperature_c(self) -> float:
        return float(self._call(lambda: self._tec().read_temperature_degrees_celsius()))

    def wait_tec_stable(self, tolerance_c: float = 0.5, timeout_s: float = 600.0,
                        poll_s: float = 5.0, stable_for_s: float = 30.0) -> float:
        """Wait until the detector is within `tolerance_c` of its TEC set point *and* has
        stayed there for `stable_for_s` (a cooling CCD passes through the band on its way
        down).  Returns the temperature; `NotReady` after `timeout_s` (the engine then asks
        the operator: retry, skip or abort)."""
        deadline = self.clock.now_s() + timeout_s
        inside_since: float | None = None
        while True:
            t = self.tec_temperature_c()
            now = self.clock.now_s()
            if abs(t - self.tec_setpoint_c) <= tolerance_c:
                inside_since = now if inside_since is None else inside_since
                if now - inside_since >= stable_for_s:
                    return t
            else:
                inside_since = None
            if now >= deadline:
                raise NotReady(f"TEC at {t:.2f} °C, set point {self.tec_setpoint_c:.1f} °C "
                               f"± {tolerance_c:g} °C not reached and held for "
                               f"{stable_for_s:g} s within {timeout_s:g} s",
                               instrument=self.instrument_id)
            self.clock.sleep(poll_s)

    def set_lamp_enabled(self, on: bool) -> None:
        """The lamp-enable line (wired to the gonio lamp's shutter)."""
        lamps = self._features().get("strobe_lamp")
        if not lamps:
            raise NotReady("this backend has no lamp-enable feature",
                           instrument=self.instrument_id)
        self._call(lambda: self._features()["strobe_lamp"][0].enable_lamp(bool(on)))

    def white_standard(self) -> Any:
        """The simulated gonio's white-standard slide (None for a real device)."""
        return self._white_standard

    def status(self) -> dict[str, Any]:
        return {"integration_time_s": self.integration_time_s,
                "tec_temperature_c": self.tec_temperature_c() if self.has_tec else None,
                "tec_setpoint_c": getattr(self, "tec_setpoint_c", None),
                "nonlinearity_correction": self.has_nonlinearity}


QEProSpectrometer = QEPro

__all__ = ["Acquisition", "QEPro", "QEProSpectrometer"]
