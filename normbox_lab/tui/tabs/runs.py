"""Tab 4, Runs: the store's runs (status, readings, flags) and the selected run's readings."""

from __future__ import annotations

from typing import Any

from textual import on
from textual.widgets import DataTable, TabPane

from normbox_lab.tui.tabs.common import table


class RunsPane(TabPane):
    DEFAULT_CSS = """
    #runs-table { height: 1fr; }
    #readings-table { height: 1fr; }
    """

    def __init__(self) -> None:
        super().__init__("4 Runs", id="runs")
        self._readings_shown: tuple[int, int] | None = None

    def build(self) -> None:
        self.mount_all([
            table("runs-table", ("id", "uuid", "protocol", "status", "readings", "flags",
                                 "created"), cursor_type="row", zebra_stripes=True),
            table("readings-table", ("key", "angle°", "patch", "Lv cd/m²", "x", "y", "t_int s"),
                  cursor_type="row", zebra_stripes=True)])

    @property
    def store(self) -> Any:
        return self.app.session.store

    def refresh_runs(self) -> None:
        from normbox_lab.analyze import qa
        from normbox_lab.tui.views import run_row

        tab = self.query_one("#runs-table", DataTable)
        selected = self.selected_run_id()
        tab.clear()
        runs = self.store.runs()
        flags = qa.summaries_by_run(self.store)
        for r in runs:
            tab.add_row(*run_row(r, flags.get(r.id)), key=str(r.id))
        if runs:
            ids = [r.id for r in runs]
            row = ids.index(selected) if selected in ids else len(ids) - 1
            tab.move_cursor(row=row)
            self.show_readings(ids[row])

    def selected_run_id(self) -> int | None:
        tab = self.query_one("#runs-table", DataTable)
        if tab.row_count == 0:
            return None
        try:
            key = tab.coordinate_to_cell_key((tab.cursor_row, 0)).row_key
        except Exception:  # noqa: BLE001 - no valid cursor
            return None
        return int(str(key.value)) if key.value is not None else None

    @on(DataTable.RowHighlighted, "#runs-table")
    def _run_highlighted(self, event: DataTable.RowHighlighted) -> None:
        if event.row_key.value is not None:
            self.show_readings(int(str(event.row_key.value)))

    def show_readings(self, run_id: int) -> None:
        from normbox_lab.tui.views import reading_row

        tab = self.query_one("#readings-table", DataTable)
        if self._readings_shown == (run_id, self.store.get_run(run_id).done):
            return
        tab.clear()
        for r in self.store.readings(run_id):
            tab.add_row(*reading_row(r))
        self._readings_shown = (run_id, tab.row_count)
