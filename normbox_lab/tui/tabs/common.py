"""Small pieces shared by the tab panes."""

from __future__ import annotations

from typing import Any

from textual.widgets import DataTable, Input

#: the columns of a run's row (`views.run_row`): the Runs tab and the resume offer
RUN_COLUMNS = ("id", "protocol", "status", "readings", "flags", "created")


def table(wid: str, columns: tuple[str, ...], **kw: Any) -> DataTable:
    """A DataTable with these columns."""
    t: DataTable = DataTable(id=wid, **kw)
    t.add_columns(*columns)
    return t


class StopSafeInput(Input):
    """A text field that leaves `x` to the emergency stop: Textual skips even a priority
    binding for a key the focused widget would consume (a printable one in an Input)."""

    def check_consume_key(self, key: str, character: str | None) -> bool:
        return key != "x" and super().check_consume_key(key, character)

    def on_mount(self) -> None:
        self.cursor_position = 0          # a long value shows its beginning, not its end

    def on_blur(self) -> None:
        self.cursor_position = 0
