"""The report's data: what `report.write_report` shows (`ReportData`), the image figures it
embeds (`ImageFigure`, also stored as ``image-figure`` artifacts and shown by the console), and
the numbers of its first screen (`Headline`).  Plain data, no rendering: `report_store` fills a
`ReportData` from the store, tests from synthetic arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.analyze.compare import (
    RATING_SCALE,
    ComparisonResult,
    ErrorModelResult,
    rating_index,
)
from normbox_lab.analyze.fit import BrdfData
from normbox_lab.analyze.paper_figures import patch_number, value
from normbox_lab.predict.brdf_model import MaterialFit


@dataclass
class ReportData:
    """Everything the report shows; plain data, so it works from synthetic data or the store."""

    comparison: ComparisonResult | None = None
    fits: dict[str, MaterialFit] = field(default_factory=dict)
    brdf_data: dict[str, BrdfData] = field(default_factory=dict)
    error_model: ErrorModelResult | None = None
    title: str = "Normbox validation report"
    #: the paper's choices (`paper_figures`): polar plots at 730 nm (Figs. 10/11), the NSE of
    #: patch 22 (Fig. 13), patches 19, 23, 24 (Fig. 14a), patch 21 and the wall at (−70°, 80°)
    #: (Fig. 14b); patch indices are 0-based
    polar_wavelength_nm: float = value("polar_wavelength")
    polar_materials: Sequence[str] | None = None   # default: patch08, patch18 (as the paper), wall
    prediction_patches: Sequence[int] = (0, 5, 12, 18)   # 0-based indices for fig-prediction
    nse_patch: int = patch_number("fig13_patch") - 1
    nse_fit_patches: Sequence[int] = tuple(patch_number("fig14a", k) - 1 for k in range(3))
    nse_fit_patch_b: int = patch_number("fig14b") - 1
    wall_name: str = "wall"
    wall_geometry_deg: tuple[float, float] = (value("fig14b", 2), value("fig14b", 3))
    patch_fit_names: Sequence[str] | None = None       # fit name per patch index (fig-nse-fit)
    notes: list[str] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)
    images: list[ImageFigure] = field(default_factory=list)   # virtual-camera figures
    #: the campaign: one dict per run (id, protocol, status, readings, started, finished)
    runs: list[dict[str, Any]] = field(default_factory=list)
    #: instruments: one dict per instrument (role, model, serial, firmware, calibration)
    instruments: list[dict[str, Any]] = field(default_factory=list)
    #: quality flags (`analyze.qa.Flag`: severity, run_id, key, gate, value, limit, message);
    #: None = no QA data available for these runs
    flags: list[Any] | None = field(default_factory=list)
    #: error budget (`analyze.budget`): (arrays, sources) of the latest error-budget artifact
    budget: tuple[dict[str, Any], list[str]] | None = None
    #: methods: name → value rows (software versions, seeds, render quality, MC error)
    methods: dict[str, str] = field(default_factory=dict)
    #: a campaign of the virtual Normbox (emulated instruments): the verdict says "simulated"
    simulated: bool = False
    #: every renderer's comparison (`report_renderers.RendererRow`), ours first
    renderers: list[Any] = field(default_factory=list)
    #: spectral-vs-RGB rendering errors (`report_renderers.RenderingError`)
    rendering_errors: list[Any] = field(default_factory=list)
    #: (observation, the paper's published figure, this run) rows
    paper: list[tuple[str, str, str]] = field(default_factory=list)


@dataclass
class ImagePanel:
    """One panel of an image figure: an encoded sRGB image (H, W, 3) in [0, 1] or uint8, or a
    scalar map (H, W) shown with a colour bar (`vmax`; default: its 99th percentile)."""

    label: str
    data: np.ndarray
    vmax: float | None = None
    unit: str = ""


@dataclass
class ImageFigure:
    """A row of image panels (e.g. the paper's Fig. 1: truth | prediction | ΔE00 map).

    Stored in the store as an ``image-figure`` artifact named `fid` (arrays ``p0``, ``p1``…;
    labels, colour-bar limits and units in the metadata) by `to_artifact`."""

    fid: str
    title: str
    caption: str
    panels: list[ImagePanel]
    subject: str = ""          # what it shows, e.g. "patch 19 at 30°" (the console's header)

    def store(self, store: Store, run_ref: int | str | None = None) -> int:
        # the store keeps float64: sRGB panels go in as encoded values in [0, 1]
        arrays = {f"p{k}": (np.asarray(p.data) / 255.0 if np.asarray(p.data).dtype == np.uint8
                            else np.asarray(p.data)) for k, p in enumerate(self.panels)}
        meta = {"title": self.title, "caption": self.caption, "subject": self.subject,
                "panels": [{"label": p.label, "vmax": p.vmax, "unit": p.unit}
                           for p in self.panels]}
        return store.add_artifact("image-figure", self.fid, arrays, metadata=meta,
                                  run_ref=run_ref)

    @classmethod
    def from_artifact(cls, a: Any) -> ImageFigure:
        m = a.metadata
        panels = [ImagePanel(p["label"], np.asarray(a.arrays[f"p{k}"]), p.get("vmax"),
                             p.get("unit", "")) for k, p in enumerate(m["panels"])]
        return cls(a.name, m["title"], m["caption"], panels, m.get("subject", ""))


# -- headline numbers ----------------------------------------------------------------------------

@dataclass
class Headline:
    """The numbers of the report's first screen."""

    white_delta_e00: float           # white patch at the white angle, paper convention
    white_delta_e00_adapted: float
    mean_delta_e00: float
    mean_delta_e00_adapted: float
    max_delta_e00: float
    nrmse_mean_pct: float
    nrmse_by_angle_pct: np.ndarray   # [angle] mean over patches
    rating_counts: list[int]         # per RATING_SCALE class (paper convention)
    rating_counts_adapted: list[int]
    worst: list[tuple[str, float, float, float, float]]   # patch, angle, ΔE00, ΔE00 adapted, NRMSE %
    verdict: str
    #: where each convention's maximum is: (patch, angle °), and the adapted maximum
    max_at: tuple[str, float] = ("", float("nan"))
    max_delta_e00_adapted: float = float("nan")
    max_adapted_at: tuple[str, float] = ("", float("nan"))


def headline(c: ComparisonResult, adapted: np.ndarray, n_worst: int = 5) -> Headline:
    """The first screen's numbers from a comparison and its adapted-convention ΔE00."""
    wa = int(np.flatnonzero(np.isclose(c.angle_deg, c.white_angle_deg))[0])
    de = c.delta_e00
    idx, idx_a = rating_index(de), rating_index(adapted)
    counts = [int(np.sum(idx == k)) for k in range(len(RATING_SCALE))]
    counts_a = [int(np.sum(idx_a == k)) for k in range(len(RATING_SCALE))]
    order = np.argsort(np.nan_to_num(de, nan=-1.0), axis=None)[::-1][:n_worst]
    worst = []
    for flat in order:
        p, a = np.unravel_index(flat, de.shape)
        worst.append((c.patch_names[p], float(c.angle_deg[a]), float(de[p, a]),
                      float(adapted[p, a]), 100.0 * float(c.nrmse[p, a])))
    n = int(np.isfinite(de).sum())
    within = counts[0] + counts[1]
    mean_de = float(np.nanmean(de))
    p_w, a_w, de_w = worst[0][0], worst[0][1], worst[0][2]
    verdict = (f"The prediction is within ΔE00 ≤ 2 (not discernible side by side) for {within} "
               f"of {n} patch × angle configurations (mean ΔE00 {mean_de:.2f}, paper "
               f"convention) with a mean spectral error (NRMSE) of "
               f"{100.0 * float(np.nanmean(c.nrmse)):.1f} %; the largest difference is patch "
               f"{p_w} at {a_w:g}° (ΔE00 {de_w:.2f}).")
    return Headline(float(de[c.white_patch, wa]), float(adapted[c.white_patch, wa]), mean_de,
                    float(np.nanmean(adapted)), float(np.nanmax(de)),
                    100.0 * float(np.nanmean(c.nrmse)), 100.0 * np.nanmean(c.nrmse, axis=0),
                    counts, counts_a, worst, verdict, _argmax_at(c, de),
                    float(np.nanmax(adapted)) if np.isfinite(adapted).any() else float("nan"),
                    _argmax_at(c, adapted))


def _argmax_at(c: ComparisonResult, values: np.ndarray) -> tuple[str, float]:
    """(patch name, sample angle °) of the largest finite value; ("", nan) if none."""
    v = np.asarray(values, dtype=float)
    if not np.isfinite(v).any():
        return "", float("nan")
    p, a = np.unravel_index(int(np.nanargmax(v)), v.shape)
    return c.patch_names[p], float(c.angle_deg[a])
