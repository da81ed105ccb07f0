"""Scenarios of the simulation campaign (`normbox-lab sim campaign`), drawn from a seed.

A `Scenario` is plain data: a protocol and its (small) parameters, the world, the instruments
(any radiometer of the emulator registry, `sim.core.devices_for("radiometer")`; APT or Zaber
sample rotator), a fault schedule over every fault kind
every emulator declares (`sim.core.fault_table`: kind, range, distribution; every parameter is
drawn over its whole physical range, log-uniform where it spans decades, both ends included
with probability `core.BOUNDARY_SHARE` each), the operator's answer to persistent faults (retry, skip, abort) and a list
of operator actions (pause, emergency stop, `kill -9`), each fired at the n-th engine event of
a kind in its own segment (process) of the run.  `draw(seed, index)` is deterministic (Python's
`random.Random` seeded with a string), `Scenario.to_json()` / `from_json()` round-trip exactly,
so a shrunk scenario is reproduced from its JSON alone (`sim campaign --replay JSON`).

`lab_toml(scenario)` writes the scenario's lab config: the simulated template with each port's
``faults=`` and ``seed=`` and the render quality set.
"""

from __future__ import annotations

import json
import random
import re
import urllib.parse
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from normbox_lab.sim import core
from normbox_lab.sim.core import FaultKind


def fault_kinds(device: str) -> dict[str, FaultKind]:
    """Every fault kind the emulator of `device` declares, transport kinds included for a
    line device (`sim.core.fault_table`), that the campaign draws (each over its whole
    range); a kind nothing in the lab can detect (`FaultKind.campaign` False) is not drawn."""
    return {k: v for k, v in core.fault_table(device)[device].items() if v.campaign}


def all_fault_kinds() -> dict[str, dict[str, FaultKind]]:
    return core.fault_table()


#: the emulators on a serial line (the QE Pro is USB: no line, so none of the serial transport
#: kinds): every device of the emulator registry
LINE_DEVICES = tuple(core.EMULATORS)
#: the radiometers a scenario draws from (the emulator name is the driver name)
RADIOMETERS = core.devices_for("radiometer")

#: lab role → the emulator behind it (which depends on the scenario's instrument choice)
SWEEP_ROLES = ("radiometer", "rotator", "sphere")
GONIO_ROLES = ("gonio_light_arm", "gonio_detector_arm", "spectrometer")

PROTOCOLS = ("reference-sweep", "brdf-inplane", "light-map", "repeatability")
PROTOCOL_WEIGHTS = (0.4, 0.25, 0.15, 0.2)
ANGLES_DEG = tuple(range(30, 91, 5))
ACTION_EVENTS = ("reading-stored", "step-started:measure", "step-started:wait-stable",
                 "step-started:move", "step-started:calibrate", "prompt", "answer", "fault",
                 "suspended", "run-started", "run-finished")
ACTIONS = ("kill", "pause", "estop", "resume2")
ACTION_WEIGHTS = (0.5, 0.22, 0.18, 0.1)


@dataclass(frozen=True)
class Fault:
    role: str
    kind: str
    mode: str                 # "=" rate, "@" once at the n-th opportunity
    value: float              # the rate, or n
    param: float | None = None

    def spec(self) -> str:
        value = f"{self.value:g}" if self.mode == "=" else f"{int(self.value)}"
        tail = "" if self.param is None else f":{self.param:g}"
        return f"{self.kind}{self.mode}{value}{tail}"


@dataclass(frozen=True)
class Action:
    what: str                 # kill (SIGKILL), pause (one SIGINT), estop (two SIGINTs),
                              # resume2 (a second `run --resume` while the run executes)
    event: str                # engine event kind, "step-started:KIND" for a step kind
    nth: int                  # fire at the nth such event of its segment (1-based)

    def label(self) -> str:
        return f"{self.what}@{self.event}#{self.nth}"


@dataclass(frozen=True)
class Scenario:
    seed: int
    index: int
    protocol: str
    params: dict[str, Any]
    world: str = "analytic"
    radiometer: str = "cs1000a"
    rotator: str = "rotator-apt"
    policy: str = "retry"
    faults: tuple[Fault, ...] = ()
    actions: tuple[Action, ...] = ()
    quality: str = "quick"
    radiometer_format: str = "ascii"      # data transfer: ascii | binary (CS-1000A) | hex
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"s{self.seed}-{self.index}"

    def device_of(self, role: str) -> str:
        return {"radiometer": self.radiometer, "rotator": self.rotator, "sphere": "sphere",
                "spectrometer": "qepro", "gonio_light_arm": "rotator-zaber",
                "gonio_detector_arm": "rotator-zaber"}[role]

    def device_seed(self, role: str) -> int:
        return random.Random(f"{self.seed}:{self.index}:{role}").randrange(1, 10**6)

    def fault_spec(self, role: str) -> str:
        return ",".join(f.spec() for f in self.faults if f.role == role)

    def to_json(self) -> str:
        d = asdict(self)
        d["faults"] = [[f.role, f.kind, f.mode, f.value, f.param] for f in self.faults]
        d["actions"] = [[a.what, a.event, a.nth] for a in self.actions]
        if not d["extra"]:
            d.pop("extra")
        return json.dumps(d, separators=(",", ":"), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Scenario:
        d = json.loads(text)
        if not isinstance(d, dict):
            raise TypeError("a scenario is a JSON object")
        d["faults"] = tuple(Fault(*f) for f in d.get("faults", ()))
        d["actions"] = tuple(Action(*a) for a in d.get("actions", ()))
        return cls(**d)

    def with_(self, **changes: Any) -> Scenario:
        return replace(self, **changes)

    def describe(self) -> str:
        params = " ".join(f"{k}={json.dumps(v, separators=(',', ':'))}"
                          for k, v in sorted(self.params.items()))
        faults = " ".join(f"{f.role}:{f.spec()}" for f in self.faults) or "no faults"
        actions = " ".join(a.label() for a in self.actions) or "no actions"
        fmt = "" if self.radiometer_format == "ascii" else f" ({self.radiometer_format})"
        return (f"{self.protocol} [{params}] world={self.world} {self.radiometer}{fmt} "
                f"{self.rotator} policy={self.policy}; {faults}; {actions}")


def _sample_sorted(rng: random.Random, pool: list[Any] | tuple[Any, ...], lo: int,
                   hi: int) -> list[Any]:
    picked = rng.sample(list(pool), rng.randint(lo, hi))
    return sorted(picked, key=lambda v: (isinstance(v, str), v))


def draw_params(rng: random.Random, protocol: str) -> dict[str, Any]:
    if protocol == "reference-sweep":
        return {"angles_deg": _sample_sorted(rng, ANGLES_DEG, 1, 3),
                "patches": _sample_sorted(rng, range(1, 25), 1, 3)}
    if protocol == "brdf-inplane":
        return {"materials": _sample_sorted(rng, [*range(1, 25), "wall"], 1, 2),
                "theta_i_deg": _sample_sorted(rng, range(-80, 1, 10), 1, 2),
                "theta_o_deg": _sample_sorted(rng, range(-80, 81, 10), 1, 3)}
    if protocol == "light-map":
        return {"rows": rng.randint(1, 3), "columns": rng.randint(1, 3)}
    return {"repeats": rng.randint(2, 5), "patch": rng.randint(1, 24),
            "angle_deg": float(rng.choice(ANGLES_DEG))}


def _alternative_formats(radiometer: str) -> list[str]:
    """The radiometer driver's data formats other than ASCII (the driver registry's)."""
    from normbox_lab.acquire.registry import DRIVERS

    entry = DRIVERS.get(radiometer)
    return [f for f in (entry.data_formats if entry else ()) if f != "ascii"]


def _draw_fault(rng: random.Random, role: str, device: str) -> Fault:
    kinds = fault_kinds(device)
    kind = kinds[rng.choice(sorted(kinds))]
    return Fault(role, kind.kind, kind.mode, kind.draw_value(rng), kind.draw_param(rng))


def draw(seed: int, index: int, *, normbox_share: float = 0.0,
         max_faults: int = 3, max_actions: int = 2) -> Scenario:
    """Scenario `index` of the campaign `seed` (the same pair always gives the same one)."""
    rng = random.Random(f"normbox-campaign:{seed}:{index}")
    protocol = rng.choices(PROTOCOLS, PROTOCOL_WEIGHTS)[0]
    params = draw_params(rng, protocol)
    gonio = protocol == "brdf-inplane"
    world = "normbox" if (not gonio and rng.random() < normbox_share) else "analytic"
    radiometer = rng.choice(RADIOMETERS)
    rotator = rng.choice(("rotator-apt", "rotator-zaber"))
    policy = rng.choices(("retry", "skip", "abort"), (0.6, 0.25, 0.15))[0]
    formats = _alternative_formats(radiometer)
    data_format = (formats[0] if len(formats) == 1 else rng.choice(formats)) \
        if formats and rng.random() < 0.3 else "ascii"
    roles = GONIO_ROLES if gonio else SWEEP_ROLES
    probe = Scenario(seed, index, protocol, params, world, radiometer, rotator, policy,
                     radiometer_format=data_format)
    faults: dict[tuple[str, str], Fault] = {}
    for _ in range(rng.randint(0, max_faults)):
        role = rng.choice(roles)
        f = _draw_fault(rng, role, probe.device_of(role))
        faults[(f.role, f.kind)] = f          # one rule per kind and device
    actions = []
    for _ in range(rng.choices(range(max_actions + 1), (0.35, 0.4, 0.25)[:max_actions + 1])[0]):
        actions.append(Action(rng.choices(ACTIONS, ACTION_WEIGHTS)[0],
                              rng.choice(ACTION_EVENTS), rng.randint(1, 4)))
    return probe.with_(faults=tuple(faults.values()), actions=tuple(actions))


def port_url(scenario: Scenario, role: str, base: str) -> str:
    """`base` (e.g. ``sim://rotator-zaber?key=gonio-light``) with the scenario's faults and
    the role's seed."""
    sep = "&" if "?" in base else "?"
    query = {"seed": str(scenario.device_seed(role))}
    spec = scenario.fault_spec(role)
    if spec:
        query["faults"] = spec
    return base + sep + urllib.parse.urlencode(query, safe=",:@=")


def lab_toml(scenario: Scenario) -> str:
    """The simulated lab template with the scenario's instruments, faults and seeds."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE

    text = SIM_CONFIG_TEMPLATE
    text = text.replace("seed = 1\n", f"seed = {scenario.device_seed('lab')}\n", 1)
    # the template's radiometer (its first instrument), with its baud line, becomes the
    # scenario's (which runs at its driver's default rate)
    first = re.search(r'driver = "([^"]+)" .*\nport = "sim://\1"\nbaud = \d+[^\n]*', text)
    if first is None:
        raise ValueError("the simulated template has no radiometer block to replace")
    if scenario.radiometer != first.group(1):
        text = text.replace(first.group(0), f'driver = "{scenario.radiometer}"\n'
                            f'port = "sim://{scenario.radiometer}"', 1)
    if scenario.rotator == "rotator-zaber":
        text = text.replace('driver = "apt-k10cr1"   # apt-k10cr1 | zaber\n'
                            'port = "sim://rotator-apt"',
                            'driver = "zaber"\nport = "sim://rotator-zaber"', 1)
    ports = {"radiometer": f"sim://{scenario.radiometer}", "rotator": f"sim://{scenario.rotator}",
             "sphere": "sim://sphere",
             "gonio_light_arm": "sim://rotator-zaber?key=gonio-light",
             "gonio_detector_arm": "sim://rotator-zaber?key=gonio-detector",
             "spectrometer": "sim://qepro"}
    for role, base in ports.items():
        old = f'port = "{base}"'
        if old not in text:
            raise ValueError(f"the simulated template has no port line {old!r} for {role}")
        text = text.replace(old, f'port = "{port_url(scenario, role, base)}"', 1)
    if scenario.radiometer_format != "ascii":
        line = f'port = "{port_url(scenario, "radiometer", ports["radiometer"])}"'
        text = text.replace(line, f'{line}\ndata_format = "{scenario.radiometer_format}"', 1)
    text = text.replace('quality = "default"', f'quality = "{scenario.quality}"', 1)
    return text


__all__ = ["ACTIONS", "ACTION_EVENTS", "PROTOCOLS", "Action", "Fault", "Scenario", "all_fault_kinds", "draw", "fault_kinds", "lab_toml", "port_url"]
