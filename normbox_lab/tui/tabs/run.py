"""Tab 2, Run: the protocol, its parameters, the run's state and progress, and its log."""

from __future__ import annotations

import json
import math
from typing import Any

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.content import Content
from textual.widgets import Input, Label, ProgressBar, RichLog, Select, Static, TabPane

from normbox_lab.core.clock import Clock
from normbox_lab.tui.tabs.common import StopSafeInput


class RunProgress:
    """The run's state and progress as the Run tab shows them, from the engine's events (no
    Textual: the app feeds it with `on_event`, the pane draws `info_markup`).

    The remaining time in a simulated lab is `normbox_lab.acquire.estimate.RemainingTime`:
    the instruments' time from the timing model × the time scale (+ the overhead the readings
    after the first show; the first reading's one-off costs kept out), plus the operator's
    measured answer time × the prompts left.  Preparation, lamp warm-ups, suspensions and
    pauses are one-off waits.  The reading under way counts down.  No estimate while paused."""

    #: statuses during which a remaining time is shown (none after an abort, a failure, the end,
    #: or while paused: a pause lasts as long as the operator wants)
    ACTIVE = ("running", "suspended", "pausing…")

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.status = "idle"
        self.done = 0
        self.planned = 0
        self.step = ""
        self.lab_remaining_s: float | None = None             # the engine's timing model
        #: the segment has ended (also `paused`: an emergency stop, a quit): nothing to estimate
        self.ended = False
        self.warming = False                   # a lamp warm-up (or suspension) under way
        self.paused = False
        #: made at the first start (its module imports the engine's plan: not before the
        #: console's first paint)
        self.estimator: Any = None

    @staticmethod
    def _model(data: Any) -> tuple[float | None, int | None]:
        """(the model's instrument lab seconds left, the prompts left) of an event."""
        if not isinstance(data, dict) or "remaining_model_s" not in data:
            return None, None
        try:
            model = float(data["remaining_model_s"])
            prompts = int(data.get("prompts_left", 0))
            model -= prompts * float(data.get("prompt_model_s", 0.0) or 0.0)
        except (TypeError, ValueError):
            return None, None
        return (max(0.0, model) if math.isfinite(model) else None), prompts

    def started(self, done: int, planned: int, lab_remaining_s: float,
                data: Any = None) -> None:
        """A segment starts (`data`: the run-started event's, with the time model)."""
        self.done, self.planned, self.status = done, planned, "running"
        self.ended = False
        self.lab_remaining_s = lab_remaining_s
        self.warming = self.paused = False
        model, prompts = self._model(data)
        if self.estimator is None:
            from normbox_lab.acquire.estimate import RemainingTime

            self.estimator = RemainingTime()
        self.estimator.start(self.clock.now_s(), model, prompts)

    def progressed(self, done: int, lab_remaining_s: float,
                   model_remaining_s: float | None = None, data: Any = None) -> None:
        """A reading was stored (`data`: the progress event's, with the time model)."""
        count = done - self.done
        self.done, self.lab_remaining_s = done, lab_remaining_s
        if self.estimator is None:
            return
        now = self.clock.now_s()
        if not self.warming and not self.paused:
            self.estimator.was_active()          # measured without a step event: no wait
        model, prompts = self._model(data)
        if model is None and model_remaining_s is not None:
            m = float(model_remaining_s)
            model = m if math.isfinite(m) else None
        self.estimator.reading(now, model, prompts, count)

    def on_event(self, kind: str, data: Any) -> None:
        """An engine event's effect on the estimate (the app calls it for every event)."""
        now = self.clock.now_s()
        est = self.estimator
        if est is None:
            return
        if kind == "step-started":
            self.warming = data.get("kind") == "wait-stable"
            est.set_active(now, not self.warming and not self.paused)
        elif kind == "step-finished" and data.get("kind") == "wait-stable":
            self.warming = False
            est.set_active(now, not self.paused)
        elif kind == "suspended":
            self.warming = True
            est.set_active(now, False)
        elif kind == "unsuspended":
            self.warming = False
            est.set_active(now, not self.paused)
        elif kind == "paused":
            self.paused = True
            est.set_active(now, False)
        elif kind == "resumed":
            self.paused = False
            est.set_active(now, not self.warming)
        elif kind == "prompt":
            est.prompt(now)
        elif kind == "answer":
            est.answered(now)

    def remaining_s(self, lab_time_scale: float | None) -> float | None:
        """The estimate in seconds (None: not known yet); see `remaining_text`."""
        if self.status not in self.ACTIVE or self.ended:
            return None
        if lab_time_scale is None:
            return self.lab_remaining_s
        if self.estimator is None:
            return None
        return self.estimator.remaining_s(self.clock.now_s(), lab_time_scale,
                                          max(0, self.planned - self.done))

    def remaining_text(self, lab_time_scale: float | None) -> str:
        """"remaining 0:04:10 · done ≈ 14:32" while a run goes; "" when none does (paused,
        after an abort or the end no estimate is shown).  On a real clock (`lab_time_scale`
        None) the remaining time is the engine's timing model (instrument and operator time);
        on a virtual clock (a simulated lab) it is `RemainingTime` on the console's clock
        (the model × the time scale, the operator's measured answer time), since the lab clock
        says nothing about how long a person waits."""
        import datetime

        from normbox_lab.acquire.estimate import format_duration

        if self.status not in self.ACTIVE or self.ended:
            return ""
        remaining_s = self.remaining_s(lab_time_scale)
        if remaining_s is None or math.isnan(remaining_s):
            return ("remaining: measuring… (lamp warming up)" if self.warming
                    else "remaining: measuring…")
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
    #params { height: auto; min-height: 3; max-height: 45vh;
              border: round $surface-lighten-2; }
    .param { height: 1; }
    .param Input { width: 1fr; }
    /* the field being typed in is plain to see (it was background 235 on 234) */
    .param Input:focus { background: $accent 45%; text-style: bold; }
    .param:focus-within Label { background: $accent; color: $text; text-style: bold; }
    .param Input.-invalid { color: $error; }
    #param-error { height: auto; color: $error; padding: 0 1; }
    #run-info { height: auto; max-height: 4; padding: 0 1; }
    #progress { height: 1; padding: 0 1; }
    #progress Bar { width: 1fr; }
    #events { height: 1fr; }
    /* the faces of the protocol Select and of the empty log until they are mounted right
       after the first paint, drawn as they draw (a layout: Textual draws a scroll bar only
       for a widget with a layout or children) */
    #protocol-face { width: 26; padding: 0 1 0 0; background: $surface; }
    #events-face { height: 1fr; background: $surface; overflow-y: scroll; layout: vertical; }
    """

    def __init__(self, protocol: str) -> None:
        super().__init__("2 Run", id="run")
        self.protocol = protocol
        self.defaults: dict[str, Any] = {}
        self.limits: dict[str, Any] = {}
        self.config: Any = None

    def compose(self) -> ComposeResult:
        with Horizontal(id="run-top"):
            # the protocol as the compact Select shows it: the Select (with its option list, a
            # scroll view of its own styles, hidden until opened: about a fifth of the CPU
            # from the start of the app to its first frame) is mounted with the protocol list
            # (engine import) after the first paint, as are the parameters
            yield Static(self.face(self.protocol), id="protocol-face")
            yield Label("  parameters: JSON values · s start · d dry-run", id="run-hint")
        params = VerticalScroll(id="params")
        params.can_focus = False           # no invisible Tab stop before the first field
        yield params
        yield Static("", id="param-error")
        yield Static("idle", id="run-info")
        with Horizontal(id="progress"):
            yield ProgressBar(total=1, show_eta=False, id="bar")
        # the event log is empty before the first paint: its face (the same background and
        # scroll bar) until `build` mounts it right after the paint
        yield Static("", id="events-face")

    def build(self) -> None:
        """The event log in place of its face (right after the first paint, before anything
        is logged)."""
        for face in self.query("#events-face"):
            self.mount(RichLog(id="events", max_lines=500, wrap=True, markup=True),
                       before=face)
            face.remove()

    @staticmethod
    def face(protocol: str) -> str:
        """The protocol's name as the compact Select draws it: the name, the arrow at the
        Select's 25th column."""
        from textual.markup import escape

        name = protocol if len(protocol) <= 23 else protocol[:22] + "…"
        return f"{escape(f'{name:<24}')}[$foreground 50%]▼[/]"

    def set_protocols(self, names: list[str], current: str) -> None:
        """The protocol list: the Select takes the place of its face (the first call, right
        after the first paint), or gets the new list and value."""
        options = [(Content(n), n) for n in names]      # a file's name as named, no markup
        for face in self.query("#protocol-face"):
            self.query_one("#run-top", Horizontal).mount(
                Select(options, value=current, allow_blank=False, compact=True,
                       type_to_search=False, id="protocol"), before=face)
            face.remove()
            return
        select = self.query_one("#protocol", Select)
        if not select.is_mounted:           # mounted by the call before, not composed yet
            self.call_after_refresh(self.set_protocols, names, current)
            return
        with select.prevent(Select.Changed):
            select.set_options(options)
            select.value = current

    def show_params(self, params: dict[str, Any] | Exception,
                    prefill: dict[str, str], limits: dict[str, Any] | None = None,
                    config: Any = None) -> None:
        """One line per parameter (JSON text, as `--param K=V` takes it), each checked as it
        is typed against its default's kind and the protocol's declared limits (`limits`,
        angle ranges from the lab `config`); or the error of a protocol file that cannot be
        read.  Labels are as wide as the longest name."""
        box = self.query_one("#params", VerticalScroll)
        box.remove_children()
        self.query_one("#param-error", Static).update("")
        self.query_one("#param-error", Static).display = False
        if isinstance(params, Exception):
            box.mount(Label(Content.styled(str(params), "red")))    # names a typed path
            return
        width = max((len(k) for k in params), default=8) + 2
        self.defaults = dict(params)

        self.limits, self.config = dict(limits or {}), config

        for k, v in params.items():
            # compact JSON: the 24 patch numbers fit an 80-column field
            text = prefill.get(k, v if isinstance(v, str) else json.dumps(v, separators=(
                ", ", ": ") if not isinstance(v, list) or len(json.dumps(v)) < 56 else (",", ":")))
            label = Label(k)
            label.styles.width = width - 1
            field = StopSafeInput(text, id=f"param-{k}", compact=True)
            box.mount(Horizontal(label, field, classes="param"))

    #: seconds after the last key before the form is checked (checked per key, 2000 keys of
    #: a paste took 17 s: every key parsed every field)
    FORM_CHECK_S = 0.15
    #: checks of the whole form so far (tests: a paste, or a burst of keys, is one check)
    form_checks = 0

    def on_input_changed(self, event: Input.Changed) -> None:
        if str(event.input.id or "").startswith("param-"):
            timer = getattr(self, "_check_timer", None)
            if timer is not None:
                timer.stop()
            self._check_timer = self.set_timer(self.FORM_CHECK_S, self.check_parameters)

    def check_one(self, key: str, text: str) -> Any:
        """The value of one field: parsed like its default, then checked against the
        protocol's declared limits (the other fields as typed, or their defaults)."""
        from normbox_lab.acquire.params import check_parameters
        from normbox_lab.acquire.plan import PlanError, coerce_param

        value = coerce_param(self.defaults[key], text, key, self.limits.get(key))
        if key in self.limits:
            others = dict(self.defaults)
            for k, t in self.parameter_texts().items():
                if k != key and k in self.defaults:
                    try:
                        others[k] = coerce_param(self.defaults[k], t, k, self.limits.get(k))
                    except PlanError:
                        pass
            others[key] = value
            check_parameters(self.limits, others, self.config, only=key)
        return value

    def check_parameters(self) -> str:
        """The first parameter that does not parse or is outside its limits, named with what
        it expects, shown under the form ("" when all do)."""
        from normbox_lab.acquire.plan import PlanError

        self.form_checks += 1
        message = ""
        for inp in self.query("#params Input").results(Input):
            key = str(inp.id).removeprefix("param-")
            if key not in self.defaults:
                continue
            try:
                self.check_one(key, inp.value)
                inp.set_class(False, "-invalid")
            except PlanError as exc:
                message = message or str(exc)     # the first bad field, named
                inp.set_class(True, "-invalid")
        line = self.query_one("#param-error", Static)
        line.update(Content(message))        # its text: it quotes what was typed (no markup)
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

    def scroll_log_end(self) -> None:
        log = self.query_one("#events", RichLog)
        log.call_after_refresh(log.scroll_end, animate=False)

    def set_info(self, text: str) -> None:
        self.query_one("#run-info", Static).update(text)

    def bar(self, done: int, planned: int) -> None:
        self.query_one("#bar", ProgressBar).update(total=max(planned, 1), progress=done)
