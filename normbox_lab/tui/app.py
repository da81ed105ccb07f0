"""The operator console (Textual): Instruments, Run, Spectrum, Runs, Results.

Keyboard first, laid out for 80×24.  The engine runs in a worker thread (`Session`); its events
arrive as `EngineMessage`s (posted thread-safely), so the screen never waits for an
instrument.  First paint happens before the store, the lab or its world are opened: those load
in a background thread right after it (a Mitsuba world may take seconds; the analytic one
milliseconds), as does the plot library.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar

from textual import on, work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.css.query import NoMatches
from textual.message import Message
from textual.screen import ModalScreen
from textual.widgets import (
    Button,
    DataTable,
    Footer,
    Input,
    Label,
    ProgressBar,
    RichLog,
    Select,
    Static,
    TabbedContent,
    TabPane,
)

from normbox_lab.tui.controller import Session

TABS = ("instruments", "run", "spectrum", "runs", "results", "images")
RADIANCE_TITLE = "spectral radiance W·sr⁻¹·m⁻²·nm⁻¹"
BRDF_TITLE = "BRDF sr⁻¹"


class EngineMessage(Message):
    """An engine event (or ("error", exc) / ("finished", result)) for the UI thread."""

    def __init__(self, event: Any) -> None:
        super().__init__()
        self.event = event


class LabReady(Message):
    def __init__(self, error: str = "") -> None:
        super().__init__()
        self.error = error


# --- modals ----------------------------------------------------------------------------------

class PromptScreen(ModalScreen[str]):
    """An operator or fault prompt.  Enter = the first choice (ok / retry)."""

    BINDINGS: ClassVar = [Binding("enter", "choose(0)", "answer", show=True),
                          Binding("r", "pick('retry')", "retry", show=False),
                          Binding("s", "pick('skip')", "skip", show=False),
                          Binding("a", "pick('abort')", "abort", show=False),
                          Binding("p", "app.pause_resume", "pause", show=False),
                          Binding("q", "app.quit_console", "quit", show=False)]
    DEFAULT_CSS = """
    PromptScreen { align: center middle; }
    PromptScreen > Vertical { width: 70; height: auto; border: thick $accent; padding: 0 1;
                              background: $panel; }
    PromptScreen.fault > Vertical { border: thick $error; }
    PromptScreen Horizontal { height: auto; }
    PromptScreen Button { margin: 0 1 0 0; }
    """

    def __init__(self, request: Any) -> None:
        super().__init__(classes="fault" if request.kind == "fault" else "")
        self.request = request

    def compose(self) -> ComposeResult:
        req = self.request
        title = "Fault" if req.kind == "fault" else "Operator"
        hint = ("r retry · s skip · a abort · Enter retry" if req.kind == "fault"
                else "Enter done · p pause after this reading · a abort · q quit")
        with Vertical():
            yield Label(f"[b]{title}[/b]  {req.key}")
            yield Static(prompt_text(req), id="prompt-message")
            yield Label(f"[dim]{hint}[/dim]")
            with Horizontal():
                for i, c in enumerate(req.choices):
                    yield Button(c, id=f"choice-{c}", compact=True,
                                 variant="primary" if i == 0 else
                                 ("error" if c == "abort" else "default"))

    def action_choose(self, index: int) -> None:
        self.dismiss(self.request.choices[int(index)])

    def action_pick(self, choice: str) -> None:
        if choice in self.request.choices:
            self.dismiss(choice)
        elif choice == "abort":              # an operator prompt: abort the run
            self.app.action_abort()

    @on(Button.Pressed)
    def _pressed(self, event: Button.Pressed) -> None:
        self.dismiss(str(event.button.id).removeprefix("choice-"))


def prompt_text(req: Any) -> str:
    """"Place patch 7 (orange) on the holder, then press Enter" for a place_patch prompt."""
    msg = str(req.message)
    if req.kind == "operator":
        msg = msg[:1].upper() + msg[1:]
        if req.data.get("action") == "place_patch":
            msg += " on the holder"
        msg += " — then Enter"
    return msg


class ResumeScreen(ModalScreen[int | None]):
    """Offered at start when the store holds runs that are not done."""

    BINDINGS: ClassVar = [Binding("enter", "resume", "resume"), Binding("escape,n", "later", "not now")]
    DEFAULT_CSS = """
    ResumeScreen { align: center middle; }
    ResumeScreen > Vertical { width: 74; height: auto; max-height: 18; border: thick $warning;
                              padding: 0 1; background: $panel; }
    ResumeScreen DataTable { height: auto; max-height: 10; }
    """

    def __init__(self, runs: list[Any]) -> None:
        super().__init__()
        self.runs = runs

    def compose(self) -> ComposeResult:
        from normbox_lab.tui.views import run_row

        with Vertical():
            yield Label(f"[b]{len(self.runs)} interrupted run(s)[/b] in the store. Resume one?")
            table: DataTable = DataTable(id="resume-table", cursor_type="row")
            table.add_columns("id", "uuid", "protocol", "status", "readings", "flags", "created")
            for r in reversed(self.runs):
                table.add_row(*run_row(r), key=str(r.id))
            yield table
            yield Label("[dim]↑↓ pick · Enter resume · n / Esc not now[/dim]")

    def action_resume(self) -> None:
        table = self.query_one(DataTable)
        row = table.cursor_row
        runs = list(reversed(self.runs))
        self.dismiss(runs[row].id if 0 <= row < len(runs) else None)

    def action_later(self) -> None:
        self.dismiss(None)

    @on(DataTable.RowSelected)
    def _selected(self, _event: DataTable.RowSelected) -> None:
        self.action_resume()


class DrillScreen(ModalScreen[None]):
    """Per-patch drill-down of the Results heat map."""

    BINDINGS: ClassVar = [Binding("escape,enter,q", "close", "close")]
    DEFAULT_CSS = """
    DrillScreen { align: center middle; }
    DrillScreen > VerticalScroll { width: 78; height: auto; max-height: 22;
                                   border: thick $accent; background: $panel; }
    """

    def __init__(self, lines: list[str]) -> None:
        super().__init__()
        self.lines = lines

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("\n".join(self.lines), id="drill-text")
            yield Label("[dim]Esc / Enter: close[/dim]")

    def action_close(self) -> None:
        self.dismiss(None)


# --- the app ---------------------------------------------------------------------------------

class NormboxConsole(App):
    """normbox-lab tui."""

    TITLE = "normbox-lab"
    ENABLE_COMMAND_PALETTE = False
    CSS = """
    #status { height: 1; background: $boost; padding: 0 1; }
    TabbedContent { height: 1fr; }
    TabPane { padding: 0; }
    #inst-table { height: auto; max-height: 10; }
    #live { height: auto; padding: 0 1; }
    #run-top { height: 1; }
    #run-top Select { width: 26; }
    #params { height: 6; border: round $surface-lighten-2; }
    .param { height: 1; }
    .param Label { width: 16; }
    .param Input { width: 1fr; }
    #run-info { height: 2; padding: 0 1; }
    #progress { height: 1; padding: 0 1; }
    #progress Bar { width: 1fr; }
    #events { height: 1fr; }
    #runs-table { height: 1fr; }
    #readings-table { height: 1fr; }
    #res-head { height: 2; padding: 0 1; }
    #heatmap { height: 1fr; }
    #drill { height: 1; padding: 0 1; }
    #spectrum-head { height: 1; padding: 0 1; }
    #images-view { height: 1fr; padding: 0 1; }
    """
    BINDINGS: ClassVar = [
        Binding("x", "emergency_stop", "E-STOP", priority=True),
        Binding("q", "quit_console", "quit"),
        # Ctrl+Q is Textual's "close now"; here it leaves the same safe way as q (the run
        # pauses after the reading under way, a waiting prompt is withdrawn), on every screen
        Binding("ctrl+q", "quit_console", "quit", show=False, priority=True),
        Binding("s", "start", "start"),
        Binding("d", "dry_run", "dry-run"),
        Binding("p", "pause_resume", "pause"),
        Binding("a", "abort", "abort"),
        Binding("r", "resume_selected", "resume"),
        Binding("e", "export", "export"),
        Binding("i", "poll", "poll"),
        Binding("escape", "leave_input", "", show=False),
        *[Binding(str(k + 1), f"tab('{t}')", t, show=False) for k, t in enumerate(TABS)],
    ]

    def __init__(self, session: Session, *, exit_after_paint: bool = False,
                 offer_resume: bool = True, protocol: str = "reference-sweep",
                 prefill: dict[str, str] | None = None) -> None:
        super().__init__()
        self.session = session
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
        self.latest: Any = None          # (key, wavelength, radiance) of the latest reading
        self.previous: Any = None
        self._spectrum_dirty = False
        self._runs_dirty = True
        self._plot: Any = None
        self._heatmap: Any = None
        self.progress_done = 0
        self.progress_planned = 0
        self.run_status = "idle"
        self.current_step = ""
        self.events_seen: list[str] = []

    # --- layout ------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static("normbox-lab · starting…", id="status")
        with TabbedContent(initial="run", id="tabs"):
            yield TabPane("1 Instruments", id="instruments")   # filled after first paint
            with TabPane("2 Run", id="run"):
                with Horizontal(id="run-top"):
                    # the protocol list (engine import) and parameters load after first paint
                    yield Select([(self.protocol, self.protocol)], value=self.protocol,
                                 allow_blank=False, compact=True, type_to_search=False,
                                 id="protocol")
                    yield Label("  parameters: JSON values · s start · d dry-run", id="run-hint")
                yield VerticalScroll(id="params")
                yield Static("idle", id="run-info")
                with Horizontal(id="progress"):
                    yield ProgressBar(total=1, show_eta=False, id="bar")
                yield RichLog(id="events", max_lines=500, wrap=False, markup=True)
            yield TabPane("3 Spectrum", id="spectrum")
            yield TabPane("4 Runs", id="runs")
            yield TabPane("5 Results", id="results")
            yield TabPane("6 Images", id="images")
        yield Footer()

    def on_mount(self) -> None:
        self.call_after_refresh(self._first_paint)
        self.set_interval(0.5, self._tick)

    def _build_panes(self) -> None:
        """The tabs not shown at start: built right after the first paint (less to style and
        lay out before it)."""
        def table(wid: str, columns: tuple[str, ...], **kw: Any) -> DataTable:
            t: DataTable = DataTable(id=wid, **kw)
            t.add_columns(*columns)
            return t
        self.query_one("#instruments", TabPane).mount_all([
            table("inst-table", ("role", "connection", "identity", "state", "last seen"),
                  cursor_type="row", zebra_stripes=True),
            Static("", id="live")])
        self.query_one("#spectrum", TabPane).mount_all([
            Static("no reading yet", id="spectrum-head"), Vertical(id="plot-box")])
        self.query_one("#runs", TabPane).mount_all([
            table("runs-table", ("id", "uuid", "protocol", "status", "readings", "flags",
                                 "created"),
                  cursor_type="row", zebra_stripes=True),
            table("readings-table", ("key", "angle°", "patch", "Lv cd/m²", "x", "y", "t_int s"),
                  cursor_type="row", zebra_stripes=True)])
        self.query_one("#results", TabPane).mount_all([
            Static("no comparison in the store yet (normbox-lab compare …)", id="res-head"),
            DataTable(id="heatmap", cursor_type="cell"),
            Static("", id="drill")])
        self.query_one("#images", TabPane).mount_all([
            VerticalScroll(Static("no image in the store yet (normbox-lab image figure1 …)",
                                  id="images-text"), id="images-view")])
        self.panes_built = True

    def _first_paint(self) -> None:
        self.first_paint_wall_s = time.time()
        self.first_paint_cpu_s = time.process_time()
        if self.exit_after_paint:
            self.exit()
            return
        select = self.query_one("#protocol", Select)
        names = _protocol_names()
        if self.protocol not in names:
            names.append(self.protocol)
        with select.prevent(Select.Changed):
            select.set_options([(n, n) for n in names])
            select.value = self.protocol
        self._show_params(self.protocol)
        self._build_panes()
        self.call_after_refresh(self._load)

    @work(thread=True, exclusive=True, group="load")
    def _load(self) -> None:
        s = self.session
        try:
            s.open_store()
            runs = s.unfinished_runs()
            if self.offer_resume and runs:
                self.call_from_thread(self._offer_resume, runs)
            self._runs_dirty = True
            s.ensure_lab()
            rows = s.poll_instruments()
            self.call_from_thread(self._show_instruments, rows)
            self.post_message(LabReady())
        except Exception as exc:  # noqa: BLE001 - shown to the operator, the console stays up
            self.post_message(LabReady(f"{type(exc).__name__}: {exc}"))

    def on_lab_ready(self, message: LabReady) -> None:
        if message.error:
            self.lab_error = message.error
            self._set_status(f"lab not ready: {message.error}")
            self._log("[red]lab not ready[/] ", message.error)
            return
        self.lab_ready = True
        s = self.session
        kind = "simulated" if s.config.simulated else "real"
        scale = getattr(s.lab.clock, "time_scale", None)
        clock = "real clock" if scale is None else f"virtual clock ×{scale:g}"
        self._set_status(f"{kind} lab · world {s.world_kind} · {clock} · "
                         f"store {s.store_path.name} · {s.config.name}")
        self._refresh_results()

    # --- helpers -----------------------------------------------------------------------------
    def _set_status(self, text: str) -> None:
        self.query_one("#status", Static).update(text)

    def _log(self, markup: str, detail: str = "") -> None:
        """One line in the Run tab's log: `markup` (ours) + `detail` (plain: messages and
        errors from instruments may contain brackets)."""
        from rich.text import Text

        line = Text.from_markup(markup)
        if detail:
            line.append(detail)
        self.query_one("#events", RichLog).write(line)

    def _show_params(self, protocol: str) -> None:
        box = self.query_one("#params", VerticalScroll)
        box.remove_children()
        try:
            params = self.session.default_parameters(protocol)
        except Exception as exc:  # noqa: BLE001 - a broken protocol file is shown, not fatal
            box.mount(Label(f"[red]{exc}[/]"))
            return
        import json

        for k, v in params.items():
            text = v if isinstance(v, str) else json.dumps(v)   # as `--param K=V` takes it
            if protocol == self.prefill_protocol:
                text = self.prefill.get(k, text)
            box.mount(Horizontal(Label(k), Input(text, id=f"param-{k}", compact=True),
                                 classes="param"))

    def parameters(self) -> dict[str, Any]:
        """The parameters as typed in the Run tab (JSON, like `--param K=V`)."""
        from normbox_lab.acquire import engine as eng

        module = eng.load_protocol(self.protocol)
        out: dict[str, Any] = {}
        for inp in self.query("#params Input").results(Input):
            key = str(inp.id).removeprefix("param-")
            out[key] = eng.coerce_param(module.PARAMETERS[key], inp.value)
        return out

    def set_parameter(self, key: str, value: str) -> None:
        self.query_one(f"#param-{key}", Input).value = value

    # --- actions -----------------------------------------------------------------------------
    def action_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab

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
        text = (f"dry-run {protocol}: {len(dry.plan)} steps, {dry.plan.planned} readings, "
                f"{len(dry.executed)} executed · lab time {format_duration(dry.total_s)} "
                f"({dry.total_s:.0f} s of instrument and operator time; in a simulated lab "
                f"the remaining time is measured once the run goes)")
        self.dry = dry
        self.call_from_thread(self._after_dry, text)

    def _after_dry(self, text: str) -> None:
        self.query_one("#run-info", Static).update(text)
        self._log("", text)

    def _ready_for_run(self) -> bool:
        if not self.lab_ready:
            error = getattr(self, "lab_error", "")
            self.notify(f"the lab could not be assembled: {error}" if error
                        else "the lab is still loading", severity="warning", markup=False)
            return False
        if self.session.busy:
            self.notify("a run is active", severity="warning")
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
        self._log("", f"starting {self.protocol} {params}")

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
        else:
            self.session.pause()
            self._log("pause requested: after the current reading")
            self._set_run_status("pausing…")

    #: seconds within which a second `a` confirms the abort
    ABORT_CONFIRM_S = 5.0

    def action_abort(self) -> None:
        """a asks for confirmation (a again within 5 s) before it aborts the run."""
        if not self.session.busy:
            return
        armed = getattr(self, "_abort_armed_until", 0.0)
        if time.monotonic() <= armed:
            self._abort_armed_until = 0.0
            self.session.abort()
            self._log("[red]abort requested[/]")
            return
        self._abort_armed_until = time.monotonic() + self.ABORT_CONFIRM_S
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

    def action_emergency_stop(self) -> None:
        """x: every axis stops and every lamp goes off now; a run ends paused (resumable)."""
        if not self.lab_ready:
            return
        failed = self.session.emergency_stop()
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        self._log("[b red]EMERGENCY STOP[/] ", "axes halted, lamps off"
                  + (f"; not reached: {'; '.join(failed)}" if failed else ""))
        self.notify("EMERGENCY STOP: axes halted, lamps off"
                    + (" — run paused, r resumes" if self.session.busy else ""),
                    severity="error", markup=False)

    def action_poll(self) -> None:
        if self.lab_ready:
            self._poll()

    @work(thread=True, exclusive=True, group="poll")
    def _poll(self) -> None:
        try:
            rows = self.session.poll_instruments()
        except Exception as exc:  # noqa: BLE001
            self.call_from_thread(self._log, "[red]poll failed:[/] ", str(exc))
            return
        self.call_from_thread(self._show_instruments, rows)

    def action_export(self) -> None:
        run_id = self._selected_run_id()
        if run_id is None:
            self.notify("select a run in the Runs tab (4) first")
            return
        self._export(run_id)

    @work(thread=True, group="export")
    def _export(self, run_id: int) -> None:
        from normbox_lab.acquire.export import export_run

        try:
            path = export_run(self.session.open_store(), run_id, "csv")
        except Exception as exc:  # noqa: BLE001
            self.call_from_thread(self.notify, f"export failed: {exc}", severity="error",
                                  markup=False)
            return
        self.call_from_thread(self.notify, f"exported run {run_id} → {path}", markup=False)
        self.call_from_thread(self._log, "", f"exported run {run_id} → {path}")

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
        if k == "run-started":
            self.progress_planned, self.progress_done = d["planned"], d["done"]
            self._bar(d["done"], d["planned"])
            self._set_run_status("running")
            self._eta_start = (time.monotonic(), d["done"])
            self._lab_remaining_s = float(d["eta_s"])
            self._log(f"run {d['run_uuid'][:8]} segment {d['segment']}: {d['done']}/"
                      f"{d['planned']} done, lab time left {format_duration(d['eta_s'])}")
            self._runs_dirty = True
        elif k == "step-started":
            self.current_step = f"{ev.key} · {d.get('label', d.get('kind', ''))}"
            self._update_run_info()
        elif k == "progress":
            self.progress_done = d["done"]
            self._lab_remaining_s = float(d["eta_s"])
            self._bar(d["done"], d["planned"])
            self._update_run_info()
        elif k == "reading-stored":
            r = d.get("reading")
            values, title = getattr(r, "radiance_W_sr_m2_nm", None), RADIANCE_TITLE
            if values is None:
                values, title = getattr(r, "brdf_per_sr", None), BRDF_TITLE
            if values is not None:
                if self.latest is None or self.latest[4] == title:
                    self.previous = self.latest
                else:                         # a different quantity: nothing to compare
                    self.previous = None
                self.latest = (ev.key, r.wavelength_nm, values,
                               getattr(r, "colorimetry", None), title)
                self._spectrum_dirty = True
            self._runs_dirty = True
            self._live_dirty = True
        elif k == "prompt":
            self._show_prompt(d["prompt"])
        elif k == "answer":
            self._log("", f"{ev.key}: answered {d.get('answer')}")
        elif k in ("warning", "fault", "suspended", "unsuspended"):
            msg = d.get("message") or d.get("error") or d.get("role") or ""
            self._log(f"[yellow]{k}[/] ", f"{ev.key} {msg}")
        elif k == "paused":
            self._set_run_status("paused")
            self._log(f"paused before {ev.key or 'the end'} (p: resume)")
        elif k == "resumed":
            self._set_run_status("running")
            self._log("resumed")
        elif k == "run-finished":
            self._set_run_status(d.get("status", "finished"))
            self._log(f"run finished: {d.get('status')} ({d.get('done', '?')}/"
                      f"{d.get('planned', '?')} readings)")
            self._runs_dirty = True

    def _finished(self, result: Any) -> None:
        if self.prompt_screen is not None:
            self.prompt_screen.dismiss("")
        self._runs_dirty = True
        self._poll_after_run()
        if self.quitting:
            self.exit()

    def _poll_after_run(self) -> None:
        if self.lab_ready and not self.session.busy:
            self._poll()

    def _bar(self, done: int, planned: int) -> None:
        self.query_one("#bar", ProgressBar).update(total=max(planned, 1), progress=done)

    def _set_run_status(self, status: str) -> None:
        self.run_status = status
        self._update_run_info()

    def remaining_text(self) -> str:
        """"remaining 0:04:10 · done ≈ 14:32" while a run goes; "" when none does (after an
        abort or the end no estimate is shown).  On a real clock the remaining time is the
        engine's timing model (instrument and operator time); on a virtual clock (a simulated
        lab) it is the observed wall-clock rate of this segment × the readings left, since
        the lab clock says nothing about how long a person waits."""
        import datetime

        from normbox_lab.acquire.engine import format_duration

        if self.run_status not in ("running", "suspended", "paused"):
            return ""
        left = max(0, self.progress_planned - self.progress_done)
        scale = getattr(getattr(self.session.lab, "clock", None), "time_scale", None)
        if scale is None:                           # real clock: the timing model
            remaining_s = getattr(self, "_lab_remaining_s", None)
        else:                                       # simulated: the observed rate
            t0, done0 = getattr(self, "_eta_start", (time.monotonic(), self.progress_done))
            taken = self.progress_done - done0
            remaining_s = ((time.monotonic() - t0) / taken * left) if taken > 0 else None
        if remaining_s is None:
            return "remaining: measuring…"
        finish = datetime.datetime.now() + datetime.timedelta(seconds=remaining_s)
        return f"remaining {format_duration(remaining_s)} · done ≈ {finish:%H:%M}"

    def _update_run_info(self) -> None:
        remaining = self.remaining_text()
        self.query_one("#run-info", Static).update(
            f"[b]{self.run_status}[/b] · {self.progress_done}/{self.progress_planned} readings"
            f"{' · ' + remaining if remaining else ''}\nstep: {self.current_step}")

    def _show_prompt(self, req: Any) -> None:
        if self.session.operator is None:      # the virtual operator answered already
            self._log("", f"{req.key}: {req.message} (virtual operator)")
            return
        if self.quitting:
            return
        self._log("[b]prompt[/b] ", f"{req.key}: {req.message}")
        screen = PromptScreen(req)
        self.prompt_screen = screen

        def answered(choice: str | None) -> None:
            if self.prompt_screen is screen:
                self.prompt_screen = None
            if choice:
                try:
                    self.session.answer(choice)
                except Exception as exc:  # noqa: BLE001 - the prompt was withdrawn
                    self._log("answer not taken: ", str(exc))
        self.push_screen(screen, answered)

    # --- periodic refresh (throttled: at time scale 0 readings arrive in bursts) -------------
    def _tick(self) -> None:
        try:
            self._refresh_dirty()
        except NoMatches:          # the console is closing: the widgets are gone
            pass

    def _refresh_dirty(self) -> None:
        if not self.panes_built:
            return
        if self._spectrum_dirty:
            self._spectrum_dirty = False
            self._draw_spectrum()
        if getattr(self, "_live_dirty", False):
            self._live_dirty = False
            self._show_live()
        if self._runs_dirty and self.session.store is not None:
            self._runs_dirty = False
            self._refresh_runs()
        pending = getattr(self, "_pending_resume", None)
        if pending is not None and self.lab_ready:
            self._pending_resume = None
            self.resume_run(pending)

    def _show_instruments(self, rows: list[dict[str, Any]]) -> None:
        from rich.text import Text

        table = self.query_one("#inst-table", DataTable)
        table.clear()
        width = max(24, self.size.width - 60)
        for r in rows:
            ident = r["identity"] or "-"
            seen = r.get("last_seen")
            seen_text = time.strftime("%H:%M:%S", time.localtime(seen)) if seen else "never"
            style = "bold white on #D55E00" if r.get("ok") is False else ""
            cells = (r["role"], connection_text(r),
                     ident if len(ident) <= width else ident[:width - 1] + "…",
                     r["state"] or "-", seen_text)
            table.add_row(*[Text(str(c), style=style) for c in cells], key=r["role"])
        self._show_live()
        bad = [r["role"] for r in rows if r.get("ok") is False]
        self.notify(f"instruments polled at {time.strftime('%H:%M:%S')}: "
                    + (f"no answer from {', '.join(bad)}" if bad else "all answered"),
                    severity="error" if bad else "information", markup=False)

    def _show_live(self) -> None:
        live = self.session.live
        angle = "?" if live.angle_deg is None else f"{live.angle_deg:.1f}°"
        lamp = live.lamp
        if live.lamp_stable is not None and live.lamp != "stable":
            lamp += " (stable)" if live.lamp_stable else " (not stable)"
        temp = "-" if live.temperature_c is None else f"{live.temperature_c:.1f} °C"
        last = "-"
        if live.last_key:
            lv = "?" if live.last_Lv_cd_m2 is None else f"{live.last_Lv_cd_m2:.3g} cd/m²"
            xy = "" if live.last_xy is None else f"  x {live.last_xy[0]:.4f} y {live.last_xy[1]:.4f}"
            last = f"{live.last_key}: Lv {lv}{xy}"
        patch = "-" if live.patch is None else str(live.patch)
        self.query_one("#live", Static).update(
            f"sample angle {angle} · patch on holder {patch} · lamp {lamp}\n"
            f"spectrometer temperature {temp}\nlast reading {last}")

    def _draw_spectrum(self) -> None:
        if self.latest is None:
            return
        key, wl, rad, colo, title = self.latest
        head = f"latest {key}"
        if colo is not None:
            head += f" · Lv {colo.Lv_cd_m2:.3g} cd/m² · x {colo.x:.4f} y {colo.y:.4f}"
        if self.previous is not None:
            head += f" · previous {self.previous[0]}"
        self.query_one("#spectrum-head", Static).update(head)
        if self._plot is None:
            from textual_plotext import PlotextPlot

            self._plot = PlotextPlot(id="plot")
            self.query_one("#plot-box", Vertical).mount(self._plot)
        plt = self._plot.plt
        plt.clear_data()
        plt.title(title)
        plt.xlabel("wavelength nm")
        step = max(1, len(wl) // 100)
        if self.previous is not None:
            pk, pwl, prad, _, _ = self.previous
            plt.plot(list(pwl[::step]), list(prad[::step]), label=pk, marker="dot",
                     color="gray")
        plt.plot(list(wl[::step]), list(rad[::step]), label=key, marker="braille",
                 color="cyan")
        self._plot.refresh()

    def spectrum_series(self) -> list[str]:
        """Labels of the plotted series (tests)."""
        out = []
        if self.previous is not None:
            out.append(self.previous[0])
        if self.latest is not None:
            out.append(self.latest[0])
        return out

    def _refresh_runs(self) -> None:
        from normbox_lab.analyze import qa
        from normbox_lab.tui.views import run_row

        store = self.session.store
        table = self.query_one("#runs-table", DataTable)
        selected = self._selected_run_id()
        table.clear()
        runs = store.runs()
        flags = qa.summaries_by_run(store)
        for r in runs:
            table.add_row(*run_row(r, flags.get(r.id)), key=str(r.id))
        if runs:
            ids = [r.id for r in runs]
            row = ids.index(selected) if selected in ids else len(ids) - 1
            table.move_cursor(row=row)
            self._show_readings(ids[row])

    def _selected_run_id(self) -> int | None:
        table = self.query_one("#runs-table", DataTable)
        if table.row_count == 0:
            return None
        try:
            key = table.coordinate_to_cell_key((table.cursor_row, 0)).row_key
        except Exception:  # noqa: BLE001 - no valid cursor
            return None
        return int(str(key.value)) if key.value is not None else None

    @on(DataTable.RowHighlighted, "#runs-table")
    def _run_highlighted(self, event: DataTable.RowHighlighted) -> None:
        if event.row_key.value is not None:
            self._show_readings(int(str(event.row_key.value)))

    def _show_readings(self, run_id: int) -> None:
        from normbox_lab.tui.views import reading_row

        table = self.query_one("#readings-table", DataTable)
        if getattr(self, "_readings_shown", None) == (run_id, self.session.store.get_run(run_id).done):
            return
        table.clear()
        for r in self.session.store.readings(run_id):
            table.add_row(*reading_row(r))
        self._readings_shown = (run_id, table.row_count)

    @on(TabbedContent.TabActivated)
    def _tab_activated(self, event: TabbedContent.TabActivated) -> None:
        pane = event.pane.id
        target = {"instruments": "#inst-table", "runs": "#runs-table",
                  "results": "#heatmap"}.get(str(pane))
        if target is not None:
            self.query_one(target).focus()
        elif self.focused is not None and not self._in_pane(self.focused, str(pane)):
            # focus must not stay in the pane just hidden: Textual's TabbedContent would
            # switch back to the pane that holds the focused widget (the Runs-tab trap)
            self.set_focus(None)
        if pane == "results":
            self._refresh_results()
        elif pane == "images":
            self._refresh_images()
        elif pane == "runs":
            self._runs_dirty = True
        elif pane == "spectrum":
            self._spectrum_dirty = self.latest is not None

    def _in_pane(self, widget: Any, pane_id: str) -> bool:
        return any(getattr(node, "id", None) == pane_id for node in widget.ancestors)

    def _refresh_results(self) -> None:
        from normbox_lab.tui.views import latest_heatmap

        store = self.session.store
        if store is None:
            return
        hm = latest_heatmap(store)
        if hm is None or (self._heatmap is not None and self._heatmap.artifact_id == hm.artifact_id):
            return
        self.show_heatmap(hm)

    def _refresh_images(self) -> None:
        """The store's latest image figures (one per id; the virtual camera's truth | prediction
        | ΔE00 first) as half-block previews, each figure's panels side by side across the
        console's width."""
        from rich.console import Group

        from normbox_lab.images.terminal import figure_renderable

        store = self.session.store
        if store is None:
            return
        found = store.artifacts(kind="image-figure")
        if not found or getattr(self, "_image_shown", None) == found[-1].id:
            return
        latest = {a.name: a for a in found}
        order = sorted(latest.values(), key=lambda a: (a.name != "fig-camera", -a.id))
        self._image_shown = found[-1].id
        width = max(24, min(160, self.size.width - 4))
        figures = []
        for a in order:
            panels = [(p["label"], a.arrays[f"p{k}"], p.get("vmax"), p.get("unit", ""))
                      for k, p in enumerate(a.metadata.get("panels", []))]
            title = f"{a.metadata.get('title', a.name)} (artifact {a.id}, run {a.run_id})"
            figures.append(figure_renderable(title, panels, width))
        self.query_one("#images-text", Static).update(Group(*figures))

    def show_heatmap(self, hm: Any) -> None:
        from rich.text import Text

        from normbox_lab.tui.views import RATING_STYLES, rating_class

        self._heatmap = hm
        counts = hm.counts()
        legend = Text()
        for (style, label), n in zip(RATING_STYLES, counts, strict=True):
            legend.append(f"{label} ({n})", style=style)
            legend.append(" ")
        head = Text(f"comparison {hm.name!r} (artifact {hm.artifact_id}"
                    f"{'' if hm.run_id is None else f', run {hm.run_id}'}) · "
                    f"mean ΔE00 {float(hm.delta_e00.mean()):.2f}\n")
        head.append_text(legend)
        self.query_one("#res-head", Static).update(head)
        table = self.query_one("#heatmap", DataTable)
        table.clear(columns=True)
        table.add_column("patch", key="patch")
        for a in hm.angle_deg:
            table.add_column(f"{a:g}°", key=f"{a:g}")
        for i, name in enumerate(hm.patch_names):
            cells: list[Any] = [Text(name[:13])]
            for j in range(hm.angle_deg.size):
                de = float(hm.delta_e00[i, j])
                cells.append(Text(f"{de:4.1f}", style=RATING_STYLES[rating_class(de)][0]))
            table.add_row(*cells, key=f"p{i}")
        table.add_row(Text("NRMSE %", style="bold"),
                      *[Text(f"{100 * v:4.1f}", style="bold") for v in hm.nrmse_per_angle],
                      key="nrmse")
        self._drill(0)

    @on(DataTable.CellSelected, "#heatmap")
    def _cell_selected(self, event: DataTable.CellSelected) -> None:
        hm = self._heatmap
        if hm is not None and 0 <= event.coordinate.row < len(hm.patch_names):
            self.push_screen(DrillScreen(hm.drill_down(event.coordinate.row)))

    @on(DataTable.CellHighlighted, "#heatmap")
    def _cell(self, event: DataTable.CellHighlighted) -> None:
        self._drill(event.coordinate.row)

    def _drill(self, row: int) -> None:
        hm = self._heatmap
        if hm is None:
            return
        drill = self.query_one("#drill", Static)
        if 0 <= row < len(hm.patch_names):
            drill.update(hm.summary(row))
        else:
            drill.update("NRMSE per angle (mean over patches): " + ", ".join(
                f"{a:g}° {100 * v:.1f}%" for a, v in zip(hm.angle_deg, hm.nrmse_per_angle,
                                                         strict=True)))


def connection_text(row: dict[str, Any]) -> str:
    """"sim cs1000a" for an emulator URL, "real /dev/ttyUSB0" for a port."""
    port = str(row["port"])
    if port.startswith("sim://"):
        return "sim " + port.removeprefix("sim://").split("?")[0]
    return ("sim " if row["simulated"] else "real ") + port


def _protocol_names() -> list[str]:
    from normbox_lab.acquire.engine import PROTOCOL_NAMES

    return list(PROTOCOL_NAMES)
