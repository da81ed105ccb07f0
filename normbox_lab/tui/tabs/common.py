"""Small pieces shared by the tab panes."""

from __future__ import annotations

from typing import Any

from textual.widgets import DataTable, Input

#: the columns of a run's row (`views.run_row`): the Runs tab and the resume offer
RUN_COLUMNS = ("id", "protocol", "status", "readings", "flags", "created")


def plain(cells: Any) -> list[Any]:
    """A table row's text cells as text (a DataTable reads a str cell as markup: the protocol
    file ``sweep[b]v2[i].py`` was listed as "sweepv2.py" in bold italics)."""
    from rich.text import Text

    return [Text(c) if isinstance(c, str) else c for c in cells]


def table(wid: str, columns: tuple[str, ...], **kw: Any) -> DataTable:
    """A DataTable with these columns."""
    t: DataTable = DataTable(id=wid, **kw)
    t.add_columns(*columns)
    return t


class StopSafeInput(Input):
    """A text field whose keys are its own: `x` typed (or pasted) here is text, never the
    emergency stop (2000 pasted x's queued 2000 stops); Ctrl+X stops from a field (a priority
    binding: Textual checks it before the field), Esc leaves the field and x stops."""

    def on_mount(self) -> None:
        self.cursor_position = 0          # a long value shows its beginning, not its end

    def on_blur(self) -> None:
        self.cursor_position = 0
