"""Quality gates at acquisition time: every suspect reading becomes a stored flag.

A flag is data (DESIGN §3): (run, reading key or artifact, gate, severity, measured value,
limit, message), kept in the store's ``flags`` table and read through
`normbox_lab.analyze.qa`.  This module holds the limits (lab config ``[quality]``, defaults
below with their source) and the gates the engine applies to each reading as it is committed
(`RunGates.reading`), to instrument error codes (`RunGates.device_error`) and to the whole run
when it ends (`RunGates.finish`).  The pipeline's gates (fits, predictions) live in
`normbox_lab.analyze.qa`.

Gates (severity; what is measured; limit field):

=====================  ========  =============================================================
gate                   severity  condition
=====================  ========  =============================================================
brdf-nonfinite         error     a BRDF value is NaN or infinite
brdf-negative          error     min BRDF < −`brdf_negative_per_sr` (unblocked geometries)
saturation             error     peak raw counts > `saturation_fraction` × full scale
                                 (nonlinear beyond the stored correction: may be wrong)
noise-floor            warning   peak dark-corrected counts < `noise_floor_counts`
dark-current           error     a gonio reading's dark current above
                                 `dark_current_max_counts_s` (10× the detector's own)
dark-drift             warning   |dark current change| between consecutive darks >
                                 `dark_drift_counts_s` + 3σ of the change (frame noise)
tec-off-setpoint       error     |TEC − set point| > `tec_tolerance_c` during a reading
lamp-drift             error     lamp monitor (the light source's own, e.g. MEAS:LUM?) off
                                 the reference by more than `lamp_drift_percent`: the lab's
                                 `lamp_reference_cd_m2` when configured, else the run's
                                 first reading (docs/quality.md: why flag, not correct);
                                 gonio: the lamp check (`lamp_ratio`) beyond the gonio's
                                 `lamp_drift_limit_percent` even after re-referencing
lamp-unstable          error     the lamp's output noise above `lamp_flicker_percent`,
                                 from the monitor: the scatter of the `LAMP_SAMPLES` samples
                                 taken back to back just before and just after the reading
                                 (pooled rms about each group's mean, 4 degrees of freedom:
                                 this reading's own estimate), or the rms of the relative
                                 change across readings / √2 over the last `LAMP_WINDOW`
                                 readings (slower changes)
repeatability-cv       warning   CV of the luminance of a repeatability run >
                                 `repeatability_cv_percent`
radiometer-range       error     Lv outside `radiometer_min_luminance_cd_m2` …
                                 `radiometer_max_luminance_cd_m2`
radiance-negative      error     a radiometer band below −2e-9 W·sr⁻¹·m⁻²·nm⁻¹ (outside the
                                 physical range: a dark over-subtracted)
identical-spectrum     error     a radiometer spectrum equal bit for bit to an earlier
                                 reading's of the run (a repeated data block)
instrument-error       warning   the instrument answered with an error code (e.g. CS-1000A
                                 ER10 over range); the reading was retried or skipped
instrument-error:      error     data corrupted on the wire were refused (re-read); the
  implausible-data               value stored at that key may be wrong
position               error     a stage's readback differs from its setpoint by more than
                                 the tolerance the stage states (`Location.tolerance`, e.g.
                                 the rotator's `position_tolerance_deg`): the reading was
                                 taken at another angle than the one it is keyed by
=====================  ========  =============================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

from normbox_lab.acquire.store_api import Store

#: where each default comes from (shown by `normbox-lab qa --limits` and in docs)
LIMIT_SOURCES: dict[str, str] = {
    "brdf_negative_per_sr": "3× the per-pixel BRDF noise of a dark patch at grazing geometry "
                            "(QE Pro SNR 1000:1 at full scale, auto-ranged to ≥ 5 % of it)",
    "saturation_fraction": "QE Pro: 18-bit counts; above ~95 % of full scale the CCD is "
                           "nonlinear beyond its stored correction (Ocean Insight QE Pro data "
                           "sheet)",
    "noise_floor_counts": "QE Pro read noise ~15 counts and SNR 1000:1 at full scale: 2000 "
                          "counts gives ~1.5 % per-pixel noise",
    "dark_drift_counts_s": "dark current ~200 counts/s at −10 °C doubling every ~6 °C: 100 "
                           "counts/s is a ~3.5 °C change of the detector",
    "dark_current_max_counts_s": "10× the QE Pro's dark current at its −10 °C set point (~200 "
                                 "counts/s): beyond it the detector is not what its stated "
                                 "noise (SNR 1000:1) describes: its shot noise swamps weak bands",
    "tec_tolerance_c": "cseabreeze QE Pro TEC set point −10 °C; ±0.5 °C (the calibration "
                       "wait's tolerance)",
    "lamp_drift_percent": "Image Engineering LE7: regulated output; 0.5 % is a quarter of the "
                          "CS-1000A's ±2 % radiometric accuracy",
    "lamp_flicker_percent": "half the drift limit: an output noise of 0.25 % rms leaves a "
                            "reading within ±0.5 % (2σ) of the lamp's mean",
    "lamp_reference_cd_m2": "the lamp monitor's reading at the lamp's calibration (0: none; "
                            "the run's first reading is then the reference)",
    "repeatability_cv_percent": "half the repeatability protocol's 1 % change threshold",
    "radiometer_min_luminance_cd_m2": "CS-1000A specified luminance range, lower end "
                                      "(Konica Minolta catalogue, 1° acceptance; assumed)",
    "radiometer_max_luminance_cd_m2": "CS-1000A specified luminance range, upper end "
                                      "(Konica Minolta catalogue, 1° acceptance; assumed)",
    "fit_error_limit_pct": "paper: fit errors of the ColorChecker patches are a few percent; "
                           "15 % is clearly out of family",
    "fit_outlier_factor": "a material whose fit error exceeds this multiple of the median of "
                          "all materials' fit errors",
    "fit_outlier_min_pct": "…and exceeds this absolute fit error (below it the fit is within "
                           "the gonio's ±0.7 % white-standard uncertainty, a few times over)",
    "prediction_rel_se_limit": "Monte-Carlo standard error per band relative to the "
                               "radiance: 1 % (the fast renderer's default target is 0.4 %)",
}


@dataclass(frozen=True)
class QualityLimits:
    """Limits of the quality gates (lab config ``[quality]``; every field optional)."""

    brdf_negative_per_sr: float = 0.002
    saturation_fraction: float = 0.95
    noise_floor_counts: float = 2000.0
    dark_drift_counts_s: float = 100.0
    dark_current_max_counts_s: float = 2000.0
    tec_tolerance_c: float = 0.5
    lamp_drift_percent: float = 0.5
    lamp_flicker_percent: float = 0.25
    lamp_reference_cd_m2: float = 0.0
    repeatability_cv_percent: float = 0.5
    radiometer_min_luminance_cd_m2: float = 0.01
    radiometer_max_luminance_cd_m2: float = 80_000.0
    fit_error_limit_pct: float = 15.0
    fit_outlier_factor: float = 2.5
    fit_outlier_min_pct: float = 2.0
    prediction_rel_se_limit: float = 0.01


def parse_limits(table: Any, err: Callable[[str, str | None, str], Exception]) -> QualityLimits:
    """The ``[quality]`` table of a lab config; `err(table, key, message)` builds the
    `ConfigError` (file:line:field)."""
    if table is None:
        return QualityLimits()
    if not isinstance(table, dict):
        raise err("quality", None, "must be a table")
    known = {f.name for f in fields(QualityLimits)}
    values: dict[str, float] = {}
    for key, v in table.items():
        if key not in known:
            raise err("quality", key, f"unknown limit; known: {', '.join(sorted(known))}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise err("quality", key, f"must be a finite number, got {v!r}")
        if key in ("brdf_negative_per_sr", "lamp_reference_cd_m2") and v < 0:
            raise err("quality", key, f"must be ≥ 0, got {v}")
        elif key == "saturation_fraction" and not 0 < v <= 1:
            raise err("quality", key, f"must be in (0, 1], got {v}")
        elif key == "fit_outlier_factor" and v <= 1:
            raise err("quality", key, f"must be > 1, got {v}")
        elif key not in ("brdf_negative_per_sr", "lamp_reference_cd_m2") and v <= 0:
            raise err("quality", key, f"must be > 0, got {v}")
        values[key] = float(v)
    limits = QualityLimits(**values)
    if limits.radiometer_min_luminance_cd_m2 >= limits.radiometer_max_luminance_cd_m2:
        raise err("quality", "radiometer_min_luminance_cd_m2",
                  "must be below radiometer_max_luminance_cd_m2")
    return limits


def limits_from_text(text: str, path: str = "lab config") -> QualityLimits:
    """The limits in a lab-config snapshot (a run's ``lab_config``); defaults when absent."""
    import tomllib

    from normbox_lab.core.errors import ConfigError

    if not text.strip():
        return QualityLimits()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(path, 0, "quality", f"not TOML: {exc}") from exc
    lines = text.splitlines()

    def err(table: str, key: str | None, message: str) -> Exception:
        line = 0
        inside = False
        for i, raw in enumerate(lines, 1):
            s = raw.strip()
            if s.startswith("["):
                inside = s.strip("[] ") == table
                if inside and key is None:
                    line = i
                continue
            if inside and key is not None and s.split("=", 1)[0].strip() == key:
                line = i
        return ConfigError(path, line, f"{table}.{key}" if key else table, message)

    return parse_limits(data.get("quality"), err)


@dataclass(frozen=True)
class FlagSpec:
    """A flag before it is stored."""

    key: str
    gate: str
    severity: str
    value: float | None
    limit: float | None
    message: str


def brdf_flags(key: str, metadata: Mapping[str, Any], arrays: Mapping[str, Any],
               limits: QualityLimits) -> list[FlagSpec]:
    """Gates on one gonio reading (metadata and arrays as stored)."""
    import numpy as np

    out: list[FlagSpec] = []
    brdf = np.asarray(arrays["brdf_per_sr"], dtype=float)
    blocked = bool(metadata.get("blocked", False))
    bad = brdf.size - int(np.count_nonzero(np.isfinite(brdf)))
    if bad:
        out.append(FlagSpec(key, "brdf-nonfinite", "error", float(bad), 0.0,
                            f"{bad} BRDF values are NaN or infinite"))
    finite = brdf[np.isfinite(brdf)]
    if not blocked and finite.size and float(finite.min()) < -limits.brdf_negative_per_sr:
        lo = float(finite.min())
        out.append(FlagSpec(key, "brdf-negative", "error", lo, -limits.brdf_negative_per_sr,
                            f"BRDF down to {lo:.4f} sr⁻¹ (below "
                            f"−{limits.brdf_negative_per_sr:g}): stale dark or bad reference?"))
    full = metadata.get("full_scale_counts")
    peak = metadata.get("peak_counts")
    if full and peak is not None:
        frac = float(peak) / float(full)
        if frac > limits.saturation_fraction:
            out.append(FlagSpec(key, "saturation", "error", frac, limits.saturation_fraction,
                                f"peak {float(peak):.0f} counts = {100 * frac:.1f} % of full "
                                f"scale (limit {100 * limits.saturation_fraction:.0f} %)"))
    signal = metadata.get("peak_signal_counts")
    if signal is not None and not blocked and float(signal) < limits.noise_floor_counts:
        out.append(FlagSpec(key, "noise-floor", "warning", float(signal),
                            limits.noise_floor_counts,
                            f"peak signal {float(signal):.0f} counts is below the noise floor "
                            f"{limits.noise_floor_counts:g}"))
    drift = metadata.get("dark_drift_counts_s")
    # the limit plus 3 σ of the estimate itself (short darks give a noisy dark rate)
    limit = limits.dark_drift_counts_s + 3.0 * float(metadata.get("dark_drift_sigma_counts_s")
                                                     or 0.0)
    if metadata.get("dark_new") and drift is not None and abs(float(drift)) > limit:
        out.append(FlagSpec(key, "dark-drift", "warning", float(drift), limit,
                            f"dark current changed by {float(drift):+.0f} counts/s since the "
                            f"previous dark (limit ±{limits.dark_drift_counts_s:g} + 3σ of the "
                            f"estimate = ±{limit:.0f})"))
    rate = metadata.get("dark_rate_counts_s")
    if rate is not None and math.isfinite(float(rate)) and \
            float(rate) > limits.dark_current_max_counts_s:
        out.append(FlagSpec(key, "dark-current", "error", float(rate),
                            limits.dark_current_max_counts_s,
                            f"dark current {float(rate):.0f} counts/s (limit "
                            f"{limits.dark_current_max_counts_s:g}): its shot noise swamps the "
                            "weak bands; the detector is not in its stated state"))
    tec, sp = metadata.get("tec_temperature_c"), metadata.get("tec_setpoint_c")
    if tec is not None and sp is not None and math.isfinite(float(tec)) and \
            math.isfinite(float(sp)) and abs(float(tec) - float(sp)) > limits.tec_tolerance_c:
        d = float(tec) - float(sp)
        out.append(FlagSpec(key, "tec-off-setpoint", "error", d, limits.tec_tolerance_c,
                            f"detector at {float(tec):.2f} °C, {d:+.2f} °C off its set point "
                            f"{float(sp):.1f} °C (limit ±{limits.tec_tolerance_c:g})"))
    ratio, lamp_limit = metadata.get("lamp_ratio"), metadata.get("lamp_drift_limit_percent")
    if ratio is not None and lamp_limit is not None and not (
            math.isfinite(float(ratio)) and abs(100.0 * (float(ratio) - 1.0)) <= float(lamp_limit)):
        change = 100.0 * (float(ratio) - 1.0)
        out.append(FlagSpec(key, "lamp-drift", "error", change, float(lamp_limit),
                            f"gonio lamp {change:+.1f} % from its output at the white reference, "
                            f"still after the references were taken again (limit "
                            f"±{float(lamp_limit):g} %, drivers/gonio.py lamp check)"))
    return out


#: radiance below minus this is outside the physical range (the wire's resolution: values
#: below 1e-9 W·sr⁻¹·m⁻²·nm⁻¹ are sent as 0)
RADIANCE_FLOOR_W_SR_M2_NM = 2e-9
#: a spectrum with at least this many distinct non-zero values that equals an earlier reading's to
#: the last bit is a repeated data block (the radiometers' noise and ±0.3 nm / ±2 % draw
#: make two measurements differ)
IDENTICAL_MIN_BANDS = 10


def spectrum_digest(arrays: Mapping[str, Any]) -> bytes | None:
    """A digest of a radiometer reading's radiance (None when it has too few distinct
    non-zero values to call two readings the same measurement)."""
    import numpy as np

    rad = np.ascontiguousarray(np.asarray(arrays.get("radiance_W_sr_m2_nm", ()), dtype="<f8"))
    if np.unique(rad[rad != 0]).size < IDENTICAL_MIN_BANDS:
        return None                      # (a flat or empty spectrum: no measurement's shape)
    import hashlib

    return hashlib.sha256(rad.tobytes()).digest()


def spectral_flags(key: str, metadata: Mapping[str, Any], arrays: Mapping[str, Any],
                   limits: QualityLimits) -> list[FlagSpec]:
    """Gates on one radiometer reading."""
    import numpy as np

    out: list[FlagSpec] = []
    rad = np.asarray(arrays["radiance_W_sr_m2_nm"], dtype=float)
    bad = rad.size - int(np.count_nonzero(np.isfinite(rad)))
    if bad:
        out.append(FlagSpec(key, "radiance-nonfinite", "error", float(bad), 0.0,
                            f"{bad} radiance values are NaN or infinite"))
    finite = rad[np.isfinite(rad)]
    if finite.size and float(finite.min()) < -RADIANCE_FLOOR_W_SR_M2_NM:
        lo = float(finite.min())
        n = int(np.count_nonzero(finite < -RADIANCE_FLOOR_W_SR_M2_NM))
        out.append(FlagSpec(key, "radiance-negative", "error", lo, -RADIANCE_FLOOR_W_SR_M2_NM,
                            f"{n} band(s) below zero, down to {lo:.4g} W/sr/m²/nm: radiance is "
                            "never negative (a dark over-subtracted: the low bands may be "
                            "wrong)"))
    colo = metadata.get("colorimetry") or {}
    lv = colo.get("Lv_cd_m2")
    if lv is not None:
        lv = float(lv)
        lo, hi = limits.radiometer_min_luminance_cd_m2, limits.radiometer_max_luminance_cd_m2
        if not lo <= lv <= hi:
            out.append(FlagSpec(key, "radiometer-range", "error", lv, lo if lv < lo else hi,
                                f"Lv {lv:.4g} cd/m² outside the radiometer's specified range "
                                f"{lo:g} … {hi:g} cd/m²"))
    return out


def position_flags(key: str, metadata: Mapping[str, Any]) -> list[FlagSpec]:
    """`position`: every stored location whose readback is beyond its stated tolerance of
    the setpoint (a reading without a readback — an older store — is never flagged)."""
    from normbox_lab.core.types import LOCATIONS, Location

    out = []
    for name, d in (metadata.get(LOCATIONS) or {}).items():
        if d.get("tolerance") is None or d.get("setpoint") is None \
                or d.get("readback") is None:
            continue                                 # nothing stated to check against
        loc = Location.from_dict(d)
        if not loc.out_of_tolerance():
            continue
        dev = float(loc.deviation or 0.0)
        out.append(FlagSpec(key, "position", "error", dev, loc.tolerance,
                            f"{name}: readback {loc.readback:.4f} {loc.unit} differs from the "
                            f"setpoint {loc.setpoint:.4f} {loc.unit} by {dev:+.4f} (tolerance "
                            f"±{loc.tolerance:g} {loc.unit})"))
    return out


#: readings over which the lamp's output noise is estimated (`lamp-unstable`)
LAMP_WINDOW = 5
#: monitor samples taken back to back before, and again after, each reading: 2 × (3 − 1) = 4
#: degrees of freedom for the reading's own noise estimate, so a lamp flickering at 8× the
#: limit (2 % rms against 0.25 %) goes unflagged with a probability of ~5e-4 (χ²₄ below
#: 4/64), where one before/after pair (1 degree of freedom) missed it ~10 % of the time
LAMP_SAMPLES = 3


def _lamp_scatter(metadata: Mapping[str, Any]) -> float | None:
    """The lamp's relative output noise from this reading's own monitor samples (the first
    half taken before it, the second after): pooled rms about each half's mean, relative to
    the mean of all; None without at least two samples on each side."""
    samples = metadata.get("lamp_monitor_samples_cd_m2")
    if not isinstance(samples, list | tuple) or len(samples) < 4 or len(samples) % 2:
        return None
    values = [float(v) for v in samples]
    if not all(math.isfinite(v) for v in values):
        return None
    mean = sum(values) / len(values)
    if not mean > 0:
        return None
    half = len(values) // 2
    squares, dof = 0.0, 0
    for group in (values[:half], values[half:]):
        m = sum(group) / len(group)
        squares += sum((v - m) ** 2 for v in group)
        dof += len(group) - 1
    return math.sqrt(squares / dof) / mean


def _lamp_step(metadata: Mapping[str, Any]) -> float | None:
    """The relative change of the lamp monitor across one reading (after / before − 1)."""
    before, after = metadata.get("lamp_monitor_before_cd_m2"), metadata.get("lamp_monitor_cd_m2")
    if before is None or after is None or not float(before) > 0 or not math.isfinite(
            float(after)):
        return None
    return float(after) / float(before) - 1.0


class RunGates:
    """The gates of one run as the engine commits readings (also replayable from the store)."""

    def __init__(self, store: Store, run_id: int, limits: QualityLimits | None = None) -> None:
        self.store = store
        self.run_id = run_id
        self.limits = limits or QualityLimits()
        self.lamp_first: tuple[str, float] | None = None
        self.lamp_steps: list[float] = []          # the last LAMP_WINDOW monitor steps
        self.found: list[FlagSpec] = []
        #: reading keys with a flag in the store (earlier segments) or recorded since
        self._flagged = {row["key"] for row in store.flag_rows(run_id=run_id)}
        #: radiance digest → the first reading that had it (`identical-spectrum`)
        self._spectra: dict[bytes, str] = {}
        for r in store.readings(run_id):
            digest = spectrum_digest(r.arrays) if r.kind == "spectral" else None
            if digest is not None:
                self._spectra.setdefault(digest, r.key)
            mon = r.metadata.get("lamp_monitor_cd_m2")
            if mon is not None and self.lamp_first is None:
                self.lamp_first = (r.key, float(mon))
            step = _lamp_step(r.metadata)
            if step is not None:
                self.lamp_steps = [*self.lamp_steps, step][-LAMP_WINDOW:]

    def _record(self, specs: list[FlagSpec]) -> list[FlagSpec]:
        for f in specs:
            self.store.add_flag(run_id=self.run_id, artifact_id=None, key=f.key, gate=f.gate,
                                severity=f.severity, value=f.value, limit=f.limit,
                                message=f.message)
        self.found += specs
        self._flagged.update(f.key for f in specs)
        return specs

    def reading(self, key: str, kind: str, metadata: Mapping[str, Any],
                arrays: Mapping[str, Any]) -> list[FlagSpec]:
        """The per-reading gates; records and returns the flags."""
        if kind == "brdf":
            specs = brdf_flags(key, metadata, arrays, self.limits)
        elif kind == "spectral":
            specs = spectral_flags(key, metadata, arrays, self.limits)
            specs += self._identical(key, arrays)
        else:                           # e.g. a lab check's result: it flags itself
            specs = []
        specs += self._lamp(key, metadata)
        specs += position_flags(key, metadata)
        return self._record(specs)

    def _identical(self, key: str, arrays: Mapping[str, Any]) -> list[FlagSpec]:
        """`identical-spectrum`: this reading's radiance equals an earlier reading's bit for
        bit — a data block the instrument repeated (a stale buffer), not a measurement."""
        digest = spectrum_digest(arrays)
        if digest is None:
            return []
        first = self._spectra.setdefault(digest, key)
        if first == key:
            return []
        return [FlagSpec(key, "identical-spectrum", "error", None, None,
                         f"the radiance equals that of {first} bit for bit: a repeated data "
                         "block (two measurements always differ by their noise)")]

    def _lamp(self, key: str, metadata: Mapping[str, Any]) -> list[FlagSpec]:
        """`lamp-drift` and `lamp-unstable` (see the module table): values that may be wrong,
        so errors.  A reading is not corrected by the monitor: the monitor samples the panel
        at one instant, the radiometer integrates over seconds, so under flicker a ratio would
        add the monitor's own noise to the reading (docs/quality.md)."""
        out: list[FlagSpec] = []
        mon = metadata.get("lamp_monitor_cd_m2")
        if mon is None:
            return out
        mon = float(mon)
        if self.lamp_first is None:
            self.lamp_first = (key, mon)
        ref_cd_m2, ref_name = ((self.limits.lamp_reference_cd_m2, "the lamp reference")
                               if self.limits.lamp_reference_cd_m2 > 0
                               else (self.lamp_first[1], self.lamp_first[0]))
        if ref_cd_m2 > 0 and math.isfinite(mon):
            change = 100.0 * (mon / ref_cd_m2 - 1.0)
            if abs(change) > self.limits.lamp_drift_percent:
                out.append(FlagSpec(key, "lamp-drift", "error", change,
                                    self.limits.lamp_drift_percent,
                                    f"lamp monitor {mon:.4g} cd/m², {change:+.2f} % from "
                                    f"{ref_name} {ref_cd_m2:.4g} cd/m² (limit "
                                    f"±{self.limits.lamp_drift_percent:g} %)"))
        step = _lamp_step(metadata)
        estimates: list[tuple[float, str]] = []
        scatter = _lamp_scatter(metadata)
        if scatter is not None:
            n = len(metadata["lamp_monitor_samples_cd_m2"])
            how = f"scatter of the {n} monitor samples just before and after this reading"
            estimates.append((100.0 * scatter, how))
        if step is not None:
            self.lamp_steps = [*self.lamp_steps, step][-LAMP_WINDOW:]
            noise = 100.0 * math.sqrt(sum(d * d for d in self.lamp_steps)
                                      / len(self.lamp_steps) / 2.0)
            how = f"monitor before and after the last {len(self.lamp_steps)} readings"
            estimates.append((noise, how))
        if estimates:
            noise, how = max(estimates)
            if noise > self.limits.lamp_flicker_percent:
                out.append(FlagSpec(key, "lamp-unstable", "error", noise,
                                    self.limits.lamp_flicker_percent,
                                    f"lamp output noise {noise:.2f} % rms ({how}; limit "
                                    f"{self.limits.lamp_flicker_percent:g} %)"))
        return out

    def attempt(self, key: str) -> int:
        """A reading is about to be taken: the mark `superseded` needs (the newest flag id;
        0 — nothing to supersede, no query — when `key` has no flag)."""
        return int(self.store.last_flag_id()) if key in self._flagged else 0

    def superseded(self, key: str, mark: int) -> None:
        """Reading `key` was committed: the flags of earlier attempts at it (a skip in an
        earlier segment, the faults that led to it) no longer describe stored data."""
        self.store.delete_reading_flags(self.run_id, key, up_to_id=mark)

    def device_error(self, key: str, role: str, code: str, message: str) -> list[FlagSpec]:
        """An instrument error code met while taking `key` (retried or skipped)."""
        # corrupted data refused on the wire: what was stored at this key may be wrong (an
        # error); an instrument's own error code (it refused to measure) is a warning
        severity = "error" if code == "implausible-data" else "warning"
        return self._record([FlagSpec(key, f"instrument-error:{code}", severity, None, None,
                                      f"{role} reported {code}: {message}")])

    def skipped(self, key: str, role: str, message: str) -> list[FlagSpec]:
        return self._record([FlagSpec(key, "skipped", "error", None, None,
                                      f"{role}: reading skipped by the operator ({message})")])

    def finish(self, protocol: str) -> list[FlagSpec]:
        """Run-level gates once the run ends (repeatability CV)."""
        import numpy as np

        specs: list[FlagSpec] = []
        if protocol.endswith(("repeatability", "repeatability.py")):
            lv = [float((r.metadata.get("colorimetry") or {}).get("Lv_cd_m2", float("nan")))
                  for r in self.store.readings(self.run_id, "spectral")]
            lv_arr = np.array([v for v in lv if math.isfinite(v)])
            if lv_arr.size >= 2 and lv_arr.mean() > 0:
                cv = 100.0 * float(lv_arr.std(ddof=1) / lv_arr.mean())
                if cv > self.limits.repeatability_cv_percent:
                    specs.append(FlagSpec("", "repeatability-cv", "warning", cv,
                                          self.limits.repeatability_cv_percent,
                                          f"luminance CV {cv:.2f} % over {lv_arr.size} repeats "
                                          f"(limit {self.limits.repeatability_cv_percent:g} %)"))
        return self._record(specs)


__all__ = ["LAMP_SAMPLES", "LAMP_WINDOW", "LIMIT_SOURCES", "FlagSpec", "QualityLimits", "RunGates", "brdf_flags",
           "limits_from_text", "parse_limits", "spectral_flags"]
