"""The neutral transport: how a driver reaches its instrument, without knowing what is there.

- Serial instruments: `open_port(url, …)` is pyserial's ``serial_for_url``: a device path
  (``/dev/ttyUSB0``, ``COM3``), ``socket://host:port``, ``rfc2217://…``, ``loop://``, or any
  scheme a package registered with `register_serial_scheme` (pyserial looks up
  ``PACKAGE.protocol_SCHEME``).  The emulators register ``sim://`` when a simulated lab is built.
- USB spectrometers (seabreeze): `open_spectrometer(target, clock)` for a registered scheme
  (the emulators register ``sim``: their QE Pro sits on an emulated pyusb bus) says which
  seabreeze backend and pyusb backend reach it; the driver opens seabreeze itself.
- `Port`: what a serial driver may ask of its port (pyserial's `Serial`, the ``sim://`` port,
  the tests' scripted port all are one), so no driver probes it with ``hasattr``.
- `recover_link(clock, timeout_s, attempt, …)`: the one deadline-and-reconnect loop after a
  lost link (reopen, re-handshake, wait, again, until a deadline on the injected clock), and
  `reopen(port)`, the usual first half of such an attempt.

Drivers import this module only; nothing here imports the simulator.
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, runtime_checkable

import serial

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import InstrumentError

T = TypeVar("T")


@runtime_checkable
class Port(Protocol):
    """A byte link to one instrument, as pyserial's `Serial` offers it: reads honour `timeout`
    (seconds; they return what arrived by then), `reset_input_buffer` drops what has arrived,
    `close`/`open` drop and re-establish the link; `port` names it (a device path or URL)."""

    port: str | None
    timeout: float | None
    is_open: bool

    def open(self) -> None: ...
    def close(self) -> None: ...
    def write(self, data: bytes) -> int | None: ...
    def read(self, size: int = 1) -> bytes: ...
    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes: ...
    def reset_input_buffer(self) -> None: ...


def reopen(port: Port) -> None:
    """Close `port` if open, then open it again (a USB-serial adapter that re-enumerated, a TCP
    link that dropped); errors are the port's own (`SerialException`, `OSError`)."""
    if port.is_open:
        port.close()
    port.open()


def recover_link(clock: Clock, timeout_s: float, attempt: Callable[[], T], *,
                 retry_on: tuple[type[BaseException], ...], instrument_id: str,
                 what: str = "link lost", error: type[InstrumentError] = InstrumentError,
                 interval_s: float = 0.5, first_wait_s: float = 0.0,
                 on_failure: Callable[[BaseException], None] | None = None) -> T:
    """Bring a lost link back within `timeout_s` on `clock`, or raise a typed error.

    After `first_wait_s`, call `attempt()` (reopen the port or device, handshake again) until it
    returns; an exception in `retry_on` is passed to `on_failure` (close what half-opened, count
    the fault), and unless `timeout_s` has passed since the call the attempt is repeated after
    `interval_s`.  Past the deadline `error(f"{what}; not back within …: {last}")` for
    `instrument_id` is raised, chained to the last failure.  Never sleeps on the wall clock
    (tests run it on a virtual clock) and never loops without a bound."""
    deadline_s = clock.now_s() + float(timeout_s)
    if first_wait_s > 0:
        clock.sleep(first_wait_s)
    while True:
        try:
            return attempt()
        except retry_on as exc:
            if on_failure is not None:
                on_failure(exc)
            if clock.now_s() >= deadline_s:
                raise error(f"{what}; not back within {float(timeout_s):g} s: {exc}",
                            instrument=instrument_id) from exc
            clock.sleep(interval_s)


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
    """Where a registered scheme's USB spectrometer is: the driver opens it with seabreeze
    (`backend`, and for pyseabreeze the pyusb backend by name) by its serial number."""

    serial_number: str
    backend: str = "pyseabreeze"
    pyusb_backend: str | None = None
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
    "Port",
    "SpectrometerLink",
    "open_port",
    "open_spectrometer",
    "recover_link",
    "register_serial_scheme",
    "register_spectrometer_scheme",
    "reopen",
    "spectrometer_scheme",
]
