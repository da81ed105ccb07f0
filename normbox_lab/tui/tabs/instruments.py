"""Tab 1, Instruments: every instrument's connection, identity, state and when it last
answered (a red row when it did not), the live state of the box, and manual control: home,
go to / jog the rotator, lamp on / off / level, a single reading — each refused, with the
reason, while a run owns the instruments."""

from __future__ import annotations

import time
from typing import Any, ClassVar

from textual import work
from textual.binding import Binding
from textual.widgets import DataTable, Static, TabPane

from normbox_lab.tui.tabs.common import table


def connection_text(row: dict[str, Any]) -> str:
    """"sim cs1000a" for an emulator URL, "real /dev/ttyUSB0" for a port."""
    port = str(row["port"])
    if port.startswith("sim://"):
        return "sim " + port.removeprefix("sim://").split("?")[0]
    return ("sim " if row["simulated"] else "real ") + port


INSTRUMENT_COLUMNS = ("role", "connection", "identity", "state", "last seen")
#: the narrowest each column gets (role and last seen are never shortened)
INSTRUMENT_MIN_WIDTHS = (99, 10, 8, 14, 99)
#: the order in which columns give up width when the terminal is narrow
SHRINK_ORDER = (2, 1, 3)


def fit_widths(natural: list[int], minimum: tuple[int, ...], available: int) -> list[int]:
    """Column widths within `available` cells: each column its natural width, then the
    columns of SHRINK_ORDER give up width in turn, down to their minimum."""
    widths = list(natural)
    for i in SHRINK_ORDER:
        excess = sum(widths) - available
        if excess <= 0:
            break
        widths[i] = max(min(minimum[i], natural[i]), widths[i] - excess)
    return widths


def shorten(text: str, width: int) -> str:
    return text if len(text) <= width else text[:max(1, width - 1)] + "…"


class InstrumentsPane(TabPane):
    # not in the footer (it would push the global keys, E-STOP among them, off an 80-column
    # screen): the pane's own key line lists them
    BINDINGS: ClassVar = [
        Binding("h", "manual('home')", "home", show=False),
        Binding("g", "goto", "go to", show=False),
        Binding("j", "manual('jog', -5)", "jog −5°", show=False),
        Binding("k", "manual('jog', 5)", "jog +5°", show=False),
        Binding("o", "manual('lamp-on')", "lamp on", show=False),
        Binding("f", "manual('lamp-off')", "lamp off", show=False),
        Binding("v", "level", "level", show=False),
        Binding("m", "manual('measure')", "reading", show=False),
    ]
    #: the manual-control keys, shown under the table
    KEYS_TEXT = ("[b]h[/b] home · [b]g[/b] go to · [b]j[/b]/[b]k[/b] jog −5°/+5° · "
                 "[b]o[/b]/[b]f[/b] lamp on/off · [b]v[/b] level · [b]m[/b] reading")
    DEFAULT_CSS = """
    #inst-table { height: auto; max-height: 10; }
    #live { height: auto; padding: 0 1; }
    #manual-keys { height: auto; padding: 0 1; color: $text-muted; }
    """

    def __init__(self) -> None:
        super().__init__("1 Instruments", id="instruments")

    def build(self) -> None:
        """Filled after the first paint (less to lay out before it)."""
        self.mount_all([
            table("inst-table", INSTRUMENT_COLUMNS,
                  cursor_type="row", zebra_stripes=True),
            Static("", id="live"),
            Static("manual: " + self.KEYS_TEXT, id="manual-keys")])

    def show_instruments(self, rows: list[dict[str, Any]], width_cells: int) -> None:
        """The rows, their columns fitted to the terminal: role, state and last seen whole
        (what the operator looks for), identity then connection shortened with … first."""
        from rich.text import Text

        tab = self.query_one("#inst-table", DataTable)
        cursor_row = tab.cursor_row
        cells_of = []
        for r in rows:
            seen = r.get("last_seen")
            seen_text = time.strftime("%H:%M:%S", time.localtime(seen)) if seen else "never"
            cells_of.append([r["role"], connection_text(r), r["identity"] or "-",
                             r["state"] or "-", seen_text])
        natural = [max([len(h)] + [len(c[i]) for c in cells_of])
                   for i, h in enumerate(INSTRUMENT_COLUMNS)]
        # each column has one cell of padding either side; 2 for the scroll bar
        widths = fit_widths(natural, INSTRUMENT_MIN_WIDTHS, width_cells - 2 * len(natural) - 2)
        # columns made anew with these widths (a DataTable's automatic widths only grow: a
        # long state once seen would push the last column off an 80-column screen for good)
        tab.clear(columns=True)
        for header, w in zip(INSTRUMENT_COLUMNS, widths, strict=True):
            tab.add_column(header, width=w)
        for r, cells in zip(rows, cells_of, strict=True):
            style = "bold white on #D55E00" if r.get("ok") is False else ""
            tab.add_row(*[Text(shorten(c, w), style=style) for c, w in zip(cells, widths,
                                                                           strict=True)],
                        key=r["role"])
        if 0 < cursor_row < tab.row_count:
            tab.move_cursor(row=cursor_row)

    def show_live(self, live: Any) -> None:
        from normbox_lab.tui.views import luminance_text, xy_text

        angle = "?" if live.angle_deg is None else f"{live.angle_deg:.1f}°"
        lamp = live.lamp
        if live.lamp_stable is not None and live.lamp not in ("stable", "unstable",
                                                              "warming up", "error"):
            lamp += " (stable)" if live.lamp_stable else " (not stable)"
        temp = "-" if live.temperature_c is None else f"{live.temperature_c:.1f} °C"
        last = "-"
        if live.last_key:
            lv = ("?" if live.last_Lv_cd_m2 is None
                  else f"{luminance_text(live.last_Lv_cd_m2)} cd/m²")
            xy = "" if live.last_xy is None else "  " + xy_text(*live.last_xy)
            last = f"{live.last_key}: Lv {lv}{xy}"
        patch = "-" if live.patch is None else str(live.patch)
        manual = getattr(live, "manual_state", "")
        self.query_one("#live", Static).update(
            (f"[b]{manual}…[/b]\n" if manual else "")
            + f"sample angle {angle} · patch on holder {patch} · lamp {lamp}\n"
            f"spectrometer temperature {temp}\nlast reading {last}")

    def show_manual_keys(self, run_owns: bool) -> None:
        self.query_one("#manual-keys", Static).update(
            ("manual (refused while the run owns the instruments): " if run_owns
             else "manual: ") + self.KEYS_TEXT)

    # --- manual control ------------------------------------------------------------------------
    def action_manual(self, action: str, value: float | None = None) -> None:
        self.manual(action, value)

    def manual(self, action: str, value: float | None = None) -> None:
        """A manual action (in a worker: a move or a reading takes time); refused at once
        while a run owns the instruments."""
        app: Any = self.app
        if not app.lab_ready:
            app.notify("the lab is still loading", severity="warning")
            return
        if app.session.busy:
            # a paused run still owns them (it waits to go on): only its end frees them
            name = app.session.MANUAL[action][1]
            app.notify(f"{name} refused: the run owns the instruments until it ends (a, a "
                       "aborts it; r resumes it later)", severity="warning", markup=False)
            return
        if app.session.manual_action:
            app.notify(f"{app.session.MANUAL[action][1]}: wait — "
                       f"{app.session.manual_action} is under way", severity="warning",
                       markup=False)
            return
        app.session.manual_action = app.session.MANUAL[action][1]   # s waits from now on
        self._manual(action, value)

    @work(thread=True, exclusive=True, group="manual")
    def _manual(self, action: str, value: float | None) -> None:
        from normbox_lab.core.errors import NormboxError

        app: Any = self.app
        try:
            text, reading = app.session.manual(action, value)
        except (NormboxError, OSError) as exc:
            app.call_from_thread(app.notify, str(exc), severity="error", markup=False)
            app.call_from_thread(app._log, "[red]manual:[/] ", str(exc))
            return
        finally:
            app.session.manual_action = ""
        app.call_from_thread(self._manual_done, text, reading)

    def _manual_done(self, text: str, reading: Any) -> None:
        from normbox_lab.tui.tabs.spectrum import RADIANCE_TITLE, SpectrumPane
        from normbox_lab.tui.views import chromaticity_text, luminance_text

        app: Any = self.app
        from normbox_lab.core.types import SpectralReading

        text, _, warning = text.partition(" — ")        # "…taken — the lamp is not stable…"
        if isinstance(reading, SpectralReading):
            colo = reading.colorimetry
            if colo is not None:
                text += f": Lv {luminance_text(colo.Lv_cd_m2)} cd/m² · {chromaticity_text(colo)}"
            app.query_one(SpectrumPane).add_reading("manual", reading.wavelength_nm,
                                                    reading.radiance_W_sr_m2_nm, colo,
                                                    RADIANCE_TITLE)
        if warning:
            text += f" — WARNING: {warning}"
        app._log("[b]manual[/b] ", text)
        app.notify(text, markup=False, severity="warning" if warning else "information")
        app._poll(announce=False)          # the table shows the new state (no second toast)

    def action_goto(self) -> None:
        from normbox_lab.tui.screens import NumberScreen

        def chosen(angle: float | None) -> None:
            if angle is not None:
                self.manual("goto", angle)
        low, high, where = self.app.session.angle_limits_deg("rotator")
        self.app.push_screen(NumberScreen(f"rotator: go to angle, degrees ({where})", low,
                                          high), chosen)

    def action_level(self) -> None:
        from normbox_lab.tui.screens import NumberScreen

        def chosen(level: float | None) -> None:
            if level is not None:
                self.manual("lamp-level", level)
        self.app.push_screen(NumberScreen("lamp level, percent", 0.0, 100.0, 100.0), chosen)

