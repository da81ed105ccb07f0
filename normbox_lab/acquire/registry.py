"""The driver registry: the one table that says which driver a lab config may name.

    [instruments.radiometer]
    driver = "cs1000a"            # a name of DRIVERS
    port = "sim://cs1000a"
    command_timeout_s = 5.0       # an option: a keyword of the driver's open() (or __init__)

Each entry names the driver's module and class (imported lazily: a config is checked without
opening a port) and the instrument roles it can fill.  The options an instrument table may
hold are *derived* from the driver itself (`driver_options`): the keyword parameters of its
``open(url, clock, ...)`` classmethod, and — when ``open`` forwards ``**options`` — those of
its ``__init__``; each with the TOML type its annotation names (``int``, ``float``, ``bool``,
``str``; ``float | None`` is a float).  Parameters of any other type (callables, objects) and
those an entry lists as `internal` are the program's, not the config's.  So a keyword added
to a driver is a config option at once, and a keyword removed is refused at once
(tests/acquire/test_lab.py checks every entry).

Each entry also declares how `normbox-lab lab discover` may ask the instrument who it is
(`Identification`): the exact bytes of its identification exchanges, the baud rates to try, and
the driver function that reads the replies.  Discover sends those bytes and nothing else (a
port wrapper refuses any other write), so what may reach an unknown instrument is readable
here: identification queries and remote-mode switches, never a command that moves, switches a
lamp or measures.

docs/adding-an-instrument.md walks a new model through every file it touches.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from normbox_lab.core.errors import NormboxError


@dataclass(frozen=True)
class Exchange:
    """One identification exchange: `send` goes out as it is; the reply ends with `reply_end`
    (a terminator, or a byte count for binary frames; None: no reply is awaited, whatever
    comes back within the quiet time is drained and ignored).  When `expect` is given and the
    reply does not start with it, the exchanges after this one are not sent."""

    send: bytes
    reply_end: bytes | int | None = b"\n"
    expect: bytes = b""


@dataclass(frozen=True)
class Identification:
    """How `lab discover` finds this driver's instrument.

    Serial instruments: `exchanges` at each of `bauds` (8N1, RTS/CTS when `rtscts`); the driver
    module's function `parse` turns the list of replies into an `InstrumentIdentity`, or None
    when they are not this instrument's.  `binary`: the exchanges are binary frames (probed
    before the line-oriented ones, so that no ASCII probe can misalign a binary framing).
    USB instruments: `usb` lists (VID, PID); the module's function `parse` is then
    ``parse(backend, pyusb_backend) -> list[(target, InstrumentIdentity)]``."""

    parse: str
    exchanges: tuple[Exchange, ...] = ()
    bauds: tuple[int, ...] = ()
    rtscts: bool = False
    binary: bool = False
    usb: tuple[tuple[int, int], ...] = ()


@dataclass(frozen=True)
class DriverEntry:
    """One driver a lab config may name."""

    module: str                      # e.g. "normbox_lab.drivers.cs1000"
    cls: str                         # e.g. "CS1000A"
    roles: tuple[str, ...]           # the instrument roles it can fill
    #: keyword parameters that are the program's, not the lab config's
    internal: tuple[str, ...] = ()
    #: how `lab discover` asks the instrument who it is (None: it cannot be discovered)
    identification: Identification | None = None
    #: the line rates a config's ``baud`` may name (empty: any of `acquire.config.BAUD_RATES`)
    baud_rates: tuple[int, ...] = ()
    #: the values of its ``data_format`` option, the default first (empty: no such option)
    data_formats: tuple[str, ...] = ()


_RADIOMETER = ("radiometer",)
_STAGE = ("rotator", "gonio_light_arm", "gonio_detector_arm")

#: the blank line a line-oriented probe starts with: it ends whatever partial line an earlier
#: probe (another driver's, or a binary frame) left in the instrument, whose error reply is
#: drained and ignored
_FLUSH = Exchange(b"\n", reply_end=None)

#: config driver name → entry.  The one registry: roles, classes and options all come from it.
DRIVERS: dict[str, DriverEntry] = {
    # CS-1000A: no identification command; remote on, the status STR (a read), remote off
    "cs1000a": DriverEntry("normbox_lab.drivers.cs1000", "CS1000A", _RADIOMETER,
                           identification=Identification(
                               "parse_identification",
                               (_FLUSH, Exchange(b"RMT,1\n", expect=b"OK"), Exchange(b"STR\n"),
                                Exchange(b"RMT,0\n")),
                               bauds=(9600, 19200, 4800)),
                           data_formats=("ascii", "binary")),
    # CS-2000A: remote on without flash writes, IDDR (name, variation, serial), remote off
    "cs2000a": DriverEntry("normbox_lab.drivers.cs2000", "CS2000A", _RADIOMETER,
                           identification=Identification(
                               "parse_identification",
                               (_FLUSH, Exchange(b"RMTS,2\n", expect=b"OK00"),
                                Exchange(b"IDDR\n"), Exchange(b"RMTS,0\n")),
                               bauds=(115200,), rtscts=True),
                           baud_rates=(115200,), data_formats=("ascii", "hex")),
    # JETI specbos 1211: an empty line (its NAK ignored), *IDN?, serial number, firmware
    "specbos1211": DriverEntry("normbox_lab.drivers.specbos", "Specbos1211", _RADIOMETER,
                               identification=Identification(
                                   "parse_identification",
                                   (Exchange(b"\r", reply_end=None),
                                    Exchange(b"*IDN?\r", b"\r", expect=b"JETI_SB"),
                                    Exchange(b"*PARA:SERNO?\r", b"\r"),
                                    Exchange(b"*VERS?\r", b"\r")),
                                   bauds=(921600, 115200, 38400)),
                               baud_rates=(921600, 115200, 38400)),
    # APT: HW_REQ_INFO (0x0005) → HW_GET_INFO (0x0006, 90 bytes); MOD_IDENTIFY would flash the LED
    "apt-k10cr1": DriverEntry("normbox_lab.drivers.rotator_apt", "AptRotationStage", _STAGE,
                              internal=("connect",),
                              identification=Identification(
                                  "parse_identification",
                                  (Exchange(b"\x05\x00\x00\x00\x50\x01", reply_end=90),),
                                  bauds=(115200,), rtscts=True, binary=True)),
    # Zaber ASCII: three reads of the device at address 1
    "zaber": DriverEntry("normbox_lab.drivers.rotator_zaber", "ZaberRotationStage", _STAGE,
                         internal=("connect",),
                         identification=Identification(
                             "parse_identification",
                             (_FLUSH, Exchange(b"/1 get deviceid\n", expect=b"@01"),
                              Exchange(b"/1 get system.serial\n"),
                              Exchange(b"/1 get version\n")),
                             bauds=(115200,))),
    "sphere-scpi": DriverEntry("normbox_lab.drivers.sphere", "SphereLightSource", ("sphere",),
                               identification=Identification(
                                   "parse_identification", (_FLUSH, Exchange(b"*IDN?\n")),
                                   bauds=(115200,))),
    # QE Pro on USB (Ocean Insight VID 0x2457, PID 0x4004): seabreeze lists it with its serial
    "qepro": DriverEntry("normbox_lab.drivers.qepro", "QEPro", ("spectrometer",),
                         internal=("simulated",),
                         identification=Identification("usb_identities",
                                                       usb=((0x2457, 0x4004),))),
}

@dataclass(frozen=True)
class CompositeEntry:
    """A role made of other roles' instruments (e.g. the gonioreflectometer): the driver
    function ``function(parts, clock, ask_operator)`` composes it from the opened parts."""

    module: str
    function: str
    parts: tuple[str, ...]


#: composite role → entry (`normbox_lab.acquire.lab.Lab.instrument` opens the parts first)
COMPOSITES: dict[str, CompositeEntry] = {
    "gonio": CompositeEntry("normbox_lab.drivers.gonio", "compose",
                            ("gonio_light_arm", "gonio_detector_arm", "spectrometer")),
}

#: every role a lab config may declare, in the order the docs list them
ROLES: tuple[str, ...] = ("radiometer", "rotator", "sphere", "gonio_light_arm",
                          "gonio_detector_arm", "spectrometer")
REQUIRED_ROLES = ("radiometer", "rotator", "sphere")
#: TOML value types an option may take, by the annotation's name
_TOML_TYPES: dict[str, type] = {"int": int, "float": float, "bool": bool, "str": str}


def drivers_for(role: str) -> tuple[str, ...]:
    """The driver names that can fill `role`, in registry order."""
    return tuple(name for name, e in DRIVERS.items() if role in e.roles)


def entry(name: str) -> DriverEntry:
    try:
        return DRIVERS[name]
    except KeyError:
        raise NormboxError(f"unknown driver {name!r}; known: {', '.join(DRIVERS)}") from None


def driver_class(name: str) -> type:
    """The driver class of a config name (its module is imported now)."""
    e = entry(name)
    return getattr(importlib.import_module(e.module), e.cls)


def composer(role: str) -> Callable[..., Any]:
    """The driver function that composes composite `role` (its module is imported now)."""
    e = COMPOSITES[role]
    return getattr(importlib.import_module(e.module), e.function)


def _toml_type(annotation: object) -> type | None:
    """The TOML type of an annotation (a string under ``from __future__ import annotations``):
    ``float``, ``float | None`` → float; anything else → None (not a config option)."""
    if isinstance(annotation, type):
        return annotation if annotation in _TOML_TYPES.values() else None
    parts = {p.strip() for p in str(annotation).split("|")} - {"None"}
    if len(parts) != 1:
        return None
    return _TOML_TYPES.get(parts.pop())


def _keywords(func: object) -> tuple[list[inspect.Parameter], bool]:
    """The keyword parameters of `func` (keyword-only, or with a default: not the port, the
    clock or ``self``) and whether it takes ``**options``."""
    params = inspect.signature(func).parameters.values()
    named = [p for p in params if p.kind == p.KEYWORD_ONLY or (
        p.kind == p.POSITIONAL_OR_KEYWORD and p.default is not p.empty)]
    return named, any(p.kind == p.VAR_KEYWORD for p in params)


def signature_options(cls: type, internal: tuple[str, ...] = ()) -> dict[str, type]:
    """Options of a driver class from its signatures: ``open(url, clock, ...)``'s keywords,
    and ``__init__(port, clock, ...)``'s when ``open`` forwards ``**options``."""
    named, forwards = _keywords(cls.open)
    if forwards:
        named += [p for p in _keywords(cls.__init__)[0] if p.name not in {q.name for q in named}]
    out = {p.name: _toml_type(p.annotation) for p in named}   # None: not a TOML option
    return {k: t for k, t in out.items() if t is not None and k not in internal}


def identification_parser(name: str) -> Any:
    """The parse function of driver `name`'s identification (its module is imported now)."""
    e = entry(name)
    if e.identification is None:
        raise NormboxError(f"driver {name!r} declares no identification")
    return getattr(importlib.import_module(e.module), e.identification.parse)


def driver_options(name: str) -> dict[str, type]:
    """Option name → TOML type for driver `name` (derived from its class; see module doc)."""
    e = entry(name)
    return signature_options(driver_class(name), e.internal)


__all__ = ["COMPOSITES", "DRIVERS", "REQUIRED_ROLES", "ROLES", "CompositeEntry", "DriverEntry",
           "composer", "driver_class", "driver_options", "drivers_for", "entry",
           "signature_options"]
