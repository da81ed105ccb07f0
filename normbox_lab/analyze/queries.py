"""The store queries now live in `normbox_lab.acquire.queries` (next to the store, below
predict and analyze); this module keeps the old import path for the analysis' callers."""

from __future__ import annotations

from normbox_lab.acquire.queries import (
    WHITE_PATCH,
    ReferenceData,
    fit_key,
    lamp_from_light_map,
    latest_fits,
    latest_run,
    reference_data,
    white_index,
)

__all__ = ["WHITE_PATCH", "ReferenceData", "fit_key", "lamp_from_light_map", "latest_fits",
           "latest_run", "reference_data", "white_index"]
