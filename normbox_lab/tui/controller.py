"""The console's model: the lab, the store and one engine run in a worker thread.

No Textual here (tested without a UI).  The UI calls `start()`, `resume_run()`, `pause()`,
`resume()`, `abort()`, `quit()` and `answer()` from its own thread; engine events reach the UI
through the `post` callback (the app wraps them in a message: `App.post_message` is
thread-safe), so the engine never waits for the screen.

Prompts: the engine runs with a `ConsoleOperator` — it blocks the *engine* thread until the
UI answers (`answer(choice)`), and in a simulated lab it carries out what the operator was asked
to do on the virtual world (place the patch, mount the material, aim at the panel), as the
person in front of the box would.  Quitting while a prompt waits ends the segment as
`paused` (nothing is being measured), like Ctrl-C at a prompt in `normbox-lab run`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from normbox_lab.acquire.events import fault_text
from normbox_lab.core.errors import NormboxError, OperatorAbort

if TYPE_CHECKING:
    from normbox_lab.acquire.store_api import Store

log = logging.getLogger("normbox_lab.tui")

UNFINISHED = ("created", "running", "paused", "interrupted", "aborted", "failed")


def poll_failure(exc: BaseException) -> str:
    """What a failed health poll means: "no answer" only when nothing (complete) came back."""
    from normbox_lab.core.errors import DeviceError, InstrumentTimeout, ProtocolError

    if isinstance(exc, InstrumentTimeout):
        return "no answer"
    if isinstance(exc, ProtocolError):
        return "garbled reply"
    if isinstance(exc, DeviceError):
        return "device error"
    if isinstance(exc, OSError):
        return "port error"
    return "error"



class _Quit(KeyboardInterrupt):
    """Raised in the engine thread when the operator leaves the console at a prompt: the
    engine ends the segment as `paused` (it treats KeyboardInterrupt as a resumable stop)."""


class ConsoleOperator:
    """Answers the engine's prompts with what the person at the console chose."""

    expected_response_s = 20.0      # for the ETA: one prompt ≈ 20 s of a person's time

    def __init__(self, world: Any = None) -> None:
        self.world = world
        self._event = threading.Event()
        self._choice: str | None = None
        self._cancel: str | None = None      # "quit" | "abort" | "emergency-stop"
        self.pending: Any = None             # the PromptRequest being asked

    def __call__(self, req: Any) -> str:
        self.pending = req
        try:
            while self._cancel is None and not self._event.wait(0.05):
                pass
            self._event.clear()
            if self._cancel == "quit":
                raise _Quit("operator left the console at a prompt")
            if self._cancel == "emergency-stop":
                raise OperatorAbort(f"emergency stop at {req.key}")
            if self._cancel == "abort":
                if "abort" in req.choices:
                    return "abort"
                raise OperatorAbort(f"operator aborted at {req.key}")
            choice = self._choice or req.choices[0]
            self._choice = None
        finally:
            self.pending = None
        if req.kind == "operator" and choice == "ok":
            # a simulated lab: do on the world what the operator confirmed doing
            from normbox_lab.acquire.operator import act_on_world

            act_on_world(self.world, req)
        return choice

    def answer(self, choice: str) -> None:
        req = self.pending
        if req is None:
            raise NormboxError("no prompt is waiting for an answer")
        if choice not in req.choices:
            raise NormboxError(f"answer {choice!r} is not one of {', '.join(req.choices)}")
        self._choice, self._cancel = choice, None
        self._event.set()

    def cancel(self, why: str) -> None:
        """Release a waiting prompt, and refuse every later one: `quit` (the segment ends
        paused), `abort` or `emergency-stop` (the engine's emergency stop is under way)."""
        self._cancel = why
        self._event.set()

    def reset(self) -> None:
        self._event.clear()
        self._choice = self._cancel = None


@dataclass
class LiveState:
    """What the Instruments tab shows, updated from engine events (never by polling a port
    the engine is using) and by `Session.poll_instruments()` while no run is active."""

    angle_deg: float | None = None
    lamp: str = "?"
    lamp_stable: bool | None = None
    temperature_c: float | None = None
    last_key: str = ""
    last_Lv_cd_m2: float | None = None
    last_xy: tuple[float, float] | None = None
    patch: int | None = None
    #: role → what the run last did with it ("30.00°", "on, stable", "measured a30/p07"):
    #: the Instruments table's state column while a run owns the instruments
    run_state: dict[str, str] = field(default_factory=dict)
    #: the roles the current run's plan uses (the others are not "in use by the run")
    roles_used: tuple[str, ...] = ()
    #: a manual action under way ("rotator moving to 30°"), "" when none
    manual_state: str = ""


class Session:
    """One console session: config, store, lab (built lazily), the current engine run."""

    def __init__(self, config: Any, store_path: str | Path, *, world: str = "normbox",
                 virtual_operator: bool = False, time_scale: float | None = None,
                 post: Callable[[Any], None] | None = None,
                 load_config: Callable[[], Any] | None = None) -> None:
        """`config`: the lab config, or None with `load_config`, which reads it when it is
        first needed: the console paints before the config is read (its checks import the
        drivers and the protocols, numpy with them: 0.3 s of CPU before the first paint)."""
        if config is None and load_config is None:
            raise ValueError("Session needs a config or a load_config")
        self._config = config
        self._load_config = load_config
        self._config_lock = threading.Lock()
        self._world = world
        self.store_path = Path(store_path)
        self.virtual_operator = virtual_operator
        self.time_scale = time_scale
        self.post = post or (lambda ev: None)
        self.store: Store | None = None
        self.lab: Any = None
        self.engine: Any = None
        self.operator: ConsoleOperator | None = None
        self.thread: threading.Thread | None = None
        self.result: Any = None
        self.error: BaseException | None = None
        self.live = LiveState()
        #: role → wall time (s) of the last answer to the health poll
        self.last_seen: dict[str, float] = {}
        self.last_rows: list[dict[str, Any]] = []     # the latest health poll
        self.stopped = threading.Event()               # an emergency stop (ends a manual wait)
        self.halted_at_s: float | None = None          # lab time the last stop had halted
        self._step_index: tuple[Any, dict[str, Any]] | None = None
        self._prompt: Any = None                       # the latest operator prompt asked
        self._lock = threading.Lock()
        #: the manual action under way (a worker thread): a run does not start meanwhile
        self.manual_action = ""

    @property
    def config(self) -> Any:
        """The lab config (read now if it was not: a `ConfigError` names file, line, field)."""
        return self.read_config()

    def read_config(self) -> Any:
        if self._config is None:
            with self._config_lock:
                if self._config is None and self._load_config is not None:
                    self._config = self._load_config()
        return self._config

    @property
    def world_kind(self) -> str:
        return self._world if self.config.simulated else "none"

    # --- setup (call from a worker thread: the world may take seconds) -------------------------
    def open_store(self) -> Any:
        from normbox_lab.acquire.store import Store

        with self._lock:
            if self.store is None:
                self.store = Store(self.store_path)
        return self.store

    def ensure_lab(self) -> Any:
        from normbox_lab.sim.labsim import build_lab

        with self._lock:
            if self.lab is None:
                cfg = self.config
                if self.time_scale is not None and cfg.simulated:
                    from dataclasses import replace

                    cfg = replace(cfg, time_scale=self.time_scale)
                self.lab = build_lab(cfg, world=self.world_kind,
                                     virtual_operator=self.virtual_operator)
        return self.lab

    def unfinished_runs(self) -> list[Any]:
        return [r for r in self.runs() if r.status in UNFINISHED]

    def runs(self) -> list[Any]:
        """The store's runs as the console shows them: a run stored as `running` whose
        execution lock no process holds (its owner died: a closed terminal, a kill) is
        `interrupted` — resumable, never shown as running."""
        from dataclasses import replace

        return [replace(r, status="interrupted") if r.status == "running"
                and not self.run_is_owned(r.id) else r for r in self.open_store().runs()]

    def run_is_owned(self, run_id: int) -> bool:
        """Whether a live process (this one included) holds the run's execution lock."""
        from normbox_lab.core.errors import StoreError

        engine = self.engine
        if engine is not None and self.busy and engine.run_id == run_id:
            return True
        try:
            lock = self.open_store().lock_run(run_id)
        except StoreError:
            return True
        lock.release()
        return False

    # --- protocols ---------------------------------------------------------------------------
    def default_parameters(self, protocol: str) -> dict[str, Any]:
        from normbox_lab.acquire import engine as eng

        module = eng.load_protocol(protocol)
        return eng.resolve_parameters(module, self.config.protocol_defaults(protocol))

    def parameter_limits(self, protocol: str) -> dict[str, Any]:
        """The protocol's declared kinds and limits of its parameters (`LIMITS`; none for a
        protocol file that declares none)."""
        from normbox_lab.acquire import engine as eng

        return dict(vars(eng.load_protocol(protocol)).get("LIMITS") or {})

    def angle_limits_deg(self, role: str) -> tuple[float, float, str]:
        """(min, max, where from) of the instrument of `role`: the lab config's range, else its
        driver's default (what the go-to dialog offers)."""
        from normbox_lab.acquire.params import angle_limits_deg

        found = angle_limits_deg(self.config, role)
        if found is None:
            return -180.0, 180.0, "no configured range"
        low, high, source = found
        return low, high, f"range from the {source}"

    def make_engine(self, protocol: str | None, params: Mapping[str, Any] | None = None, *,
                    resume: int | None = None) -> Any:
        from normbox_lab.acquire.engine import open_run

        lab = self.ensure_lab()
        if lab.operator is not None:           # --virtual-operator: the simulation answers
            self.operator = None
            operator = lab.operator
        else:
            self.operator = ConsoleOperator(lab.world)
            operator = self.operator
        # the run records its world and lab (a resume elsewhere is refused: one run, one
        # simulated truth); the lab config, the time scale and the seed come with `lab`
        engine = open_run(protocol, lab=lab, store=self.open_store(), params=params,
                          resume=resume, operator=operator, wait_when_paused=True,
                          segment_info={"world": self.world_kind,
                                        "lab": self.config.path}).engine
        engine.subscribe(self._on_event)
        return engine

    def dry_run(self, protocol: str, params: Mapping[str, Any],
                committed: set[str] | frozenset[str] = frozenset()) -> Any:
        if self.busy:
            raise NormboxError("a run is active; dry-run when it has finished")
        return self.make_engine(protocol, params).dry_run(committed)

    # --- running -----------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def start(self, protocol: str, params: Mapping[str, Any]) -> None:
        if self.busy:
            raise NormboxError("a run is already active")
        self.engine = self.make_engine(protocol, params)
        self._launch(None)

    def resume_run(self, run_ref: int | str) -> None:
        """Continue an interrupted run with its stored protocol and parameters."""
        if self.busy:
            raise NormboxError("a run is already active")
        rec = self.open_store().get_run(run_ref)
        if rec.status == "done":
            raise NormboxError(f"run {rec.uuid[:8]} is done; nothing to resume")
        self.engine = self.make_engine(None, resume=rec.id)
        self._launch(rec.id)

    def _launch(self, resume: int | None) -> None:
        self.result, self.error = None, None
        engine = self.engine

        def work() -> None:
            try:
                self.result = engine.run(resume=resume)
            except _Quit:
                self.result = None                 # engine stored status `paused`
            except BaseException as exc:
                self.error = exc
                log.exception("engine run failed")
                self.post(("error", exc))
            finally:
                self.post(("finished", self.result))

        self.thread = threading.Thread(target=work, name="normbox-engine", daemon=True)
        self.thread.start()

    def pause(self) -> None:
        if self.engine is not None:
            self.engine.pause()

    def resume(self) -> None:
        if self.engine is not None:
            self.engine.resume()

    def abort(self) -> None:
        if self.engine is not None:
            self.engine.abort()
        if self.operator is not None:
            self.operator.cancel("abort")

    def emergency_stop(self) -> list[str]:
        """The operator's emergency stop: every axis halts and every lamp goes off.  During a
        run the engine does it (the reading under way is abandoned, the run ends `paused`,
        resumable); otherwise the console halts the lab's instruments itself.  Returns what
        could not be reached."""
        from normbox_lab.acquire.runner import halt
        from normbox_lab.core.capabilities import Switchable

        if self.engine is not None and self.busy:
            self.engine.emergency_stop()
            if self.operator is not None:
                self.operator.cancel("emergency-stop")
            self._mark_stopped()
            return []
        from normbox_lab.core.capabilities import Movable

        failed = []
        self.stopped.set()
        lab = self.lab
        others = []
        for role in (lab.roles() if lab is not None else []):
            try:
                inst = lab.instrument(role)
                if not isinstance(inst, (Movable, Switchable)):
                    others.append((role, inst))
                    continue
                halt(role, inst)
                if isinstance(inst, Switchable):
                    inst.set_output(False)
            except (NormboxError, OSError) as exc:
                failed.append(f"{role}: {exc}")
        #: lab time when the axes and lamps had been told to stop (the poll that follows moves
        #: a virtual clock on with its own exchanges)
        self.halted_at_s = lab.clock.now_s() if lab is not None else None
        # axes and lamps first and at once; an instrument busy with a manual reading (its
        # port held for seconds) is told to abort from a thread of its own
        if others:
            threading.Thread(target=lambda: [halt(r, i) for r, i in others],
                             name="normbox-estop", daemon=True).start()
        return failed

    def _mark_stopped(self) -> None:
        """The live state after an emergency stop during a run (the table shows it until the
        poll after the run has asked the instruments themselves)."""
        from normbox_lab.core.capabilities import Movable, Switchable

        live = self.live
        lab = self.lab
        for role in (lab.roles() if lab is not None else []):
            inst = lab.instrument(role)
            if isinstance(inst, Switchable):
                live.run_state[role] = "off (emergency stop)"
                live.lamp, live.lamp_stable = "off", False
            elif isinstance(inst, Movable):
                live.run_state[role] = "halted (emergency stop)"

    # --- manual control (Instruments tab) ------------------------------------------------------
    #: what each manual action needs of the instrument, and how the console names it; LAMP:
    #: the lab's light source (the first role whose driver is `Settling`: `Lab.light_sources`)
    LAMP = "<the lab's light source>"
    MANUAL: ClassVar[dict[str, tuple[str, str]]] = {
        "home": ("rotator", "home"), "goto": ("rotator", "go to"), "jog": ("rotator", "jog"),
        "lamp-on": (LAMP, "lamp on"), "lamp-off": (LAMP, "lamp off"),
        "lamp-level": (LAMP, "lamp level"), "measure": ("radiometer", "single reading")}

    def lamp_role(self) -> str | None:
        """The role of the lab's (first) light source; None before the lab is built or when
        it has none."""
        lab = self.lab
        if lab is None:
            return None
        lamps = lab.light_sources()
        return lamps[0] if lamps else None

    def manual(self, action: str, value: float | None = None) -> tuple[str, Any]:
        """One manual action on an idle lab, through the instrument's capabilities: `home`,
        `goto` (value: angle °), `jog` (value: ±°), `lamp-on`, `lamp-off`, `lamp-level`
        (value: %), `measure` (a single radiometer reading, not stored).  Refused with a
        `NotReady` naming why while a run owns the instruments, or when the instrument cannot
        do it.  Returns (what was done, the reading or None).  Call from a worker thread."""
        from normbox_lab.core.capabilities import (
            Homeable,
            LampLevel,
            Movable,
            SpectrumReadable,
            Switchable,
        )
        from normbox_lab.core.errors import NotReady

        if action not in self.MANUAL:
            raise ValueError(f"unknown manual action {action!r}")
        role, name = self.MANUAL[action]
        if self.busy:
            raise NotReady(f"{name} refused: the run owns the instruments until it ends "
                           "(a paused run too: it waits to go on)", instrument=role)
        lab = self.ensure_lab()
        if role == self.LAMP:
            role = self.lamp_role() or "light source"
        if role not in lab.roles():
            raise NotReady(f"{name}: this lab has no {role}", instrument=role)
        inst = lab.instrument(role)
        need = {"home": Homeable, "goto": Movable, "jog": Movable, "lamp-on": Switchable,
                "lamp-off": Switchable, "lamp-level": LampLevel,
                "measure": SpectrumReadable}[action]
        if not isinstance(inst, need):
            raise NotReady(f"{name}: the {role} cannot do that ({type(inst).__name__})",
                           instrument=role)
        live = self.live
        self.manual_action = name
        try:
            return self._manual(action, name, role, inst, value)
        finally:
            self.manual_action = ""
            live.manual_state = ""

    def _manual(self, action: str, name: str, role: str, inst: Any,
                value: float | None) -> tuple[str, Any]:
        from normbox_lab.core.capabilities import Homeable, Movable, Settling
        from normbox_lab.core.errors import NotReady

        lab = self.lab
        live = self.live
        if action == "home":
            live.manual_state = f"{role} homing"
            inst.home(wait=True)
            live.angle_deg = float(inst.position_deg()) if isinstance(inst, Movable) else 0.0
            return f"{role} homed at {live.angle_deg:.2f}°", None
        if action in ("goto", "jog"):
            if isinstance(inst, Homeable) and not inst.is_homed():
                raise NotReady(f"{name}: home the {role} first (h)", instrument=role)
            target = float(value or 0.0)
            if action == "jog":
                target += float(inst.position_deg())
            self.stopped.clear()
            live.manual_state = f"{role} moving to {target:g}°"
            inst.move_to(target, wait=False)
            deadline = lab.clock.now_s() + 1.5 * float(inst.estimate_move_time_s(
                float(inst.position_deg()), target)) + 5.0
            while inst.is_moving() and not self.stopped.is_set():
                if lab.clock.now_s() > deadline:
                    raise NotReady(f"{name}: the motion did not end in time", instrument=role)
                lab.clock.sleep(0.05)
            live.angle_deg = float(inst.position_deg())
            if self.stopped.is_set():
                live.run_state[role] = f"halted at {live.angle_deg:.2f}° (emergency stop)"
                return (f"{name} {target:g}° stopped by the emergency stop: {role} halted at "
                        f"{live.angle_deg:.2f}°"), None
            return f"{role} at {live.angle_deg:.2f}°", None
        if action in ("lamp-on", "lamp-off"):
            inst.set_output(action == "lamp-on")
            live.lamp = str(inst.state())
            return f"{role} {live.lamp}", None
        if action == "lamp-level":
            inst.set_level_percent(float(value if value is not None else 100.0))
            return f"{role} level {float(value or 100.0):g} %", None
        lamp = self.lamp_role()
        unstable = ""
        if lamp is not None and isinstance(lab.instrument(lamp), Settling) \
                and not lab.instrument(lamp).is_stable():
            unstable = f" — the {lamp} is not stable: the reading is not representative"
        live.manual_state = f"{role} measuring (single reading)"
        reading = inst.measure()
        live.last_key = "manual"
        self._take_colorimetry(reading)
        return "single reading taken (not stored)" + unstable, reading

    def quit(self) -> None:
        """Leave safely: the current reading finishes and is committed, the segment ends
        `paused` (resumable from the console or `normbox-lab run --resume`)."""
        if self.engine is not None:
            self.engine.stop()
        if self.operator is not None:
            self.operator.cancel("quit")

    def pause_at_prompt(self) -> None:
        """`p` while an operator prompt waits: pause now, before the reading the prompt
        prepares (no one more patch to place first).  The prompt is withdrawn; the segment ends
        `paused` and a resume asks it again."""
        if self.engine is not None:
            self.engine.stop()
        if self.operator is not None:
            self.operator.cancel("quit")

    def answer(self, choice: str) -> None:
        if self.operator is None:
            raise NormboxError("prompts are answered by the virtual operator")
        self.operator.answer(choice)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Join the worker thread (tests, shutdown).  True when it has ended."""
        if self.thread is None:
            return True
        self.thread.join(timeout_s)
        return not self.thread.is_alive()

    def close(self) -> None:
        if self.lab is not None:
            self.lab.close()
        if self.store is not None:
            self.store.close()

    # --- live state ----------------------------------------------------------------------------
    def _on_event(self, ev: Any) -> None:
        """Engine thread: keep the live state current, then hand the event to the UI."""
        live = self.live
        kind, data = ev.kind, ev.data
        if kind == "run-started":
            live.run_state.clear()
            live.roles_used = tuple(self.engine.plan.roles) if self.engine is not None else ()
        if kind == "step-started":
            step = self._step(ev.key)
            if step is not None and step.kind == "wait-stable":
                live.lamp, live.lamp_stable = "warming up", False
                live.run_state[step.role] = "on, warming up (the run waits)"
            elif step is not None and step.kind == "move":
                live.run_state[step.role] = f"moving to {float(step.params['angle_deg']):g}°"
        elif kind == "step-finished":
            step = self._step(ev.key)
            if step is not None and step.kind == "move":
                live.angle_deg = float(step.params["angle_deg"])
                live.run_state[step.role] = f"{live.angle_deg:.2f}° (homed)"
            elif step is not None and step.kind == "wait-stable":
                live.lamp, live.lamp_stable = "stable", True
                live.run_state[step.role] = "on, stable"
        elif kind in ("suspended", "unsuspended"):
            live.lamp_stable = kind == "unsuspended"
            live.lamp = "stable" if live.lamp_stable else "unstable"
            live.run_state[str(data.get("role", ""))] = (
                "on, stable" if live.lamp_stable else "on, NOT stable (run waits)")
        elif kind == "fault":
            role = str(data.get("role", ""))
            live.run_state[role] = f"ERROR: {fault_text(data)}"
            if role == self.lamp_role():
                live.lamp, live.lamp_stable = "error", False
        elif kind == "prompt":
            self._prompt = data.get("prompt")
        elif kind == "answer" and data.get("answer") == "ok":
            req = self._prompt
            if req is not None and req.key == ev.key and req.data.get("action") == "place_patch":
                live.patch = int(req.data["patch"])
        elif kind == "reading-stored":
            from normbox_lab.core.types import BrdfReading  # numpy: after the first paint

            r = data.get("reading")
            live.last_key = ev.key
            step = self._step(ev.key)
            if step is not None:
                live.run_state[step.role] = f"measured {ev.key}"
                self._recovered(step)
            self._take_colorimetry(r)
            if isinstance(r, BrdfReading):
                temp = r.metadata.get("tec_temperature_c")          # QE Pro TEC
                if temp is not None:
                    live.temperature_c = float(temp)
        self.post(ev)

    def _recovered(self, step: Any) -> None:
        """A reading was stored: every instrument it required was as it required (a fault on
        one of them, retried, is over — its row no longer says ERROR)."""
        live = self.live
        for role, value in step.requires.items():
            if not str(live.run_state.get(role, "")).startswith("ERROR"):
                continue
            if value == "stable":
                live.run_state[role] = "on, stable"
                if role == self.lamp_role():
                    live.lamp, live.lamp_stable = "stable", True
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                live.run_state[role] = f"{float(value):.2f}°"
            else:
                live.run_state[role] = "ok (recovered after a retry)"

    def _take_colorimetry(self, reading: Any) -> None:
        from normbox_lab.core.types import SpectralReading

        if isinstance(reading, SpectralReading) and reading.colorimetry is not None:
            colo = reading.colorimetry
            self.live.last_Lv_cd_m2 = float(colo.Lv_cd_m2)
            self.live.last_xy = (float(colo.x), float(colo.y))

    def _step(self, key: str) -> Any:
        if self.engine is None:
            return None
        plan = self.engine.plan
        index = self._step_index
        if index is None or index[0] is not plan:
            index = (plan, {s.key: s for s in plan.steps})
            self._step_index = index
        return index[1].get(key)

    def poll_instruments(self) -> list[dict[str, Any]]:
        """Connection, identity and state of every configured instrument (only while no run is
        active: the engine owns the ports during a run).  One dict per role."""
        import time

        from normbox_lab.core.capabilities import HealthPollable, Identifiable

        lab = self.ensure_lab()
        rows: list[dict[str, Any]] = []
        for role in lab.roles():
            cfg = lab.config.instruments.get(role)
            row: dict[str, Any] = {"role": role, "driver": cfg.driver if cfg else "composite",
                                   "port": cfg.port if cfg else "-",
                                   "simulated": bool(cfg.simulated) if cfg else lab.simulated,
                                   "identity": "", "state": "", "ok": None,
                                   "last_seen": self.last_seen.get(role)}
            if self.busy:
                row["state"] = self.live.run_state.get(role, "in use by the run")
                rows.append(row)
                continue
            try:
                inst = lab.instrument(role)
                ident = inst.identify() if isinstance(inst, Identifiable) else None
                if ident is not None:
                    row["identity"] = " ".join(str(x) for x in (
                        ident.model, ident.serial_number, ident.firmware) if x)
                if isinstance(inst, HealthPollable):
                    inst.status()                 # a cheap query over the wire: is it there?
                row["state"] = self._state_of(role, inst)
                row["ok"] = True
                row["last_seen"] = self.last_seen[role] = time.time()
            except (NormboxError, OSError) as exc:
                what, detail = poll_failure(exc), str(exc).removeprefix(role + ": ")
                # "device error 201: Lamp failure", not "device error: device error 201: …"
                row["state"] = detail if detail.startswith(what) else f"{what}: {detail}"
                row["ok"] = False
            rows.append(row)
        self.last_rows = rows
        return rows

    def instrument_rows(self) -> list[dict[str, Any]]:
        """The Instruments table: the last poll's rows, and while a run owns the instruments
        (no polling then) each state as the run's events last left it."""
        rows = [dict(r) for r in self.last_rows]
        if self.busy:
            used = self.live.roles_used
            for r in rows:
                if r["role"] in self.live.run_state:
                    r["state"] = self.live.run_state[r["role"]]
                elif r["role"] in used or (r["role"] == "gonio" and "gonio" in used):
                    r["state"] = "in use by the run"
                # roles the run does not use keep what the last poll found
        return rows

    def _state_of(self, role: str, inst: Any) -> str:
        from normbox_lab.core.capabilities import (
            Homeable,
            Movable,
            Settling,
            Switchable,
            TemperatureReadable,
        )
        from normbox_lab.core.clock import VirtualClock

        live = self.live
        if isinstance(inst, Movable):
            pos = float(inst.position_deg())
            if role == "rotator":
                live.angle_deg = pos
            homed = not isinstance(inst, Homeable) or inst.is_homed()
            return f"{pos:.2f}°" + ("" if homed else " unhomed")
        if isinstance(inst, Switchable) and isinstance(inst, Settling):
            clock = self.lab.clock if self.lab is not None else None
            if isinstance(clock, VirtualClock) and clock.time_scale == 0 \
                    and inst.state() != "off" and not inst.is_stable():
                # at time scale 0 lab time moves only when someone waits: nobody waits for
                # an idle lamp, so it would say "settling" for ever — its warm-up is instant
                clock.sleep(float(inst.estimate_settle_time_s()))
            live.lamp, live.lamp_stable = str(inst.state()), bool(inst.is_stable())
            return live.lamp
        if isinstance(inst, TemperatureReadable):
            live.temperature_c = float(inst.tec_temperature_c())
            return f"{live.temperature_c:.1f} °C"
        return "connected"
