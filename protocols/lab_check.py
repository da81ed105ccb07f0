"""Lab check: a safe self-test of every configured instrument, run through the engine.

Each check is one step of kind ``check`` (registered here; `CheckKind`), keyed
``ROLE/CHECK``.  It drives its instrument through the driver's public methods, returns a
`CheckResult` (pass/fail, the value, the limit and the limit's *source*: a datasheet, the
lab's own quality limits, or the lab's history in the store), and is committed as a reading of
kind ``check`` — so results are stored, resumable and listed by ``runs`` / ``qa`` like any
other run.  A failed check is also an error flag (gate ``lab-check``); an expired calibration
a warning flag (gate ``calibration``; an error under ``strict``).

Safe by default: nothing moves outside the configured soft limits (the soft-limit checks ask
for a target 1° beyond each limit and pass when the driver refuses it *before* sending
anything), lamps are only switched off (the radiometer's dark) or on at the configured level,
no calibration or flash setting is written.

    radiometer   identity, calibration, dark (lamp off), level (white patch at 90°, sphere at
                 `sphere_level_percent`), repeatability (`repeats` readings)
    rotator      identity, home, soft-limits, move-readback, backlash
    sphere       identity, warm-up (to stable, with its monitor's scatter)
    spectrometer identity, tec, dark-current, nonlinearity
    gonio arms   identity, home, soft-limits, travel (to each configured limit and back)

An instrument failing to answer at all fails its check (the error is the finding); the engine's
retry policy is not involved.  `run_check` runs the protocol and returns a `CheckReport`;
`normbox_lab.acquire.trust.require_recent_check` is what a run asks when the lab config wants a
passing check younger than ``[lab] require_check_h``.
"""

from __future__ import annotations

import datetime
import math
import statistics
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from normbox_lab.acquire.steps import KINDS, PlanError, Step, StepKind, prompt
from normbox_lab.acquire.store import ReadingRecord
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import DeviceError, InstrumentError, NotReady
from normbox_lab.core.spectral import WHITE_PATCH, patch_name

PROTOCOL = "lab-check"
PARAMETERS: dict[str, Any] = {
    "roles": [],                      # empty: every configured instrument
    "sphere_level_percent": 100.0,
    "repeats": 3,
    "test_angle_deg": 45.0,           # rotator: move + readback, backlash around it
    "backlash_step_deg": 5.0,
    "warmup_timeout_s": 1800.0,
    "tec_timeout_s": 600.0,
    "strict": False,                  # an expired calibration fails (default: a warning)
}

#: stages and their checks; the gonio arms get the rotator's minus the move checks
_STAGE_ROLES = ("rotator", "gonio_light_arm", "gonio_detector_arm")


@dataclass(frozen=True)
class Limit:
    """A pass limit and where it comes from."""

    low: float | None
    high: float | None
    unit: str
    source: str

    def text(self) -> str:
        if self.low is not None and self.high is not None:
            return f"{self.low:g} … {self.high:g} {self.unit}".strip()
        if self.high is not None:
            return f"≤ {self.high:g} {self.unit}".strip()
        if self.low is not None:
            return f"≥ {self.low:g} {self.unit}".strip()
        return "present"

    def holds(self, value: float) -> bool:
        return math.isfinite(value) and (self.low is None or value >= self.low) \
            and (self.high is None or value <= self.high)


#: the limits that do not depend on the lab config (the others are built in `_limits`)
DARK_LV_CD_M2 = Limit(None, 0.05, "cd/m²", "lab criterion: a dark reading (lamp off) below 5× "
                      "the radiometer's lower range limit (0.01 cd/m², [quality]), under 0.1 % "
                      "of the white patch at 90° at full level (≈68 cd/m² in the virtual Normbox)")
REPEATABILITY = Limit(None, 4.0, "% (max-min)/mean", "Konica Minolta CS-1000A / CS-2000A "
                      "specifications: ±2 % luminance accuracy; readings of a stable source "
                      "stay inside that band (a span of 4 %)")
HISTORY_PERCENT = 4.0
HISTORY_SOURCE = ("lab history: the last lab check that passed every check, ±4 % (each "
                  "reading within the radiometer's stated ±2 %)")
BACKLASH = Limit(None, 0.1, "°", "lab criterion: 2 % of the reference sweep's 5° "
                 "sample-angle step")
SPHERE_SCATTER = Limit(None, 0.5, "% (max-min)/mean", "[quality] lamp_drift_percent (0.5 %, "
                       "a quarter of the radiometer's ±2 %; docs/quality.md), applied to the "
                       "monitor's 10 samples after the sphere reports stable")
NONLINEARITY = Limit(0.5, 1.5, "(c0)", "Ocean Insight QE Pro: factory nonlinearity "
                     "coefficients stored on the device (OBP 0x00181100); c0 near 1")


@dataclass
class CheckResult:
    """One check's outcome (what the store keeps in the reading's metadata)."""

    check: str
    role: str
    passed: bool
    value: float | None
    limit: str
    unit: str
    source: str
    message: str
    samples: list[float] = field(default_factory=list)
    warning: str = ""
    limit_value: float | None = None

    def as_metadata(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("samples")
        return d


def _checked(step: Step) -> str:
    """The role of the instrument a check examines (`instrument`, else the step's role: the
    radiometer's dark runs under the lamp's role, since the engine holds every radiometer
    reading until the lamps are stable)."""
    return str(step.params.get("instrument") or step.role)


def _result(check: str, role: str, value: float, limit: Limit, message: str,
            samples: list[float] | None = None) -> CheckResult:
    ok = limit.holds(value)
    bound = limit.high if limit.high is not None and (limit.low is None or value > limit.high) \
        else limit.low
    return CheckResult(check, role, ok, float(value), limit.text(), limit.unit, limit.source,
                       message, list(samples or [value]), limit_value=bound)


def _fail(check: str, role: str, message: str, source: str = "") -> CheckResult:
    return CheckResult(check, role, False, None, "", "", source, message)


# --- the check functions (run: the engine's StepRunner; step: the check's step) -------------------

def _history(run: Any, role: str, check: str) -> tuple[float, str] | None:
    """The value of `check` of `role` in the newest earlier lab-check run that passed every
    check it made (a value from a run with a fault elsewhere is no reference)."""
    best = None
    for rec in run.store.runs():
        if rec.protocol != PROTOCOL or rec.id == run.run_id or rec.status != "done":
            continue
        results = {f"{m.get('role')}/{m.get('check')}": m for m in results_of(run.store, rec.id)}
        m = results.get(f"{role}/{check}")
        if m is None or m.get("value") is None or not all(r.get("passed")
                                                          for r in results.values()):
            continue
        best = (float(m["value"]), f"run {rec.id}")
    return best


def check_identity(run: Any, step: Step) -> CheckResult:
    role = step.role
    inst = run.instrument(role)
    ident = inst.identify()
    want = step.params.get("serial_number", "")
    got = str(ident.serial_number)
    if want and got != want:
        return _fail("identity", role, f"{ident.model} serial {got!r} is not the configured "
                     f"{want!r}: another instrument on this port (swapped cables?)",
                     "lab config: serial_number (written by lab discover)")
    note = f"{ident.model} serial {got or '(none reported)'}" + (
        f", firmware {ident.firmware}" if ident.firmware else "")
    return CheckResult("identity", role, True, None, want or "(not configured)", "",
                       "lab config: serial_number", note)


def check_calibration(run: Any, step: Step) -> CheckResult:
    role = step.role
    p = step.params
    today = datetime.date.fromisoformat(p["today"])
    due = datetime.date.fromisoformat(p["due"])
    days = (due - today).days
    what = f"certificate {p['certificate']} ({p['laboratory']}), due {p['due']}"
    source = f"lab config: instruments.{role}.calibration"
    if days >= 0:
        return CheckResult("calibration", role, True, float(days), "due date not passed",
                           "days left", source, f"{what}: in force, {days} days left")
    message = f"{what}: EXPIRED {-days} days ago"
    strict = bool(p.get("strict"))
    return CheckResult("calibration", role, not strict, float(days), "due date not passed",
                       "days left", source, message, warning="" if strict else message)


def _luminance(reading: Any) -> float:
    colo = getattr(reading, "colorimetry", None)
    if colo is None:
        raise DeviceError("COLORIMETRY", "the reading carries no luminance")
    return float(colo.Lv_cd_m2)


def check_dark(run: Any, step: Step) -> CheckResult:
    lamp_role = step.params.get("lamp", "")
    if lamp_role:
        run.instrument(lamp_role).set_output(False)          # the only lamp action: off
    role = _checked(step)
    lv = _luminance(run.instrument(role).measure())
    return _result("dark", role, lv, DARK_LV_CD_M2, f"Lv {lv:.4g} cd/m² with the lamp off")


def check_level(run: Any, step: Step) -> CheckResult:
    role = step.role
    lv = _luminance(run.instrument(role).measure())
    lo, hi = float(step.params["range_low"]), float(step.params["range_high"])
    in_range = Limit(lo, hi, "cd/m²", "the radiometer's specified luminance range "
                     "([quality] radiometer_min/max_luminance_cd_m2, docs/quality.md)")
    result = _result("level", role, lv, in_range,
                     f"Lv {lv:.4g} cd/m² of the white patch at 90°, sphere at "
                     f"{step.params['level_percent']:g} %")
    history = _history(run, role, "level")
    if result.passed and history is not None:
        ref, where = history
        limit = Limit(ref * (1 - HISTORY_PERCENT / 100), ref * (1 + HISTORY_PERCENT / 100),
                      "cd/m²", f"{HISTORY_SOURCE} ({where}: {ref:.4g} cd/m²)")
        result = _result("level", role, lv, limit,
                         f"Lv {lv:.4g} cd/m², {100 * (lv / ref - 1):+.2f} % from {where}")
    elif result.passed:
        result.message += "; no earlier check: this value is the lab's reference from now on"
    return result


def check_repeatability(run: Any, step: Step) -> CheckResult:
    inst = run.instrument(step.role)
    values = [_luminance(inst.measure()) for _ in range(int(step.params["repeats"]))]
    mean = statistics.fmean(values)
    span = 100.0 * (max(values) - min(values)) / mean if mean > 0 else math.inf
    return _result("repeatability", step.role, span, REPEATABILITY,
                   f"{len(values)} readings, mean {mean:.4g} cd/m², span {span:.3f} %", values)


def _stage(run: Any, step: Step) -> Any:
    return run.instrument(step.role)


def check_home(run: Any, step: Step) -> CheckResult:
    stage = _stage(run, step)
    stage.home(wait=True)
    pos = float(stage.position_deg())
    tol = float(stage.position_tolerance_deg)
    limit = Limit(-tol, tol, "°", "the driver's position tolerance (position_tolerance_deg)")
    if not stage.is_homed():
        return _fail("home", step.role, "homing ended without a reference")
    return _result("home", step.role, pos, limit, f"homed, at {pos:.4f}°")


def check_soft_limits(run: Any, step: Step) -> CheckResult:
    stage = _stage(run, step)
    lo, hi = float(stage.min_angle_deg), float(stage.max_angle_deg)
    refused = []
    for target in (hi + 1.0, lo - 1.0):
        try:
            stage.check_target(target)
        except DeviceError as exc:
            if exc.code == "SOFT_LIMIT":
                refused.append(target)
    source = f"lab config: instruments.{step.role} min/max_angle_deg"
    if len(refused) != 2:
        return _fail("soft-limits", step.role, f"a target outside {lo:g} … {hi:g}° was not "
                     "refused", source)
    return CheckResult("soft-limits", step.role, True, None, f"{lo:g} … {hi:g} °", "°", source,
                       f"{hi + 1:g}° and {lo - 1:g}° refused before anything was sent")


def check_travel(run: Any, step: Step) -> CheckResult:
    """Drive to each configured soft limit (the range the lab declared safe) and back to 0°;
    the largest readback error is the value (a stall, a limit switch inside the range)."""
    stage = _stage(run, step)
    tol = float(stage.position_tolerance_deg)
    errors = []
    for target in (float(stage.max_angle_deg), float(stage.min_angle_deg), 0.0):
        stage.move_to(target, wait=True)
        errors.append(abs(float(stage.position_deg()) - target))
    limit = Limit(None, tol, "°", "the driver's position tolerance (position_tolerance_deg)")
    return _result("travel", step.role, max(errors), limit,
                   f"reached {stage.max_angle_deg:g}°, {stage.min_angle_deg:g}° and 0°; "
                   f"largest readback error {max(errors):.4f}°", errors)


def check_move(run: Any, step: Step) -> CheckResult:
    stage = _stage(run, step)
    target = float(step.params["angle_deg"])
    stage.move_to(target, wait=True)
    pos = float(stage.position_deg())
    tol = float(stage.position_tolerance_deg)
    limit = Limit(target - tol, target + tol, "°",
                  "the driver's position tolerance (position_tolerance_deg)")
    return _result("move-readback", step.role, pos, limit,
                   f"moved to {target:g}°, reads back {pos:.4f}°")


def check_backlash(run: Any, step: Step) -> CheckResult:
    stage = _stage(run, step)
    target, d = float(step.params["angle_deg"]), float(step.params["step_deg"])
    stage.move_to(target - d, wait=True)
    stage.move_to(target, wait=True)
    from_below = float(stage.position_deg())
    stage.move_to(target + d, wait=True)
    stage.move_to(target, wait=True)
    from_above = float(stage.position_deg())
    diff = abs(from_below - from_above)
    return _result("backlash", step.role, diff, BACKLASH,
                   f"{target:g}° from below {from_below:.4f}°, from above {from_above:.4f}°",
                   [from_below, from_above])


def check_warmup(run: Any, step: Step) -> CheckResult:
    lamp = run.instrument(step.role)
    level = float(step.params["level_percent"])
    timeout_s = float(step.params["timeout_s"])
    lamp.set_level_percent(level)
    lamp.set_output(True)
    t0 = run.clock.now_s()
    while not lamp.is_stable():
        if run.clock.now_s() - t0 > timeout_s:
            return _fail("warm-up", step.role, f"not stable after {timeout_s:g} s "
                         f"(state {lamp.state()})", "protocol parameter warmup_timeout_s")
        run.clock.sleep(1.0)
    took = run.clock.now_s() - t0
    samples = []
    for _ in range(10):
        samples.append(float(lamp.luminance_cd_m2()))
        run.clock.sleep(1.0)
    mean = statistics.fmean(samples)
    scatter = 100.0 * (max(samples) - min(samples)) / mean if mean > 0 else math.inf
    limit = Limit(None, float(step.params.get("scatter_percent", SPHERE_SCATTER.high)),
                  SPHERE_SCATTER.unit, SPHERE_SCATTER.source)
    return _result("warm-up", step.role, scatter, limit,
                   f"stable after {took:.0f} s at {level:g} %; monitor {mean:.4g} cd/m², "
                   f"scatter {scatter:.3f} %", samples)


def check_tec(run: Any, step: Step) -> CheckResult:
    """The TEC reaches its set point and holds it through an acquisition (the lamp shutter
    closed): the temperature read after the frame is the value."""
    spec = run.instrument(step.role)
    tol = float(step.params["tolerance_c"])
    setpoint = float(getattr(spec, "tec_setpoint_c", -10.0))
    limit = Limit(setpoint - tol, setpoint + tol, "°C", "[quality] tec_tolerance_c around the "
                  "set point (QE Pro: thermoelectric cooling, set point −10 °C by default)")
    try:
        spec.wait_tec_stable(tolerance_c=tol, timeout_s=float(step.params["timeout_s"]))
    except NotReady as exc:
        t = float(spec.tec_temperature_c())
        return _result("tec", step.role, t, limit, str(exc))
    _close_shutter(spec)
    spec.set_integration_time_s(0.1)
    spec.acquire(correct_dark=False, correct_nonlinearity=False)
    t = float(spec.tec_temperature_c())
    return _result("tec", step.role, t, limit,
                   f"TEC at {t:.2f} °C after a frame, set point {setpoint:g} °C")


def _close_shutter(spec: Any) -> None:
    try:
        spec.set_lamp_enabled(False)      # the gonio lamp's shutter: closed
    except NotReady:
        pass                              # a backend without the lamp line


def check_dark_current(run: Any, step: Step) -> CheckResult:
    import numpy as np

    spec = run.instrument(step.role)
    _close_shutter(spec)
    t_s = float(step.params["integration_s"])
    spec.set_integration_time_s(t_s)
    acq = spec.acquire(correct_dark=False, correct_nonlinearity=False)
    raw = np.asarray(acq.raw_counts, dtype=float)
    dark_px = list(range(4)) + list(range(raw.size - 4, raw.size))
    active = np.ones(raw.size, bool)
    active[dark_px] = False
    rate = float((raw[active].mean() - raw[dark_px].mean()) / t_s)
    history = _history(run, step.role, "dark-current")
    if history is None:
        limit = Limit(None, float(step.params["max_counts_s"]), "counts/s",
                      "lab criterion: under 1 % of full scale (262 143 counts) per second")
    else:
        ref, where = history
        limit = Limit(None, max(2.0 * ref, 50.0), "counts/s",
                      f"lab history ({where}: {ref:.4g} counts/s): at most twice that")
    return _result("dark-current", step.role, rate, limit,
                   f"{rate:.4g} counts/s above the electrically dark pixels at {t_s:g} s, "
                   f"TEC {acq.tec_temperature_c:.2f} °C")


def check_nonlinearity(run: Any, step: Step) -> CheckResult:
    spec = run.instrument(step.role)
    if not spec.has_nonlinearity:
        return _fail("nonlinearity", step.role, "no nonlinearity coefficients on the device",
                     NONLINEARITY.source)
    coeffs = [float(c) for c in spec._features()["nonlinearity_coefficients"][0]
              .get_nonlinearity_coefficients()]
    if not coeffs or not all(math.isfinite(c) for c in coeffs):
        return _fail("nonlinearity", step.role, f"coefficients not finite: {coeffs}",
                     NONLINEARITY.source)
    return _result("nonlinearity", step.role, coeffs[0], NONLINEARITY,
                   f"{len(coeffs)} coefficients, c0 {coeffs[0]:.6g}", coeffs)


CHECKS: dict[str, Callable[[Any, Step], CheckResult]] = {
    "identity": check_identity, "calibration": check_calibration, "dark": check_dark,
    "level": check_level, "repeatability": check_repeatability, "home": check_home,
    "soft-limits": check_soft_limits, "travel": check_travel, "move-readback": check_move, "backlash": check_backlash,
    "warm-up": check_warmup, "tec": check_tec, "dark-current": check_dark_current,
    "nonlinearity": check_nonlinearity,
}
#: rough durations for the dry run's ETA (s)
_ESTIMATE_S = {"travel": 40.0, "dark": 130.0, "level": 10.0, "repeatability": 30.0, "home": 20.0,
               "move-readback": 10.0, "backlash": 10.0, "warm-up": 600.0, "tec": 120.0,
               "dark-current": 2.0}


class CheckKind(StepKind):
    """One check: runs its function, commits a ``check`` reading (and a flag when it fails)."""

    name = "check"
    commits = True

    def describe(self, step: Step) -> str:
        return f"check {_checked(step)}: {step.params['check']}"

    def estimate_s(self, step: Step, est: Any) -> float:
        return _ESTIMATE_S.get(str(step.params["check"]), 1.0)

    def execute(self, step: Step, run: Any, for_key: str) -> CheckResult:
        name = str(step.params["check"])
        try:
            return CHECKS[name](run, step)
        except (InstrumentError, NotReady) as exc:      # the instrument's failure is the finding
            return _fail(name, _checked(step), f"{type(exc).__name__}: {exc}")

    def commit(self, step: Step, result: CheckResult, run: Any,
               metadata: dict[str, Any]) -> ReadingRecord:
        import numpy as np

        meta = {**metadata, **result.as_metadata()}
        record = ReadingRecord("check", {"samples": np.asarray(result.samples, dtype=float)},
                               meta, _checked(step), run.clock.wall_time_s())
        run.store.add_record(run.run_id, step.key, record)
        if not result.passed:
            gate = "calibration" if result.check == "calibration" else "lab-check"
            run.store.add_flag(run_id=run.run_id, artifact_id=None, key=step.key, gate=gate,
                               severity="error", value=result.value, limit=result.limit_value,
                               message=f"{step.key}: {result.message} (limit {result.limit}; "
                                       f"{result.source})")
        elif result.warning:
            run.store.add_flag(run_id=run.run_id, artifact_id=None, key=step.key,
                               gate="calibration", severity="warning", value=result.value,
                               limit=0.0, message=f"{step.key}: {result.warning}")
        return record


KINDS.setdefault(CheckKind.name, CheckKind())


def _check(role: str, name: str, requires: dict[str, Any] | None = None,
           **params: Any) -> Step:
    return Step(f"{role}/{name}", "check", {"role": role, "check": name, **params},
                requires=dict(requires or {}))


def steps(params: dict[str, Any], lab: Any = None) -> list[Step]:
    config = getattr(lab, "config", None)
    configured = list(config.instruments) if config is not None else \
        ["radiometer", "rotator", "sphere"]
    roles = _roles(params, configured)
    quality = getattr(config, "quality", None)
    today = datetime.date.today().isoformat()
    level = float(params["sphere_level_percent"])
    out: list[Step] = []

    def common(role: str, requires: dict[str, Any] | None = None) -> None:
        out.extend(_common_checks(config, role, requires, today, bool(params["strict"])))

    for role in (r for r in _STAGE_ROLES if r in roles):
        common(role)
        out.append(_check(role, "home"))
        out.append(_check(role, "soft-limits"))
        if role == "rotator":
            a = float(params["test_angle_deg"])
            out.append(_check(role, "move-readback", angle_deg=a))
            out.append(_check(role, "backlash", angle_deg=a,
                              step_deg=float(params["backlash_step_deg"])))
        else:
            out.append(_check(role, "travel"))
    if "sphere" in roles:
        common("sphere")
        out.append(_check("sphere", "warm-up", level_percent=level,
                          timeout_s=float(params["warmup_timeout_s"]),
                          scatter_percent=quality.lamp_drift_percent if quality is not None
                          else SPHERE_SCATTER.high))
    if "radiometer" in roles and "rotator" in configured and "sphere" in configured:
        need = {"sphere": "stable", "rotator": 90.0, "sample": f"patch:{WHITE_PATCH}"}
        out.extend(_white_at_90(params, level))
        # (a radiometer's every step waits for stable lamps: these too)
        common("radiometer", need)
        out.extend(_radiometer_on_white(params, quality, level, need))
    if "radiometer" in roles:
        if "radiometer/level" not in {s.key for s in out}:
            common("radiometer")
        lamp = "sphere" if "sphere" in configured else ""
        # under the lamp's role: the engine holds a radiometer reading until the lamps are
        # stable, and this one wants the lamp off (switched off here, last)
        out.append(Step("radiometer/dark", "check", {"role": lamp or "radiometer",
                                                     "instrument": "radiometer",
                                                     "check": "dark", "lamp": lamp}))
    if "spectrometer" in roles:
        common("spectrometer")
        tol = quality.tec_tolerance_c if quality is not None else 0.5
        out.append(_check("spectrometer", "tec", tolerance_c=tol,
                          timeout_s=float(params["tec_timeout_s"])))
        out.append(_check("spectrometer", "dark-current", integration_s=1.0,
                          max_counts_s=2621.0))
        out.append(_check("spectrometer", "nonlinearity"))
    return out


def _roles(params: dict[str, Any], configured: list[str]) -> list[str]:
    """The roles to check (default: every configured one), after the parameters' limits."""
    roles = list(params["roles"]) or configured
    for r in roles:
        if r not in configured:
            raise PlanError(f"roles: {r!r} is not an instrument of the lab config "
                            f"({', '.join(configured)})")
    for key in ("sphere_level_percent", "warmup_timeout_s", "tec_timeout_s",
                "backlash_step_deg"):
        v = params[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1e6:
            raise PlanError(f"{key}: must be a positive number, got {v!r}")
    if isinstance(params["repeats"], bool) or not isinstance(params["repeats"], int) \
            or not 2 <= params["repeats"] <= 100:
        raise PlanError(f"repeats: must be an integer 2–100, got {params['repeats']!r}")
    return roles


def _common_checks(config: Any, role: str, requires: dict[str, Any] | None, today: str,
                   strict: bool) -> list[Step]:
    """What every instrument gets: its identity, and its certificate when the config names
    one (checked against `today`; `strict`: an expired one is an error)."""
    inst = config.instruments[role] if config is not None else None
    out = [_check(role, "identity", requires,
                  serial_number=inst.serial_number if inst is not None else "")]
    cal = inst.calibration if inst is not None else None
    if cal is not None:
        out.append(_check(role, "calibration", requires,
                          today=today, due=cal.due.isoformat(),
                          certificate=cal.certificate, laboratory=cal.laboratory,
                          strict=strict))
    return out


def _white_at_90(params: dict[str, Any], level: float) -> list[Step]:
    """Stable lamps, the rotator at 90° and the white patch on the holder."""
    from normbox_lab.acquire.steps import move, wait_stable

    return [wait_stable("sphere/stable", "sphere", level_percent=level,
                        timeout_s=float(params["warmup_timeout_s"])),
            move("rotator/to-90", "rotator", 90.0),
            prompt("radiometer/place-white",
                   f"place patch {WHITE_PATCH} ({patch_name(WHITE_PATCH)}) on the holder",
                   action="place_patch", patch=WHITE_PATCH,
                   sets={"sample": f"patch:{WHITE_PATCH}"})]


def _radiometer_on_white(params: dict[str, Any], quality: Any, level: float,
                         need: dict[str, Any]) -> list[Step]:
    """The radiometer on the white patch at 90°: its level within the quality limits, and
    its repeatability."""
    lo = quality.radiometer_min_luminance_cd_m2 if quality is not None else 0.01
    hi = quality.radiometer_max_luminance_cd_m2 if quality is not None else 80000.0
    return [Step("radiometer/level", "check",
                 {"role": "radiometer", "check": "level", "level_percent": level,
                  "range_low": lo, "range_high": hi, "angle_deg": 90.0,
                  "patch": WHITE_PATCH}, requires=need),
            Step("radiometer/repeatability", "check",
                 {"role": "radiometer", "check": "repeatability",
                  "repeats": int(params["repeats"]), "angle_deg": 90.0,
                  "patch": WHITE_PATCH}, requires=need)]


# --- running it, and what a sweep asks of it ------------------------------------------------------

@dataclass
class CheckReport:
    run_id: int
    uuid: str
    status: str
    results: list[dict[str, Any]]

    @property
    def passed(self) -> bool:
        return self.status == "done" and all(r.get("passed") for r in self.results)

    def lines(self) -> list[str]:
        out = []
        for r in self.results:
            mark = "PASS" if r.get("passed") else "FAIL"
            warn = " (warning)" if r.get("warning") else ""
            limit = f" [limit {r['limit']}; {r['source']}]" if r.get("limit") else ""
            out.append(f"{mark}{warn} {r['role']}/{r['check']}: {r['message']}{limit}")
        failed = sum(not r.get("passed") for r in self.results)
        out.append(f"lab check run {self.run_id} ({self.uuid[:8]}): {self.status}, "
                   f"{len(self.results) - failed}/{len(self.results)} checks passed"
                   + (f", {failed} FAILED" if failed else ""))
        return out


def results_of(store: Store, run_id: int) -> list[dict[str, Any]]:
    return [dict(r.metadata) for r in store.readings(run_id, kind="check")]


def run_check(config: Any, store_path: str, overrides: dict[str, Any], *,
              make_lab: Callable[..., Any] | None = None, world: str = "analytic",
              **options: Any) -> CheckReport:
    """Run the lab check on `config` into the store at `store_path` (`make_lab`: how a lab with
    ``sim://`` ports is built, ``normbox_lab.sim.labsim.build_lab``)."""
    from normbox_lab.acquire.session import open_run
    from normbox_lab.acquire.store import Store

    with Store(store_path) as store, open_run(PROTOCOL, store=store, config=config,
                                              params=overrides, world=world,
                                              make_lab=make_lab, **options) as opened:
        result = opened.run()
        results = results_of(store, result.run_id)
        done = {f"{r['role']}/{r['check']}" for r in results}
        why = {d.get("key"): d.get("error", "") for _, kind, d in store.events(result.run_id)
               if kind == "skip"}
        for step in opened.plan.steps:           # planned checks that never ran: failures too
            if step.kind == "check" and step.key not in done:
                role, _, name = step.key.partition("/")
                results.append({"role": role, "check": name, "passed": False,
                                "message": f"not run: {why.get(step.key) or result.status}"})
        return CheckReport(result.run_id, result.uuid, result.status, results)


__all__ = ["CHECKS", "PARAMETERS", "CheckKind", "CheckReport", "CheckResult", "Limit",
           "results_of", "run_check", "steps"]
