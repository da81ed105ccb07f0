"""`open_run`: the one way to start or resume a run — lab + store + plan + operator + engine.

    with open_run("reference-sweep", config=load_config("lab.toml"), store="normbox.sqlite") as r:
        print(r.dry_run().lines()[-1])
        result = r.run()

    with open_run(resume=run_uuid, config=config, store=store) as r:   # the stored protocol,
        result = r.run()                                               # parameters and world

The command line (`normbox-lab run`), the operator console, the demo and `bench engine` all
call it, so parameters resolve one way (protocol defaults ← lab config `[protocols.NAME]` ←
overrides; a resumed run keeps its stored ones), a resumed simulated run keeps its world, and
the operator is the one the lab provides unless the caller brings one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from normbox_lab.acquire import store_api
from normbox_lab.acquire.estimate import DryRun
from normbox_lab.acquire.events import Operator, RunResult
from normbox_lab.acquire.plan import (
    PROTOCOL_NAMES,
    Plan,
    PlanError,
    build_plan,
    load_protocol,
    resolve_parameters,
)
from normbox_lab.acquire.runner import Engine
from normbox_lab.core.errors import NormboxError, StoreError


@dataclass
class OpenRun:
    """An engine ready to run (or resume) one run; closes what `open_run` opened."""

    engine: Engine
    lab: Any
    store: store_api.Store
    plan: Plan
    resume: int | None                 # the run id to continue, None for a new run
    _close: list[Callable[[], None]] = field(default_factory=list)

    def dry_run(self) -> DryRun:
        committed = self.store.keys(self.resume) if self.resume is not None else set()
        return self.engine.dry_run(committed)

    def run(self) -> RunResult:
        return self.engine.run(resume=self.resume)

    def close(self) -> None:
        while self._close:
            self._close.pop()()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def _check_resumed_protocol(run_uuid: str, stored: str, given: str | None) -> None:
    """Trust boundary: a resume runs a shipped protocol, or a protocol file only when the
    user names that file now (a store may come from someone else, and a protocol file is
    Python code run with the user's rights)."""
    if stored in PROTOCOL_NAMES:
        if given is not None and given != stored:
            raise PlanError(f"run {run_uuid} ran {stored!r}, not {given!r}")
        return
    if given is None:
        raise PlanError(
            f"run {run_uuid} was recorded with the protocol file {stored}; a protocol file is "
            "Python code, so a resume runs it only when you name it on the command line: "
            f"normbox-lab run {stored} --resume {run_uuid}")
    if not given.endswith(".py") or str(Path(given).resolve()) != stored:
        raise PlanError(f"run {run_uuid} ran {stored!r}, not {given!r}")


def open_run(protocol: str | None = None, *, store: store_api.Store | str | Path,
             config: Any = None, lab: Any = None,
             params: Mapping[str, Any] | None = None, lab_defaults: bool = True,
             resume: int | str | None = None, world: str | Any | None = None,
             operator: Operator | None = None,
             make_operator: Callable[[Any], Operator] | None = None,
             virtual_operator: bool | None = None, fault_policy: str = "retry",
             make_lab: Callable[..., Any] | None = None, force: bool = False,
             **engine_options: Any) -> OpenRun:
    """Assemble a run.

    protocol      a shipped name or a .py file (omit with `resume`)
    store         a `Store`, or a path to open (and close with the run)
    config, lab   the lab config to build a lab from (closed with the run), or a built lab
    params        overrides of the protocol's parameters (not with `resume`)
    lab_defaults  apply the lab config's `[protocols.NAME]` defaults (default True)
    resume        a run id or uuid to continue with its stored protocol and parameters
    world         a lab built here from a simulated config: "normbox" | "analytic" | "none";
                  default the resumed run's world, else "normbox" (recorded with the segment)
    operator      answers the engine's prompts; default the lab's operator
    make_operator when the lab has no operator (a real lab, or `virtual_operator=False`):
                  `make_operator(lab)` becomes the lab's operator (instruments ask it too, e.g.
                  the gonio's white standard)
    virtual_operator, fault_policy   for a lab built here (see `build_lab`)
    make_lab      builds the lab from `config`: ``make_lab(config, world=…, virtual_operator=…,
                  fault_policy=…)``; a simulated config needs one (the simulation is passed in
                  from outside: ``normbox_lab.sim.labsim.build_lab``), a real config defaults
                  to `normbox_lab.acquire.lab.build_lab`
    force         resume even under another world or lab config than the run recorded
                  (refused otherwise: a part-done run would mix two simulated truths)
    engine_options  passed to `Engine` (wait_when_paused, retry, poll_s …); its
                  ``segment_info`` is recorded with the segment (a caller that passes a built
                  lab names its world there: ``{"world": "analytic"}``)

    Every segment records what a resume needs to run in the same lab: the world, the lab
    config's path, the time scale and the seed (the config's text is the run's own record).
    """
    from normbox_lab.acquire.store import Store

    closers: list[Callable[[], None]] = []
    if isinstance(store, (str, Path)):
        store = Store(store)
        closers.append(store.close)
    try:
        what, world = _what_to_run(store, protocol, params, config if config is not None
                                   else _config_of(lab), lab_defaults, resume, world, force)
        _require_recent_check(what.protocol, config if config is not None else _config_of(lab),
                              store)
        info: dict[str, Any] = {}
        if lab is None:
            lab, world = _lab_from_config(config, world, make_lab, virtual_operator,
                                          fault_policy)
            closers.append(lab.close)
            info = {"world": world, "lab": config.path}
        current = config if config is not None else _config_of(lab)
        _check_resumed_lab(what, current, info, engine_options.get("segment_info"), force)
        if current is not None:
            info.setdefault("lab", current.path)
            info.update(time_scale=current.time_scale, seed=current.seed)
        if lab.operator is None and make_operator is not None:
            lab.operator = make_operator(lab)
        plan = build_plan(what.protocol, what.parameters, lab, module=what.module)
        info.update(engine_options.pop("segment_info", None) or {})
        engine = Engine(lab, store, plan, operator=operator, segment_info=info,
                        **engine_options)
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    return OpenRun(engine, lab, store, plan,
                   what.record.id if what.record is not None else None, closers)


def _what_to_run(store: store_api.Store, protocol: str | None,
                 params: Mapping[str, Any] | None, config: Any, lab_defaults: bool,
                 resume: int | str | None, world: str | Any | None,
                 force: bool) -> tuple[_ProtocolRun, str | Any | None]:
    """The protocol and parameters to run (a new run's, or the resumed run's), and the world:
    a resume defaults to its recorded world and refuses another by name (unless `force`)."""
    if resume is None:
        return _new_protocol(protocol, params, config, lab_defaults), world
    what = _resumed_protocol(store, resume, protocol, params)
    if world is None:
        world = what.recorded_world
    elif isinstance(world, str):
        _check_same_world(what.record.uuid, what.recorded_world, world, force)
    return what, world


def _check_resumed_lab(what: _ProtocolRun, current: Any, info: Mapping[str, Any],
                       segment_info: Mapping[str, Any] | None, force: bool) -> None:
    """A resume runs under the world and the lab config its run recorded (unless `force`):
    a built lab names its world in `segment_info`; a lab built here was checked already."""
    if what.record is None:
        return
    if "world" in (segment_info or {}) and not info:
        _check_same_world(what.record.uuid, what.recorded_world,
                          str(dict(segment_info or {})["world"]), force)
    _check_same_lab(what.record.uuid, what.record.lab_config, current, force)


@dataclass
class _ProtocolRun:
    """What a run will execute: the protocol (name or resolved file), its module, its full
    parameters and, for a resume, the stored run and the world its last segment recorded."""

    protocol: str
    module: Any
    parameters: dict[str, Any]
    record: Any = None
    recorded_world: str | None = None


def _resumed_protocol(store: store_api.Store, resume: int | str, protocol: str | None,
                      params: Mapping[str, Any] | None) -> _ProtocolRun:
    """The stored protocol and parameters of the run to resume (refused: a done run, another
    protocol, new parameters)."""
    rec = store.get_run(resume)
    if rec.status == "done":
        raise StoreError(f"run {rec.uuid} is already done; nothing to resume")
    _check_resumed_protocol(rec.uuid, rec.protocol, protocol)
    if params:
        raise PlanError("parameters cannot change a resumed run (they are stored with it)")
    module = load_protocol(rec.protocol)
    worlds = [d["world"] for _, k, d in store.events(rec.id)
              if k == "segment" and "world" in d]
    return _ProtocolRun(rec.protocol, module, resolve_parameters(module, None, rec.parameters),
                        rec, worlds[-1] if worlds else None)


def _new_protocol(protocol: str | None, params: Mapping[str, Any] | None, lab_config: Any,
                  lab_defaults: bool) -> _ProtocolRun:
    """A new run's protocol and its parameters: defaults ← the lab config's
    ``[protocols.NAME]`` (with `lab_defaults`) ← `params`."""
    if not protocol:
        raise PlanError("name a protocol (reference-sweep, brdf-inplane, light-map, "
                        "repeatability, or a .py file), or resume a run")
    if protocol.endswith(".py"):
        protocol = str(Path(protocol).resolve())      # a resume may start elsewhere
    module = load_protocol(protocol)
    defaults = None
    if lab_defaults and lab_config is not None:
        defaults = lab_config.protocol_defaults(
            Path(protocol).stem if protocol.endswith(".py") else protocol)
    return _ProtocolRun(protocol, module, resolve_parameters(module, defaults, params))


def _lab_from_config(config: Any, world: str | Any | None,
                     make_lab: Callable[..., Any] | None, virtual_operator: bool | None,
                     fault_policy: str) -> tuple[Any, str]:
    """The lab of `config` and its world kind: `make_lab` builds it (a simulated config
    needs one: the simulation is built outside acquire), else a real lab."""
    from normbox_lab.acquire.lab import build_lab

    if config is None:
        raise PlanError("open_run needs a lab config or a lab")
    if world is not None and not isinstance(world, str):
        raise PlanError("open_run builds its lab with a world kind; pass a lab built "
                        "with a world object instead")
    world = (world or "normbox") if config.simulated else "none"
    if make_lab is not None:
        return make_lab(config, world=world, virtual_operator=virtual_operator,
                        fault_policy=fault_policy), world
    if world != "none":
        raise PlanError("this lab config has sim:// ports: pass make_lab (the simulation is "
                        "built outside acquire: normbox_lab.sim.labsim.build_lab)")
    return build_lab(config, virtual_operator=virtual_operator,
                     fault_policy=fault_policy), world


def _require_recent_check(protocol: str, config: Any, store: store_api.Store) -> None:
    """A lab config with ``[lab] require_check_h`` lets a run (not the lab check itself, not a
    dry run) start only after a passing `lab check` that recent (`acquire.trust`)."""
    from normbox_lab.acquire.store import Store

    hours = config.require_check_h if config is not None else None
    if hours is None or protocol == "lab-check" or (isinstance(store, Store)
                                                    and store.read_only):
        return
    import time

    from normbox_lab.acquire.trust import require_recent_check

    require_recent_check(store, float(hours), time.time())


def _check_same_world(run_uuid: str, recorded: str | None, given: str, force: bool) -> None:
    """A run measured in one simulated world resumes in that world (a part-done run would
    mix two simulated truths), unless forced."""
    if recorded is None or recorded == given or force:
        return
    from normbox_lab.acquire.params import ParameterError

    raise ParameterError(f"run {run_uuid} was measured in the {recorded!r} world, not "
                         f"{given!r}: resume it with --world {recorded} (--force mixes the "
                         "two worlds' truths in one run)")


#: LabConfig fields a resume may change: where the file is, its text, the speed
_RESUME_MAY_CHANGE = ("path", "text", "time_scale", "name")


def _check_same_lab(run_uuid: str, recorded_text: str, current: Any, force: bool) -> None:
    """A run resumes with the lab config it recorded (instruments, ports, geometry, seed,
    quality limits …; the time scale and the file's place may differ), unless forced."""
    if force or current is None or not recorded_text or recorded_text == current.text:
        return
    import dataclasses

    from normbox_lab.acquire.config import parse_config

    try:
        recorded = parse_config(recorded_text, "<the run's recorded lab config>")
    except NormboxError:
        return                               # an older record we cannot read: no check
    was, now = dataclasses.asdict(recorded), dataclasses.asdict(current)
    differs = [name for name in was if name not in _RESUME_MAY_CHANGE
               and was[name] != now.get(name)]
    if not differs:
        return
    from normbox_lab.acquire.params import ParameterError

    raise ParameterError(f"run {run_uuid} was measured with another lab config "
                         f"({', '.join(differs)} differ in {current.path}): resume it with "
                         "the --lab it ran with (--force resumes in this lab anyway)")


def _config_of(lab: Any) -> Any:
    from normbox_lab.acquire.lab import Lab

    return lab.config if isinstance(lab, Lab) else None


__all__ = ["OpenRun", "open_run"]
