"""Tab 2, Run: the protocol, its parameters, the run's state and progress, and its log."""

from __future__ import annotations

import json
from typing import Any

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Input, Label, ProgressBar, RichLog, Select, Static, TabPane


class RunPane(TabPane):
    DEFAULT_CSS = """
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
    """

    def __init__(self, protocol: str) -> None:
        super().__init__("2 Run", id="run")
        self.protocol = protocol

    def compose(self) -> ComposeResult:
        with Horizontal(id="run-top"):
            # the protocol list (engine import) and parameters load after first paint
            yield Select([(self.protocol, self.protocol)], value=self.protocol,
                         allow_blank=False, compact=True, type_to_search=False, id="protocol")
            yield Label("  parameters: JSON values · s start · d dry-run", id="run-hint")
        yield VerticalScroll(id="params")
        yield Static("idle", id="run-info")
        with Horizontal(id="progress"):
            yield ProgressBar(total=1, show_eta=False, id="bar")
        yield RichLog(id="events", max_lines=500, wrap=False, markup=True)

    def set_protocols(self, names: list[str], current: str) -> None:
        select = self.query_one("#protocol", Select)
        with select.prevent(Select.Changed):
            select.set_options([(n, n) for n in names])
            select.value = current

    def show_params(self, params: dict[str, Any] | Exception,
                    prefill: dict[str, str]) -> None:
        """One line per parameter (JSON text, as `--param K=V` takes it), or the error of a
        protocol file that cannot be read."""
        box = self.query_one("#params", VerticalScroll)
        box.remove_children()
        if isinstance(params, Exception):
            box.mount(Label(f"[red]{params}[/]"))
            return
        for k, v in params.items():
            text = prefill.get(k, v if isinstance(v, str) else json.dumps(v))
            box.mount(Horizontal(Label(k), Input(text, id=f"param-{k}", compact=True),
                                 classes="param"))

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
