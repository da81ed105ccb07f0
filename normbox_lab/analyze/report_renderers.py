"""The report's renderer comparison: every renderer's prediction of one reference run, side by
side, and the rendering error of an RGB renderer against a spectral one on the same scene.

`renderer_rows(store, run_id)` gives one row per renderer with a stored comparison (ours,
"normbox-lab", first; then each `import prediction` renderer): its version, mean and max
ΔE00 (paper convention), NRMSE by sample angle and the rating counts.

`rendering_error(store, run_id, spectral, rgb)`: ΔE00 between two renderers' predictions per
patch × angle (XYZ of both normalised by the spectral renderer's white patch at the white
angle, Lab D65, as the comparison does with the reference's), i.e. the colour error the RGB
rendering adds on this run's scene, and each one's ΔE00 against the measurement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from normbox_lab.acquire.store_api import Store


@dataclass
class RendererRow:
    renderer: str
    version: str
    delta_e00_mean: float
    delta_e00_max: float
    nrmse_by_angle_pct: list[float]
    rating_counts: list[int]
    comparison_id: int


@dataclass
class RenderingError:
    """ΔE00 between an RGB and a spectral renderer's predictions, [patch, angle]."""

    spectral: str
    rgb: str
    patch_names: list[str]
    angle_deg: np.ndarray
    delta_e00: np.ndarray                       # RGB prediction vs spectral prediction
    delta_e00_vs_reference: dict[str, np.ndarray] = field(default_factory=dict)


def _version(store: Store, run_id: int, renderer: str | None) -> str:
    from normbox_lab.predict.renderers import artifact_name

    if renderer is None:
        from normbox_lab import __version__

        found = store.artifacts("prediction", artifact_name(run_id))
        q = found[-1].metadata.get("quality", "?") if found else "?"
        return f"normbox-lab {__version__} ({q})"
    found = store.artifacts("prediction", artifact_name(run_id, renderer))
    return str(found[-1].metadata.get("renderer_version", "?")) if found else "?"


def renderer_rows(store: Store, run_id: int) -> list[RendererRow]:
    from normbox_lab.acquire.queries import renderers
    from normbox_lab.analyze.compare import RATING_SCALE, ComparisonResult, rating_index
    from normbox_lab.predict.renderers import artifact_name

    rows = []
    for r in renderers(store, run_id):
        a = store.latest_artifact("comparison", artifact_name(run_id, r))
        c = ComparisonResult.from_artifact(a)
        idx = rating_index(c.delta_e00)
        rows.append(RendererRow(
            r or "normbox-lab", _version(store, run_id, r), float(np.nanmean(c.delta_e00)),
            float(np.nanmax(c.delta_e00)), [float(x) for x in 100 * np.nanmean(c.nrmse, 0)],
            [int(np.sum(idx == k)) for k in range(len(RATING_SCALE))], a.id))
    return rows


def rendering_error(store: Store, run_id: int, spectral: str | None, rgb: str
                    ) -> RenderingError | None:
    """ΔE00(RGB prediction, spectral prediction) per patch × angle; None when either is
    missing.  `spectral` None: ours."""
    from normbox_lab.acquire.queries import reference_data, white_index
    from normbox_lab.analyze.compare import compare
    from normbox_lab.core.errors import StoreError
    from normbox_lab.predict.renderers import artifact_name

    try:
        ps = store.latest_artifact("prediction", artifact_name(run_id, spectral)).arrays
        pr = store.latest_artifact("prediction", artifact_name(run_id, rgb)).arrays
    except StoreError:
        return None
    ref = reference_data(store, run_id)
    white = white_index(ref.patches)
    names = [f"{p} {n}" for p, n in zip(ref.patches, ref.patch_names)]
    wa = float(ref.angle_deg.min())
    de = compare(ps["radiance"], pr["radiance"], ref.wavelength_nm, ref.angle_deg, names,
                 white_patch=white, white_angle_deg=wa).delta_e00
    vs_ref = {}
    for name, p in ((spectral or "normbox-lab", ps), (rgb, pr)):
        vs_ref[name] = compare(ref.radiance, p["radiance"], ref.wavelength_nm, ref.angle_deg,
                               names, white_patch=white, white_angle_deg=wa).delta_e00
    return RenderingError(spectral or "normbox-lab", rgb, names, ref.angle_deg, de, vs_ref)
