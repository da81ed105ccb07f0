"""The operator console (Textual): Instruments, Run, Spectrum, Runs, Results.

Keyboard first, laid out for 80×24.  The engine runs in a worker thread (`Session`); its events
arrive as `EngineMessage`s (posted thread-safely), so the screen never waits for an
instrument.  First paint happens before the store, the lab or its world are opened: those load
in a background thread right after it (a Mitsuba world may take seconds; the analytic one
milliseconds), as does the plot library.
"""

from __future__ import annotations

import json
import time
from typing import Any, ClassVar

from textual import events, on, work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.css.query import NoMatches
from textual.message import Message
from textual.widget import Widget
from textual.widgets import Footer, Input, Select, Static, TabbedContent

from normbox_lab.core.clock import Clock, RealClock
from normbox_lab.core.errors import BadPath, ConfigError
from normbox_lab.tui.controller import Session, fault_text
from normbox_lab.tui.screens import HIDDEN, DrillScreen, PromptScreen, ResumeScreen, prompt_text
from normbox_lab.tui.tabs import (
    ImagesPane,
    InstrumentsPane,
    ResultsPane,
    RunPane,
    RunsPane,
    SpectrumPane,
)
from normbox_lab.tui.tabs.instruments import connection_text
from normbox_lab.tui.tabs.run import RunProgress
from normbox_lab.tui.tabs.spectrum import BRDF_TITLE, RADIANCE_TITLE

__all__ = ["DrillScreen", "NormboxConsole", "PromptScreen", "ResumeScreen", "connection_text",
           "prompt_text"]

TABS = ("instruments", "run", "spectrum", "runs", "results", "images")


class EngineMessage(Message):
    """An engine event (or ("error", exc) / ("finished", result)) for the UI thread."""

    def __init__(self, event: Any) -> None:
        super().__init__()
        self.event = event


class LabReady(Message):
    def __init__(self, error: str = "") -> None:
        super().__init__()
        self.error = error


# --- the app ---------------------------------------------------------------------------------

class NormboxConsole(App):
    """normbox-lab tui."""

    TITLE = "normbox-lab"
    ENABLE_COMMAND_PALETTE = False
    #: no automatic focus on the tabs' screen: with the tab bar no Tab stop, Textual's "first
    #: focusable widget" after a prompt closed was a table of a hidden pane, and focusing it
    #: switched the tabs (the modal screens focus their own first widget: AUTO_FOCUS there)
    AUTO_FOCUS = None
    CSS = """
    #status { height: 1; background: $boost; padding: 0 1; }
    TabbedContent { height: 1fr; }
    TabPane { padding: 0; }
    """
    BINDINGS: ClassVar = [
        # x: the emergency stop everywhere but in a text field (keys typed there belong to
        # the field: a pasted "xxxx…" is text, not 2000 stops); Ctrl+X also in a text field
        Binding("x", "emergency_stop", "E-STOP", priority=True),
        Binding("ctrl+x", "emergency_stop", "E-STOP", show=False, priority=True),
        Binding("q", "quit_console", "quit"),
        # Ctrl+Q is Textual's "close now"; here it leaves the same safe way as q (the run
        # pauses after the reading under way, a waiting prompt is withdrawn), on every screen
        Binding("ctrl+q", "quit_console", "quit", show=False, priority=True),
        Binding("s", "start", "start"),
        Binding("d", "dry_run", "dry-run"),
        Binding("p", "pause_resume", "pause"),
        Binding("a", "abort", "abort"),
        Binding("r", "resume_selected", "resume"),
        Binding("e", "export", "csv"),
        Binding("i", "poll", "poll"),
        Binding("w", "show_prompt", "prompt", show=False),
        Binding("escape", "leave_input", "", show=False),
        *[Binding(str(k + 1), f"tab('{t}')", t, show=False) for k, t in enumerate(TABS)],
    ]

    def __init__(self, session: Session, *, exit_after_paint: bool = False,
                 offer_resume: bool = True, protocol: str = "reference-sweep",
                 prefill: dict[str, str] | None = None, clock: Clock | None = None) -> None:
        super().__init__()
        self.session = session
        #: the console's own clock (abort confirmation window, remaining time, poll times);
        #: tests inject a VirtualClock and move it instead of sleeping
        self.clock: Clock = clock if clock is not None else RealClock()
        session.post = lambda ev: self.post_message(EngineMessage(ev))
        self.exit_after_paint = exit_after_paint
        self.offer_resume = offer_resume
        self.first_paint_wall_s: float | None = None
        self.lab_ready = False
        self.panes_built = False
        self.protocol = protocol
        self.prefill = dict(prefill or {})     # --param K=V for the initial protocol
        self.prefill_protocol = protocol
        self.quitting = False
        self.prompt_screen: PromptScreen | None = None
        #: the operator prompt the engine waits for (also while it steps aside)
        self.waiting_prompt: Any = None
        self._runs_dirty = True
        self.progress = RunProgress(self.clock)
        self.events_seen: list[str] = []
        self.toasts_shown: list[str] = []
        self.lab_error = ""                   # why the lab could not be assembled
        #: a lab config or a store the console cannot use (read after the first paint): the
        #: console ends and the command line says it in one line, exit 2
        self.startup_error: ConfigError | BadPath | None = None
        self.dry: Any = None                  # the latest dry run
        self._paint_tries = 0                 # refreshes waited for the footer's keys
        self._status_text = ""                # the top line's lab part
        self._abort_armed_until = 0.0         # console clock s until which a second a aborts
        self._live_dirty = False              # the Instruments tab needs redrawing
        self._pending_resume: int | None = None   # a run to resume once the lab is ready
        self.first_paint_footer_keys = 0
        self.first_paint_cpu_s = 0.0
        #: the emergency stop under way (a worker thread), and when the last press came: a
        #: burst of presses while one stop is under way, or right after it, is that one stop
        self._estop_running = False
        self._estop_last_press_s = -1e9
        #: keys (and clicks) other than the stop's since the start: a burst of x presses is
        #: one stop only while nothing else came between them (x, g 45 Enter, x: two stops)
        self._other_input = 0
        self._other_input_at_stop = -1
        self.estops_started = 0               # stops commanded (tests: a burst is one)
        self.estops_coalesced = 0             # presses that joined a stop already under way

    # --- layout ------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static("normbox-lab · starting…", id="status")
        with TabbedContent(initial="run", id="tabs"):
            yield InstrumentsPane()             # the other tabs are filled after first paint
            yield RunPane(self.protocol)
            yield SpectrumPane()
            yield RunsPane()
            yield ResultsPane()
            yield ImagesPane()
        yield Footer()

    def pane(self, kind: type) -> Any:
        """The tab pane of that class."""
        return self.query_one(kind)

    @property
    def _plot(self) -> Any:
        return self.pane(SpectrumPane).plot

    def on_mount(self) -> None:
        from textual.widgets import Tabs

        # the tab bar is no Tab stop (1–6 switch tabs): Tab goes protocol → parameters
        for tabs in self.query(Tabs):
            tabs.can_focus = False
        self.call_after_refresh(self._first_paint)
        self.set_interval(0.5, self._tick)

    def _build_panes(self) -> None:
        """The tabs not shown at start: built right after the first paint (less to style and
        lay out before it)."""
        for kind in (InstrumentsPane, SpectrumPane, RunsPane, ResultsPane, ImagesPane):
            self.pane(kind).build()
        self.panes_built = True

    def _first_paint(self) -> None:
        # the complete first screen includes the footer's keys, which Textual fills in a
        # refresh after the first: the first paint is the first frame that has them
        if not self.query_one(Footer).children and self._paint_tries < 50:
            self._paint_tries += 1
            self.call_after_refresh(self._first_paint)
            return
        self.first_paint_wall_s = time.time()
        self.first_paint_footer_keys = len(self.query_one(Footer).children)
        self.first_paint_cpu_s = time.process_time()
        if self.exit_after_paint:
            self.exit()
            return
        self.pane(RunPane).build()               # the event log, before anything is logged
        try:
            self.session.read_config()           # now, after the first paint
        except ConfigError as exc:
            self.startup_error = exc
            self.exit(return_code=2)
            return
        names = _protocol_names()
        if self.protocol not in names:
            names.append(self.protocol)
        self.pane(RunPane).set_protocols(names, self.protocol)
        self._show_params(self.protocol)
        self._build_panes()
        self.call_after_refresh(self._load)

    @work(thread=True, exclusive=True, group="load")
    def _load(self) -> None:
        s = self.session
        try:
            try:
                s.open_store()
            except BadPath as exc:       # --store names no store (a directory, another file)
                self.call_from_thread(self._end_with, exc)
                return
            runs = s.unfinished_runs()
            if runs and not self.prefill:
                self.call_from_thread(self._show_run_parameters, runs[-1])
            if self.offer_resume and runs:
                self.call_from_thread(self._offer_resume, runs)
            self._runs_dirty = True
            s.ensure_lab()
            rows = s.poll_instruments()
            self.call_from_thread(self._show_instruments, rows)
            self.post_message(LabReady())
        except Exception as exc:  # noqa: BLE001 - shown to the operator, the console stays up
            self.post_message(LabReady(f"{type(exc).__name__}: {exc}"))

    def _end_with(self, error: BadPath) -> None:
        """A refusal of what was typed, found after the first paint: the console ends, and
        the command line says it in one line (exit 2)."""
        self.startup_error = error
        self.exit(return_code=2)

    def on_lab_ready(self, message: LabReady) -> None:
        if message.error:
            self.lab_error = message.error
            self._set_status(f"lab not ready: {message.error}")
            self._log("[red]lab not ready[/] ", message.error)
            return
        self.lab_ready = True
        s = self.session
        kind = "simulated" if s.config.simulated else "real"
        scale = self._lab_time_scale()
        clock = "real clock" if scale is None else f"virtual clock ×{scale:g}"
        self._set_status(f"store {s.store_path.name} · {kind} lab · {clock} · "
                         f"world {s.world_kind} · {s.config.name}")
        self._refresh_results()

    async def on_event(self, event: Any) -> None:
        """Counts the operator's input other than the stop's keys (see `_other_input`)."""
        if (isinstance(event, events.Key) and event.key not in ("x", "ctrl+x")) \
                or isinstance(event, events.MouseDown):
            self._other_input += 1
        await super().on_event(event)

    # --- helpers -----------------------------------------------------------------------------
    #: toasts on screen at once: at 80×24 each covers half the width, a burst of them (a few
    #: manual actions, a poll) would hide the table or the log they are about
    MAX_TOASTS = 2

    def notify(self, message: str, *, title: str = "", severity: Any = "information",
               timeout: float | None = None, markup: bool = True) -> None:
        """A toast; the oldest goes when more than MAX_TOASTS would show (errors last).
        Every toast's text is kept in `toasts_shown`, in order."""
        self.toasts_shown.append(str(message))
        shown = list(self._notifications)
        while len(shown) >= self.MAX_TOASTS:
            oldest = next((n for n in shown if n.severity != "error"), shown[0])
            self._unnotify(oldest, refresh=False)
            shown.remove(oldest)
        super().notify(message, title=title, severity=severity, timeout=timeout, markup=markup)

    def _set_status(self, text: str | None = None) -> None:
        """The top line: the lab (`text`), and — on every tab — a prompt that waits while the
        operator looks elsewhere."""
        from rich.text import Text

        if text is not None:
            self._status_text = text
        line = Text(self._status_text)
        if self.waiting_prompt is not None and self.prompt_screen is None:
            line = Text.assemble(("prompt waiting: w ", "bold reverse"), " ", line)
        self.query_one("#status", Static).update(line)

    def _log(self, markup: str, detail: str = "") -> None:
        """One line in the Run tab's log: `markup` (ours) + `detail` (plain)."""
        self.pane(RunPane).log(markup, detail)

    def _show_params(self, protocol: str) -> None:
        try:
            params: dict[str, Any] | Exception = self.session.default_parameters(protocol)
        except Exception as exc:  # noqa: BLE001 - a broken protocol file is shown, not fatal
            params = exc
        prefill = self.prefill if protocol == self.prefill_protocol else {}
        try:
            limits = self.session.parameter_limits(protocol)
        except Exception:  # noqa: BLE001 - the protocol's own error is shown by the form
            limits = {}
        self.pane(RunPane).show_params(params, prefill, limits, self.session.config)

    def _show_run_parameters(self, run: Any) -> None:
        """The Run tab shows an interrupted run's protocol and parameters (the console used
        to show the default sweep after a relaunch)."""
        from normbox_lab.acquire.plan import PROTOCOL_NAMES

        if run.protocol not in PROTOCOL_NAMES:
            return                     # a protocol file: named on the command line only
        self.protocol = self.prefill_protocol = run.protocol
        self.prefill = {k: v if isinstance(v, str) else json.dumps(v)
                        for k, v in run.parameters.items()}
        self.pane(RunPane).set_protocols(_protocol_names(), run.protocol)
        self._show_params(run.protocol)
        self._log("", f"run {run.id} ({run.status}) parameters shown; r resumes it")

    def parameters(self) -> dict[str, Any]:
        """The parameters as typed in the Run tab (JSON, like `--param K=V`)."""
        from normbox_lab.acquire import engine as eng

        module = eng.load_protocol(self.protocol)
        limits = vars(module).get("LIMITS") or {}
        return {key: eng.coerce_param(module.PARAMETERS[key], text, key, limits.get(key))
                for key, text in self.pane(RunPane).parameter_texts().items()}

    def set_parameter(self, key: str, value: str) -> None:
        self.pane(RunPane).set_parameter(key, value)

    # --- actions -----------------------------------------------------------------------------
    def action_show_prompt(self) -> None:
        """Bring back a prompt that stepped aside."""
        if self.waiting_prompt is not None and self.prompt_screen is None:
            self._push_prompt(self.waiting_prompt)

    def action_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab
        if tab == "run":
            self.action_show_prompt()

    def action_leave_input(self) -> None:
        if isinstance(self.focused, Input):
            self.set_focus(None)

    @on(Select.Changed, "#protocol")
    def _protocol_changed(self, event: Select.Changed) -> None:
        if event.value != self.protocol and isinstance(event.value, str):
            self.protocol = event.value
            self._show_params(self.protocol)

    def action_dry_run(self) -> None:
        if not self._ready_for_run():
            return
        try:
            params = self.parameters()
        except Exception as exc:  # noqa: BLE001
            self._log("[red]parameters:[/] ", str(exc))
            return
        self._dry_run(self.protocol, params)

    @work(thread=True, exclusive=True, group="dry")
    def _dry_run(self, protocol: str, params: dict[str, Any]) -> None:
        from normbox_lab.acquire.engine import format_duration

        try:
            dry = self.session.dry_run(protocol, params)
        except Exception as exc:  # noqa: BLE001
            self.call_from_thread(self._log, "[red]dry-run failed:[/] ", str(exc))
            return
        simulated = self._lab_time_scale() is not None
        text = (f"dry-run {protocol}: {len(dry.plan)} steps, {dry.plan.planned} readings, "
                f"{len(dry.executed)} executed · lab time {format_duration(dry.total_s)} "
                f"({dry.total_s:.0f} s of instrument and operator time"
                + ("; in a simulated lab the remaining time is measured once the run goes)"
                   if simulated else ")"))
        self.dry = dry
        self.call_from_thread(self._after_dry, text)

    def _after_dry(self, text: str) -> None:
        self.pane(RunPane).set_info(text)
        self._log("", text)

    def _ready_for_run(self) -> bool:
        if not self.lab_ready:
            error = self.lab_error
            self.notify(f"the lab could not be assembled: {error}" if error
                        else "the lab is still loading", severity="warning", markup=False)
            return False
        if self.session.busy:
            self.notify("a run is active", severity="warning")
            return False
        if self.session.manual_action:
            self.notify(f"a manual action is under way ({self.session.manual_action}): start "
                        "when it has finished", severity="warning", markup=False)
            return False
        return True

    def action_start(self) -> None:
        if not self._ready_for_run():
            return
        try:
            params = self.parameters()
            self.session.start(self.protocol, params)
        except Exception as exc:  # noqa: BLE001 - shown, the console stays up
            self._log("[red]cannot start:[/] ", str(exc))
            self.notify(str(exc), severity="error", markup=False)
            return
        self.action_tab("run")
        self._log("", f"starting {self.protocol} " + " ".join(
            f"{key}={json.dumps(value)}" for key, value in params.items()))

    def action_resume_selected(self) -> None:
        """Resume the run selected in the Runs tab (or the latest unfinished one)."""
        if not self._ready_for_run():
            return
        run_id = self._selected_run_id()
        if run_id is None:
            unfinished = self.session.unfinished_runs()
            if not unfinished:
                self.notify("no interrupted run to resume")
                return
            run_id = unfinished[-1].id
        self.resume_run(run_id)

    def resume_run(self, run_id: int) -> None:
        try:
            self.session.resume_run(run_id)
        except Exception as exc:  # noqa: BLE001
            self._log(f"[red]cannot resume run {run_id}:[/] ", str(exc))
            self.notify(str(exc), severity="error", markup=False)
            return
        self.action_tab("run")
        self._log(f"resuming run {run_id}")

    def _offer_resume(self, runs: list[Any]) -> None:
        def chosen(run_id: int | None) -> None:
            if run_id is None:
                return
            if self.lab_ready:
                self.resume_run(run_id)
            else:
                self._pending_resume = run_id
        self.push_screen(ResumeScreen(runs), chosen)

    def action_pause_resume(self) -> None:
        engine = self.session.engine
        if engine is None or not self.session.busy:
            return
        if engine.state == "paused":
            self.session.resume()
            self._log("resume requested")
        elif self.progress.status == "pausing…":       # p again before it paused: cancelled
            self.session.resume()
            self._set_run_status("running")
            self._log("pause cancelled: the run goes on")
            self.notify("pause cancelled: the run goes on", markup=False)
        elif self.waiting_prompt is not None or self._operator_pending() is not None:
            # nothing is being measured: pause here, before the reading the prompt prepares
            # (no one more patch to place first); a resume asks the prompt again.  Also when
            # the engine asks and the prompt's event has not reached the screen yet.
            self._pause_at_prompt(self.waiting_prompt or self._operator_pending())
        else:
            self.session.pause()
            self._log("pause requested: after the current reading")
            self._set_run_status("pausing…")
            self.notify("pause: the run stops after the current reading", markup=False)

    def _operator_pending(self) -> Any:
        operator = self.session.operator
        return operator.pending if operator is not None else None

    def _pause_at_prompt(self, req: Any) -> None:
        """End the segment paused before the reading `req` prepares: the prompt is withdrawn
        and a resume asks it again."""
        self.waiting_prompt = None
        self.session.pause_at_prompt()
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        self._set_run_status("pausing…")
        self._log("pause at the prompt: ", f"the run pauses before {req.key} (r resumes "
                  "and asks it again)")
        self.notify(f"paused before {req.key}: r resumes", markup=False)

    #: seconds within which a second `a` confirms the abort
    ABORT_CONFIRM_S = 5.0

    def action_abort(self) -> None:
        """a asks for confirmation (a again within 5 s) before it aborts the run."""
        if not self.session.busy:
            return
        if self.clock.now_s() <= self._abort_armed_until:
            self._abort_armed_until = 0.0
            self.session.abort()
            self._log("[red]abort requested[/]")
            return
        self._abort_armed_until = self.clock.now_s() + self.ABORT_CONFIRM_S
        self.notify("abort the run? press a again within 5 s (p pauses instead; x is the "
                    "emergency stop)", severity="warning", markup=False)

    def action_quit_console(self) -> None:
        if not self.session.busy:
            self.exit()
            return
        if self.quitting:                      # second q: abort now
            self.session.abort()
            self._log("[red]abort requested (second q)[/]")
            return
        self.quitting = True
        self.session.quit()
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        self._log("quitting: the run pauses after the current reading (q again: abort)")
        self.notify("pausing the run before quitting… (q again: abort now)")
        # a warm-up, a prompt or a pause end at once; a move or a reading under way at a
        # real pace may take longer: the console leaves anyway, the command waits for it
        self.set_timer(self.QUIT_WAIT_S, self._leave)

    #: seconds the console waits for the run to pause before it leaves the screen anyway
    QUIT_WAIT_S = 1.5

    def _leave(self) -> None:
        if self.quitting and self.is_running:
            self.exit()

    #: presses of x within this many seconds of the previous one join its stop
    ESTOP_BURST_S = 0.5

    def action_emergency_stop(self) -> None:
        """x: every axis stops and every lamp goes off now; a run ends paused (resumable).
        The stop is commanded from a worker thread (the screen never waits for a port); a
        press while it is under way, or within `ESTOP_BURST_S` of the previous press with no
        other key between them, is the same stop (a held or repeated key used to queue one
        stop per press and freeze the screen for 65 s)."""
        if not self.lab_ready:
            return
        now = self.clock.now_s()
        repeated = self._other_input == self._other_input_at_stop and (
            self._estop_running or now - self._estop_last_press_s <= self.ESTOP_BURST_S)
        self._estop_last_press_s = now
        self._other_input_at_stop = self._other_input
        if repeated:
            self.estops_coalesced += 1
            return
        self._estop_running = True
        self.estops_started += 1
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        busy = self.session.busy
        self.notify("EMERGENCY STOP: axes halted, lamps off"
                    + (" — run paused, r resumes" if busy else ""),
                    severity="error", markup=False)
        self._emergency_stop(busy)

    @work(thread=True, group="estop")
    def _emergency_stop(self, busy: bool) -> None:
        try:
            failed = self.session.emergency_stop()
        except Exception as exc:  # noqa: BLE001 - shown; the operator may press x again
            failed = [f"{type(exc).__name__}: {exc}"]
        self.call_from_thread(self._emergency_stopped, failed, busy)

    def _emergency_stopped(self, failed: list[str], busy: bool) -> None:
        self._estop_running = False
        self._estop_last_press_s = self.clock.now_s()
        self._live_dirty = True
        self._log("[b red]EMERGENCY STOP[/] ", "axes halted, lamps off"
                  + (f"; not reached: {'; '.join(failed)}" if failed else ""))
        if failed:
            self.notify("EMERGENCY STOP: not reached: " + "; ".join(failed),
                        severity="error", markup=False)
        if not busy and not self.session.busy:
            self._poll(announce=False)        # the table: the real angle where it halted

    def action_poll(self) -> None:
        if self.lab_ready:
            self._poll()

    @work(thread=True, exclusive=True, group="poll")
    def _poll(self, after_run: bool = False, announce: bool = True) -> None:
        # after a run: its "finished" message is posted from the engine thread just before
        # that thread ends; the poll waits for the end (the engine no longer owns the ports)
        if after_run and not self.session.wait(5.0):
            return
        try:
            rows = self.session.poll_instruments()
        except Exception as exc:  # noqa: BLE001
            self.call_from_thread(self._log, "[red]poll failed:[/] ", str(exc))
            return
        self.call_from_thread(self._show_instruments, rows, announce)

    def action_export(self) -> None:
        self.pane(RunsPane).export_selected()

    # --- engine events -----------------------------------------------------------------------
    def on_engine_message(self, message: EngineMessage) -> None:
        try:
            self._engine_message(message.event)
        except NoMatches:          # the console is closing: the widgets are gone
            pass

    def _engine_message(self, ev: Any) -> None:
        if isinstance(ev, tuple):
            what, payload = ev
            if what == "error":
                self._log("[red]run failed:[/] ", repr(payload))
            elif what == "finished":
                self._finished(payload)
            return
        self.events_seen.append(ev.kind)
        from normbox_lab.acquire.engine import format_duration

        k = ev.kind
        d = ev.data
        self.progress.on_event(k, d)           # one-off waits (warm-up, pauses) for the rate
        if k in ("run-started", "step-finished", "suspended", "unsuspended", "fault"):
            self._live_dirty = True            # the Instruments tab follows the run
        if k == "run-started":
            self.progress.started(d["done"], d["planned"], float(d["eta_s"]), d)
            self.progress.step = "preparing the instruments (remote mode, homing)"
            self._bar(d["done"], d["planned"])
            self._update_run_info()
            self._log(f"run {d['run_uuid'][:8]} segment {d['segment']}: {d['done']}/"
                      f"{d['planned']} done, lab time left {format_duration(d['eta_s'])}")
            self._runs_dirty = True
        elif k == "step-started":
            self.progress.step = f"{ev.key} · {d.get('label', d.get('kind', ''))}"
            self._update_run_info()
        elif k == "progress":
            self.progress.progressed(d["done"], float(d["eta_s"]),
                                     d.get("remaining_estimate_s"), d)
            self._bar(d["done"], d["planned"])
            self._update_run_info()
        elif k == "reading-stored":
            from normbox_lab.core.types import BrdfReading, SpectralReading  # numpy: lazy

            r = d.get("reading")
            if isinstance(r, SpectralReading):
                self.pane(SpectrumPane).add_reading(ev.key, r.wavelength_nm,
                                                    r.radiance_W_sr_m2_nm, r.colorimetry,
                                                    RADIANCE_TITLE)
            elif isinstance(r, BrdfReading):
                self.pane(SpectrumPane).add_reading(ev.key, r.wavelength_nm, r.brdf_per_sr,
                                                    None, BRDF_TITLE)
            self._runs_dirty = True
            self._live_dirty = True
        elif k == "prompt":
            if self.panes_built and self._live_dirty:   # what the run did before it asks
                self._live_dirty = False
                self._show_live()
            self._show_prompt(d["prompt"])
        elif k == "answer":
            self.waiting_prompt = None
            self._set_status()
            self._log("", f"{ev.key}: answered {d.get('answer')}")
        elif k in ("warning", "fault", "suspended", "unsuspended"):
            msg = fault_text(d) or str(d.get("role", ""))
            self._log(f"[yellow]{k}[/] ", f"{ev.key} {msg}")
        elif k == "paused":
            self._set_run_status("paused")
            self._log(f"paused before {ev.key or 'the end'} (p: resume)")
        elif k == "resumed":
            self._set_run_status("running")
            self._log("resumed")
        elif k == "run-finished":
            self.progress.ended = True         # ended paused too: no remaining time
            status = d.get("status", "finished")
            if status != "done" and self.progress.step:   # where it stopped, not "step: …"
                self.progress.step = (f"stopped at {self.progress.step.split(' · ')[0]}"
                                      " · r resumes")
            elif status == "done":
                self.progress.step = ""
            self._set_run_status(status)
            self._log(f"run finished: {d.get('status')} ({d.get('done', '?')}/"
                      f"{d.get('planned', '?')} readings)")
            self._runs_dirty = True

    def _finished(self, result: Any) -> None:
        self.waiting_prompt = None
        self._set_status()
        self._repeatability_summary()
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        self._runs_dirty = True
        self._poll_after_run()
        if self.quitting:
            self.exit()

    def _repeatability_summary(self) -> None:
        """A repeatability run ends with its spread: σ, CV and flags (log and toast)."""
        from normbox_lab.tui.views import repeatability_summary

        engine, store = self.session.engine, self.session.store
        run_id = engine.run_id if engine is not None else None
        if run_id is None or store is None:
            return
        if not str(store.get_run(run_id).protocol).endswith("repeatability"):
            return
        text = repeatability_summary(store, run_id)
        self._log("[b]summary[/b] ", text)
        self.notify(text, timeout=30, markup=False)

    def _poll_after_run(self) -> None:
        if self.lab_ready:
            self._poll(after_run=True)

    def _bar(self, done: int, planned: int) -> None:
        self.pane(RunPane).bar(done, planned)

    def _set_run_status(self, status: str) -> None:
        self.progress.status = status
        self._update_run_info()

    # the run's state for tests and the footer logic (RunProgress holds it)
    @property
    def run_status(self) -> str:
        return self.progress.status

    @property
    def progress_done(self) -> int:
        return self.progress.done

    @property
    def progress_planned(self) -> int:
        return self.progress.planned

    def _lab_time_scale(self) -> float | None:
        """None on a real clock; the virtual clock's time scale in a simulated lab."""
        from normbox_lab.core.clock import VirtualClock

        lab = self.session.lab
        return lab.clock.time_scale if lab is not None and isinstance(
            lab.clock, VirtualClock) else None

    def remaining_text(self) -> str:
        return self.progress.remaining_text(self._lab_time_scale())

    def _update_run_info(self) -> None:
        self._set_status()
        waiting = self.waiting_prompt is not None and self.prompt_screen is None
        self.pane(RunPane).set_info(self.progress.info_markup(self._lab_time_scale(), waiting))

    def _show_prompt(self, req: Any) -> None:
        if self.session.operator is None:      # the virtual operator answered already
            self._log("", f"{req.key}: {req.message} (virtual operator)")
            return
        if self.quitting:
            return
        if self.progress.status == "pausing…":
            # p was pressed while the run moved, warmed up or measured: the pause takes effect
            # at this prompt, before the reading it prepares (not after one more patch)
            self._pause_at_prompt(req)
            return
        self._log("[b]prompt[/b] ", f"{req.key}: {req.message}")
        self.waiting_prompt = req
        self._push_prompt(req)

    def _push_prompt(self, req: Any) -> None:
        screen = PromptScreen(req)
        self.prompt_screen = screen
        self.clear_notifications()      # toasts are drawn above the prompt: none hides it

        def answered(choice: str | None) -> None:
            if self.prompt_screen is screen:
                self.prompt_screen = None
            if choice == HIDDEN:               # stepped aside: it keeps waiting
                self._update_run_info()
                tab = screen.look_tab
                if tab is not None:
                    # the tabs' screen gives the focus it had back when it resumes (the Runs
                    # table, if the prompt came over the Runs tab), and Textual shows the
                    # pane that holds the focus: focus the asked tab's widget first, so
                    # however late the resume comes it cannot switch back
                    self._focus_tab_widget(tab)
                    self.call_after_refresh(self.action_tab, tab)
                return
            self.waiting_prompt = None
            if choice:
                try:
                    self.session.answer(choice)
                except Exception as exc:  # noqa: BLE001 - the prompt was withdrawn
                    self._log("answer not taken: ", str(exc))
            self._update_run_info()
        self.push_screen(screen, answered)

    # --- periodic refresh (throttled: at time scale 0 readings arrive in bursts) -------------
    def _tick(self) -> None:
        try:
            self._refresh_dirty()
            if self.session.busy and self.panes_built:
                self._update_run_info()        # the remaining time counts down between events
        except NoMatches:          # the console is closing: the widgets are gone
            pass

    def _refresh_dirty(self) -> None:
        if not self.panes_built:
            return
        if self.session.manual_action:
            self._live_dirty = True            # a manual move: "moving to 30°", the angle
        self.pane(SpectrumPane).redraw_if_dirty()
        if self._live_dirty:
            self._live_dirty = False
            self._show_live()
        if self._runs_dirty and self.session.store is not None:
            self._runs_dirty = False
            self._refresh_runs()
        pending = self._pending_resume
        if pending is not None and self.lab_ready:
            self._pending_resume = None
            self.resume_run(pending)

    def _show_instruments(self, rows: list[dict[str, Any]], announce: bool = True) -> None:
        """The poll's rows in the table; a toast with the poll's time and who did not answer
        (always when someone did not; after a manual action's poll otherwise not)."""
        self.pane(InstrumentsPane).show_instruments(rows, self.size.width)
        self._show_live()
        bad = [r["role"] for r in rows if r.get("ok") is False]
        if not (announce or bad):
            return
        polled = time.strftime("%H:%M:%S", time.localtime(self.clock.wall_time_s()))
        self.notify(f"instruments polled at {polled}: "
                    + (f"no answer from {', '.join(bad)}" if bad else "all answered"),
                    severity="error" if bad else "information", markup=False)

    def _show_live(self) -> None:
        pane = self.pane(InstrumentsPane)
        pane.show_live(self.session.live)
        pane.show_manual_keys(self.session.busy)
        if self.session.busy:          # the table follows the run (no polling during it)
            pane.show_instruments(self.session.instrument_rows(), self.size.width)

    @property
    def latest(self) -> tuple | None:
        """The latest reading drawn in the Spectrum tab (key, wavelength_nm, values, …)."""
        return self.pane(SpectrumPane).latest

    def spectrum_series(self) -> list[str]:
        """Labels of the plotted series (tests)."""
        return self.pane(SpectrumPane).series()

    def _refresh_runs(self) -> None:
        self.pane(RunsPane).refresh_runs()

    def _selected_run_id(self) -> int | None:
        return self.pane(RunsPane).selected_run_id()

    def on_resize(self, event: Any) -> None:
        if not self.panes_built:
            return
        self.pane(RunPane).scroll_log_end()
        if self.session.store is not None:
            self.pane(ImagesPane).refresh_from(self.session.store, self.size.width)
        rows = self.session.instrument_rows() if self.session.busy else self.session.last_rows
        if rows:
            self.pane(InstrumentsPane).show_instruments(rows, self.size.width)

    @on(TabbedContent.TabActivated)
    def _tab_activated(self, event: TabbedContent.TabActivated) -> None:
        pane = event.pane.id
        self._focus_tab_widget(str(pane))
        if pane == "results":
            self._refresh_results()
        elif pane == "images":
            self._refresh_images()
        elif pane == "runs":
            self._runs_dirty = True
        elif pane == "spectrum":
            self.pane(SpectrumPane).dirty = self.latest is not None

    def _focus_tab_widget(self, pane: str) -> None:
        """Give the focus of the tabs' own screen to the widget of tab `pane` (its table), or
        to none when the focus sits in another pane."""
        target = {"instruments": "#inst-table", "runs": "#runs-table",
                  "results": "#heatmap"}.get(pane)
        # the tabs' own screen (a prompt may be above it: its focus stays the prompt's, or a
        # table below would take the prompt's Enter)
        base = self.screen_stack[0]
        if target is not None:
            # at once (Widget.focus() is deferred: two deferred focuses in different panes
            # would switch the tabs back and forth for ever)
            base.set_focus(base.query_one(target))
        elif base.focused is not None and not self._in_pane(base.focused, pane):
            # focus must not stay in the pane just hidden: Textual's TabbedContent would
            # switch back to the pane that holds the focused widget (the Runs-tab trap)
            base.set_focus(None)

    def _in_pane(self, widget: Any, pane_id: str) -> bool:
        return any(node.id == pane_id for node in widget.ancestors if isinstance(node, Widget))

    def _refresh_results(self) -> None:
        if self.session.store is not None:
            self.pane(ResultsPane).refresh_from(self.session.store)

    def _refresh_images(self) -> None:
        if self.session.store is not None:
            self.pane(ImagesPane).refresh_from(self.session.store, self.size.width)

    def show_heatmap(self, hm: Any) -> None:
        self.pane(ResultsPane).show_heatmap(hm)


def _protocol_names() -> list[str]:
    from normbox_lab.acquire.engine import PROTOCOL_NAMES

    return list(PROTOCOL_NAMES)
