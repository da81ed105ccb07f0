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
(tests/test_lab.py checks every entry).

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
class DriverEntry:
    """One driver a lab config may name."""

    module: str                      # e.g. "normbox_lab.drivers.cs1000"
    cls: str                         # e.g. "CS1000A"
    roles: tuple[str, ...]           # the instrument roles it can fill
    #: keyword parameters that are the program's, not the lab config's
    internal: tuple[str, ...] = ()


_RADIOMETER = ("radiometer",)
_STAGE = ("rotator", "gonio_light_arm", "gonio_detector_arm")

#: config driver name → entry.  The one registry: roles, classes and options all come from it.
DRIVERS: dict[str, DriverEntry] = {
    "cs1000a": DriverEntry("normbox_lab.drivers.cs1000", "CS1000A", _RADIOMETER),
    "cs2000a": DriverEntry("normbox_lab.drivers.cs2000", "CS2000A", _RADIOMETER),
    "apt-k10cr1": DriverEntry("normbox_lab.drivers.rotator_apt", "AptRotationStage", _STAGE,
                              internal=("connect",)),
    "zaber": DriverEntry("normbox_lab.drivers.rotator_zaber", "ZaberRotationStage", _STAGE,
                         internal=("connect",)),
    "sphere-scpi": DriverEntry("normbox_lab.drivers.sphere", "SphereLightSource", ("sphere",)),
    "qepro": DriverEntry("normbox_lab.drivers.qepro", "QEPro", ("spectrometer",),
                         internal=("simulated",)),
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


def driver_options(name: str) -> dict[str, type]:
    """Option name → TOML type for driver `name` (derived from its class; see module doc)."""
    e = entry(name)
    return signature_options(driver_class(name), e.internal)


__all__ = ["COMPOSITES", "DRIVERS", "REQUIRED_ROLES", "ROLES", "CompositeEntry", "DriverEntry",
           "composer", "driver_class", "driver_options", "drivers_for", "entry",
           "signature_options"]
