"""The emulator framework every simulated instrument shares.

An emulator is a byte-fed state machine on an injected clock.  The host writes bytes with
`feed()`; the emulator schedules replies with `emit(data, delay_s)`.  Whoever moves time (the
in-process serial port on a virtual clock, or the pty/TCP server on the real clock) calls
`poll()` and collects what has become due with `take_output()`.

    host bytes ─feed()─▶ Emulator ─emit(delay)─▶ [(due_s, bytes)…] ─poll()/take_output()─▶ host

`next_event_s()` tells the transport when something will next happen, so a virtual clock can
jump straight there instead of sleeping.

Faults: every emulator owns a `FaultInjector` built from a spec string, e.g.
``"no-reply=0.1,garble=0.05,late-reply=0.1:5,disconnect@7"``: ``kind=p`` fires with
probability p per reply, ``kind@n`` fires once on the n-th reply (1-based), ``:x`` attaches a
parameter (the delay of ``late-reply`` in seconds, for instance).  Transport-level kinds are
applied here (`no-reply`, `late-reply`, `garble`, `truncate`, `disconnect`; where the emulator
sets `replies_in_order`, a late reply delays the replies after it); device-level kinds
(`device-error`, `busy`, `stall`, ...) are consulted by the emulators themselves through
`faults.fires(kind)`.
"""

from __future__ import annotations

import heapq
import itertools
import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from normbox_lab.core.clock import Clock, VirtualClock

#: how often a drawn value sits exactly on a boundary of its range (each end)
BOUNDARY_SHARE = 0.1


@dataclass(frozen=True)
class FaultKind:
    """One fault an emulator can inject, and the whole physical range it is drawn over.

    `mode` "=" is a rate per opportunity (reply, command, acquisition), "@" fires (or latches
    a condition) once at the n-th opportunity; `value_range` is the rate's range (drawn
    log-uniform: it spans decades) or n's (integers, uniform).  `param_range` is the range of
    the parameter (``kind@n:PARAM``; None: the kind takes none), drawn on `param_scale`:
    "linear", "log" (log-uniform, for a range that spans decades), "int" (integers,
    uniform), "log-int" (integers, log-uniform) or "choice" (one of `choices`).  Both ends of
    every range are drawn with probability `BOUNDARY_SHARE` each.  `detector` says what
    catches the fault (docs/fault-behaviour.md)."""

    kind: str
    mode: str
    value_range: tuple[float, float]
    param_range: tuple[float, float] | None = None
    param_scale: str = "linear"
    choices: tuple[float | None, ...] = ()
    unit: str = ""
    means: str = ""
    detector: str = ""
    #: False for a fault nothing in the lab detects (docs/fault-behaviour.md gives the error
    #: it leaves): modelled and tested, but not drawn by the campaign, whose oracle would
    #: rightly call every reading it touches wrong
    campaign: bool = True
    #: the parameter is a time (s) the lab legitimately waits out when the fault fires (a
    #: lamp that takes this long to be stable again): the campaign's timing bound allows it
    param_is_wait_s: bool = False

    def draw_value(self, rng: random.Random) -> float:
        lo, hi = self.value_range
        if self.mode == "@":
            return float(_draw(rng, lo, hi, "int"))
        return round(_draw(rng, lo, hi, "log"), 6)

    def draw_param(self, rng: random.Random) -> float | None:
        if self.param_scale == "choice":
            return rng.choice(self.choices)
        if self.param_range is None:
            return None
        lo, hi = self.param_range
        return float(f"{_draw(rng, lo, hi, self.param_scale):.4g}")

    def check(self, rule: FaultRule, item: str) -> None:
        """A ValueError when `rule` (parsed from `item`) lies outside this kind's ranges."""
        if rule.at_count is not None and rule.at_count < 1:
            raise ValueError(f"fault {item!r}: the opportunity count starts at 1")
        if rule.parameter is None:
            return
        if not math.isfinite(rule.parameter):
            raise ValueError(f"fault {item!r}: the parameter must be a finite number")
        if self.param_scale == "choice" and self.param_range is None:
            if rule.parameter not in [c for c in self.choices if c is not None]:
                raise ValueError(f"fault {item!r}: the parameter is one of "
                                 f"{', '.join(f'{c:g}' for c in self.choices if c is not None)}")
            return
        if self.param_range is None:
            raise ValueError(f"fault {item!r}: {self.kind} takes no parameter")
        lo, hi = self.param_range
        if not lo <= rule.parameter <= hi:
            raise ValueError(f"fault {item!r}: the parameter of {self.kind} ({self.unit}) lies "
                             f"in {lo:g} … {hi:g}")

    def row(self) -> str:
        """One line of the fault parameter table (`fault_table_text`)."""
        lo, hi = self.value_range
        value = (f"once at the n-th, n = {lo:g} … {hi:g} (uniform)" if self.mode == "@"
                 else f"rate {lo:g} … {hi:g} (log-uniform)")
        if self.param_scale == "choice":
            param = "one of " + ", ".join("default" if c is None else f"{c:g}"
                                          for c in self.choices)
        elif self.param_range is None:
            param = "—"
        else:
            param = (f"{self.param_range[0]:g} … {self.param_range[1]:g} {self.unit} "
                     f"({self.param_scale})")
        drawn = value if self.campaign else f"not drawn (undetectable); {value}"
        return f"| `{self.kind}` | {drawn} | {param} | {self.means} | {self.detector} |"


def _draw(rng: random.Random, lo: float, hi: float, scale: str) -> float:
    u = rng.random()
    if u < BOUNDARY_SHARE:
        return lo
    if u < 2 * BOUNDARY_SHARE:
        return hi
    if scale == "int":
        return rng.randint(int(lo), int(hi))
    if scale in ("log", "log-int"):
        v = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        return min(hi, max(lo, round(v))) if scale == "log-int" else v
    return rng.uniform(lo, hi)


#: the faults every line (serial, TCP) emulator gets from this framework
TRANSPORT_FAULT_KINDS: tuple[FaultKind, ...] = (
    FaultKind("no-reply", "=", (1e-3, 1.0), means="a reply is lost",
              detector="driver timeout → retry; typed InstrumentTimeout"),
    FaultKind("late-reply", "=", (1e-3, 1.0), (0.05, 600.0), "log", unit="s",
              means="a reply comes this much later",
              detector="late window, resynchronise, repeat"),
    FaultKind("garble", "=", (1e-3, 1.0), means="1-3 bits flipped in a reply",
              detector="two reads must agree; plausibility; typed ProtocolError"),
    FaultKind("truncate", "=", (1e-3, 1.0), means="a reply cut short",
              detector="framing / value count → retry; typed ProtocolError"),
    FaultKind("disconnect", "@", (1, 12), (0.05, 1e5), "log", unit="s",
              means="the link drops for this long",
              detector="reconnect within the window, else typed InstrumentError"),
)
TRANSPORT_FAULTS = tuple(k.kind for k in TRANSPORT_FAULT_KINDS)


@dataclass
class FaultRule:
    kind: str
    probability: float = 0.0
    at_count: int | None = None       # fire once when the kind's counter reaches this
    parameter: float | None = None
    fired: int = 0


class FaultInjector:
    """Decides, reply by reply, whether a fault of a given kind happens.  Seeded, so repeatable."""

    def __init__(self, spec: str = "", seed: int = 0,
                 known_kinds: tuple[str, ...] | Mapping[str, FaultKind] | None = None):
        """`known_kinds`: the kinds allowed (a mapping to their `FaultKind` also checks each
        rule's opportunity count and parameter against the kind's range)."""
        self.rules: dict[str, FaultRule] = {}
        self._counters: dict[str, int] = {}
        self._rng = random.Random(seed)
        self.log: list[str] = []
        for item in filter(None, (s.strip() for s in spec.split(","))):
            rule = self._parse(item)
            if known_kinds is not None and rule.kind not in known_kinds:
                raise ValueError(f"unknown fault kind {rule.kind!r}; known: {', '.join(known_kinds)}")
            if isinstance(known_kinds, Mapping):
                known_kinds[rule.kind].check(rule, item)
            elif rule.at_count is not None and rule.at_count < 1:
                raise ValueError(f"fault {item!r}: the opportunity count starts at 1")
            self.rules[rule.kind] = rule

    @staticmethod
    def _parse(item: str) -> FaultRule:
        head, _, param = item.partition(":")
        try:
            parameter = float(param) if param else None
            if "@" in head:
                kind, _, n = head.partition("@")
                return FaultRule(kind.strip(), at_count=int(n), parameter=parameter)
            prob = float(head.partition("=")[2]) if "=" in head else 1.0
        except ValueError:
            raise ValueError(f"fault {item!r}: KIND=RATE, KIND@N or KIND, then :PARAMETER "
                             "(numbers)") from None
        if "=" in head:
            kind = head.partition("=")[0]
            if not 0.0 <= prob <= 1.0:
                raise ValueError(f"fault probability out of [0, 1] in {item!r}")
            return FaultRule(kind.strip(), probability=prob, parameter=parameter)
        return FaultRule(head.strip(), probability=1.0, parameter=parameter)

    def add(self, kind: str, probability: float = 1.0, at_count: int | None = None,
            parameter: float | None = None) -> None:
        """Python API: arm a fault (`probability` per opportunity, or once at `at_count`)."""
        self.rules[kind] = FaultRule(kind, probability, at_count, parameter)

    def clear(self, kind: str | None = None) -> None:
        if kind is None:
            self.rules.clear()
        else:
            self.rules.pop(kind, None)

    def fires(self, kind: str) -> bool:
        """Count one opportunity for `kind`; True when the fault happens now."""
        rule = self.rules.get(kind)
        n = self._counters[kind] = self._counters.get(kind, 0) + 1
        if rule is None:
            return False
        hit = (n == rule.at_count) if rule.at_count is not None else (
            self._rng.random() < rule.probability)
        if hit:
            rule.fired += 1
            self.log.append(f"{kind}#{n}")
        return hit

    def parameter(self, kind: str, default: float) -> float:
        rule = self.rules.get(kind)
        return default if rule is None or rule.parameter is None else rule.parameter

    def corrupt(self, data: bytes) -> bytes:
        """Flip bits of one to three bytes (never producing the line terminators)."""
        buf = bytearray(data)
        for _ in range(self._rng.randint(1, 3)):
            if not buf:
                break
            i = self._rng.randrange(len(buf))
            new = buf[i] ^ (1 << self._rng.randrange(7))
            buf[i] = new if new not in (0x0A, 0x0D) else 0x3F
        return bytes(buf)

    def cut(self, data: bytes) -> bytes:
        return data[: self._rng.randrange(max(1, len(data)))]


class Emulator:
    """Base class: the output schedule, the fault hooks and the connection state.

    Subclasses implement `on_bytes(data)` (called for every chunk the host writes) and may
    override `on_time(now_s)` to advance internal processes (motion, warm-up) and `next_state_s()`
    to announce when their internal state changes next.
    """

    #: the device name used by `sim://NAME` URLs and `sim serve NAME`
    device_name = "emulator"
    #: device-level faults the subclass injects, with their ranges (in addition to the
    #: transport faults); `device_faults` are their names
    fault_kinds: tuple[FaultKind, ...] = ()
    device_faults: tuple[str, ...] = ()
    #: True for an instrument that works its commands strictly in turn: a late reply then
    #: delays the replies after it (they never overtake it), as on its real line
    replies_in_order = False

    def __init__(self, clock: Clock | None = None, faults: str = "", seed: int = 0) -> None:
        self.clock: Clock = clock if clock is not None else VirtualClock()
        self.faults = FaultInjector(faults, seed, self.known_faults())
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = itertools.count()
        self._out = bytearray()
        self._last_reply_due_s = -float("inf")
        self.connected = True
        self.disconnected_until_s: float | None = None

    @classmethod
    def known_faults(cls) -> dict[str, FaultKind]:
        """Every fault this emulator understands → its declared range (a kind only named in
        `device_faults` gets an unchecked entry)."""
        kinds = {k.kind: k for k in (*TRANSPORT_FAULT_KINDS, *cls.fault_kinds)}
        for name in cls.device_faults:
            kinds.setdefault(name, FaultKind(name, "@", (1, 12), (-math.inf, math.inf)))
        return kinds

    # --- host side -------------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        self.poll()
        if not self.connected:
            return  # bytes into a dead cable
        self.on_bytes(bytes(data))

    def poll(self) -> None:
        now = self.clock.now_s()
        if not self.connected and self.disconnected_until_s is not None \
                and now >= self.disconnected_until_s:
            self.connected = True
            self.disconnected_until_s = None
            self.on_reconnect()
        self.on_time(now)
        while self._queue and self._queue[0][0] <= now:
            _, _, data = heapq.heappop(self._queue)
            if self.connected:
                self._out += data

    def take_output(self) -> bytes:
        self.poll()
        data = bytes(self._out)
        self._out.clear()
        return data

    def next_event_s(self) -> float | None:
        times = [t for t in (self._queue[0][0] if self._queue else None,
                             self.next_state_s(), self.disconnected_until_s) if t is not None]
        return min(times) if times else None

    # --- device side -------------------------------------------------------------------------
    def emit(self, data: bytes, delay_s: float = 0.0, *, reply: bool = True) -> None:
        """Schedule `data` to appear on the wire `delay_s` from now.

        With `reply=True` the transport faults are applied (no-reply, late-reply, garble,
        truncate, disconnect).  Unsolicited or multi-part output can pass `reply=False`.
        """
        if reply:
            # every kind counts every reply, so `kind@n` means "the n-th reply"
            hit = {kind: self.faults.fires(kind) for kind in TRANSPORT_FAULTS}
            if hit["disconnect"]:
                self.disconnect(self.faults.parameter("disconnect", 2.0))
                return
            if hit["no-reply"]:
                return
            if hit["late-reply"]:
                delay_s += self.faults.parameter("late-reply", 5.0)
            if hit["garble"]:
                data = self.faults.corrupt(data)
            if hit["truncate"]:
                data = self.faults.cut(data)
        due_s = self.clock.now_s() + max(0.0, delay_s)
        if reply and self.replies_in_order:
            # one line, one instrument working its commands in turn: a reply never overtakes
            # the one before it (a late reply delays those after it)
            due_s = max(due_s, self._last_reply_due_s)
            self._last_reply_due_s = due_s
        heapq.heappush(self._queue, (due_s, next(self._seq), data))

    def cancel_output(self) -> None:
        """Drop everything scheduled but not yet on the wire (e.g. on an abort command)."""
        self._queue.clear()
        self._last_reply_due_s = -float("inf")

    def new_client(self) -> None:
        """A new client took the line (`sim serve`): nothing said to the one before, now or
        later, may reach it.  Drops what is scheduled and lets the device drop what it was
        still going to say (`on_new_client`)."""
        self.poll()
        self.cancel_output()
        self._out.clear()
        self.on_new_client()

    def disconnect(self, duration_s: float) -> None:
        """Cable pulled / USB re-enumerated: nothing in or out for `duration_s`."""
        self.connected = False
        self.disconnected_until_s = self.clock.now_s() + duration_s
        self._queue.clear()
        self._last_reply_due_s = -float("inf")
        self._out.clear()
        self.on_disconnect()

    # --- hooks ---------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Load what the first command would otherwise load (tables, libraries), so a served
        emulator answers its first command on its timing model (default: nothing)."""

    def on_bytes(self, data: bytes) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def on_time(self, now_s: float) -> None:
        """Advance internal processes to `now_s` (default: nothing)."""

    def next_state_s(self) -> float | None:
        """When the internal state changes next on its own (default: never)."""
        return None

    def on_disconnect(self) -> None:
        """The link dropped (default: nothing; a power blip would reset state here)."""

    def on_reconnect(self) -> None:
        """The link is back (default: nothing)."""

    def on_new_client(self) -> None:
        """A new client took the line: forget half-received commands and replies still to
        come for the one before (default: nothing)."""


class LineEmulator(Emulator):
    """Emulator for line-oriented ASCII protocols: splits the input on `terminators`."""

    terminators: tuple[bytes, ...] = (b"\n",)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._inbuf = bytearray()

    def on_bytes(self, data: bytes) -> None:
        self._inbuf += data
        while True:
            cut = [(self._inbuf.find(t), t) for t in self.terminators]
            cut = [(i, t) for i, t in cut if i >= 0]
            if not cut:
                return
            i, term = min(cut)
            line = bytes(self._inbuf[:i])
            del self._inbuf[: i + len(term)]
            self.on_line(line, term)

    def on_line(self, line: bytes, terminator: bytes) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


# --- the registry of emulated devices ------------------------------------------------------------

EmulatorFactory = Callable[..., Emulator]


@dataclass
class SimContext:
    """Process-wide simulation state: the clock, the live device instances and the world.

    Instances persist across opening and closing their port (like a real device stays powered
    when the cable is replugged); `reset()` powers everything off.
    """

    clock: Clock = field(default_factory=VirtualClock)
    world: Any = None
    instances: dict[str, Emulator] = field(default_factory=dict)

    def reset(self, clock: Clock | None = None, world: Any = None) -> None:
        self.clock = clock if clock is not None else VirtualClock()
        self.world = world
        self.instances.clear()


_FACTORIES: dict[str, EmulatorFactory] = {}
_FAULT_TABLES: dict[str, dict[str, FaultKind]] = {}
CONTEXT = SimContext()


def register(name: str, factory: EmulatorFactory, *,
             faults: Mapping[str, FaultKind] | None = None) -> None:
    """Make `sim://NAME` and `sim serve NAME` create emulators with `factory(clock=, faults=,
    seed=, world=, **options)`; `faults` are the kinds it injects (default: what the
    factory's emulator class declares)."""
    _FACTORIES[name] = factory
    if faults is None and isinstance(factory, type) and issubclass(factory, Emulator):
        faults = factory.known_faults()
    if faults is not None:
        declare_faults(name, faults)


def declare_faults(name: str, faults: Mapping[str, FaultKind] | tuple[FaultKind, ...]) -> None:
    """The faults device `name` injects, with their ranges: the registry the campaign's
    scenarios, `sim serve --faults` and the tests derive from."""
    table = dict(faults) if isinstance(faults, Mapping) else {k.kind: k for k in faults}
    _FAULT_TABLES[name] = table


def fault_table(name: str | None = None) -> dict[str, dict[str, FaultKind]]:
    """device → kind → `FaultKind` (every emulated device, or just `name`)."""
    _load_builtin()
    if name is not None:
        if name not in _FAULT_TABLES:
            raise ValueError(f"unknown simulated device {name!r}; known: "
                             f"{', '.join(sorted(_FAULT_TABLES))}")
        return {name: dict(_FAULT_TABLES[name])}
    return {k: dict(v) for k, v in sorted(_FAULT_TABLES.items())}


def fault_table_text() -> str:
    """The fault parameter table (markdown): device, kind, how it is drawn, what detects it."""
    lines = ["| kind | drawn | parameter | what it does | what detects it |",
             "|---|---|---|---|---|"]
    out: list[str] = []
    for device, kinds in fault_table().items():
        out.append(f"\n**{device}**\n")
        out += lines + [k.row() for _, k in sorted(kinds.items())]
    return "\n".join(out).strip() + "\n"


def known_devices() -> list[str]:
    _load_builtin()
    return sorted(_FACTORIES)


def create(name: str, *, clock: Clock | None = None, faults: str = "", seed: int = 0,
           world: Any = None, **options: Any) -> Emulator:
    _load_builtin()
    try:
        factory = _FACTORIES[name]
    except KeyError:
        raise ValueError(f"unknown simulated device {name!r}; known: {', '.join(known_devices())}")
    return factory(clock=clock if clock is not None else CONTEXT.clock, faults=faults, seed=seed,
                   world=world if world is not None else CONTEXT.world, **options)


def instance(name: str, key: str | None = None, **kwargs: Any) -> Emulator:
    """The live emulator for `key` (default: the device name), created on first use."""
    key = key or name
    emu = CONTEXT.instances.get(key)
    if emu is None:
        emu = CONTEXT.instances[key] = create(name, **kwargs)
    return emu


@dataclass(frozen=True)
class EmulatorEntry:
    """One emulated device: the module that makes it, the lab role it plays, and its emulator
    class, called as ``cls(clock, faults, seed, world=world, **options)`` (``""``: the module
    calls `register` itself when imported)."""

    module: str
    role: str
    cls: str = ""


#: the emulator registry: device name (``sim://NAME``, ``sim serve NAME``) → entry.  The CLI's
#: device lists, the campaign's instrument choices and the tests' model lists come from here.
EMULATORS: dict[str, EmulatorEntry] = {
    "cs1000a": EmulatorEntry("normbox_lab.sim.cs1000", "radiometer"),
    "cs2000a": EmulatorEntry("normbox_lab.sim.cs2000", "radiometer"),
    "specbos1211": EmulatorEntry("normbox_lab.sim.specbos", "radiometer", "SpecbosEmulator"),
    "rotator-apt": EmulatorEntry("normbox_lab.sim.rotator_apt", "rotator"),
    "rotator-zaber": EmulatorEntry("normbox_lab.sim.rotator_zaber", "rotator"),
    "sphere": EmulatorEntry("normbox_lab.sim.sphere", "sphere"),
}
#: modules that register their emulators when imported (a module not written yet is skipped)
BUILTIN_MODULES: tuple[str, ...] = tuple(dict.fromkeys(e.module for e in EMULATORS.values()))


def devices_for(role: str) -> tuple[str, ...]:
    """The emulated devices that play lab role `role`, in registry order (no import)."""
    return tuple(name for name, e in EMULATORS.items() if e.role == role)


def emulator_class(name: str) -> type[Emulator] | None:
    """The emulator class an entry names (its module is imported now); None for a module
    that registers a factory itself."""
    import importlib

    e = EMULATORS[name]
    return getattr(importlib.import_module(e.module), e.cls) if e.cls else None


def _class_factory(cls: type[Emulator]) -> EmulatorFactory:
    def factory(clock: Clock | None = None, faults: str = "", seed: int | str = 0,
                world: Any = None, **options: Any) -> Emulator:
        return cls(clock, faults, int(seed), world=world, **options)  # type: ignore[call-arg]

    return factory


def _load_builtin() -> None:
    import importlib

    for name, e in EMULATORS.items():
        try:
            module = importlib.import_module(e.module)
        except ModuleNotFoundError as exc:
            if exc.name != e.module:
                raise
            continue
        if e.cls and name not in _FACTORIES:
            cls = getattr(module, e.cls)
            _FACTORIES[name] = _class_factory(cls)
            declare_faults(name, cls.known_faults())
    for mod in FAULT_ONLY_MODULES:      # devices off the serial registry that declare faults
        importlib.import_module(mod)


#: modules of emulated devices outside `EMULATORS` (the QE Pro sits on the emulated USB bus,
#: not on ``sim://``) that declare their faults when imported
FAULT_ONLY_MODULES: tuple[str, ...] = ("normbox_lab.sim.qepro",)


# --- what the emulators ask of the world -------------------------------------------------------

class World(Protocol):
    """The physics behind the emulators (the virtual Normbox implements it in `sim/world.py`).

    Emulators hold an optional world; tests may pass a tiny object with just the methods used.
    """

    def radiance_in_view(self) -> tuple[np.ndarray, np.ndarray]:
        """(wavelength_nm, spectral radiance W·sr⁻¹·m⁻²·nm⁻¹) the radiometer sees now."""
        ...

    def brdf_truth(self, theta_i_deg: float, theta_o_deg: float, tilt_deg: float,
                   wavelength_nm: np.ndarray) -> np.ndarray:
        """Truth BRDF (sr⁻¹) of the material mounted on the gonioreflectometer."""
        ...
