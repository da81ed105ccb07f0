"""Tab 2, Run: the protocol, its parameters, the run's state and progress, and its log."""

from __future__ import annotations

import json
from typing import Any

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Input, Label, ProgressBar, RichLog, Select, Static, TabPane

from normbox_lab.core.clock import Clock
from normbox_lab.tui.tabs.common import StopSafeInput


class RunProgress:
    """The run's state and progress as the Run tab shows them, from the engine's events (no
    Textual: the app feeds it, the pane draws `info_markup`)."""

    #: statuses during which a remaining time is shown (none after an abort, a failure, the end)
    ACTIVE = ("running", "suspended", "paused")

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.status = "idle"
        self.done = 0
        self.planned = 0
        self.step = ""
        self.segment_start: tuple[float, int] | None = None   # (clock s, done) at its start
        self.lab_remaining_s: float | None = None             # the engine's timing model
        #: the segment has ended (also `paused`: an emergency stop, a quit): nothing to estimate
        self.ended = False

    def started(self, done: int, planned: int, lab_remaining_s: float) -> None:
        """A segment starts: the observed rate is measured from here."""
        self.done, self.planned, self.status = done, planned, "running"
        self.ended = False
        self.segment_start = (self.clock.now_s(), done)
        self.lab_remaining_s = lab_remaining_s

    def progressed(self, done: int, lab_remaining_s: float) -> None:
        self.done, self.lab_remaining_s = done, lab_remaining_s

    def remaining_text(self, lab_time_scale: float | None) -> str:
        """"remaining 0:04:10 · done ≈ 14:32" while a run goes; "" when none does (after an
        abort or the end no estimate is shown).  On a real clock (`lab_time_scale` None) the
        remaining time is the engine's timing model (instrument and operator time); on a
        virtual clock (a simulated lab) it is the observed rate of this segment on the
        console's clock × the readings left, since the lab clock says nothing about how long
        a person waits."""
        import datetime

        from normbox_lab.acquire.estimate import format_duration

        if self.status not in self.ACTIVE or self.ended:
            return ""
        left = max(0, self.planned - self.done)
        if lab_time_scale is None:
            remaining_s = self.lab_remaining_s
        else:
            t0, done0 = self.segment_start or (self.clock.now_s(), self.done)
            taken = self.done - done0
            remaining_s = ((self.clock.now_s() - t0) / taken * left) if taken > 0 else None
        if remaining_s is None:
            return "remaining: measuring…"
        finish = datetime.datetime.fromtimestamp(self.clock.wall_time_s() + remaining_s)
        return f"remaining {format_duration(remaining_s)} · done ≈ {finish:%H:%M}"

    def info_markup(self, lab_time_scale: float | None, prompt_waiting: bool) -> str:
        """The Run tab's two status lines."""
        remaining = self.remaining_text(lab_time_scale)
        waiting = "  [b reverse] prompt waiting: w [/]" if prompt_waiting else ""
        return (f"[b]{self.status}[/b] · {self.done}/{self.planned} readings"
                f"{' · ' + remaining if remaining else ''}{waiting}\nstep: {self.step}")


class RunPane(TabPane):
    DEFAULT_CSS = """
    #run-top { height: 1; }
    #run-top Select { width: 26; }
    #params { height: auto; min-height: 3; max-height: 30vh;
              border: round $surface-lighten-2; }
    .param { height: 1; }
    .param Input { width: 1fr; }
    .param Input.-invalid { color: $error; }
    #param-error { height: auto; color: $error; padding: 0 1; }
    #run-info { height: 2; padding: 0 1; }
    #progress { height: 1; padding: 0 1; }
    #progress Bar { width: 1fr; }
    #events { height: 1fr; }
    """

    def __init__(self, protocol: str) -> None:
        super().__init__("2 Run", id="run")
        self.protocol = protocol
        self.defaults: dict[str, Any] = {}
        self.limits: dict[str, Any] = {}
        self.config: Any = None

    def compose(self) -> ComposeResult:
        with Horizontal(id="run-top"):
            # the protocol list (engine import) and parameters load after first paint
            yield Select([(self.protocol, self.protocol)], value=self.protocol,
                         allow_blank=False, compact=True, type_to_search=False, id="protocol")
            yield Label("  parameters: JSON values · s start · d dry-run", id="run-hint")
        yield VerticalScroll(id="params")
        yield Static("", id="param-error")
        yield Static("idle", id="run-info")
        with Horizontal(id="progress"):
            yield ProgressBar(total=1, show_eta=False, id="bar")
        yield RichLog(id="events", max_lines=500, wrap=True, markup=True)

    def set_protocols(self, names: list[str], current: str) -> None:
        select = self.query_one("#protocol", Select)
        with select.prevent(Select.Changed):
            select.set_options([(n, n) for n in names])
            select.value = current

    def show_params(self, params: dict[str, Any] | Exception,
                    prefill: dict[str, str], limits: dict[str, Any] | None = None,
                    config: Any = None) -> None:
        """One line per parameter (JSON text, as `--param K=V` takes it), each checked as it
        is typed against its default's kind and the protocol's declared limits (`limits`,
        angle ranges from the lab `config`); or the error of a protocol file that cannot be
        read.  Labels are as wide as the longest name."""
        from textual.validation import Function

        from normbox_lab.acquire.plan import PlanError

        box = self.query_one("#params", VerticalScroll)
        box.remove_children()
        self.query_one("#param-error", Static).update("")
        self.query_one("#param-error", Static).display = False
        if isinstance(params, Exception):
            box.mount(Label(f"[red]{params}[/]"))
            return
        width = max((len(k) for k in params), default=8) + 2
        self.defaults = dict(params)

        self.limits, self.config = dict(limits or {}), config

        def check(key: str, default: Any) -> Function:
            def ok(text: str) -> bool:
                try:
                    self.check_one(key, text)
                except PlanError:
                    return False
                return True
            return Function(ok, f"{key}: not a value of its kind")

        for k, v in params.items():
            text = prefill.get(k, v if isinstance(v, str) else json.dumps(v))
            label = Label(k)
            label.styles.width = width
            field = StopSafeInput(text, id=f"param-{k}", compact=True,
                                  validators=[check(k, v)], validate_on=["changed"])
            box.mount(Horizontal(label, field, classes="param"))

    def on_input_changed(self, event: Input.Changed) -> None:
        if str(event.input.id or "").startswith("param-"):
            self.check_parameters()

    def check_one(self, key: str, text: str) -> Any:
        """The value of one field: parsed like its default, then checked against the
        protocol's declared limits (the other fields as typed, or their defaults)."""
        from normbox_lab.acquire.plan import PlanError, coerce_param
        from normbox_lab.protocols._common import check_parameters

        value = coerce_param(self.defaults[key], text, key)
        if key in self.limits:
            others = dict(self.defaults)
            for k, t in self.parameter_texts().items():
                if k != key and k in self.defaults:
                    try:
                        others[k] = coerce_param(self.defaults[k], t, k)
                    except PlanError:
                        pass
            others[key] = value
            check_parameters(self.limits, others, self.config, only=key)
        return value

    def check_parameters(self) -> str:
        """The first parameter that does not parse or is outside its limits, named with what
        it expects, shown under the form ("" when all do)."""
        from normbox_lab.acquire.plan import PlanError

        message = ""
        for key, text in self.parameter_texts().items():
            if key not in self.defaults:
                continue
            try:
                self.check_one(key, text)
            except PlanError as exc:
                message = str(exc)
                break
        line = self.query_one("#param-error", Static)
        line.update(message)
        line.display = bool(message)
        return message

    def parameter_texts(self) -> dict[str, str]:
        return {str(inp.id).removeprefix("param-"): inp.value
                for inp in self.query("#params Input").results(Input)}

    def set_parameter(self, key: str, value: str) -> None:
        self.query_one(f"#param-{key}", Input).value = value

    def log(self, markup: str, detail: str = "") -> None:
        """One line: `markup` (ours) + `detail` (plain: messages and errors from instruments
        may contain brackets)."""
        from rich.text import Text

        line = Text.from_markup(markup)
        if detail:
            line.append(detail)
        self.query_one("#events", RichLog).write(line)

    def set_info(self, text: str) -> None:
        self.query_one("#run-info", Static).update(text)

    def bar(self, done: int, planned: int) -> None:
        self.query_one("#bar", ProgressBar).update(total=max(planned, 1), progress=done)
