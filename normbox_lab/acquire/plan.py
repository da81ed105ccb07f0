"""Plans: a protocol's declared, validated list of keyed steps, and loading protocols.

`Plan.pending_state_steps` is the lazy executor's bookkeeping: before a measurement, the state
steps (in plan order) whose variables are not known to hold.  In a fresh run this is exactly
the declared order; after a crash (physical state unknown) it replays precisely the moves and
prompts the first missing reading needs.  `build_plan` turns a protocol (a shipped name or a
`.py` file defining PARAMETERS and steps(params, lab)) into a Plan.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from normbox_lab.acquire.steps import KINDS, STEP_KINDS, PlanError, Step, iter_roles
from normbox_lab.core.errors import NormboxError


class Plan:
    """An ordered, validated list of steps with the bookkeeping the lazy executor needs."""

    def __init__(self, protocol: str, parameters: Mapping[str, Any], steps: Iterable[Step],
                 on_reading: Callable[[Step, Any, dict[str, Any]], Sequence[str] | None]
                 | None = None):
        self.protocol = protocol
        #: optional protocol hook after each committed reading → warnings to flag in the run
        self.on_reading = on_reading
        self.parameters = dict(parameters)
        self.steps: list[Step] = list(steps)
        seen: set[str] = set()
        last_setter: dict[str, int] = {}
        #: setter_before[i][var] = index of the latest step before i that sets var
        self.setter_before: list[dict[str, int]] = []
        for i, s in enumerate(self.steps):
            if s.kind not in KINDS:
                raise PlanError(f"step {s.key!r}: unknown kind {s.kind!r}; known: "
                                f"{', '.join(STEP_KINDS)}")
            if not s.key or s.key in seen:
                raise PlanError(f"step key {s.key!r} is empty or not unique in the plan")
            seen.add(s.key)
            self.setter_before.append(dict(last_setter))
            for var, val in s.requires.items():
                j = last_setter.get(var)
                if j is None or self.steps[j].sets[var] != val:
                    raise PlanError(f"step {s.key!r} requires {var}={val!r} but the latest "
                                    f"earlier step setting {var} is "
                                    f"{self.steps[j].key + ' → ' + repr(self.steps[j].sets[var]) if j is not None else 'none'}")
            for var in s.sets:
                last_setter[var] = i
        self.commit_keys: list[str] = [s.key for s in self.steps if s.commits]
        self.roles: list[str] = list(iter_roles(self.steps))
        #: index of the last reading; state steps after it (e.g. return home) run at the end
        self.last_commit_index: int = max(
            (i for i, s in enumerate(self.steps) if s.commits), default=-1)
        #: per prompt step, in plan order: the keys of the readings it serves (those after it,
        #: up to the next prompt that sets one of its variables); `estimate.prompts_left`
        self.prompt_serves: list[frozenset[str]] = [
            self._served_by(i) for i, s in enumerate(self.steps) if s.kind == "prompt"]

    def _served_by(self, i: int) -> frozenset[str]:
        sets = set(self.steps[i].sets)
        keys: list[str] = []
        for later in self.steps[i + 1:]:
            if later.kind == "prompt" and sets & set(later.sets):
                break
            if later.commits:
                keys.append(later.key)
        return frozenset(keys)

    def __len__(self) -> int:
        return len(self.steps)

    @property
    def planned(self) -> int:
        return len(self.commit_keys)

    def fingerprint(self) -> str:
        """Hash of the plan (keys, kinds, parameters, state): a resumed run must match it."""
        h = hashlib.sha256()
        for s in self.steps:
            h.update(json.dumps([s.key, s.kind, dict(s.params), dict(s.sets), dict(s.requires)],
                                sort_keys=True, default=str).encode())
        return h.hexdigest()[:16]

    def pending_state_steps(self, i: int, known: Mapping[str, Any]) -> list[int]:
        """State steps (in plan order) to run so that step i's requirements hold."""
        out: set[int] = set()

        def need(idx: int, state: dict[str, Any]) -> None:
            step = self.steps[idx]
            for var, val in step.requires.items():
                if state.get(var) == val:
                    continue
                j = self.setter_before[idx][var]
                if j not in out:
                    need(j, state)
                    out.add(j)
        need(i, dict(known))
        return sorted(out)


# --- protocols ---------------------------------------------------------------------------------

PROTOCOL_NAMES = {
    "reference-sweep": "normbox_lab.protocols.reference_sweep",
    "brdf-inplane": "normbox_lab.protocols.brdf_inplane",
    "light-map": "normbox_lab.protocols.light_map",
    "repeatability": "normbox_lab.protocols.repeatability",
    "lab-check": "normbox_lab.protocols.lab_check",
}


def load_protocol(name_or_path: str) -> ModuleType:
    """A shipped protocol by name (`reference-sweep`) or any protocol file (`my_sweep.py`)."""
    if name_or_path in PROTOCOL_NAMES:
        return importlib.import_module(PROTOCOL_NAMES[name_or_path])
    path = Path(name_or_path)
    if path.suffix != ".py":
        raise PlanError(f"unknown protocol {name_or_path!r}; known: "
                        f"{', '.join(PROTOCOL_NAMES)} or a path to a .py file")
    if not path.is_file():
        raise PlanError(f"protocol file {path} does not exist")
    mod_name = "normbox_lab_user_protocol_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:8]
    spec = importlib.util.spec_from_file_location(mod_name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as exc:     # noqa: BLE001 - the person's own code: refused in one line
        raise PlanError(_user_code_failed(path, "cannot be loaded", exc)) from None
    for attr in ("PARAMETERS", "steps"):
        if attr not in vars(module):
            raise PlanError(f"protocol file {path} defines no {attr}")
    declared = module.PARAMETERS
    if not isinstance(declared, dict) or not all(isinstance(k, str) for k in declared):
        raise PlanError(f"protocol file {path}: PARAMETERS must be a dict of names to "
                        f"defaults, not {type(declared).__name__}")
    if not callable(module.steps):
        raise PlanError(f"protocol file {path}: steps must be a function steps(params, lab)")
    return module


def _user_code_failed(path: Path | str, what: str, exc: BaseException) -> str:
    """One line for an exception raised by a protocol file's own code: the file, the line of
    that file nearest the error, and the exception (a traceback is not an answer to a person
    who ran a command)."""
    import traceback

    line = exc.lineno if isinstance(exc, SyntaxError) and exc.lineno else 0
    if not line:
        for frame in traceback.extract_tb(exc.__traceback__):
            if Path(frame.filename).resolve() == Path(path).resolve() and frame.lineno:
                line = frame.lineno
    message = " ".join(str(exc.msg if isinstance(exc, SyntaxError) else exc).split())
    message = message if len(message) <= 160 else message[:159] + "…"
    where = f"{path}:{line}" if line else str(path)
    return f"protocol file {where}: {what}: {type(exc).__name__}: {message}"


def _user_protocol(module: ModuleType) -> bool:
    return module.__name__.startswith("normbox_lab_user_protocol_")


def coerce_param(default: Any, text: str, name: str = "parameter", kind: Any = None) -> Any:
    """`--param K=V` (and the console's parameter form): the text parsed like the default
    by the one parser of `normbox_lab.acquire.params` (a number, a list as ``[30, 60]`` or
    ``30, 60``, true/false, a name).  Text that is no value of its kind raises
    `ParameterError` (a `PlanError`, exit 2) naming the parameter and what it expects."""
    from normbox_lab.acquire.params import parse_param

    return parse_param(default, text, name, kind)


def resolve_parameters(module: ModuleType, lab_defaults: Mapping[str, Any] | None = None,
                       overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Protocol defaults ← lab config `[protocols.NAME]` ← command-line overrides."""
    from normbox_lab.acquire.params import ParameterError, show

    params = dict(module.PARAMETERS)
    for source in (lab_defaults or {}, overrides or {}):
        for k, v in source.items():
            if k not in params:
                raise ParameterError(f"unknown parameter {show(k)}; known: "
                                     f"{', '.join(params)}")
            params[k] = v
    return params


def build_plan(protocol: str, params: Mapping[str, Any] | None = None, lab: Any = None,
               *, module: ModuleType | None = None) -> Plan:
    module = module or load_protocol(protocol)
    full = resolve_parameters(module, None, params) if params is not None \
        else dict(module.PARAMETERS)
    hook = vars(module).get("on_reading")
    on_reading = None
    if hook is not None:
        def on_reading(step: Step, reading: Any, context: dict[str, Any]) -> Any:
            return hook(full, step, reading, context)
    if not _user_protocol(module):
        return Plan(protocol, full, module.steps(full, lab), on_reading)
    try:
        steps = module.steps(full, lab)
        if not isinstance(steps, (list, tuple)) or not all(isinstance(s, Step) for s in steps):
            raise PlanError(f"protocol file {module.__file__}: steps() must return a list "
                            f"of steps, not {type(steps).__name__}")
        return Plan(protocol, full, steps, on_reading)
    except PlanError as exc:
        where = f"protocol file {module.__file__}"
        raise (exc if str(exc).startswith(where) else type(exc)(f"{where}: {exc}")) from None
    except NormboxError:
        raise
    except Exception as exc:     # noqa: BLE001 - the person's own code: refused in one line
        raise PlanError(_user_code_failed(module.__file__ or protocol, "steps() failed",
                                          exc)) from None


__all__ = [
    "PROTOCOL_NAMES",
    "Plan",
    "PlanError",
    "build_plan",
    "coerce_param",
    "load_protocol",
    "resolve_parameters",
]
