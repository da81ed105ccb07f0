"""One widget module per console tab: each pane owns its layout, its tables and how it draws
what the app hands it; `normbox_lab.tui.app` composes them and routes keys and engine events."""

from normbox_lab.tui.tabs.images import ImagesPane
from normbox_lab.tui.tabs.instruments import InstrumentsPane
from normbox_lab.tui.tabs.results import ResultsPane
from normbox_lab.tui.tabs.run import RunPane
from normbox_lab.tui.tabs.runs import RunsPane
from normbox_lab.tui.tabs.spectrum import SpectrumPane

__all__ = ["ImagesPane", "InstrumentsPane", "ResultsPane", "RunPane", "RunsPane",
           "SpectrumPane"]
