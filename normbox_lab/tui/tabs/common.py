"""Small pieces shared by the tab panes."""

from __future__ import annotations

from typing import Any

from textual.widgets import DataTable


def table(wid: str, columns: tuple[str, ...], **kw: Any) -> DataTable:
    """A DataTable with these columns."""
    t: DataTable = DataTable(id=wid, **kw)
    t.add_columns(*columns)
    return t
