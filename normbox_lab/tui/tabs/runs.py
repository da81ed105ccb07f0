"""Tab 4, Runs: the store's runs (status, readings, flags) and the selected run's readings
(geometry, Lv, flags each).  Enter on a run shows its event log, Enter on a reading its
spectrum."""

from __future__ import annotations

from typing import Any

from textual import on, work
from textual.widgets import DataTable, TabPane

from normbox_lab.tui.tabs.common import RUN_COLUMNS, plain, table

#: the Runs table's (and the resume offer's) columns: `views.run_row`


class RunsPane(TabPane):
    DEFAULT_CSS = """
    #runs-table { height: 1fr; }
    #readings-table { height: 1fr; }
    """

    def __init__(self) -> None:
        super().__init__("4 Runs", id="runs")
        self._readings_shown: tuple[int, int] | None = None
        self.shown_run_id: int | None = None

    def build(self) -> None:
        self.mount_all([
            table("runs-table", RUN_COLUMNS, cursor_type="row", zebra_stripes=True),
            table("readings-table", ("key", "geometry", "patch", "Lv cd/m²", "x", "y",
                                     "t_int s", "flags"),
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
        runs = self.app.session.runs()          # a run whose owner died: interrupted
        flags = qa.summaries_by_run(self.store)
        for r in runs:
            tab.add_row(*plain(run_row(r, flags.get(r.id))), key=str(r.id))
        if runs:
            ids = [r.id for r in runs]
            row = ids.index(selected) if selected in ids else len(ids) - 1
            tab.move_cursor(row=row)
            self.show_readings(ids[row])

    def export_selected(self) -> None:
        """e: the selected run as CSV (in a worker), `run-ID-PROTOCOL.csv` in the working
        directory."""
        run_id = self.selected_run_id()
        if run_id is None:
            self.app.notify("select a run in the Runs tab (4) first")
            return
        self._export(run_id)

    @work(thread=True, group="export")
    def _export(self, run_id: int) -> None:
        from normbox_lab.acquire.export import export_run

        app: Any = self.app
        try:
            path = export_run(app.session.open_store(), run_id, "csv")
        except Exception as exc:  # noqa: BLE001 - shown to the operator, the console stays up
            app.call_from_thread(app.notify, f"export failed: {exc}", severity="error",
                                 markup=False)
            return
        app.call_from_thread(app.notify, f"exported run {run_id} → {path}", markup=False)
        app.call_from_thread(app._log, "", f"exported run {run_id} → {path}")

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
        # an empty table highlights no row (row_key None): the random operator's find
        if event.row_key is not None and event.row_key.value is not None:
            self.show_readings(int(str(event.row_key.value)))

    def show_readings(self, run_id: int) -> None:
        from normbox_lab.analyze import qa
        from normbox_lab.tui.views import reading_row

        tab = self.query_one("#readings-table", DataTable)
        if self._readings_shown == (run_id, self.store.get_run(run_id).done):
            return
        tab.clear()
        by_key: dict[str, list] = {}
        for f in qa.flags(self.store, run_id):
            if f.key:
                by_key.setdefault(f.key, []).append(f)
        for r in self.store.readings(run_id):
            tab.add_row(*plain(reading_row(r, by_key.get(r.key, ()))), key=r.key)
        self._readings_shown = (run_id, tab.row_count)
        self.shown_run_id = run_id

    @on(DataTable.RowSelected, "#runs-table")
    def _run_selected(self, event: DataTable.RowSelected) -> None:
        """Enter on a run: its event log."""
        from normbox_lab.tui.screens import DrillScreen
        from normbox_lab.tui.views import event_lines

        if event.row_key is None or event.row_key.value is None:
            return
        run = self.store.get_run(int(str(event.row_key.value)))
        lines = [(f"run {run.id} {run.uuid[:8]} {run.protocol}: {run.status}, "
                  f"{run.done}/{run.planned} readings — event log")]
        self.app.push_screen(DrillScreen(lines + event_lines(self.store.events(run.id))))

    @on(DataTable.RowSelected, "#readings-table")
    def _reading_selected(self, event: DataTable.RowSelected) -> None:
        """Enter on a reading: its spectrum, what it is, and its flags."""
        from normbox_lab.analyze import qa
        from normbox_lab.tui.screens import SpectrumScreen
        from normbox_lab.tui.views import geometry_text, luminance_text

        run_id = self.shown_run_id
        if run_id is None or event.row_key is None or event.row_key.value is None:
            return
        key = str(event.row_key.value)
        r = self.store.reading(run_id, key)
        if "brdf_per_sr" in r.arrays:
            values, title = r.arrays["brdf_per_sr"], "BRDF sr⁻¹"
        else:
            values = r.arrays.get("radiance_W_sr_m2_nm")
            title = "spectral radiance W·sr⁻¹·m⁻²·nm⁻¹"
        if values is None:
            return
        colo = r.metadata.get("colorimetry") or {}
        flags = [f for f in qa.flags(self.store, run_id) if f.key == key]
        head = (f"run {run_id} · {key} · {geometry_text(r.metadata)} · patch "
                f"{r.metadata.get('patch', r.metadata.get('material', '-'))} · Lv "
                f"{luminance_text(colo.get('Lv_cd_m2'))} cd/m²\n"
                + ("flags: " + "; ".join(f"{f.severity} {f.gate}: {f.message}" for f in flags)
                   if flags else "no flags"))
        self.app.push_screen(SpectrumScreen(head, r.arrays["wavelength_nm"], values, title))
