"""Ocean Optics / Ocean Insight QE Pro, emulated on its USB wire (Ocean Binary Protocol).

`QEProUsb` is the instrument's firmware as the host sees it through USB: device descriptor
VID 0x2457 / PID 0x4004, one vendor-specific interface with bulk endpoints 0x01/0x81 and
0x02/0x82 (512-byte packets), and Ocean Binary Protocol (OBP) frames on 0x01 → 0x81.  It sits on
the emulated pyusb bus of `normbox_lab.sim.usb` (`emulated_usb("qepro")`), where unmodified
python-seabreeze (pyseabreeze backend) lists, opens and reads it.  `SimulatedQEProDevice` is
the physics behind it (optics, counts, TEC, faults); nothing here imports seabreeze.

OBP frames (written from the protocol facts in [QEPRO] / [OBP] of docs/references.md,
little-endian): 44-byte header ``<H start 0xC0C1 (bytes C1 C0)><H version 0x1100><H flags>
<H error><L message type><L regarding><6s reserved><B checksum type><B immediate length>
<16s immediate data><L bytes remaining>``, then a payload when the data exceed 16 bytes, then
``<16s checksum><L footer 0xC2C3C4C5>``.  Checksum type 0 = none, 1 = MD5 over everything
before the checksum; a request with a wrong MD5 is refused (NACK, error 3).  Replies carry the
response flag 0x0001; a set command answers ACK (0x0002) only when the request asked for one
(flag 0x0004); an error answers NACK (0x0008) with its error number (2 unknown message type, 3
bad checksum, 5 payload length, 6 payload data invalid, 8 unknown checksum type, 1 wrong
protocol version) when the request asked for an ACK or expects data (*assumed*: a refused
set command without the ACK request gets no reply, so no stale NACK waits in the pipe).
Bytes before a start marker are dropped (resynchronisation).

Messages (request → reply data):

    0x00000100 GET_SERIAL_NUMBER          → the serial number (ASCII, ≤ 16 bytes)
    0x00000101 GET_SERIAL_NUMBER_LENGTH   → <B length>
    0x00000080 / 0x00000090 GET_HARDWARE / FIRMWARE_REVISION → <B> / <H>
    0x00000E11 GET_ORIGINAL_DEVICE_STRING → "QE-PRO"
    0x00100928 GET_BUF_SPEC32_META        → 32-byte metadata + 1044 × <L counts> (the
                                            acquisition runs now, for the integration time, on
                                            the device clock); metadata ``<L spectrum count>
                                            <Q time stamp µs><L integration time µs><B trigger
                                            mode>`` then zeros (*assumed* layout)
    0x00101100 GET_RAW_SPECTRUM_NOW       → 1044 × <L counts> (no metadata)
    0x00110000 GET_INTEGRATION_TIME_US    → <L µs>
    0x00110001 / 0x00110002 min / max     → <L 8000> / <L 1600000000>
    0x00110010 SET_ITIME_USEC  <L µs>     8 ms … 1600 s, else NACK 6
    0x00110100 / 0x00110110 GET / SET_TRIG_MODE <B 0 normal, 1 level, 2 synchronisation,
                                            3 edge>
    0x00110220 GET_NUMBER_OF_PIXELS       → <L 1044>
    0x00110400 / 0x00110410 GET / SET_LAMP_ENABLE <B>  (the lamp-enable line; the gonio's
                                            lamp shutter)
    0x00180100 / 0x00180101 <B i>  wavelength coefficient count / coefficient i (<f>)
    0x00181100 / 0x00181101 <B i>  nonlinearity coefficient count / coefficient i (<f>)
    0x00420000 / 0x00420001 GET_TE_ENABLE / GET_TE_SETPOINT → <B> / <f °C>
    0x00420004 GET_TE_TEMPERATURE         → <f °C>
    0x00420010 / 0x00420011 SET_TE_ENABLE <B> / SET_TE_SETPOINT <f °C>
    0x00100830 CLEAR_BUFFER_ALL / 0x00100000 ABORT_ACQUISITION   accepted

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
15 counts (``noise=False`` / ``sim://qepro?noise=off``: neither), electrical offset 1500 counts
(the only thing the electrically dark pixels see),
dark current 200 counts/s at −10 °C doubling every 6 °C, clipped at 262143.  The stored
nonlinearity coefficients [1, −0.005/262143] undo the 0.5 % nonlinearity the seabreeze way
(``counts / polyval(coeffs, counts)`` after the dark-pixel offset is removed).  TEC: first
order towards the set point, τ = 30 s, from 25 °C at power-up.  `intensities()` blocks for the
integration time on the injected clock.

Faults (`faults=` spec), at the USB level: ``disconnect``: the device drops off the bus for the
parameter's seconds (default 3), counted per spectrum request (``disconnect@3:30`` = the
third spectrum request is lost and the device is gone for 30 s): transfers on the old handle fail with
ENODEV, and it is not enumerated until it is back, at a new bus address.  Conditions, counted
per acquisition and latched from the one at which they fire (``kind@n`` = from the n-th
spectrum on; ``kind`` alone = from the first): ``saturation`` (a light leak holds pixels
500–519 at `parameter` × full scale, default 0.97, whatever the integration time),
``tec-drift`` (the detector warms by `parameter` °C, default 2, while the set point stays),
``dark-drift`` (`parameter` counts/s more dark current, default 1000), ``lamp-dim`` (the gonio
lamp's output × `parameter`, default 1e-4).  A bad fault spec is a `ValueError` here; the
driver reports it as an `InstrumentError`.
"""

from __future__ import annotations

import hashlib
import math
import struct
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
                    "lamp-dim": 1e-4, "dead-pixel": 600.0, "overflow": 2.0 ** 20,
                    "hot-pixel": 1e5}
OVERFLOW_PIXEL = 700
HOT_PIXEL = 650
#: the QE Pro's faults (USB: none of the serial transport kinds) and their ranges
FAULT_KINDS: tuple[core.FaultKind, ...] = (
    core.FaultKind("disconnect", "@", (1, 12), (0.05, 1e5), "log", unit="s",
                   means="the n-th spectrum request is lost; off the bus this long",
                   detector="reopen within reconnect_timeout_s, else typed InstrumentError"),
    core.FaultKind("saturation", "@", (1, 12), (0.01, 1.0), "log", unit="× full scale",
                   means="a light leak holds pixels 500-519 at ≥ this level from the n-th "
                         "acquisition on",
                   detector="driver: 8+ pixels at one identical count (noise makes that "
                            "impossible) → typed DeviceError(PLATEAU); at full scale: "
                            "saturation flag"),
    core.FaultKind("tec-drift", "@", (1, 12), (0.05, 30.0), "log", unit="°C",
                   means="the detector warms by this much, the set point stays",
                   detector="tec-off-setpoint gate (±0.5 °C); below it the dark follows"),
    core.FaultKind("dark-drift", "@", (1, 12), (1.0, 1e5), "log", unit="counts/s",
                   means="the dark current jumps by this much",
                   detector="dark taken with every reading; darks bracketing the white "
                            "reference must agree (gonio), dark-drift gate"),
    core.FaultKind("lamp-dim", "@", (1, 12), (1e-4, 1.0), "log", unit="× output",
                   means="the gonio lamp's output falls to this fraction",
                   detector="lamp check against the white (±2 %) → re-reference; "
                            "lamp-drift gate"),
    core.FaultKind("dead-pixel", "@", (1, 12), (4, 1039), "int", unit="pixel",
                   means="from the n-th acquisition on, this pixel sees no light (reads the "
                         "electrical offset)",
                   detector="driver: a pixel at the offset between two lit neighbours → "
                            "typed DeviceError(PIXEL)"),
    core.FaultKind("hot-pixel", "@", (1, 12), (1e3, 1e8), "log", unit="counts/s",
                   means="from the n-th acquisition on, pixel 650 has this much more dark "
                         "current",
                   detector="subtracted with the dark taken with every reading (the value "
                            "stays right); one that fills the pixel is saturation: ranged "
                            "down, else typed DeviceError(SATURATED)"),
    core.FaultKind("overflow", "@", (1, 12), (262144.0, 4294967295.0), "log",
                   unit="counts", means="from the n-th acquisition on, pixel 700 reads this "
                                        "value, beyond the 18-bit full scale",
                   detector="driver: counts outside 0 … 262143 → typed ProtocolError"),
)


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


class SimulatedQEProDevice:
    """The physical QE Pro on the detector arm (state persists across open/close)."""

    model = "QE-PRO"

    def __init__(self, clock: Clock | None = None, *, world: Any = None,
                 serial_number: str = "QEP-SIM-0001", light_arm: Any = None,
                 detector_arm: Any = None, tilt_deg: float = 4.0, arm_clearance_deg: float = 10.0,
                 lamp: Any = None, faults: str = "", seed: int = 0, noise: bool = True) -> None:
        self.clock = clock if clock is not None else VirtualClock()
        self.world = world
        self.serial_number = serial_number
        self.light_angle = _angle_source(light_arm, "gonio-light")
        self.detector_angle = _angle_source(detector_arm, "gonio-detector")
        self.tilt_deg = float(tilt_deg)
        self.arm_clearance_deg = float(arm_clearance_deg)
        self.faults = core.FaultInjector(faults, seed, {k.kind: k for k in FAULT_KINDS})
        self.conditions: dict[str, float] = {}      # latched condition faults → parameter
        self.rng = np.random.default_rng(seed)
        self.noise = bool(noise)                    # False: no shot or read noise
        px = np.arange(PIXELS, dtype=float)
        c0, c1, c2 = WAVELENGTH_COEFFS
        self.wavelengths = c0 + c1 * px + c2 * px * px
        self._lamp = lamp
        self.lamp_on = True
        self.white_in_place = False
        self.white_reflectance = 0.99
        self.integration_time_us = 100_000
        self.trigger_mode = 0
        self.spectrum_count = 0
        self.disconnected_until_s: float | None = None
        self.usb_backend: Any = None                # set when plugged into the emulated bus
        self._power_on_s = self.clock.now_s()
        self._tec_from_c, self._tec_since_s = AMBIENT_C, self._power_on_s
        self._tec_setpoint_c, self._tec_enabled = -10.0, True
        optical = self.wavelengths
        self.responsivity = np.exp(-((optical - 600.0) / 250.0) ** 2)
        white = (0.99 / math.pi * self.lamp_irradiance(optical) * math.cos(math.radians(tilt_deg))
                 * self.responsivity)
        self.responsivity *= WHITE_TARGET_COUNTS / (0.1 * float(white.max()))

    # --- link ---------------------------------------------------------------------------------
    def request_lost(self) -> bool:
        """A spectrum request reaches the device: True when the link drops now
        (``disconnect`` fault), for the fault's parameter in seconds."""
        if self.faults.fires("disconnect"):
            self.disconnected_until_s = self.clock.now_s() + \
                self.faults.parameter("disconnect", 3.0)
            return True
        return False

    @property
    def present(self) -> bool:
        """On the bus (enumerable) now."""
        if self.disconnected_until_s is not None and \
                self.clock.now_s() >= self.disconnected_until_s:
            self.disconnected_until_s = None
        return self.disconnected_until_s is None

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
        if "hot-pixel" in self.conditions:
            optical = optical.copy()
            optical[HOT_PIXEL] += float(self.conditions["hot-pixel"]) * t
        # the pixel's full well: beyond twice full scale nothing more is collected (so the
        # nonlinearity below never turns a flooded pixel's counts negative)
        optical = np.minimum(optical, 2.0 * MAX_COUNTS)
        measured = optical * (1.0 - NONLINEARITY * optical / MAX_COUNTS)
        noise = self.rng.normal(0.0, 1.0, PIXELS) * np.sqrt(
            SHOT_VAR_PER_COUNT * np.maximum(measured, 0.0) + READ_NOISE_COUNTS ** 2)
        if not self.noise:
            noise = np.zeros(PIXELS)
        counts = OFFSET_COUNTS + measured + noise
        if "saturation" in self.conditions:
            counts[500:520] = np.maximum(counts[500:520],
                                         self.conditions["saturation"] * MAX_COUNTS)
        counts[DARK_PIXELS] = OFFSET_COUNTS + self.rng.normal(0.0, READ_NOISE_COUNTS,
                                                              len(DARK_PIXELS)) * self.noise
        counts = np.clip(np.round(counts), 0, MAX_COUNTS)
        if "dead-pixel" in self.conditions:          # no light, no dark current: the offset
            counts[int(self.conditions["dead-pixel"])] = round(OFFSET_COUNTS)
        if "overflow" in self.conditions:            # a word beyond the ADC's 18 bits
            counts[OVERFLOW_PIXEL] = min(float(self.conditions["overflow"]), 2.0 ** 32 - 1)
        return counts


class WhiteStandardSlide:
    """The simulated gonio's reference slide: puts the Spectralon in the sample plane (a
    motorised slide: the gonio may bracket readings with lamp checks)."""

    def __init__(self, device: SimulatedQEProDevice, reflectance: float = 0.99, *,
                 motorised: bool = True) -> None:
        #: False: a slide moved only for the calibration (like a standard placed by hand), so
        #: the gonio does not bracket readings with lamp checks (``sim://qepro?slide=manual``)
        self.motorised = bool(motorised)
        self.device = device
        device.white_reflectance = float(reflectance)

    def reflectance(self, wavelength_nm: np.ndarray) -> np.ndarray:
        return np.full(np.shape(wavelength_nm), self.device.white_reflectance)

    def insert(self) -> None:
        self.device.white_in_place = True

    def remove(self) -> None:
        self.device.white_in_place = False


# --- the USB side: Ocean Binary Protocol ------------------------------------------------------
VENDOR_ID = 0x2457
PRODUCT_ID = 0x4004
EP_OUT, EP_IN, EP_OUT2, EP_IN2 = 0x01, 0x81, 0x02, 0x82
OBP_START = 0xC0C1
OBP_VERSION = 0x1100
OBP_FOOTER = 0xC2C3C4C5
OBP_HEADER = struct.Struct("<HHHHLL6sBB16sL")
OBP_HEADER_SIZE, OBP_FOOTER_SIZE = 44, 20
FLAG_RESPONSE, FLAG_ACK, FLAG_REQUEST_ACK, FLAG_NACK = 0x0001, 0x0002, 0x0004, 0x0008
CHECKSUM_NONE, CHECKSUM_MD5 = 0, 1
ERR_VERSION, ERR_UNKNOWN, ERR_CHECKSUM, ERR_LENGTH, ERR_INVALID, ERR_CHECKSUM_TYPE = \
    1, 2, 3, 5, 6, 8
METADATA_BYTES = 32


def obp_frame(message_type: int, data: bytes = b"", *, flags: int = 0, error: int = 0,
              regarding: int = 0, checksum_type: int = CHECKSUM_NONE) -> bytes:
    """One OBP frame (data ≤ 16 bytes go in the header's immediate field)."""
    if len(data) <= 16:
        immediate, payload = data, b""
    else:
        immediate, payload = b"", data
    head = OBP_HEADER.pack(OBP_START, OBP_VERSION, flags, error, message_type, regarding,
                           bytes(6), checksum_type, len(immediate), immediate.ljust(16, b"\0"),
                           len(payload) + OBP_FOOTER_SIZE)
    body = head + payload
    checksum = hashlib.md5(body).digest() if checksum_type == CHECKSUM_MD5 else bytes(16)
    return body + checksum + struct.pack("<L", OBP_FOOTER)


class QEProUsb:
    """The QE Pro's USB function: descriptors, bulk endpoints, OBP message handling."""

    def __init__(self, device: SimulatedQEProDevice) -> None:
        from normbox_lab.sim.usb_descriptors import bulk_endpoint, device_descriptor

        self.device = device
        self.clock = device.clock
        self.device_descriptor = device_descriptor(VENDOR_ID, PRODUCT_ID, bcd_device=0x0100)
        self.strings = {1: "Ocean Optics", 2: "QE-PRO", 3: device.serial_number}
        self.endpoints = [bulk_endpoint(EP_OUT), bulk_endpoint(EP_IN),
                          bulk_endpoint(EP_OUT2), bulk_endpoint(EP_IN2)]
        self._rx = bytearray()
        self._tx = bytearray()
        self.log: list[tuple[int, int]] = []       # (message type, error) per request

    # --- UsbFunction ---------------------------------------------------------------------------
    def present(self) -> bool:
        return self.device.present

    def reset(self) -> None:
        self._rx.clear()
        self._tx.clear()

    def bulk_out(self, endpoint: int, data: bytes) -> None:
        if endpoint != EP_OUT:
            return                                   # 0x02: not used by OBP over USB
        self._rx += data
        while True:
            frame = self._next_frame()
            if frame is None:
                return
            if self._counts_for_disconnect(frame) and self.device.request_lost():
                self.reset()                         # the link dropped with this request
                return
            self._tx += self._handle(frame)

    def bulk_in(self, endpoint: int, size: int) -> bytes:
        if endpoint != EP_IN or not self.device.present:
            return b""
        out = bytes(self._tx[:size])
        del self._tx[:size]
        return out

    # --- framing -------------------------------------------------------------------------------
    def _next_frame(self) -> bytes | None:
        start = self._rx.find(struct.pack("<H", OBP_START))
        if start < 0:
            del self._rx[:max(0, len(self._rx) - 1)]
            return None
        del self._rx[:start]
        if len(self._rx) < OBP_HEADER_SIZE:
            return None
        remaining = struct.unpack_from("<L", self._rx, 40)[0]
        if not OBP_FOOTER_SIZE <= remaining <= 1 << 16:
            del self._rx[:2]                         # not a header after all: resynchronise
            return self._next_frame()
        total = OBP_HEADER_SIZE + remaining
        if len(self._rx) < total:
            return None
        frame = bytes(self._rx[:total])
        del self._rx[:total]
        return frame

    @staticmethod
    def _counts_for_disconnect(frame: bytes) -> bool:
        """Spectrum requests are the opportunities of the ``disconnect`` fault."""
        return struct.unpack_from("<L", frame, 8)[0] in (0x00100928, 0x00101100)

    def _handle(self, frame: bytes) -> bytes:
        (_start, version, flags, _err, mtype, regarding, _res, cktype, imm_len, imm,
         _remaining) = OBP_HEADER.unpack_from(frame)
        data = imm[:imm_len] if imm_len else frame[OBP_HEADER_SIZE:-OBP_FOOTER_SIZE]
        wants_ack = bool(flags & FLAG_REQUEST_ACK)

        def reply(payload: bytes | None, error: int = 0) -> bytes:
            self.log.append((mtype, error))
            if error:
                if not (wants_ack or mtype in _QUERIES):
                    return b""
                return obp_frame(mtype, flags=FLAG_RESPONSE | FLAG_NACK, error=error,
                                 regarding=regarding, checksum_type=self._reply_ck(cktype))
            if payload is None:
                if not wants_ack:
                    return b""
                return obp_frame(mtype, flags=FLAG_RESPONSE | FLAG_ACK, regarding=regarding,
                                 checksum_type=self._reply_ck(cktype))
            return obp_frame(mtype, payload, flags=FLAG_RESPONSE, regarding=regarding,
                             checksum_type=self._reply_ck(cktype))

        if version != OBP_VERSION:
            return reply(None, ERR_VERSION)
        if cktype not in (CHECKSUM_NONE, CHECKSUM_MD5) or imm_len > 16:
            return reply(None, ERR_CHECKSUM_TYPE if imm_len <= 16 else ERR_LENGTH)
        if struct.unpack_from("<L", frame, len(frame) - 4)[0] != OBP_FOOTER:
            return reply(None, ERR_LENGTH)
        if cktype == CHECKSUM_MD5 and \
                frame[-OBP_FOOTER_SIZE:-4] != hashlib.md5(frame[:-OBP_FOOTER_SIZE]).digest():
            return reply(None, ERR_CHECKSUM)
        handler = _HANDLERS.get(mtype)
        if handler is None:
            return reply(None, ERR_UNKNOWN)
        fmt, fn = handler
        if len(data) != struct.calcsize(fmt):
            return reply(None, ERR_LENGTH)
        try:
            result = fn(self.device, *struct.unpack(fmt, data))
        except _Invalid:
            return reply(None, ERR_INVALID)
        return reply(result)

    @staticmethod
    def _reply_ck(request_checksum_type: int) -> int:
        return CHECKSUM_MD5 if request_checksum_type == CHECKSUM_MD5 else CHECKSUM_NONE


class _Invalid(Exception):
    """Payload data the device refuses (NACK, error 6)."""


def _set_integration(dev: SimulatedQEProDevice, us: int) -> None:
    lo, hi = INTEGRATION_LIMITS_US
    if not lo <= us <= hi:
        raise _Invalid
    dev.integration_time_us = int(us)


def _set_trigger(dev: SimulatedQEProDevice, mode: int) -> None:
    if mode > 3:
        raise _Invalid
    dev.trigger_mode = mode


def _coefficient(values: Any, i: int) -> bytes:
    if i >= len(values):
        raise _Invalid
    return struct.pack("<f", float(values[i]))


def _set_lamp(dev: SimulatedQEProDevice, on: int) -> None:
    dev.lamp_on = bool(on)


def _spectrum(dev: SimulatedQEProDevice, metadata: bool) -> bytes:
    counts = dev.acquire()
    dev.spectrum_count += 1
    body = counts.astype("<u4").tobytes()
    if not metadata:
        return body
    meta = struct.pack("<LQLB", dev.spectrum_count, round(dev.clock.now_s() * 1e6),
                       dev.integration_time_us, dev.trigger_mode)
    return meta.ljust(METADATA_BYTES, b"\0") + body


#: message type → (request payload struct format, handler(device, *values) → reply data or
#: None for a set command)
_HANDLERS: dict[int, tuple[str, Callable[..., bytes | None]]] = {
    0x00000100: ("", lambda d: d.serial_number.encode("ascii")[:16]),
    0x00000101: ("", lambda d: struct.pack("<B", len(d.serial_number.encode("ascii")[:16]))),
    0x00000080: ("", lambda d: struct.pack("<B", 1)),
    0x00000090: ("", lambda d: struct.pack("<H", 0x0100)),
    0x00000E11: ("", lambda d: d.model.encode("ascii")),
    0x00100000: ("", lambda d: None),
    0x00100830: ("", lambda d: None),
    0x00100928: ("", lambda d: _spectrum(d, True)),
    0x00101100: ("", lambda d: _spectrum(d, False)),
    0x00110000: ("", lambda d: struct.pack("<L", d.integration_time_us)),
    0x00110001: ("", lambda d: struct.pack("<L", INTEGRATION_LIMITS_US[0])),
    0x00110002: ("", lambda d: struct.pack("<L", INTEGRATION_LIMITS_US[1])),
    0x00110010: ("<L", _set_integration),
    0x00110100: ("", lambda d: struct.pack("<B", d.trigger_mode)),
    0x00110110: ("<B", _set_trigger),
    0x00110220: ("", lambda d: struct.pack("<L", PIXELS)),
    0x00110400: ("", lambda d: struct.pack("<B", int(d.lamp_on))),
    0x00110410: ("<B", _set_lamp),
    0x00180100: ("", lambda d: struct.pack("<B", len(WAVELENGTH_COEFFS))),
    0x00180101: ("<B", lambda d, i: _coefficient(WAVELENGTH_COEFFS, i)),
    0x00181100: ("", lambda d: struct.pack("<B", len(NONLINEARITY_COEFFS))),
    0x00181101: ("<B", lambda d, i: _coefficient(NONLINEARITY_COEFFS, i)),
    0x00420000: ("", lambda d: struct.pack("<B", int(d._tec_enabled))),
    0x00420001: ("", lambda d: struct.pack("<f", d._tec_setpoint_c)),
    0x00420004: ("", lambda d: struct.pack("<f", d.tec_temperature_c())),
    0x00420010: ("<B", lambda d, on: d.set_tec_enabled(bool(on))),
    0x00420011: ("<f", lambda d, c: d.set_tec_setpoint(float(c))),
}
#: requests that expect data back (a refusal of one is always answered)
_QUERIES = frozenset(k for k, (fmt, _) in _HANDLERS.items()
                     if k not in (0x00100000, 0x00100830, 0x00110010, 0x00110110, 0x00110410,
                                  0x00420010, 0x00420011))


core.declare_faults("qepro", FAULT_KINDS)


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


__all__ = [
    "PRODUCT_ID",
    "VENDOR_ID",
    "QEProUsb",
    "SimulatedQEProDevice",
    "WhiteStandardSlide",
    "device",
    "halogen_irradiance",
    "obp_frame",
]
