"""Tab 6, Images: the store's latest image figures as half-block previews."""

from __future__ import annotations

from textual.containers import VerticalScroll
from textual.widgets import Static, TabPane

from normbox_lab.acquire.store_api import Store


class ImagesPane(TabPane):
    DEFAULT_CSS = """
    #images-view { height: 1fr; padding: 0 1; }
    """

    def __init__(self) -> None:
        super().__init__("6 Images", id="images")
        self.shown_artifact_id: int | None = None
        self.shown_width = 0

    def build(self) -> None:
        self.mount_all([VerticalScroll(Static(
            "no image in the store yet (normbox-lab image figure1 …)", id="images-text"),
            id="images-view")])

    def refresh_from(self, store: Store, width_cells: int) -> None:
        """The store's latest image figures (one per id; the virtual camera's truth |
        prediction | ΔE00 first), each figure's panels side by side across the width."""
        from rich.console import Group

        from normbox_lab.images.terminal import figure_renderable

        found = store.artifacts(kind="image-figure")
        if not found or (self.shown_artifact_id == found[-1].id
                         and self.shown_width == width_cells):
            return                       # drawn already at this width (a resize redraws)
        self.shown_width = width_cells
        latest = {a.name: a for a in found}
        order = sorted(latest.values(), key=lambda a: (a.name != "fig-camera", -a.id))
        self.shown_artifact_id = found[-1].id
        width = max(24, min(160, width_cells - 4))
        figures = []
        for a in order:
            panels = [(p["label"], a.arrays[f"p{k}"], p.get("vmax"), p.get("unit", ""))
                      for k, p in enumerate(a.metadata.get("panels", []))]
            subject = a.metadata.get("subject") or ""
            title = (f"{a.metadata.get('title', a.name)}{' — ' + subject if subject else ''}"
                     f" (artifact {a.id}, run {a.run_id})")
            figures.append(figure_renderable(title, panels, width))
        self.query_one("#images-text", Static).update(Group(*figures))
