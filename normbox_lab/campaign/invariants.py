"""The invariants the simulation campaign checks after each scenario (docs/simulation-testing.md).

(a) **Oracle.**  Every stored reading without an *error* flag agrees with the world's truth for
    that reading — the noise-free value at the geometry the world really rendered, at the
    lamp's set level — within the instrument's stated uncertainty:
    radiometers ±2 % radiometric and ±0.3 nm wavelength (`sim.radiometer_common`), 5
    significant digits on the wire, the lamp change the lab's `lamp-drift` gate accepts
    unflagged (0.5 %) plus the sphere's 0.02 % noise and slow drift; the gonio ±2 %
    plus the white standard's ±0.7 % plus 6σ of each band's own counting noise (the QE Pro's
    shot and read noise at the counts the reading and its white reference had:
    `brdf_sigma_rel`).  The geometry the
    world rendered must also be the one the reading claims (patch, sample angle within
    `ANGLE_TOLERANCE_DEG`, panel point, gonio material and arm angles).
(b) **Typed failures.**  A segment that ends by itself never prints a traceback; a non-zero
    exit comes with one typed line (``normbox-lab: …``) or the run's status line; exit 0 only
    when the run's data are complete or every missing reading carries an error flag.
(c) **No hang.**  No reading takes longer (virtual clock) than its timing model allows with
    its retries: the engine's own estimate for it + `DRIVER_TIMEOUT_S` (× `LATCHED_FACTOR`
    once a latched condition — a dimmed or drifting lamp, a warmer detector — changed the
    physics), plus, per fault the emulators injected since the previous reading began, the
    segment's costliest reading (every state established anew: a lamp that lost power warms
    up again) + `DRIVER_TIMEOUT_S` and the waits the scenario's faults declare (a lamp not
    stable for P seconds: `FaultKind.param_is_wait_s`, at most the suspend timeout), plus,
    per fault, warning, suspension and prompt the engine recorded for it, a retry allowance (a wait that ran to its own timeout — a lamp never
    stable — the run's stated suspend timeout); no segment outlives its wall-clock limit.
(d) **Consistent state.**  Store, ``runs`` and ``qa`` agree on the run's status, readings and
    flags; a stored reading carries no skip flag; "running" means a live owner holds the run
    lock, and a second ``run --resume`` while the run executes is refused with a typed line
    naming the owner's pid; every reading a killed process reported stored is in the store.
(e) **Resume.**  With kills, the resumed run's readings match an uninterrupted run of the same
    scenario: the same keys when both are done, the same claimed geometry, values within both
    readings' uncertainty.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from normbox_lab.campaign.harness import Execution, qa_listing, runs_listing

if TYPE_CHECKING:
    from normbox_lab.acquire.store_api import Store

RADIOMETRIC = 0.02
WAVELENGTH_NM = 0.3
DIGITS_REL = 1e-4                  # "#.####e±#": half a unit in the 5th digit, with margin
SPHERE_NOISE_REL = 0.001           # sphere noise (4σ of 0.02 %) + slow drift over a run


def lamp_gate_rel() -> float:
    """The lamp change the lab accepts without a flag (its `lamp-drift` gate, 0.5 %): part
    of an accepted reading's stated uncertainty."""
    from normbox_lab.acquire.quality import QualityLimits

    return float(QualityLimits().lamp_drift_percent) / 100.0


LAMP_REL = lamp_gate_rel() + SPHERE_NOISE_REL
ABS_FLOOR = 2e-9                   # values below 1e-9 are sent as 0.0000e-9
GONIO_REL = 0.027                  # ±2 % gonio + ±0.7 % white standard
ANGLE_TOLERANCE_DEG = 0.25
AIM_TOLERANCE_MM = 0.5
FAULT_ALLOWANCE_S = 120.0          # timeouts, drains, reconnect windows of one retry
DRIVER_TIMEOUT_S = 30.0            # a command timeout, a drain and a re-handshake
LATCHED_FACTOR = 10.0              # a dimmed lamp or a warmer detector may lengthen exposures
PROMPT_ALLOWANCE_S = 60.0
STATUS_LINE = re.compile(r"^run [0-9a-f-]{36} \(id \d+\): ")


@dataclass(frozen=True)
class Violation:
    invariant: str          # a … e
    cls: str                # a short class for grouping and shrinking, e.g. "a:spectral"
    message: str

    def line(self) -> str:
        return f"({self.invariant}) {self.cls}: {self.message}"


# --- (a) the oracle --------------------------------------------------------------------------
_ANALYTIC: Any = None


def analytic_world() -> Any:
    global _ANALYTIC
    if _ANALYTIC is None:
        from normbox_lab.sim.analytic_world import AnalyticWorld

        _ANALYTIC = AnalyticWorld()
    return _ANALYTIC


def spectral_bounds(truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The band-by-band interval a correct radiometer reading of `truth` (1 nm grid) lies in."""
    t = np.asarray(truth, dtype=float)
    slope = np.zeros_like(t)
    if t.size > 1:
        d = np.abs(np.diff(t))
        slope[:-1] = d
        slope[1:] = np.maximum(slope[1:], d)
    lo = np.maximum(t - WAVELENGTH_NM * slope, 0.0) * (1 - RADIOMETRIC)
    hi = (t + WAVELENGTH_NM * slope) * (1 + RADIOMETRIC)
    margin = (DIGITS_REL + LAMP_REL) * np.abs(t) + ABS_FLOOR
    return lo - margin, hi + margin


def _claimed_material(meta: dict[str, Any]) -> str:
    m = meta.get("material")
    return f"patch-{int(m)}" if isinstance(m, int) or str(m).isdigit() else str(m)


def spectral_truth(meta: dict[str, Any], view: dict[str, Any] | None,
                   wavelength_nm: np.ndarray) -> tuple[np.ndarray | None, list[str]]:
    """(truth on `wavelength_nm`, geometry mismatches) for a stored radiometer reading."""
    world = analytic_world()
    problems: list[str] = []
    nominal = 1.0 if view is None else float(view.get("nominal_output", 1.0))
    if "x_mm" in meta:                                   # the light map
        x, y = float(meta["x_mm"]), float(meta["y_mm"])
        aim = None if view is None else view.get("aim")
        if view is not None and (aim is None or math.hypot(aim[0] - x, aim[1] - y)
                                 > AIM_TOLERANCE_MM):
            problems.append(f"claims panel point ({x:+.0f}, {y:+.0f}) mm, the world showed "
                            f"{'the sample' if aim is None else tuple(round(v) for v in aim)}")
        truth = world.panel_radiance(x, y) * nominal
        if view is not None and view.get("truth") is not None:
            truth = np.asarray(view["truth"], dtype=float)
    else:
        patch = meta.get("patch")
        angle = float(meta.get("angle_deg", 90.0))
        if view is not None:
            if view.get("aim") is not None:
                problems.append(f"claims patch {patch} at {angle:g}°, the radiometer looked "
                                "at the panel")
            if patch is not None and view.get("patch") != int(patch):
                problems.append(f"claims patch {patch}, the world held patch "
                                f"{view.get('patch')}")
            if abs(float(view["angle_deg"]) - angle) > ANGLE_TOLERANCE_DEG:
                problems.append(f"claims {angle:g}°, the sample stood at "
                                f"{float(view['angle_deg']):.2f}°")
            angle = float(view["angle_deg"])
        if view is not None and view.get("truth") is not None:
            truth = np.asarray(view["truth"], dtype=float)
        else:
            truth = world.radiance_at(None if patch is None else int(patch), angle) * nominal
    wl = world.wavelength_nm
    if truth.shape != wl.shape or not np.array_equal(np.asarray(wavelength_nm, float), wl):
        truth = np.interp(np.asarray(wavelength_nm, float), wl, truth)
    return truth, problems


def check_spectral(key: str, meta: dict[str, Any], arrays: dict[str, np.ndarray],
                   view: dict[str, Any] | None) -> list[str]:
    wl = np.asarray(arrays["wavelength_nm"], dtype=float)
    measured = np.asarray(arrays["radiance_W_sr_m2_nm"], dtype=float)
    truth, problems = spectral_truth(meta, view, wl)
    if truth is None:
        return problems
    if measured.shape != truth.shape or not np.all(np.isfinite(measured)):
        return [*problems, (f"{measured.size} values (finite: "
                            f"{np.isfinite(measured).all()}), expected {truth.size} finite")]
    lo, hi = spectral_bounds(truth)
    bad = np.flatnonzero((measured < lo) | (measured > hi))
    if bad.size:
        ratio = measured[bad] / np.where(truth[bad] != 0, truth[bad], np.nan)
        worst = bad[int(np.nanargmax(np.abs(np.nan_to_num(ratio - 1, nan=np.inf))))]
        problems.append(
            f"{bad.size}/{wl.size} bands outside ±2 %/±0.3 nm of the truth; worst "
            f"{wl[worst]:.0f} nm: {measured[worst]:.4g} vs {truth[worst]:.4g} "
            f"(×{measured[worst] / truth[worst] if truth[worst] else math.inf:.3f}); "
            f"median ratio {np.nanmedian(measured / np.where(truth > 0, truth, np.nan)):.4f}")
    return problems


def check_brdf(key: str, meta: dict[str, Any], arrays: dict[str, np.ndarray],
               note: dict[str, Any] | None) -> list[str]:
    problems: list[str] = []
    claimed = _claimed_material(meta)
    if meta.get("blocked"):
        return problems                       # a declared shadowed geometry: no value claimed
    if note is not None:
        if str(note.get("material")) != claimed:
            problems.append(f"claims {claimed}, the gonio held {note.get('material')}")
        for arm in ("theta_i_deg", "theta_o_deg"):
            if arm in meta and abs(float(note[arm]) - float(meta[arm])) > 0.5:
                problems.append(f"claims {arm} {float(meta[arm]):g}, the arm stood at "
                                f"{float(note[arm]):.2f}")
    world = analytic_world()
    wl = np.asarray(arrays["wavelength_nm"], dtype=float)
    f = np.asarray(arrays["brdf_per_sr"], dtype=float)
    truth = np.interp(wl, world.wavelength_nm, world._rho(claimed)) / np.pi
    if not np.all(np.isfinite(f)):
        return [*problems, "non-finite BRDF values"]
    sigma = brdf_sigma_rel(meta, arrays, truth)
    if "raw_counts" not in arrays:          # no counts to state the noise from: its estimate
        with np.errstate(divide="ignore", invalid="ignore"):
            sigma = local_scatter(np.where(truth > 0, f / truth, 1.0))
    limit = GONIO_REL + BRDF_SIGMAS * sigma
    band = np.isfinite(limit) & (truth > 0)
    if not band.any():
        return problems
    r = f[band] / truth[band]
    out = np.abs(r - 1.0) > limit[band]
    if out.any():
        i = int(np.argmax(np.abs(r - 1.0) - limit[band]))
        problems.append(f"{int(out.sum())}/{int(band.sum())} bands beyond their stated "
                        f"uncertainty; worst {wl[band][i]:.0f} nm ×{r[i]:.3f} (limit "
                        f"±{limit[band][i]:.3f}); median ×{float(np.median(r)):.3f} "
                        "(shown, not judged)")
    return problems


#: a band's limit: ±2 % gonio ±0.7 % white standard + this many standard deviations of its
#: own counting noise (6σ: ~2e-9 per band, so none of the ~10⁶ bands of a campaign by chance)
BRDF_SIGMAS = 6.0


def brdf_sigma_rel(meta: dict[str, Any], arrays: dict[str, np.ndarray],
                   truth: np.ndarray) -> np.ndarray:
    """The stated relative standard deviation of each output band of a gonio reading: the QE
    Pro's counting noise (shot noise 0.262 counts² per count, read noise 15 counts, in the
    sample frame and its dark, and in the white reference and its dark) at the counts this
    reading had (`raw_counts`) and the white reference had at those pixels (from the truth:
    sample rate = f·π/ρ_w·cos θi/cos θref × white rate).  Bands without counts, or without
    a raw frame, are NaN (not judged: the reading holds no information about them); a reading
    stored without its raw frame is judged on the scatter of its own bands (`local_scatter`)."""
    from normbox_lab.sim import qepro as q

    raw = arrays.get("raw_counts")
    wl = np.asarray(arrays["wavelength_nm"], dtype=float)
    t_s = meta.get("integration_time_s")
    t_w = meta.get("white_integration_time_s")
    if raw is None or not t_s or not t_w or np.size(raw) != q.PIXELS:
        return np.full(wl.shape, np.nan)
    raw = np.asarray(raw, dtype=float)
    px = np.arange(q.PIXELS, dtype=float)
    c0, c1, c2 = q.WAVELENGTH_COEFFS
    px_wl = c0 + c1 * px + c2 * px * px
    offset = float(np.mean(raw[q.DARK_PIXELS]))
    dark_rate = float(meta.get("dark_rate_counts_s") or q.DARK_RATE_COUNTS_S)
    dark = max(dark_rate, 0.0) * float(t_s)                # the dark the reading subtracted
    signal = np.interp(wl, px_wl, raw - offset) - dark
    cos_i = max(math.cos(math.radians(float(meta.get("theta_i_deg", 0.0)))), 1e-6)
    with np.errstate(divide="ignore", invalid="ignore"):
        white = signal * float(t_w) / float(t_s) * 0.99 / (math.pi * truth) / cos_i
        var = (q.SHOT_VAR_PER_COUNT * (np.maximum(signal, 0.0) + 2 * dark)
               + 2 * q.READ_NOISE_COUNTS ** 2) / signal ** 2 \
            + (q.SHOT_VAR_PER_COUNT * np.maximum(white, 0.0)
               + 2 * q.READ_NOISE_COUNTS ** 2) / white ** 2
        sigma = np.sqrt(var)
    return np.where((signal > 0) & (white > 0) & np.isfinite(sigma), sigma, np.nan)


def local_scatter(r: np.ndarray, half_width: int = 10) -> np.ndarray:
    """Robust standard deviation of `r` around its running median, band by band (the
    spectrometer's noise grows where the signal is small: the blue end, dark patches)."""
    hw = min(half_width, r.size - 1)
    if hw < 1:
        return np.zeros_like(r)
    win = np.lib.stride_tricks.sliding_window_view(np.pad(r, hw, mode="reflect"), 2 * hw + 1)
    dev = np.abs(win - np.median(win, axis=1, keepdims=True))
    return 1.4826 * np.median(dev, axis=1)


def _notes(ex: Execution) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for seg in ex.segments:
        for e in seg.journal:
            if e.get("ev") == "reading-stored":
                out[e["key"]] = e
    return out


def oracle(ex: Execution, store: Store, run_id: int, error_keys: set[str]) -> list[Violation]:
    out = []
    notes = _notes(ex)
    for r in store.readings(run_id):
        if r.key in error_keys:
            continue
        note = notes.get(r.key, {})
        if r.kind == "brdf":
            problems = check_brdf(r.key, r.metadata, r.arrays, note.get("brdf"))
        else:
            problems = check_spectral(r.key, r.metadata, r.arrays, note.get("view"))
        for p in problems:
            out.append(Violation("a", f"a:{r.kind}", f"{r.key} stored without an error "
                                                     f"flag: {p}"))
    return out


# --- (b) typed failures, (c) no hang -----------------------------------------------------------
def typed_failures(ex: Execution, complete: bool, missing_unflagged: list[str]) -> list[Violation]:
    out = []
    for i, seg in enumerate(ex.segments):
        if seg.rc is None:
            continue
        if "Traceback (most recent call last)" in seg.stderr:
            last = [ln for ln in seg.stderr.strip().splitlines() if ln.strip()][-1:]
            name = (last[0].split(":")[0].strip() if last else "?")[:60]
            out.append(Violation("b", f"b:traceback:{name}",
                                 f"segment {i} printed a traceback: {last[0] if last else ''}"))
            continue
        wrong = [ln for ln in seg.stderr.splitlines() if "operator answered" in ln
                 and "expected one of" in ln]
        if wrong:
            out.append(Violation("b", "b:answer-not-offered",
                                 f"segment {i}: the operator gave an answer the prompt does not "
                                 f"offer: {wrong[0][-120:]}"))
        if seg.rc != 0:
            typed = any(ln.startswith("normbox-lab: ") for ln in seg.stderr.splitlines())
            status = any(STATUS_LINE.match(ln) for ln in seg.stdout.splitlines())
            resume = any(ln.startswith("resume with: ") for ln in seg.stdout.splitlines())
            if not (typed or status or resume):
                out.append(Violation("b", "b:untyped-exit",
                                     f"segment {i} exited {seg.rc} without a typed line"))
        else:
            # exit 0: the run as this segment left it must be complete (or, for the last one,
            # every missing reading flagged as an error)
            finished = [e["d"] for e in seg.journal if e.get("ev") == "run-finished"]
            status = finished[-1].get("status") if finished else None
            last = i == len(ex.segments) - 1
            if (status is not None and status != "done" and not (last and complete)) or (
                    status is None and last and not complete):
                out.append(Violation(
                    "b", "b:exit-0-incomplete",
                    f"segment {i}{f' ({seg.action.label()})' if seg.fired else ''} exited 0 "
                    f"with the run {status or 'unfinished'}"
                    f"{'' if complete else f'; missing {len(missing_unflagged)} readings without an error flag'}"))
    return out


def _fault_waits_s(ex: Execution, suspend_s: float) -> float:
    """The waits the scenario's faults legitimately cost when they fire (a lamp not stable
    for the fault's parameter in seconds, `FaultKind.param_is_wait_s`), each at most the
    run's suspend timeout."""
    from normbox_lab.sim import core

    total = 0.0
    for f in ex.scenario.faults:
        device = ex.scenario.device_of(f.role)
        kind = core.fault_table(device)[device].get(f.kind) if device in core.fault_table() \
            else None
        if kind is not None and kind.param_is_wait_s:
            total += min(float(f.param) if f.param is not None else suspend_s, suspend_s)
    return total


def no_hang(ex: Execution) -> list[Violation]:
    out = []
    for i, seg in enumerate(ex.segments):
        if seg.hung:
            out.append(Violation("c", "c:wall-clock",
                                 f"segment {i} still running after {seg.wall_s:.0f} s "
                                 "(wall clock): killed"))
        estimates: dict[str, float] = {}
        suspend_s = 600.0
        counts: dict[str, dict[str, int]] = {}
        # faults injected since the start of the previous reading (a fault's cost may land on
        # the reading after the exchange it hit)
        fired_marks = [0, 0]
        state_s = 0.0                     # the segment's costliest reading: every state anew
        for e in seg.journal:
            ev = e.get("ev")
            if ev == "run-started":
                estimates = e.get("estimates") or {}
                suspend_s = float(e.get("suspend_timeout_s") or suspend_s)
                fired_marks = [int(e.get("f", 0))] * 2
                state_s = max([0.0, *(float(v) for v in estimates.values())])
            elif ev == "estimates":           # the engine re-estimated after a skip
                estimates = {**estimates, **(e.get("estimates") or {})}
            elif ev in ("fault", "suspended", "prompt", "warning"):
                c = counts.setdefault(e.get("key", ""), {})
                c[ev] = c.get(ev, 0) + 1
                if ev == "fault" and str(e.get("d", {}).get("error", "")).startswith(
                        "NotReady("):
                    # a wait that ran to its own timeout (a lamp never stable): it cost the
                    # timeout, which the engine states with the run
                    c["wait-timeout"] = c.get("wait-timeout", 0) + 1
            elif ev == "step-finished" and e["d"].get("kind") in ("measure",):
                key = e["key"]
                est = float(estimates.get(key, 0.0))
                if est <= 0:
                    continue
                c = dict(counts.get(key, {}))
                injected = max(0, int(e.get("f", 0)) - fired_marks[0])
                fired_marks = [fired_marks[1], int(e.get("f", 0))]
                if injected:
                    c["injected"] = injected
                latched = int(e.get("latched", 0)) > 0
                if latched:
                    c["latched"] = 1
                model = (LATCHED_FACTOR if latched else 1.0) * (est + DRIVER_TIMEOUT_S)
                waits = _fault_waits_s(ex, suspend_s) if injected else 0.0
                bound = (model + injected * (state_s + DRIVER_TIMEOUT_S) + waits
                         + (c.get("fault", 0) + c.get("warning", 0)) * (est + FAULT_ALLOWANCE_S)
                         + (c.get("suspended", 0) + c.get("wait-timeout", 0))
                         * (est + suspend_s)
                         + c.get("prompt", 0) * (est + PROMPT_ALLOWANCE_S))
                took = float(e["d"].get("duration_s", 0.0))
                if took > bound:
                    out.append(Violation(
                        "c", "c:step-time-10x" if took > 10 * bound else "c:step-time",
                        f"segment {i}: {key} took {took:.0f} s (virtual) > bound {bound:.0f} s "
                        f"(estimate {est:.0f} s, {c or 'no faults'})"))
    return out


# --- (d) consistent state, (e) resume -----------------------------------------------------------
RUNS_LINE = re.compile(r"^\s*(\d+)\s+([0-9a-f]{8})\s+(\S+)\s+(.+?)\s+(\d+)/(\d+)\s")


def _runs_line(text: str, uuid: str) -> tuple[str, int, int] | None:
    for ln in text.splitlines():
        m = RUNS_LINE.match(ln)
        if m and uuid.startswith(m.group(2)):
            return m.group(4).strip(), int(m.group(5)), int(m.group(6))
    return None


def lock_is_free(store_path: Any, uuid: str) -> bool:
    from normbox_lab.acquire.store import RunLock
    from normbox_lab.core.errors import StoreError

    lock = RunLock(store_path, uuid)
    existed = lock.path.exists()
    try:
        lock.acquire()
    except StoreError:
        return False
    lock.release()
    if not existed and lock.path.exists():
        lock.path.unlink()
    return True


def consistent_state(ex: Execution, store: Store, rec: Any, keys: set[str],
                     flags: list[Any]) -> list[Violation]:
    out = []
    for i, seg in enumerate(ex.segments):
        if seg.runs_out is not None:
            shown = _runs_line(seg.runs_out[1], ex.run_uuid or "")
            if shown is not None and shown[0] == "running":
                out.append(Violation("d", "d:running-without-owner",
                                     f"after segment {i} was killed, `runs` shows the run "
                                     "'running' with no live owner"))
        for e in seg.journal:
            second = e.get("second_owner")
            if second is not None:
                err = second.get("stderr", "")
                # fired as the run finished: the owner may be gone, the run done — a typed
                # "already done" is then the right answer
                finished = rec.status == "done" and "already done" in err
                named = any(ln.startswith("normbox-lab: ") and str(second["owner_pid"]) in ln
                            for ln in err.splitlines())
                if second.get("rc") in (0, None) or "Traceback" in err or not (named or
                                                                               finished):
                    out.append(Violation(
                        "d", "d:second-owner",
                        f"a second `run --resume` during segment {i} exited {second.get('rc')} "
                        f"without a refusal naming the owner (pid {second['owner_pid']}): "
                        f"{err.strip()[-160:]!r}"))
            if e.get("ev") == "reading-stored" and e["key"] not in keys:
                out.append(Violation("d", "d:lost-reading",
                                     f"segment {i} reported {e['key']} stored; the store "
                                     "lacks it"))
    if len(keys) != rec.done:
        out.append(Violation("d", "d:done-count",
                             f"store says done {rec.done}, holds {len(keys)} readings"))
    if rec.status == "done" and len(keys) != rec.planned:
        out.append(Violation("d", "d:done-incomplete",
                             f"status done with {len(keys)}/{rec.planned} readings"))
    if rec.status == "running" and lock_is_free(ex.store, rec.uuid):
        out.append(Violation("d", "d:running-without-owner",
                             "the store says 'running' but nobody holds the run lock"))
    for f in flags:
        if f.key in keys and ("skip" in f.gate.lower() or "skipped" in f.message.lower()):
            out.append(Violation("d", "d:stale-skip-flag",
                                 f"{f.key} is stored but keeps the flag {f.gate!r}"))
    from normbox_lab.analyze import qa

    shown_status = qa.run_status(store, rec.id)
    rc, text, err = runs_listing(ex.workdir, ex.store, "final-runs")
    line = _runs_line(text, rec.uuid)
    if rc != 0 or line is None:
        out.append(Violation("d", "d:runs-command", f"`runs` exited {rc}, no line for the run "
                                                    f"({err.strip()[-120:]})"))
    elif line != (shown_status, rec.done, rec.planned):
        out.append(Violation("d", "d:runs-disagrees",
                             f"`runs` shows {line}, the store {shown_status} "
                             f"{rec.done}/{rec.planned}"))
    rc, text, err = qa_listing(ex.workdir, ex.store, str(rec.id), "final-qa")
    s = qa.summary(store, rec.id)
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    if not lines or lines[-1] != s.line():
        out.append(Violation("d", "d:qa-disagrees",
                             f"`qa` ends {lines[-1] if lines else '(nothing)'!r}, the store "
                             f"{s.line()!r}"))
    elif rc != (1 if s.errors else 0):
        out.append(Violation("d", "d:qa-exit", f"`qa` exited {rc} with {s.errors} errors"))
    elif not any(f": {shown_status}" in ln for ln in lines[:1]):
        out.append(Violation("d", "d:qa-status",
                             f"`qa` heads {lines[0]!r}, the status is {shown_status!r}"))
    return out


def resume_matches(ex: Execution, store: Store, rec: Any, error_keys: set[str]) -> list[Violation]:
    from normbox_lab.acquire.store import Store

    ref = ex.reference
    if ref is None or ref.run_uuid is None:
        return []
    out = []
    with Store(ref.store) as rs:
        rrec = rs.get_run(ref.run_uuid)
        ref_errors = {f["key"] for f in rs.flag_rows(run_id=rrec.id) if f["severity"] == "error"}
        ref_readings = {r.key: r for r in rs.readings(rrec.id)}
    mine = {r.key: r for r in store.readings(rec.id)}
    if rec.status == "done" and rrec.status == "done" and set(mine) != set(ref_readings):
        out.append(Violation("e", "e:keys", f"resumed run holds {sorted(set(mine) ^ set(ref_readings))[:4]} "
                                            "unlike the uninterrupted run"))
    geometry = ("angle_deg", "patch", "x_mm", "y_mm", "theta_i_deg", "theta_o_deg",
                "material", "tilt_deg")
    for key in sorted(set(mine) & set(ref_readings)):
        a, b = mine[key], ref_readings[key]
        ga = {k: a.metadata.get(k) for k in geometry}
        gb = {k: b.metadata.get(k) for k in geometry}
        if ga != gb:
            out.append(Violation("e", "e:geometry", f"{key}: {ga} resumed vs {gb} uninterrupted"))
            continue
        if key in error_keys or key in ref_errors or a.kind != "spectral":
            continue
        va = np.asarray(a.arrays["radiance_W_sr_m2_nm"], float)
        vb = np.asarray(b.arrays["radiance_W_sr_m2_nm"], float)
        lo, hi = spectral_bounds(vb)
        # two independent readings of the same truth: each within its band of it
        spread = (hi - lo) + ABS_FLOOR
        if va.shape != vb.shape or np.any(np.abs(va - vb) > spread):
            out.append(Violation("e", "e:values", f"{key}: resumed and uninterrupted readings "
                                                  "differ by more than their uncertainty"))
    return out


def check(ex: Execution) -> list[Violation]:
    """Every invariant on one executed scenario."""
    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze import qa

    out = no_hang(ex)
    if ex.run_uuid is None:
        out += typed_failures(ex, True, [])
        return out
    try:
        store = Store(ex.store)
    except Exception as exc:              # noqa: BLE001 - reported as a violation
        return [*out, Violation("d", "d:store-unreadable", f"{type(exc).__name__}: {exc}")]
    with store:
        rec = store.get_run(ex.run_uuid)
        flags = qa.flags(store, rec.id)
        error_keys = {f.key for f in flags if f.severity == "error"}
        keys = set(store.keys(rec.id))
        planned = _planned_keys(ex, rec)
        missing = sorted(k for k in planned - keys if k not in error_keys)
        complete = (rec.status == "done" and len(keys) == rec.planned) or (
            bool(planned) and not missing)
        out += typed_failures(ex, complete, missing)
        out += oracle(ex, store, rec.id, error_keys)
        out += consistent_state(ex, store, rec, keys, flags)
        out += resume_matches(ex, store, rec, error_keys)
    return out


def _planned_keys(ex: Execution, rec: Any) -> set[str]:
    """The plan's reading keys (from the journals' estimates, which cover every missing key
    of a segment, plus what is stored)."""
    keys: set[str] = set()
    for seg in ex.segments:
        for e in seg.journal:
            if e.get("ev") == "run-started":
                keys |= set(e.get("estimates") or {})
    return keys


__all__ = ["Violation", "check", "check_brdf", "check_spectral", "spectral_bounds"]
