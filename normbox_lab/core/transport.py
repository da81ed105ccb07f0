"""The neutral transport: how a driver reaches its instrument, without knowing what is there.

- Serial instruments: `open_port(url, …)` is pyserial's ``serial_for_url``: a device path
  (``/dev/ttyUSB0``, ``COM3``), ``socket://host:port``, ``rfc2217://…``, ``loop://``, or any
  scheme a package registered with `register_serial_scheme` (pyserial looks up
  ``PACKAGE.protocol_SCHEME``).  The emulators register ``sim://`` when a simulated lab is built.
- USB spectrometers (seabreeze): `open_spectrometer(target, clock)` for a registered scheme
  (the emulators register ``sim``), else the driver opens seabreeze itself.

Drivers import this module only; nothing here imports the simulator.
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import serial

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import InstrumentError


def register_serial_scheme(package: str) -> None:
    """Let ``open_port("SCHEME://…")`` use ``PACKAGE.protocol_SCHEME`` (pyserial's URL
    handler mechanism)."""
    if package not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(package)


def open_port(url: str, *, instrument_id: str = "", **kwargs: Any) -> serial.SerialBase:
    """Open a serial port by URL with pyserial settings (`baudrate`, `timeout` …).

    A port that cannot be opened — missing, refused, or an unknown URL scheme (``sim://`` in a
    lab that is not simulated) — is an `InstrumentError` (for `instrument_id`) that says which."""
    try:
        return serial.serial_for_url(url, **kwargs)
    except ValueError as exc:
        raise InstrumentError(f"cannot open {url!r}: {exc} (known URL schemes: a device path, "
                              "socket://, rfc2217://, loop://, or one a simulated lab "
                              "registers)", instrument=instrument_id) from exc
    except (serial.SerialException, OSError) as exc:
        raise InstrumentError(f"cannot open {url!r}: {exc}", instrument=instrument_id) from exc


@dataclass(frozen=True)
class SpectrometerLink:
    """An opened USB spectrometer: a seabreeze `Spectrometer` (or one that behaves like it),
    how to reopen it after a USB drop, and the errors its backend raises."""

    device: Any
    reopen: Callable[[], Any]
    error_types: tuple[type[BaseException], ...]
    simulated: bool = False
    #: the reference slide of a simulated gonio (a real lab's operator places the standard)
    white_standard: Any = None


SpectrometerOpener = Callable[..., SpectrometerLink]
_SPECTROMETER_SCHEMES: dict[str, SpectrometerOpener] = {}


def register_spectrometer_scheme(scheme: str, opener: SpectrometerOpener) -> None:
    """``opener(target, clock, **options) -> SpectrometerLink`` serves targets ``SCHEME`` and
    ``SCHEME://…``."""
    _SPECTROMETER_SCHEMES[scheme] = opener


def spectrometer_scheme(target: str) -> str | None:
    """The scheme of a spectrometer target (``sim``, ``sim://qepro?seed=1``), or None for a
    serial number (``usb:QEP01234``, ``QEP01234``, empty = the first device)."""
    if "://" in target:
        return urllib.parse.urlsplit(target).scheme
    return target if target in _SPECTROMETER_SCHEMES else None


def open_spectrometer(target: str, clock: Clock, **options: Any) -> SpectrometerLink:
    scheme = spectrometer_scheme(target)
    opener = _SPECTROMETER_SCHEMES.get(scheme or "")
    if opener is None:
        raise InstrumentError(f"cannot open spectrometer {target!r}: no backend for "
                              f"{scheme!r} (a simulated lab registers sim)")
    return opener(target, clock, **options)


__all__ = [
    "SpectrometerLink",
    "open_port",
    "open_spectrometer",
    "register_serial_scheme",
    "register_spectrometer_scheme",
    "spectrometer_scheme",
]
