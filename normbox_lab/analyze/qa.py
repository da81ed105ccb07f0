"""Quality flags: the public API the CLI (`normbox-lab qa`), the report and the TUI use.

A flag is data (DESIGN §3): (run, reading key or artifact, gate, severity warning|error,
measured value, limit, message), stored in the store's ``flags`` table.  Acquisition gates
(`normbox_lab.acquire.quality`) flag readings as the engine commits them; the pipeline gates
here flag fits (`check_fits`) and predictions (`check_prediction`).  Later pipeline steps
refuse inputs with error flags unless told to accept them (`require_clean`), and record that
acceptance in the artifact's provenance (``accepted_flags`` in its metadata).

    flags(store, run=None, *, artifact=None, severity=None) -> list[Flag]
    summary(store, run=None, *, artifact=None) -> QaSummary   # .line(): "N flags: E errors, W warnings"
    summaries_by_run(store) -> dict[int, QaSummary]
    run_status(store, run) -> str      # "completed with flags" for a done run with flags
    record(store, gate, severity, message, *, run=None, artifact=None, key="", value=None,
           limit=None) -> Flag
    require_clean(store, *, run=None, artifacts=(), accept_flagged=False, step="") -> list[Flag]
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from normbox_lab.acquire.quality import QualityLimits, limits_from_text
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import DataError

SEVERITIES = ("warning", "error")


@dataclass(frozen=True)
class Flag:
    """One stored quality flag.  `run_id` / `artifact_id` are None when not set."""

    id: int
    run_id: int | None
    artifact_id: int | None
    key: str                 # reading key, artifact name, or "" for the whole run
    gate: str
    severity: str            # "warning" | "error"
    value: float | None      # what was measured
    limit: float | None      # the limit it was held against
    message: str
    created_s: float = 0.0

    @classmethod
    def from_row(cls, row: Mapping[str, Any]) -> Flag:
        return cls(int(row["id"]), int(row["run_id"]) or None,
                   int(row["artifact_id"]) or None, str(row["key"]), str(row["gate"]),
                   str(row["severity"]), row["value"], row["limit"], str(row["message"]),
                   float(row["created_s"]))

    def line(self) -> str:
        """One line for `normbox-lab qa`: severity, where, gate, value/limit, message."""
        where = self.key or "(run)"
        if self.artifact_id is not None:
            where = f"{where} [artifact {self.artifact_id}]"
        vl = ""
        if self.value is not None:
            vl = f"  value {_num(self.value)}"
            if self.limit is not None:
                vl += f" limit {_num(self.limit)}"
        return f"{self.severity:<7} {where:<24} {self.gate:<22}{vl}  {self.message}"

    def as_dict(self) -> dict[str, Any]:
        return {"id": self.id, "run_id": self.run_id, "artifact_id": self.artifact_id,
                "key": self.key, "gate": self.gate, "severity": self.severity,
                "value": self.value, "limit": self.limit, "message": self.message}


def _num(v: float) -> str:
    return f"{v:.4g}" if math.isfinite(v) else str(v)


@dataclass(frozen=True)
class QaSummary:
    flags: int
    errors: int
    warnings: int
    by_gate: dict[str, int] = field(default_factory=dict)

    def line(self) -> str:
        return f"{self.flags} flags: {self.errors} errors, {self.warnings} warnings"


def _summarise(items: Iterable[Flag]) -> QaSummary:
    items = list(items)
    by_gate: dict[str, int] = {}
    for f in items:
        by_gate[f.gate] = by_gate.get(f.gate, 0) + 1
    errors = sum(1 for f in items if f.severity == "error")
    return QaSummary(len(items), errors, len(items) - errors, by_gate)


def flags(store: Store, run: int | str | None = None, *, artifact: int | None = None,
          severity: str | None = None) -> list[Flag]:
    """Flags of a run (its readings' and its artifacts'), of one artifact, or all."""
    run_id = None if run is None else store.get_run(run).id
    rows = store.flag_rows(run_id=run_id, artifact_id=artifact)
    out = [Flag.from_row(r) for r in rows]
    return [f for f in out if severity is None or f.severity == severity]


def summary(store: Store, run: int | str | None = None, *,
            artifact: int | None = None) -> QaSummary:
    return _summarise(flags(store, run, artifact=artifact))


def summaries_by_run(store: Store) -> dict[int, QaSummary]:
    """Flag counts per run id (runs without flags are absent)."""
    per: dict[int, list[Flag]] = {}
    for f in (Flag.from_row(r) for r in store.flag_rows()):
        if f.run_id is not None:
            per.setdefault(f.run_id, []).append(f)
    return {k: _summarise(v) for k, v in per.items()}


def run_status(store: Store, run: int | str) -> str:
    """The run's status as people read it: a finished run with flags "completed with flags"."""
    rec = store.get_run(run)
    if rec.status == "done" and store.flag_rows(run_id=rec.id):
        return "completed with flags"
    return store.shown_status(rec)     # "running" only while a live process owns the run


def record(store: Store, gate: str, severity: str, message: str, *,
           run: int | str | None = None, artifact: int | None = None, key: str = "",
           value: float | None = None, limit: float | None = None) -> Flag:
    """Store one flag (the same run/artifact/key/gate replaces the earlier one)."""
    if severity not in SEVERITIES:
        raise ValueError(f"severity must be one of {SEVERITIES}, got {severity!r}")
    run_id = None if run is None else store.get_run(run).id
    fid = store.add_flag(run_id=run_id, artifact_id=artifact, key=key, gate=gate,
                         severity=severity, value=value, limit=limit, message=message)
    return Flag(fid, run_id, artifact, key, gate, severity, value, limit, message)


def limits_for(store: Store, run: int | str) -> QualityLimits:
    """The limits in force for a run: its lab-config snapshot's ``[quality]`` table."""
    rec = store.get_run(run)
    return limits_from_text(rec.lab_config, f"lab config of run {rec.id}")


def require_clean(store: Store, *, run: int | str | None = None,
                  artifacts: Iterable[int] = (), accept_flagged: bool = False,
                  step: str = "") -> list[Flag]:
    """The error flags on a run's readings and on the given artifacts.  Raises `DataError`
    when there are any and `accept_flagged` is false; returns them otherwise (for the
    provenance of what is made from them)."""
    found: list[Flag] = []
    if run is not None:
        found += [f for f in flags(store, run, severity="error") if f.artifact_id is None]
    for aid in artifacts:
        found += flags(store, artifact=int(aid), severity="error")
    if found and not accept_flagged:
        where = f"run {store.get_run(run).id}" if run is not None else "its inputs"
        first = "; ".join(f"{f.key or '(run)'} {f.gate}" for f in found[:3])
        raise DataError(str(store.path), where,
                        f"{step + ': ' if step else ''}{len(found)} error flag(s) on the "
                        f"inputs ({first}{' …' if len(found) > 3 else ''}); see "
                        f"`normbox-lab qa`; use --accept-flagged to go on anyway")
    return found


def provenance(accepted: Iterable[Flag]) -> dict[str, Any]:
    """Metadata to add to an artifact made from flagged inputs."""
    items = [f.as_dict() for f in accepted]
    return {"accepted_flags": items} if items else {}


# --- pipeline gates ------------------------------------------------------------------------

def check_fits(store: Store, brdf_run: int | str, fits: Mapping[str, tuple[int, Any]],
               limits: QualityLimits | None = None) -> list[Flag]:
    """Gates on a set of fits (name → (artifact id, MaterialFit)): fit error above the limit
    (warning), an outlier against the median of all materials (error; only above
    `fit_outlier_min_pct`), not converged
    (error), parameters at their bounds (warning)."""
    import numpy as np

    limits = limits or limits_for(store, brdf_run)
    out: list[Flag] = []
    errors = {n: float(f.fit_error_pct) for n, (_, f) in fits.items()}
    median = float(np.median(list(errors.values()))) if errors else float("nan")
    for name, (aid, fit) in fits.items():
        e = errors[name]
        if not math.isfinite(e) or e > limits.fit_error_limit_pct:
            out.append(record(store, "fit-error", "warning",
                              f"fit error {e:.2f} % above {limits.fit_error_limit_pct:g} %",
                              run=brdf_run, artifact=aid, key=name, value=e,
                              limit=limits.fit_error_limit_pct))
        if len(errors) >= 3 and math.isfinite(median) and median > 0 and \
                e > limits.fit_outlier_factor * median and e > limits.fit_outlier_min_pct:
            out.append(record(store, "fit-outlier", "error",
                              f"fit error {e:.2f} % is {e / median:.1f} × the median "
                              f"{median:.2f} % of {len(errors)} materials",
                              run=brdf_run, artifact=aid, key=name, value=e / median,
                              limit=limits.fit_outlier_factor))
        md = getattr(fit, "metadata", {}) or {}
        if md.get("converged") is False:
            out.append(record(store, "fit-not-converged", "error",
                              f"the optimiser stopped without converging "
                              f"({md.get('status_message', 'no message')})",
                              run=brdf_run, artifact=aid, key=name))
        bounds = md.get("bounds") or {}
        at = [p for p, (lo, hi) in bounds.items()
              if p != "c" and _at_bound(getattr(fit, p, float("nan")), lo, hi)]
        if at:
            out.append(record(store, "fit-at-bounds", "warning",
                              "parameter(s) at their bounds: " + ", ".join(
                                  f"{p}={getattr(fit, p):.4g} in [{bounds[p][0]:g}, "
                                  f"{bounds[p][1]:g}]" for p in at),
                              run=brdf_run, artifact=aid, key=name))
    return out


def _at_bound(v: float, lo: float, hi: float) -> bool:
    span = float(hi) - float(lo)
    return math.isfinite(v) and (v <= lo + 1e-4 * span or v >= hi - 1e-4 * span)


def check_prediction(store: Store, ref_run: int | str, artifact_id: int, patches: Iterable[int],
                     angle_deg: Iterable[float], radiance: Any, std_error: Any,
                     limits: QualityLimits | None = None) -> list[Flag]:
    """Prediction standard error above target: per configuration, the Monte-Carlo standard
    error of the band-averaged radiance relative to it."""
    import numpy as np

    limits = limits or limits_for(store, ref_run)
    rad = np.asarray(radiance, dtype=float)
    se = np.asarray(std_error, dtype=float)
    out: list[Flag] = []
    for pi, p in enumerate(patches):
        for ai, a in enumerate(angle_deg):
            mean = float(np.mean(rad[pi, ai]))
            rel = float(np.sqrt(np.mean(se[pi, ai] ** 2)) / mean) if mean > 0 else math.inf
            if not rel <= limits.prediction_rel_se_limit:
                out.append(record(store, "prediction-se", "warning",
                                  f"relative standard error {100 * rel:.2f} % above the target "
                                  f"{100 * limits.prediction_rel_se_limit:g} %",
                                  run=ref_run, artifact=artifact_id,
                                  key=f"p{int(p):02d}@{float(a):g}", value=rel,
                                  limit=limits.prediction_rel_se_limit))
    return out


def recheck_run(store: Store, run: int | str, limits: QualityLimits | None = None) -> list[Flag]:
    """Apply the acquisition gates again to a stored run (e.g. after changing the limits)."""
    from normbox_lab.acquire.quality import RunGates

    rec = store.get_run(run)
    gates = RunGates(store, rec.id, limits or limits_for(store, rec.id))
    gates.lamp_first, gates.lamp_steps = None, []
    for r in store.readings(rec.id):
        gates.reading(r.key, r.kind, r.metadata, r.arrays)
    gates.finish(rec.protocol)
    return flags(store, rec.id)


__all__ = ["Flag", "QaSummary", "check_fits", "check_prediction", "flags", "limits_for",
           "provenance", "recheck_run", "record", "require_clean", "run_status",
           "summaries_by_run", "summary"]
