"""Tab 2, Run: the protocol, its parameters, the run's state and progress, and its log."""

from __future__ import annotations

import json
import math
from typing import Any

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Input, Label, ProgressBar, RichLog, Select, Static, TabPane

from normbox_lab.core.clock import Clock
from normbox_lab.tui.tabs.common import StopSafeInput


class RunProgress:
    """The run's state and progress as the Run tab shows them, from the engine's events (no
    Textual: the app feeds it with `on_event`, the pane draws `info_markup`).

    The remaining time in a simulated lab is the time one reading takes *while the run
    measures* × the readings left: the preparation (homing), lamp warm-ups, suspensions and
    pauses are one-off waits, kept out of the rate (they made the estimate 10–20× too long);
    the reading under way counts what it has already taken.  No estimate while paused."""

    #: statuses during which a remaining time is shown (none after an abort, a failure, the end,
    #: or while paused: a pause lasts as long as the operator wants)
    ACTIVE = ("running", "suspended", "pausing…")

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
        self.idle_since: float | None = None   # clock s a one-off wait began (None: measuring)
        self.idle_s = 0.0                      # one-off waits of this segment so far
        self.last_reading_active_s = 0.0       # active time at the latest reading
        self.warming = False                   # a lamp warm-up (or suspension) under way
        #: per reading after the segment's first: (the timing model's cost, the time it took).
        #: A reading's time = the person's (not scaled) + the instruments' (the model's cost ×
        #: the time scale): fitted as a + b × cost once three readings tell, so a move or a
        #: darker patch (a longer integration) costs what the model says it does
        self.samples: list[tuple[float, float]] = []
        self.model_remaining_s: float | None = None

    def started(self, done: int, planned: int, lab_remaining_s: float) -> None:
        """A segment starts: the observed rate is measured from here (preparing the
        instruments is a one-off wait, until the first step that is not a lamp warm-up)."""
        self.done, self.planned, self.status = done, planned, "running"
        self.ended = False
        now = self.clock.now_s()
        self.segment_start = (now, done)
        self.lab_remaining_s = lab_remaining_s
        self.idle_since, self.idle_s, self.last_reading_active_s = now, 0.0, 0.0
        self.warming = False
        self.samples = []
        self.model_remaining_s = None

    def progressed(self, done: int, lab_remaining_s: float,
                   model_remaining_s: float | None = None) -> None:
        """A reading was stored; `model_remaining_s`: the timing model's instrument and
        operator time of the readings left (the engine's ``remaining_estimate_s``)."""
        self.done, self.lab_remaining_s = done, lab_remaining_s
        if self.idle_since is not None and not self.warming:
            self.idle_since = None     # measured without a step event: it was no wait
        previous_active_s = self.last_reading_active_s
        self.last_reading_active_s = self.active_s()
        model = None if model_remaining_s is None else float(model_remaining_s)
        if model is not None and math.isnan(model):       # NaN: no model
            model = None
        if model is not None and self.model_remaining_s is not None:
            self.samples.append((self.model_remaining_s - model,
                                 self.last_reading_active_s - previous_active_s))
        self.model_remaining_s = model

    def _wait(self, on: bool) -> None:
        now = self.clock.now_s()
        if on and self.idle_since is None:
            self.idle_since = now
        elif not on and self.idle_since is not None:
            self.idle_s += now - self.idle_since
            self.idle_since = None

    def active_s(self) -> float:
        """Seconds of this segment spent measuring (one-off waits left out)."""
        if self.segment_start is None:
            return 0.0
        now = self.clock.now_s()
        idle = self.idle_s + (now - self.idle_since if self.idle_since is not None else 0.0)
        return max(0.0, now - self.segment_start[0] - idle)

    def on_event(self, kind: str, data: Any) -> None:
        """An engine event's effect on the one-off waits (the app calls it for every event)."""
        if kind == "step-started":
            warm = data.get("kind") == "wait-stable"
            self.warming = warm
            self._wait(warm)
        elif kind == "step-finished" and data.get("kind") == "wait-stable":
            self.warming = False
            self._wait(False)
        elif kind == "suspended":
            self.warming = True
            self._wait(True)
        elif kind == "unsuspended":
            self.warming = False
            self._wait(False)
        elif kind == "paused":
            self._wait(True)
        elif kind == "resumed":
            self._wait(False)

    def remaining_s(self, lab_time_scale: float | None) -> float | None:
        """The estimate in seconds (None: not known yet); see `remaining_text`."""
        if self.status not in self.ACTIVE or self.ended:
            return None
        left = max(0, self.planned - self.done)
        if lab_time_scale is None:
            return self.lab_remaining_s
        done0 = self.segment_start[1] if self.segment_start else self.done
        taken = self.done - done0
        if taken <= 0:
            return None
        if left == 0:
            return 0.0
        under_way_s = self.active_s() - self.last_reading_active_s
        estimate_s = self.last_reading_active_s / taken * left
        fitted = self._fit()
        if fitted is not None and self.model_remaining_s is not None:
            a, b = fitted
            estimate_s = a * left + b * self.model_remaining_s
        return max(estimate_s * (left - 1) / left, estimate_s - under_way_s)

    def _fit(self) -> tuple[float, float] | None:
        """(a, b) of time = a + b × modelled cost over the readings so far; None until three
        readings with different costs tell, or when the fit makes no physical sense."""
        n = len(self.samples)
        if n < 3:
            return None
        mx = sum(m for m, _ in self.samples) / n
        my = sum(t for _, t in self.samples) / n
        var = sum((m - mx) ** 2 for m, _ in self.samples)
        if var <= (0.05 * mx) ** 2 * n:
            return None
        b = sum((m - mx) * (t - my) for m, t in self.samples) / var
        a = my - b * mx
        if a < 0 or b < 0:
            return None
        return a, b

    def remaining_text(self, lab_time_scale: float | None) -> str:
        """"remaining 0:04:10 · done ≈ 14:32" while a run goes; "" when none does (paused,
        after an abort or the end no estimate is shown).  On a real clock (`lab_time_scale`
        None) the remaining time is the engine's timing model (instrument and operator time);
        on a virtual clock (a simulated lab) it is the observed time per reading on the
        console's clock, one-off waits left out, × the readings left, since the lab clock says
        nothing about how long a person waits."""
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
        params = VerticalScroll(id="params")
        params.can_focus = False           # no invisible Tab stop before the first field
        yield params
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
            # compact JSON: the 24 patch numbers fit an 80-column field
            text = prefill.get(k, v if isinstance(v, str) else json.dumps(v, separators=(
                ", ", ": ") if not isinstance(v, list) or len(json.dumps(v)) < 56 else (",", ":")))
            label = Label(k)
            label.styles.width = width - 1
            field = StopSafeInput(text, id=f"param-{k}", compact=True,
                                  validators=[check(k, v)], validate_on=["changed"])
            box.mount(Horizontal(label, field, classes="param"))

    def on_input_changed(self, event: Input.Changed) -> None:
        if str(event.input.id or "").startswith("param-"):
            self.check_parameters()

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

    def scroll_log_end(self) -> None:
        log = self.query_one("#events", RichLog)
        log.call_after_refresh(log.scroll_end, animate=False)

    def set_info(self, text: str) -> None:
        self.query_one("#run-info", Static).update(text)

    def bar(self, done: int, planned: int) -> None:
        self.query_one("#bar", ProgressBar).update(total=max(planned, 1), progress=done)
