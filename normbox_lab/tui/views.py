"""What the console's tables show, computed from the store (no Textual; rich for colour).

- `heatmap(artifact)`: ΔE00 patches × angles from a pipeline `comparison` artifact
  (`normbox_lab.analyze.compare.ComparisonResult.store`), coloured by the paper's rating scale, with the
  NRMSE per angle and a per-patch drill-down.
- `reading_row(stored, flags)`: one line of the Runs tab's readings table; `event_lines`,
  `repeatability_summary`, `luminance_text`, `geometry_text`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from normbox_lab.acquire.store_api import Store
from normbox_lab.analyze.report_style import RATING_COLOURS, RATING_TEXT

#: rating class (index into normbox_lab.analyze.compare.RATING_SCALE) → cell style and legend
#: label; the report's colours (Okabe–Ito: dark blue, sky blue, orange, vermillion — distinct in
#: hue and in lightness, also for colour-blind readers)
RATING_STYLES: tuple[tuple[str, str], ...] = tuple(
    (f"{text} on {colour}", label) for colour, text, label in zip(
        RATING_COLOURS, RATING_TEXT,
        ("≤1 below JND", "≤2 just noticeable", "≤5 discernible", ">5 easily seen"), strict=True))


def rating_class(delta_e: float) -> int:
    """0 (ΔE00 ≤ 1) … 3 (> 5): the class of `normbox_lab.analyze.compare.RATING_SCALE`."""
    from normbox_lab.analyze.compare import rating_index

    return int(rating_index(delta_e))


@dataclass
class HeatMap:
    artifact_id: int
    name: str
    run_id: int | None
    patch_names: list[str]
    angle_deg: np.ndarray          # [angle]
    delta_e00: np.ndarray          # [patch, angle]
    nrmse: np.ndarray              # [patch, angle]
    radiance_mean: np.ndarray | None
    lab_reference: np.ndarray | None
    lab_prediction: np.ndarray | None

    @property
    def nrmse_per_angle(self) -> np.ndarray:
        return np.nanmean(self.nrmse, axis=0)

    def counts(self) -> list[int]:
        from normbox_lab.analyze.compare import rating_index

        idx = rating_index(self.delta_e00)
        return [int(np.sum(idx == k)) for k in range(len(RATING_STYLES))]

    def summary(self, patch_index: int) -> str:
        de = self.delta_e00[patch_index]
        return (f"#{patch_index + 1} {self.patch_names[patch_index]}: mean ΔE00 "
                f"{np.nanmean(de):.2f}, max {np.nanmax(de):.2f} at "
                f"{self.angle_deg[int(np.nanargmax(de))]:g}° · Enter: details")

    def drill_down(self, patch_index: int) -> list[str]:
        """Per-patch lines: ΔE00, rating, NRMSE and L*a*b* per angle."""
        name = self.patch_names[patch_index]
        de = self.delta_e00[patch_index]
        lines = [(f"#{patch_index + 1} {name}   mean ΔE00 {np.nanmean(de):.2f}, "
                  f"max {np.nanmax(de):.2f}, "
                  f"mean NRMSE {100 * np.nanmean(self.nrmse[patch_index]):.1f} %"),
                 (f"{'angle':>5} {'ΔE00':>5}  {'rating':<14} {'NRMSE':>6}  "
                  f"{'L*a*b* measured':<17} {'predicted'}")]
        for j, a in enumerate(self.angle_deg):
            lab_r = _lab(self.lab_reference, patch_index, j)
            lab_p = _lab(self.lab_prediction, patch_index, j)
            lines.append(f"{a:4.0f}° {de[j]:5.2f}  {RATING_STYLES[rating_class(de[j])][1]:<14} "
                         f"{100 * self.nrmse[patch_index, j]:5.1f}%  {lab_r:<17} {lab_p}")
        return lines


def _lab(arr: np.ndarray | None, i: int, j: int) -> str:
    if arr is None:
        return "-"
    L, a, b = arr[i, j]
    return f"{L:4.1f} {a:+5.1f} {b:+5.1f}"


def heatmap(artifact: Any) -> HeatMap:
    arrays, md = artifact.arrays, artifact.metadata
    de = np.asarray(arrays["delta_e00"], dtype=float)
    names = list(md.get("patch_names") or [str(k + 1) for k in range(de.shape[0])])
    return HeatMap(artifact.id, artifact.name, artifact.run_id, names,
                   np.asarray(arrays["angle_deg"], dtype=float), de,
                   np.asarray(arrays.get("nrmse", np.full(de.shape, np.nan)), dtype=float),
                   arrays.get("radiance_mean"), arrays.get("lab_reference"),
                   arrays.get("lab_prediction"))


def latest_heatmap(store: Store) -> HeatMap | None:
    found = store.artifacts(kind="comparison")
    return heatmap(found[-1]) if found else None


def luminance_text(lv_cd_m2: float | None) -> str:
    """Lv as an operator reads it: 2990.5, 45.3, 0.712 (never "3e+03")."""
    if lv_cd_m2 is None or (isinstance(lv_cd_m2, float) and math.isnan(lv_cd_m2)):
        return "-"
    v = float(lv_cd_m2)
    return f"{v:.1f}" if abs(v) >= 10 else f"{v:.3f}"


def xy_text(x: float | None, y: float | None) -> str:
    """"x 0.5698 y 0.4031"; "x — y — (no light)" for a dark reading (its xy is undefined)."""
    if x is None or y is None or math.isnan(float(x)) or math.isnan(float(y)):
        return "x — y — (no light)"
    return f"x {float(x):.4f} y {float(y):.4f}"


def chromaticity_text(colorimetry: Any) -> str:
    return xy_text(colorimetry.x, colorimetry.y)


def geometry_text(metadata: dict[str, Any]) -> str:
    """"30.0°" for a radiometer reading, "θi −30 θo 10" for a BRDF reading (the setpoints;
    a readback beyond its tolerance follows: "30.0° (read 29.7°)")."""
    from normbox_lab.core.types import ReadingGeometry

    g = ReadingGeometry.of(metadata)
    if g.theta_i is not None and g.theta_o is not None:
        return f"θi {g.theta_i.setpoint:g} θo {g.theta_o.setpoint:g}"
    if g.sample_angle is None:
        return "-"
    text = f"{g.sample_angle.setpoint:.1f}°"
    if g.sample_angle.out_of_tolerance():
        text += f" (read {g.sample_angle.readback:.1f}°)"
    return text


def reading_row(r: Any, flags: Any = ()) -> tuple[str, ...]:
    """key, geometry, patch / material, Lv, x, y, integration time, flags — for the Runs
    tab.  `flags`: this reading's `qa.Flag`s."""
    m = r.metadata
    colo = m.get("colorimetry") or {}

    def num(v: Any, fmt: str) -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)
    patch = m.get("patch", m.get("material", ""))
    flags = list(flags)
    errors = sum(1 for f in flags if f.severity == "error")
    flag_text = (f"{errors}E {len(flags) - errors}W" if flags else "—")
    return (r.key, geometry_text(m), str(patch), luminance_text(colo.get("Lv_cd_m2")),
            num(colo.get("x"), ".4f"), num(colo.get("y"), ".4f"),
            num(m.get("integration_time_s"), ".2f"), flag_text)


def event_lines(events: list[tuple[float, str, dict[str, Any]]]) -> list[str]:
    """A run's stored events, one line each: local time, kind, key and what happened."""
    import time

    out = []
    for t, kind, detail in events:
        d = dict(detail)
        key = str(d.pop("key", "") or "")
        text = d.pop("message", None) or d.pop("error", None) or ""
        rest = ", ".join(f"{k}={v}" for k, v in d.items()
                         if not isinstance(v, (dict, list)) and k not in ("in_process",))
        stamp = time.strftime("%m-%d %H:%M:%S", time.localtime(t))
        # no blank key column (most events have no key): the line fits an 80-column box
        out.append(f"{stamp} {kind:<14} " + " · ".join(x for x in (key, text, rest) if x))
    return out


def repeatability_summary(store: Store, run_id: int) -> str:
    """σ and CV of the luminance over a repeatability run's readings, and its flags."""
    from normbox_lab.analyze import qa

    lv = []
    for r in store.readings(run_id):
        colo = r.metadata.get("colorimetry") or {}
        if colo.get("Lv_cd_m2") is not None:
            lv.append(float(colo["Lv_cd_m2"]))
    flagged = [e for _, k, e in store.events(run_id) if k == "flag"]
    n_flags = len(qa.flags(store, run_id)) + len(flagged)
    if len(lv) < 2:
        return f"repeatability: {len(lv)} reading(s), too few for a spread · flags {n_flags}"
    a = np.asarray(lv)
    sd = float(a.std(ddof=1))
    return (f"repeatability: {a.size} readings · Lv mean {luminance_text(float(a.mean()))} "
            f"cd/m² · σ {sd:.3g} cd/m² · CV {100 * sd / float(a.mean()):.3f} % · "
            f"range {100 * (a.max() - a.min()) / float(a.mean()):.3f} % · flags {n_flags}")


def run_row(run: Any, flags: Any = None) -> tuple[str, ...]:
    """One row of the Runs tab; `flags`: the run's `qa.QaSummary` (None: no flags).  A done
    run with flags reads "completed with flags", as in `normbox-lab runs`."""
    import time

    created = time.strftime("%m-%d %H:%M", time.localtime(run.created_s))
    status = "completed with flags" if run.status == "done" and flags else run.status
    flag_text = f"{flags.errors}E {flags.warnings}W" if flags else "—"
    # no uuid column: at 80 columns it pushed `created` off the screen (the event log, the
    # export and `normbox-lab runs` give it)
    return (str(run.id), _short_protocol(run.protocol), status,
            f"{run.done}/{run.planned}", flag_text, created)


def _short_protocol(protocol: str) -> str:
    if protocol.endswith(".py"):
        return protocol.rsplit("/", 1)[-1]
    return protocol
