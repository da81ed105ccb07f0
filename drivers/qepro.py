"""Ocean Optics / Ocean Insight QE Pro spectrometer through python-seabreeze.

References: Ocean Insight, *QE Pro Installation and Operation Manual*; python-seabreeze
documentation (MIT) — [QEPRO] and [OBP] in docs/references.md.  The cseabreeze backend is the
default on hardware (it has the QE Pro's TEC, nonlinearity and lamp features); pyseabreeze (pure
Python on pyusb) is the fallback and the backend the simulated lab uses (its QE Pro sits on an
emulated pyusb bus, so this module's seabreeze path is the one that runs in CI).  seabreeze is
imported only when a device is opened, never at module import.

    open("usb:") / open("usb:QEP01234") / open("QEP01234")    a real QE Pro (seabreeze)
    open("QEP01234", backend="pyseabreeze", pyusb_backend="libusb1")   the pure-Python backend
    open("sim") / open("sim://qepro?seed=1&faults=disconnect@3")  the simulated one: the scheme
                                          registered with `normbox_lab.core.transport` says
                                          which seabreeze and pyusb backends reach it

Device facts used: 1044 pixels, integration time 8 ms … 1600 s (`integration_time_micros`),
18-bit counts (max 262143), electrically dark pixels (dark correction = subtract their mean),
stored nonlinearity coefficients (``counts / polyval(c, counts)``), TEC set point
(``features['thermo_electric'][0]``, default −10 °C), lamp-enable line
(``features['strobe_lamp'][0].enable_lamp``) used by the gonioreflectometer as the shutter.

The pyseabreeze gap: pyseabreeze's QEPRO has only the ``spectrometer`` and
``raw_usb_bus_access`` features — no ``thermo_electric``, ``nonlinearity_coefficients`` or
``strobe_lamp``.  When a feature is missing but raw USB access is there, this driver sends the
QE Pro's own OBP messages through ``raw_usb_bus_access`` (`ObpRawAccess`: TEC 0x00420004 /
0x00420010 / 0x00420011, nonlinearity 0x00181100 / 0x00181101, lamp enable 0x00110410), so the
TEC, the nonlinearity correction and the gonio's lamp shutter work with either backend.  With
neither (another device, or a backend without raw access) TEC calls raise `NotReady`, the
nonlinearity correction is skipped (``status()["nonlinearity_correction"]`` says so) and the
lamp line raises `NotReady`.

Numbers that are not counts are a `ProtocolError`, never data: a raw count that is not finite or
lies outside 0 … full scale (the 18-bit ADC: 262143; a device claiming a larger full scale is
refused at open), or a nonlinearity correction that is not a finite positive factor at every
pixel (coefficients that overflow or have a pole in the range).
A plateau (`PLATEAU_PIXELS` adjacent pixels with one identical count below 95 % of full scale:
an ADC stuck at a level, or light leaking onto part of the detector) is `DeviceError("PLATEAU")`
from `acquire`, for every frame (dark and white references too).
A saturated spectrum (any raw pixel at the maximum) raises `DeviceError("SATURATED")` from
`intensities_counts`; `acquire` returns it flagged instead.  A USB drop (seabreeze or pyusb
error) closes the handle, reopens the device by serial number until `reconnect_timeout_s`
(`core.transport.recover_link`) and retries the call once; if it stays away, `InstrumentError`.
Every failure of the backend, of opening or of a bad ``sim://`` option is an `InstrumentError`.
"""

from __future__ import annotations

import math
import struct
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
#: the QE Pro's ADC is 18-bit: no raw count can exceed 2**18 - 1 (a device that claims a larger
#: full scale, or sends a larger count, sends numbers that are not counts)
FULL_SCALE_COUNTS = 2 ** 18 - 1
#: an ADC plateau: this many adjacent pixels with one identical raw count.  Shot and read
#: noise (≥ 15 counts rms) make two adjacent pixels equal with a probability of ~1/50, so 8
#: in a row by chance ~1e-12 per pixel; a frame from a noise-free device (its electrically
#: dark pixels all equal: a simulation with noise off) is not judged
PLATEAU_PIXELS = 8
#: plateaus at or above this fraction of full scale are saturation (`Acquisition.saturated`,
#: the quality gate `saturation`), not an ADC or light-leak plateau
PLATEAU_CEILING_FRACTION = 0.95


@dataclass(frozen=True)
class Acquisition:
    counts: np.ndarray            # corrected as requested
    raw_counts: np.ndarray        # as read, 0 … max_counts
    integration_time_s: float
    saturated: bool
    tec_temperature_c: float


#: pyseabreeze's device listing also multicasts a discovery request for network spectrometers
#: (UDP to 239.239.239.239:57357 on the default interface, then a wait of 1 s) on every
#: listing, unless `seabreeze.use(..., network_adapter=...)` names an adapter.  The QE Pro is a
#: USB device, so the driver names an adapter that is none: pyseabreeze's discovery socket set-up
#: fails with OSError, which pyseabreeze catches, warns about and skips the discovery — nothing
#: is sent onto the network (the simulated lab, in CI, must send nothing) and nothing waits.
NO_NETWORK_ADAPTER = "none"


def _seabreeze(backend: str, pyusb_backend: str | None) -> tuple[Any, tuple[type, ...]]:
    """seabreeze's `Spectrometer` on `backend`, and the exceptions a USB failure raises there
    (pyseabreeze lets pyusb's `USBError` through unwrapped).  On pyseabreeze the network
    discovery is off (`NO_NETWORK_ADAPTER`)."""
    import warnings

    import seabreeze
    import seabreeze.backends

    kwargs: dict[str, Any] = {}
    if backend == "pyseabreeze":
        kwargs["network_adapter"] = NO_NETWORK_ADAPTER
        if pyusb_backend:
            kwargs["pyusb_backend"] = pyusb_backend
    with warnings.catch_warnings():
        # seabreeze warns when use() comes after a first device; the choice is the same one
        warnings.simplefilter("ignore")
        seabreeze.use(backend, **kwargs)
    seabreeze.backends.get_backend()             # ImportError here if the backend is missing
    from seabreeze.spectrometers import SeaBreezeError, Spectrometer, list_devices

    api = getattr(list_devices, "_api", None)    # seabreeze keeps the first API object
    if api is not None and getattr(api, "_kwargs", None) != \
            seabreeze.backends.BackendConfig.api_kwargs:
        del list_devices._api                    # made again with these keywords

    errors: tuple[type, ...] = (SeaBreezeError,)
    if backend == "pyseabreeze":
        import usb.core
        from seabreeze.pyseabreeze.transport import USBTransportDeviceInUse, USBTransportError

        # pyseabreeze on a handle closed after a drop: RuntimeError("device not opened"), or
        # ReferenceError from a feature whose protocol object is gone
        errors += (usb.core.USBError, USBTransportError, USBTransportDeviceInUse, RuntimeError,
                   ReferenceError)
    return Spectrometer, errors


def usb_identities(backend: str = "cseabreeze", pyusb_backend: str | None = None,
                   ) -> list[tuple[str, InstrumentIdentity]]:
    """`lab discover`'s identification on USB: the spectrometers seabreeze lists (it reads each
    one's model and serial number; nothing else is sent), as ``("usb:SERIAL", identity)``.
    `backend` falls back from cseabreeze to pyseabreeze as `QEPro.open` does; a missing
    seabreeze or USB backend is an `InstrumentError` that says so."""
    try:
        _, errors = _seabreeze(backend, pyusb_backend)
    except (ImportError, RuntimeError, ValueError) as exc:
        if backend != "pyseabreeze":
            return usb_identities("pyseabreeze", pyusb_backend)
        raise InstrumentError(f"seabreeze unavailable: {exc}", instrument="usb") from exc
    import warnings

    from seabreeze.spectrometers import list_devices

    try:
        with warnings.catch_warnings():          # the skipped network discovery's note
            warnings.simplefilter("ignore")
            devices = list_devices()
    except errors as exc:
        raise InstrumentError(f"USB scan failed: {exc}", instrument="usb") from exc
    out = []
    for dev in devices:
        serial, model = str(dev.serial_number), str(dev.model)
        out.append((f"usb:{serial}", InstrumentIdentity(
            "spectrometer", "QE Pro" if model.upper() == "QEPRO" else model, serial,
            extra={"seabreeze_backend": backend, **({"pyusb_backend": str(pyusb_backend)}
                                                     if pyusb_backend else {})})))
    return out


class ObpRawAccess:
    """The QE Pro's Ocean Binary Protocol messages through seabreeze's ``raw_usb_bus_access``
    feature (its `raw_usb_write` / `raw_usb_read`), for what a backend does not wrap.

    Frame (little-endian): 44-byte header ``<H 0xC0C1><H 0x1100><H flags><H error><L type>
    <L regarding><6s><B checksum type 0><B immediate length><16s immediate><L bytes
    remaining>``, payload when > 16 bytes, ``<16s checksum><L 0xC2C3C4C5>``; replies carry flag
    0x0001, a refusal flag 0x0008 with its error number."""

    HEADER = struct.Struct("<HHHHLL6sBB16sL")
    REQUEST_ACK, NACK = 0x0004, 0x0008

    def __init__(self, raw: Callable[[], Any], *, instrument_id: str = "spectrometer") -> None:
        self._raw = raw
        self.instrument_id = instrument_id

    def _frame(self, message_type: int, data: bytes, flags: int) -> bytes:
        imm, payload = (data, b"") if len(data) <= 16 else (b"", data)
        head = self.HEADER.pack(0xC0C1, 0x1100, flags, 0, message_type, 0, bytes(6), 0,
                                len(imm), imm.ljust(16, b"\0"), len(payload) + 20)
        return head + payload + bytes(16) + struct.pack("<L", 0xC2C3C4C5)

    def _exchange(self, message_type: int, data: bytes, flags: int) -> bytes:
        raw = self._raw()
        raw.raw_usb_write(self._frame(message_type, data, flags), "primary_out")
        reply = bytes(raw.raw_usb_read("primary_in", 64))
        if len(reply) < 44:
            raise ProtocolError(f"OBP reply to 0x{message_type:08X}: {len(reply)} bytes",
                                instrument=self.instrument_id)
        (start, _v, rflags, error, rtype, _r, _res, _ck, imm_len, imm,
         remaining) = self.HEADER.unpack_from(reply)
        while len(reply) < 44 + remaining:
            more = bytes(raw.raw_usb_read("primary_in", 44 + remaining - len(reply)))
            if not more:
                break
            reply += more
        if start != 0xC0C1 or rtype != message_type or len(reply) != 44 + remaining \
                or imm_len > 16:
            raise ProtocolError(f"OBP reply to 0x{message_type:08X} does not match "
                                f"(type 0x{rtype:08X}, {len(reply)} bytes)",
                                instrument=self.instrument_id)
        if rflags & self.NACK:
            raise DeviceError(f"OBP{error}", f"QE Pro refused 0x{message_type:08X} "
                              f"(OBP error {error})", instrument=self.instrument_id)
        return imm[:imm_len] if imm_len else reply[44:-20]

    def query(self, message_type: int, data: bytes = b"") -> bytes:
        return self._exchange(message_type, data, 0)

    def command(self, message_type: int, data: bytes = b"") -> None:
        """A set command, with the ACK requested (so a refusal is seen)."""
        self._exchange(message_type, data, self.REQUEST_ACK)


class _ObpTec:
    """seabreeze's thermo_electric feature, over OBP (0x00420004 / 0x00420010 / 0x00420011)."""

    def __init__(self, obp: ObpRawAccess) -> None:
        self.obp = obp

    def read_temperature_degrees_celsius(self) -> float:
        return float(struct.unpack("<f", self.obp.query(0x00420004))[0])

    def set_temperature_setpoint_degrees_celsius(self, temperature: float) -> None:
        self.obp.command(0x00420011, struct.pack("<f", float(temperature)))

    def enable_tec(self, state: bool) -> None:
        self.obp.command(0x00420010, struct.pack("<B", bool(state)))


class _ObpNonlinearity:
    """seabreeze's nonlinearity_coefficients feature, over OBP (0x00181100 / 0x00181101);
    read once (they are stored calibration values)."""

    def __init__(self, obp: ObpRawAccess) -> None:
        self.obp = obp
        self._coeffs: list[float] | None = None

    def get_nonlinearity_coefficients(self) -> list[float]:
        if self._coeffs is None:
            n = self.obp.query(0x00181100)[0]
            self._coeffs = [float(struct.unpack("<f", self.obp.query(0x00181101,
                                                                     bytes([i])))[0])
                            for i in range(n)]
        return list(self._coeffs)


class _ObpLamp:
    """seabreeze's strobe_lamp feature, over OBP (0x00110410 SET_LAMP_ENABLE)."""

    def __init__(self, obp: ObpRawAccess) -> None:
        self.obp = obp

    def enable_lamp(self, state: bool) -> None:
        self.obp.command(0x00110410, struct.pack("<B", bool(state)))


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
        self._lost: Exception | None = None  # the USB drop a failed recovery left unresolved
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
                or not 0 < self.max_counts <= FULL_SCALE_COUNTS:
            raise ProtocolError(f"implausible device data: {wl.size} wavelengths (they must "
                                f"increase), max counts {self.max_counts:g}",
                                instrument=instrument_id)
        self._filled: dict[str, list[Any]] = {}
        raw_access = bool(self._native().get("raw_usb_bus_access")) and \
            "QE" in str(getattr(self.spec, "model", "")).upper()
        if raw_access:
            obp = ObpRawAccess(lambda: self._native()["raw_usb_bus_access"][0],
                               instrument_id=instrument_id)
            for name, feature in (("thermo_electric", _ObpTec(obp)),
                                  ("nonlinearity_coefficients", _ObpNonlinearity(obp)),
                                  ("strobe_lamp", _ObpLamp(obp))):
                if not self._native().get(name):
                    self._filled[name] = [feature]
        self.has_tec = bool(self._features().get("thermo_electric"))
        self.has_nonlinearity = bool(self._features().get("nonlinearity_coefficients"))
        self.set_integration_time_s(self.integration_time_s)
        if tec_setpoint_c is not None and self.has_tec:
            self.set_tec_setpoint_c(tec_setpoint_c)

    # --- opening ------------------------------------------------------------------------------
    @classmethod
    def open(cls, serial_or_url: str, clock: Clock, *, world: Any = None,
             backend: str = "cseabreeze", pyusb_backend: str | None = None,
             **options: Any) -> QEPro:
        """Open by serial number (``usb:SERIAL``, ``SERIAL``, ``usb:`` = the first) with
        seabreeze `backend` (``cseabreeze`` or ``pyseabreeze``; `pyusb_backend` names
        pyseabreeze's pyusb backend), or a registered scheme (``sim://qepro?…``)."""
        target = str(serial_or_url)
        instrument_id = options.get("instrument_id", "spectrometer")
        if transport.spectrometer_scheme(target) is not None:
            try:
                link = transport.open_spectrometer(target, clock, world=world)
            except ValueError as exc:
                raise InstrumentError(f"cannot open spectrometer {target!r}: {exc}",
                                      instrument=instrument_id) from exc
            inst = cls._open_seabreeze(link.serial_number, clock, backend=link.backend,
                                       pyusb_backend=link.pyusb_backend,
                                       simulated=link.simulated, **options)
            inst._white_standard = link.white_standard
            return inst
        return cls._open_seabreeze(target.removeprefix("usb:") or None, clock, backend=backend,
                                   pyusb_backend=pyusb_backend, **options)

    @classmethod
    def _open_seabreeze(cls, serial: str | None, clock: Clock, *, backend: str,
                        pyusb_backend: str | None, **options: Any) -> QEPro:
        instrument_id = options.get("instrument_id", "spectrometer")
        try:
            Spectrometer, errors = _seabreeze(backend, pyusb_backend)
        except (ImportError, RuntimeError, ValueError) as exc:
            if backend == "pyseabreeze":
                raise InstrumentError(f"seabreeze unavailable: {exc}",
                                      instrument=instrument_id) from exc
            return cls._open_seabreeze(serial, clock, backend="pyseabreeze",
                                       pyusb_backend=pyusb_backend, **options)

        def reopen() -> Any:
            import warnings

            with warnings.catch_warnings():          # the skipped network discovery's note
                warnings.filterwarnings("ignore", message=".*Skipping IPv4 discovery")
                return Spectrometer.from_serial_number(serial)

        try:
            spec = reopen()
        except errors as exc:
            raise InstrumentError(f"cannot open QE Pro {serial or '(first)'}: {exc}",
                                  instrument=instrument_id) from exc
        return cls(spec, clock, reopen=reopen, error_types=errors, **options)

    # --- plumbing -----------------------------------------------------------------------------
    def _native(self) -> dict[str, list[Any]]:
        return dict(getattr(self.spec, "features", {}) or {})

    def _features(self) -> dict[str, list[Any]]:
        """The backend's features, with the gaps filled over raw USB (see the module doc)."""
        return {**self._native(), **getattr(self, "_filled", {})}

    def _call(self, fn: Callable[[], Any]) -> Any:
        """Run one seabreeze call; on a USB drop reopen the device and try once more.  After a
        recovery that failed, the next call starts with the recovery (the old handle is dead)."""
        try:
            if self._lost is not None and self._reopen is not None:
                self._reconnect(self._lost)
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
        self.close()
        self._lost = cause

        def attempt() -> Any:
            return self._reopen()  # type: ignore[misc]

        self.spec = transport.recover_link(
            self.clock, self.reconnect_timeout_s, attempt, retry_on=self._errors,
            instrument_id=self.instrument_id, what=f"QE Pro gone ({cause})")
        self._lost = None
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
            pass                        # a device that dropped off closes as far as it can

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
            coeffs = self._call(lambda: list(
                self._features()["nonlinearity_coefficients"][0]
                .get_nonlinearity_coefficients()))
            counts = self._linearised(counts, coeffs)
            if not correct_dark:
                counts = counts + offset
        saturated = bool(np.max(raw) >= self.max_counts - 0.5)
        self._refuse_plateau(raw, dark_px)
        self._refuse_dead_pixel(raw, dark_px)
        tec = self.tec_temperature_c() if self.has_tec else float("nan")
        return Acquisition(counts, raw, self.integration_time_s, saturated, tec)

    def _refuse_plateau(self, raw: np.ndarray, dark_px: list[int]) -> None:
        """`DeviceError("PLATEAU")` when `PLATEAU_PIXELS` adjacent pixels hold one identical
        count below saturation: an ADC stuck at a level or light leaking onto the detector
        (noise makes such a run impossible in a real frame).  Never data: a plateau in a dark
        or white reference would bias every reading computed from it."""
        if len(dark_px) >= 2 and float(np.ptp(raw[dark_px])) == 0.0:
            return                                   # a noise-free (simulated) device
        same = np.diff(raw) == 0
        same &= raw[1:] < PLATEAU_CEILING_FRACTION * self.max_counts
        if not same.any():
            return
        # the longest run of equal neighbours
        edges = np.flatnonzero(np.diff(np.concatenate(([0], same.astype(np.int8), [0]))))
        starts, ends = edges[::2], edges[1::2]
        longest = int(np.argmax(ends - starts))
        run = int(ends[longest] - starts[longest]) + 1
        if run >= PLATEAU_PIXELS:
            first = int(starts[longest])
            raise DeviceError("PLATEAU", f"{run} adjacent pixels ({first}–{first + run - 1}) "
                              f"hold one count, {raw[first]:.0f}: an ADC plateau or light "
                              "leak, not a spectrum", instrument=self.instrument_id)

    def _refuse_dead_pixel(self, raw: np.ndarray, dark_px: list[int]) -> None:
        """`DeviceError("PIXEL")` when a pixel reads the electrical offset (within 6× the read
        noise) while both its neighbours see light far above it (≥ 20× the read noise and
        ≥ 1000 counts): a dead pixel, or a byte lost in its word.  The optics spread light over
        several pixels, so no spectrum has such a hole."""
        if not dark_px:
            return
        dark = raw[dark_px]
        offset = float(np.mean(dark))
        read_noise = max(float(np.std(dark)), 1.0)
        if read_noise <= 1.0 and float(np.ptp(dark)) == 0.0:
            return                                   # a noise-free (simulated) device
        lit = np.maximum(20.0 * read_noise, 1000.0)
        x = raw - offset
        hole = (np.abs(x[1:-1]) < 6.0 * read_noise) & (x[:-2] > lit) & (x[2:] > lit)
        hole[[i - 1 for i in dark_px if 0 < i < raw.size - 1]] = False
        if hole.any():
            i = int(np.flatnonzero(hole)[0]) + 1
            raise DeviceError("PIXEL", f"pixel {i} reads {raw[i]:.0f} counts (the offset) "
                              f"between {raw[i - 1]:.0f} and {raw[i + 1]:.0f}: a dead pixel, "
                              "not a spectrum", instrument=self.instrument_id)

    def _linearised(self, counts: np.ndarray, coeffs: Any) -> np.ndarray:
        """``counts / polyval(coeffs, counts)`` (seabreeze's nonlinearity correction), or
        `ProtocolError` when the stored coefficients are not numbers or the
        correction is not a finite, positive factor at every pixel (an overflow, a pole of
        the polynomial): never NaN or infinite counts handed on as data."""
        try:
            c = np.asarray(coeffs, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ProtocolError(f"nonlinearity coefficients are not numbers: {exc}",
                                instrument=self.instrument_id) from None
        if c.ndim != 1 or c.size == 0 or not np.all(np.isfinite(c)):
            raise ProtocolError(f"nonlinearity coefficients {c.tolist()[:8]} are not finite "
                                "numbers", instrument=self.instrument_id)
        with np.errstate(all="ignore"):
            factor = np.polyval(c[::-1], counts)
            out = counts / factor
        bad = ~(np.isfinite(factor) & (factor > 0) & np.isfinite(out))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ProtocolError(f"nonlinearity correction fails at {int(bad.sum())} pixel(s) "
                                f"(pixel {i}: {counts[i]:.6g} counts, factor {factor[i]:.6g}):"
                                " not data", instrument=self.instrument_id)
        return out

    def _checked_counts(self, values: Any) -> np.ndarray:
        """The device's counts as floats: one finite value per pixel within 0 … full scale
        (the 18-bit ADC's `max_counts`), or ProtocolError."""
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
        out = (raw < 0) | (raw > self.max_counts)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            raise ProtocolError(f"counts: {int(out.sum())} value(s) outside 0 … "
                                f"{self.max_counts:.0f} (the ADC's full scale; pixel {i}: "
                                f"{raw[i]:.6g}): not counts", instrument=self.instrument_id)
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
