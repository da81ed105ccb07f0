"""Image previews in a terminal: two pixels per character cell with the upper-half block ▀
(foreground = upper pixel, background = lower pixel) as rich Text.  Truecolor terminals show the
colours as they are; rich/Textual reduce them to 256 or 16 colours where the terminal reports
less, and the preview stays readable as a rough picture."""

from __future__ import annotations

from typing import Any

import numpy as np


def as_uint8(image: Any, vmax: float | None = None) -> np.ndarray:
    """An (H, W, 3) uint8 image from encoded sRGB (float in [0, 1] or uint8), or from a scalar
    map (H, W) through matplotlib's 'magma' colour map scaled to [0, vmax]."""
    a = np.asarray(image)
    if a.ndim == 3:
        if a.dtype == np.uint8:
            return a[..., :3]
        return np.round(np.clip(np.nan_to_num(a[..., :3]), 0.0, 1.0) * 255).astype(np.uint8)
    from matplotlib import colormaps

    finite = a[np.isfinite(a)]
    top = float(vmax) if vmax is not None else (float(np.percentile(finite, 99))
                                                if finite.size else 1.0)
    rgba = colormaps["magma"](np.clip(np.nan_to_num(a / max(top, 1e-12)), 0.0, 1.0))
    return np.round(rgba[..., :3] * 255).astype(np.uint8)


def downsample(image: np.ndarray, width_px: int) -> np.ndarray:
    """Box-average an (H, W, 3) uint8 image to `width_px` columns (aspect kept, even height)."""
    h, w = image.shape[:2]
    width_px = max(1, min(int(width_px), w))
    height_px = max(2, round(h * width_px / w / 2.0) * 2)
    ys = np.linspace(0, h, height_px + 1).astype(int)
    xs = np.linspace(0, w, width_px + 1).astype(int)
    img = image.astype(np.float64)
    out = np.empty((height_px, width_px, 3))
    for j in range(height_px):
        rows = img[ys[j]:max(ys[j + 1], ys[j] + 1)]
        for i in range(width_px):
            out[j, i] = rows[:, xs[i]:max(xs[i + 1], xs[i] + 1)].mean(axis=(0, 1))
    return np.round(out).astype(np.uint8)


def half_block_text(image: Any, width_cells: int = 40, vmax: float | None = None) -> Any:
    """rich Text of an image `width_cells` characters wide (H/W aspect, 2 pixels per cell)."""
    from rich.style import Style
    from rich.text import Text

    px = downsample(as_uint8(image, vmax), width_cells)
    text = Text()
    for j in range(0, px.shape[0], 2):
        for i in range(px.shape[1]):
            top, bottom = px[j, i], px[j + 1, i]
            text.append("▀", Style(color=f"rgb({top[0]},{top[1]},{top[2]})",
                                   bgcolor=f"rgb({bottom[0]},{bottom[1]},{bottom[2]})"))
        if j + 2 < px.shape[0]:
            text.append("\n")
    return text


def figure_renderable(title: str, panels: list[tuple[str, Any, float | None, str]],
                      width_cells: int = 80) -> Any:
    """A titled row of panels (label, image or map, vmax, unit) side by side, sharing
    `width_cells` columns (one column of space between panels), as a rich Group."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    n = max(len(panels), 1)
    each = max(8, (int(width_cells) - (n - 1)) // n)
    grid = Table.grid(padding=(0, 1))
    for _ in panels:
        grid.add_column(width=each)        # image rows are `each` wide: only titles wrap
    # the panel titles wrap (at 80 columns a third of the width cut them)
    grid.add_row(*[Text(_panel_label(label, vmax, unit), overflow="fold")
                   for label, _data, vmax, unit in panels])
    grid.add_row(*[half_block_text(data, each, vmax) for _label, data, vmax, _unit in panels])
    if any(np.asarray(data).ndim == 2 for _l, data, _v, _u in panels):
        grid.add_row(*[colour_bar(each, vmax, unit) if np.asarray(data).ndim == 2 else Text("")
                       for _label, data, vmax, unit in panels])
    return Group(Text(title, style="bold"), grid)


def colour_bar(width_cells: int, vmax: float | None, unit: str = "") -> Any:
    """The scale of a scalar map: the 'magma' colours from 0 to vmax across `width_cells`,
    with the ends labelled underneath."""
    from matplotlib import colormaps
    from rich.style import Style
    from rich.text import Text

    n = max(2, int(width_cells))
    rgba = colormaps["magma"](np.linspace(0.0, 1.0, n))
    bar = Text()
    for r, g, b, _a in np.round(rgba * 255).astype(int):
        bar.append("█", Style(color=f"rgb({r},{g},{b})"))
    top = f"{vmax:g}" if vmax else "max"
    right = f"{top}{' ' + unit if unit else ''}"
    bar.append("\n0" + " " * max(1, n - 1 - len(right)) + right)
    return bar


def _panel_label(label: str, vmax: float | None, unit: str) -> str:
    if not vmax:
        return label
    return f"{label} (0…{vmax:g}{' ' + unit if unit else ''})"
