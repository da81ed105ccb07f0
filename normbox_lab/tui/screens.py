"""The console's modal screens: operator / fault prompts, the resume offer at start, and the
Results tab's per-patch drill-down."""

from __future__ import annotations

from typing import Any, ClassVar

from textual import on
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Button, DataTable, Label, Static

#: what a prompt that steps aside (to let the operator look at another tab) returns
HIDDEN = "<hidden>"


class PromptScreen(ModalScreen[str]):
    """An operator or fault prompt.  Enter = the first choice (ok / retry)."""

    AUTO_FOCUS = "*"

    BINDINGS: ClassVar = [Binding("enter", "choose(0)", "answer", show=True),
                          Binding("r", "pick('retry')", "retry", show=False),
                          Binding("s", "pick('skip')", "skip", show=False),
                          Binding("a", "pick('abort')", "abort", show=False),
                          Binding("p", "app.pause_resume", "pause", show=False),
                          Binding("q", "app.quit_console", "quit", show=False),
                          # look at another tab: the prompt steps aside and keeps waiting
                          # (2 or w brings it back)
                          *[Binding(str(k), f"look('{t}')", t, show=False) for k, t in
                            ((1, "instruments"), (3, "spectrum"), (4, "runs"), (5, "results"),
                             (6, "images"))],
                          # 2 / w over another tab: the Run tab under the prompt (it stays)
                          Binding("2,w", "run_tab", "run", show=False)]
    #: bottom of the screen, above the footer: the Run tab's progress line stays in view
    DEFAULT_CSS = """
    PromptScreen { align: center bottom; }
    PromptScreen > Vertical { margin-bottom: 1; }
    PromptScreen > Vertical { width: 90%; max-width: 120; height: auto; border: thick $accent; padding: 0 1;
                              background: $panel; }
    PromptScreen.fault > Vertical { border: thick $error; }
    PromptScreen Horizontal { height: auto; }
    PromptScreen Button { margin: 0 1 0 0; }
    /* toasts at the top while a prompt waits at the bottom: they never cover its text */
    PromptScreen ToastRack { dock: top; align: right top; }
    """

    def __init__(self, request: Any) -> None:
        super().__init__(classes="fault" if request.kind == "fault" else "")
        self.request = request
        self.look_tab: str | None = None       # the tab to show when it steps aside

    def compose(self) -> ComposeResult:
        req = self.request
        title = "Fault" if req.kind == "fault" else "Operator"
        keys = {"retry": "r retry", "skip": "s skip this reading", "abort": "a abort"}
        hint = (" · ".join(keys[c] for c in req.choices if c in keys) + " · Enter retry"
                if req.kind == "fault"
                else "Enter done · p pause after this reading · a abort · 1–6 look (w back)")
        with Vertical():
            yield Label(f"[b]{title}[/b]  {req.key}")
            yield Static(prompt_text(req), id="prompt-message")
            yield Static(f"[dim]{hint}[/dim]", id="prompt-hint")    # wraps, never cut
            with Horizontal():
                for i, c in enumerate(req.choices):
                    yield Button(c, id=f"choice-{c}", compact=True,
                                 variant="primary" if i == 0 else
                                 ("error" if c == "abort" else "default"))

    def action_look(self, tab: str) -> None:
        """Step aside (the prompt keeps waiting) and show another tab — once the prompt has
        gone (the app switches after the screen below has its focus back: switching first,
        the focus given back to a table of the old tab would switch the tabs back)."""
        self.look_tab = tab
        self.dismiss(HIDDEN)

    def action_run_tab(self) -> None:
        """2 or w while the prompt is shown over another tab: the Run tab (its progress and
        log) comes under the prompt, which keeps waiting in front."""
        from textual.widgets import TabbedContent

        base = self.app.screen_stack[0]
        base.query_one(TabbedContent).active = "run"

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

    AUTO_FOCUS = "*"

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
        from normbox_lab.tui.tabs.common import RUN_COLUMNS, plain
        from normbox_lab.tui.views import run_row

        with Vertical():
            yield Label(f"[b]{len(self.runs)} interrupted run(s)[/b] in the store. Resume one?")
            table: DataTable = DataTable(id="resume-table", cursor_type="row")
            table.add_columns(*RUN_COLUMNS)
            for r in reversed(self.runs):
                table.add_row(*plain(run_row(r)), key=str(r.id))
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
    """Lines of text in a scrollable box: the Results heat map's per-patch drill-down, a
    run's event log."""

    AUTO_FOCUS = "*"

    BINDINGS: ClassVar = [Binding("escape,enter,q", "close", "close")]
    DEFAULT_CSS = """
    DrillScreen { align: center middle; }
    DrillScreen > VerticalScroll { width: 95%; max-width: 120; height: auto; max-height: 90%;
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


class SpectrumScreen(ModalScreen[None]):
    """One stored reading: its spectrum (radiance or BRDF) with what it is and its flags."""

    AUTO_FOCUS = "*"

    BINDINGS: ClassVar = [Binding("escape,enter,q", "close", "close")]
    DEFAULT_CSS = """
    SpectrumScreen { align: center middle; }
    SpectrumScreen > Vertical { width: 90%; height: 80%; border: thick $accent;
                                background: $panel; }
    SpectrumScreen #reading-head { height: auto; padding: 0 1; }
    """

    def __init__(self, head: str, wavelength_nm: Any, values: Any, title: str) -> None:
        super().__init__()
        self.head, self.wavelength_nm, self.values, self.title = head, wavelength_nm, values, title

    def compose(self) -> ComposeResult:
        from textual_plotext import PlotextPlot

        with Vertical():
            yield Static(self.head, id="reading-head")
            yield PlotextPlot(id="reading-plot")
            yield Label("[dim]Esc / Enter: close[/dim]")

    def on_mount(self) -> None:
        from textual_plotext import PlotextPlot

        plot = self.query_one("#reading-plot", PlotextPlot)
        plt = plot.plt
        plt.title(self.title)
        plt.xlabel("wavelength nm")
        step = max(1, len(self.wavelength_nm) // 100)
        plt.plot(list(self.wavelength_nm[::step]), list(self.values[::step]), marker="braille",
                 color="cyan")

    def action_close(self) -> None:
        self.dismiss(None)


class NumberScreen(ModalScreen[float | None]):
    """Ask for one number (go to angle, lamp level): Enter takes it, Esc cancels; a value that
    is not a number or out of range is refused in place, naming the range."""

    AUTO_FOCUS = "*"

    BINDINGS: ClassVar = [Binding("escape", "cancel", "cancel")]
    DEFAULT_CSS = """
    NumberScreen { align: center middle; }
    NumberScreen > Vertical { width: 60; height: auto; border: thick $accent; padding: 0 1;
                              background: $panel; }
    NumberScreen #number-error { color: $error; height: auto; }
    NumberScreen #number-title { width: 100%; height: auto; }
    """

    def __init__(self, question: str, low: float, high: float, value: float | None = None
                 ) -> None:
        super().__init__()
        self.question, self.low, self.high, self.value = question, low, high, value

    def compose(self) -> ComposeResult:
        from normbox_lab.tui.tabs.common import StopSafeInput

        with Vertical():
            # a Static wraps: the question and its range are never cut at 80 columns
            yield Static(f"{self.question}: {self.low:g} … {self.high:g}", id="number-title")
            yield StopSafeInput("" if self.value is None else f"{self.value:g}", id="number")
            yield Static("", id="number-error")
            yield Label("[dim]Enter: go · Esc: cancel[/dim]")

    def on_mount(self) -> None:
        from textual.widgets import Input

        self.query_one("#number", Input).focus()

    def on_input_submitted(self, event: Any) -> None:
        from textual.content import Content

        from normbox_lab.acquire.params import Number, ParameterError, read

        try:
            value = float(read(str(event.value), Number(self.low, self.high), "value"))
        except ParameterError as exc:       # the same parser as --param and the form
            # its text: the refusal quotes what was typed, which is no markup
            self.query_one("#number-error", Static).update(
                Content(str(exc).removeprefix("value: ")))
            return
        self.dismiss(value)

    def action_cancel(self) -> None:
        self.dismiss(None)

