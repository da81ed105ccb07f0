"""One word for precision: the target relative standard error per band.

Every renderer of the prediction and of the simulated truth (the stock Mitsuba `render_view`,
the fast band-vector `FastNormbox`, the simulated worlds) renders until

    rel_se(mean, se) = max over the bands with signal of  SE(band) / |radiance(band)|

is at most the target (the *worst* band: "bands with signal" are those above 1e-6 of the
spectrum's peak).  That is the one statistic; each result reports the value it reached.  The
Mitsuba renderer adds batches of its quality's samples per pixel up to its batch cap, and
reports what it reached when the cap comes first.

The quality names are presets of the target, defined here once (`PRESETS`); the command line
takes either (``--quality default`` or ``--target-se 0.15%``).  Which renderer runs is chosen
by name (``--renderer fast|mitsuba``), never by where it runs (``--executor``).
"""

from __future__ import annotations

from typing import Any

from normbox_lab.predict.bandpath import max_rel_se

#: the statistic every renderer's target refers to (stated with each result)
STATISTIC = "largest relative standard error over the bands with signal (worst band)"
#: quality name → target relative standard error per band (worst band)
PRESETS: dict[str, float] = {"quick": 0.02, "default": 0.0015, "high": 0.001}
#: the default target: the "default" preset (0.15 %)
DEFAULT_TARGET_SE = PRESETS["default"]
#: the renderers a prediction may use, by name
RENDERERS = ("fast", "mitsuba")


def rel_se(mean: Any, se: Any) -> float:
    """The statistic (`STATISTIC`) of one spectrum: its worst band's relative standard error."""
    import numpy as np

    return max_rel_se(np.asarray(mean, dtype=float), np.asarray(se, dtype=float))


def target_se(quality: str | None = None, target: float | None = None) -> float:
    """The target of a render: `target` when given, else the preset of `quality` (default
    "default")."""
    if target is not None:
        value = float(target)
        if not 0.0 < value < 1.0:
            raise ValueError(f"target relative standard error {value!r} must be in (0, 1)")
        return value
    name = quality or "default"
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown quality {name!r}; known: {', '.join(PRESETS)}") from None


def parse_target_se(text: str) -> float:
    """``"0.15%"`` → 0.0015, ``"0.0015"`` → 0.0015 (a fraction in (0, 1), or a percentage)."""
    s = str(text).strip()
    try:
        value = float(s[:-1]) / 100.0 if s.endswith("%") else float(s)
    except ValueError:
        raise ValueError(f"not a relative standard error: {text!r} (e.g. 0.15% or "
                         "0.0015)") from None
    return target_se(target=value)


def describe(target: float) -> str:
    return f"{100.0 * target:g} % ({STATISTIC})"


__all__ = ["DEFAULT_TARGET_SE", "PRESETS", "RENDERERS", "STATISTIC", "describe",
           "parse_target_se", "rel_se", "target_se"]
