"""Tab 5, Results: the latest comparison as a ΔE00 heat map (patches × angles, the paper's
rating scale) with the NRMSE per angle; a cell shows its patch's summary, Enter drills down."""

from __future__ import annotations

from typing import Any

from textual import on
from textual.widgets import DataTable, Static, TabPane

from normbox_lab.acquire.store_api import Store
from normbox_lab.tui.screens import DrillScreen


class ResultsPane(TabPane):
    DEFAULT_CSS = """
    #res-head { height: 2; padding: 0 1; }
    #heatmap { height: 1fr; }
    #drill { height: 1; padding: 0 1; }
    """

    def __init__(self) -> None:
        super().__init__("5 Results", id="results")
        self.heatmap: Any = None

    def build(self) -> None:
        self.mount_all([
            Static("no comparison in the store yet (normbox-lab compare …)", id="res-head"),
            DataTable(id="heatmap", cursor_type="cell", fixed_columns=1),
            Static("", id="drill")])

    def refresh_from(self, store: Store) -> None:
        """Show the store's latest comparison, if it is not the one shown."""
        from normbox_lab.tui.views import latest_heatmap

        hm = latest_heatmap(store)
        if hm is None or (self.heatmap is not None
                          and self.heatmap.artifact_id == hm.artifact_id):
            return
        self.show_heatmap(hm)

    def show_heatmap(self, hm: Any) -> None:
        from rich.text import Text

        from normbox_lab.tui.views import RATING_STYLES, rating_class

        self.heatmap = hm
        counts = hm.counts()
        legend = Text()
        for (style, label), n in zip(RATING_STYLES, counts, strict=True):
            legend.append(f"{label} ({n})", style=style)
            legend.append(" ")
        head = Text(f"comparison {hm.name!r} (artifact {hm.artifact_id}"
                    f"{'' if hm.run_id is None else f', run {hm.run_id}'}) · "
                    f"mean ΔE00 {float(hm.delta_e00.mean()):.2f}\n")
        head.append_text(legend)
        self.query_one("#res-head", Static).update(head)
        tab = self.query_one("#heatmap", DataTable)
        tab.clear(columns=True)
        tab.add_column("patch", key="patch")
        for a in hm.angle_deg:
            tab.add_column(f"{a:g}°", key=f"{a:g}")
        # names as long as the terminal allows (13 characters at 80 columns)
        room = max(13, self.app.size.width - 6 * int(hm.angle_deg.size) - 6)
        for i, name in enumerate(hm.patch_names):
            cells: list[Any] = [Text(name if len(name) <= room else name[:room - 1] + "…")]
            for j in range(hm.angle_deg.size):
                de = float(hm.delta_e00[i, j])
                cells.append(Text(f"{de:4.1f}", style=RATING_STYLES[rating_class(de)][0]))
            tab.add_row(*cells, key=f"p{i}")
        tab.add_row(Text("NRMSE %", style="bold"),
                    *[Text(f"{100 * v:4.1f}", style="bold") for v in hm.nrmse_per_angle],
                    key="nrmse")
        self.drill(0)

    @on(DataTable.CellSelected, "#heatmap")
    def _cell_selected(self, event: DataTable.CellSelected) -> None:
        hm = self.heatmap
        if hm is not None and 0 <= event.coordinate.row < len(hm.patch_names):
            self.app.push_screen(DrillScreen(hm.drill_down(event.coordinate.row)))

    @on(DataTable.CellHighlighted, "#heatmap")
    def _cell(self, event: DataTable.CellHighlighted) -> None:
        self.drill(event.coordinate.row)

    def drill(self, row: int) -> None:
        hm = self.heatmap
        if hm is None:
            return
        drill = self.query_one("#drill", Static)
        if 0 <= row < len(hm.patch_names):
            drill.update(hm.summary(row))
        else:
            drill.update("NRMSE per angle (mean over patches): " + ", ".join(
                f"{a:g}° {100 * v:.1f}%" for a, v in zip(hm.angle_deg, hm.nrmse_per_angle,
                                                         strict=True)))
