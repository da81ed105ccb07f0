"""Tab 3, Spectrum: the latest reading's spectrum over the previous one's."""

from __future__ import annotations

from typing import Any

from textual.containers import Vertical
from textual.widgets import Static, TabPane

RADIANCE_TITLE = "spectral radiance W·sr⁻¹·m⁻²·nm⁻¹"
BRDF_TITLE = "BRDF sr⁻¹"


class SpectrumPane(TabPane):
    DEFAULT_CSS = """
    #spectrum-head { height: 1; padding: 0 1; }
    """

    def __init__(self) -> None:
        super().__init__("3 Spectrum", id="spectrum")
        self.plot: Any = None
        #: (key, wavelength_nm, values, colorimetry or None, title) of the latest reading and
        #: of the one before it (None when it is another quantity: nothing to compare)
        self.latest: tuple | None = None
        self.previous: tuple | None = None
        self.dirty = False

    def add_reading(self, key: str, wavelength_nm: Any, values: Any, colorimetry: Any,
                    title: str) -> None:
        """A new reading (from the run or a manual one); drawn at the next refresh."""
        same = self.latest is not None and self.latest[4] == title
        self.previous = self.latest if same else None
        self.latest = (key, wavelength_nm, values, colorimetry, title)
        self.dirty = True

    def series(self) -> list[str]:
        """Keys of the plotted series, previous first."""
        return [s[0] for s in (self.previous, self.latest) if s is not None]

    def legend(self) -> list[str]:
        """The plot's legend, previous first: two manual readings are "previous: manual" and
        "latest: manual", never two "manual"."""
        out = [f"previous: {self.previous[0]}"] if self.previous is not None else []
        return out + ([f"latest: {self.latest[0]}"] if self.latest is not None else [])

    def redraw_if_dirty(self) -> None:
        if self.dirty and self.latest is not None:
            self.dirty = False
            self.draw(self.latest, self.previous)

    def build(self) -> None:
        self.mount_all([Static("no reading yet", id="spectrum-head"), Vertical(id="plot-box")])

    def draw(self, latest: tuple, previous: tuple | None) -> None:
        """latest / previous: (key, wavelength_nm, values, colorimetry or None, title)."""
        from normbox_lab.tui.views import chromaticity_text, luminance_text

        key, wl, values, colo, title = latest
        head = f"latest {key}"
        if colo is not None:
            head += (f" · Lv {luminance_text(colo.Lv_cd_m2)} cd/m² · "
                     f"{chromaticity_text(colo)}")
        if previous is not None:
            head += f" · previous {previous[0]}"
        self.query_one("#spectrum-head", Static).update(head)
        if self.plot is None:
            from textual_plotext import PlotextPlot

            self.plot = PlotextPlot(id="plot")
            self.query_one("#plot-box", Vertical).mount(self.plot)
        plt = self.plot.plt
        plt.clear_data()
        plt.title(title)
        plt.xlabel("wavelength nm")
        step = max(1, len(wl) // 100)
        if previous is not None:
            _, pwl, pvalues, _, _ = previous
            plt.plot(list(pwl[::step]), list(pvalues[::step]), label=self.legend()[0],
                     marker="dot", color="gray")
        plt.plot(list(wl[::step]), list(values[::step]), label=self.legend()[-1],
                 marker="braille", color="cyan")
        self.plot.refresh()
