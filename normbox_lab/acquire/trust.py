"""What a run rests on beyond its readings: the calibrations in force and the last lab check.

- `calibration_record(config, role)`: the calibration the lab config states for a role, as the
  run stores it with the instrument (`Store.add_instrument(..., calibration=...)`), and
  `calibration_flag`: the quality warning an expired one gives (gate ``calibration``).
- `last_passing_check(store)` / `require_recent_check(store, hours, now_s)`: a run whose lab
  config sets ``[lab] require_check_h`` starts only when a `lab check` run in the same store
  passed every check within that many hours (`NotReady` otherwise, one line saying what to do).
"""

from __future__ import annotations

import datetime
from typing import Any

from normbox_lab.acquire.store_api import Store
from normbox_lab.core.errors import NotReady

LAB_CHECK = "lab-check"
GATE = "calibration"


def calibration_record(config: Any, role: str) -> dict[str, Any] | None:
    inst = config.instruments.get(role) if config is not None else None
    cal = getattr(inst, "calibration", None)
    return cal.as_dict() if cal is not None else None


def calibration_flag(store: Store, run_id: int, role: str, record: dict[str, Any],
                     today: datetime.date) -> bool:
    """Store the warning for an expired calibration of `role`; True when one was stored."""
    due = datetime.date.fromisoformat(str(record["due"]))
    if today <= due:
        return False
    days = (today - due).days
    store.add_flag(run_id=run_id, artifact_id=None, key=f"calibration/{role}", gate=GATE,
                   severity="warning", value=float(-days), limit=0.0,
                   message=f"{role}: calibration {record['certificate']} "
                           f"({record['laboratory']}) expired on {due} ({days} days before "
                           "this run); the readings rest on it")
    return True


def last_passing_check(store: Store) -> tuple[int, float] | None:
    """(run id, wall time s of its last event) of the newest done lab-check run whose every
    check passed; None when there is none."""
    best = None
    for rec in store.runs():
        if rec.protocol != LAB_CHECK or rec.status != "done":
            continue
        results = [r.metadata for r in store.readings(rec.id, kind="check")]
        if results and all(m.get("passed") for m in results):
            times = [float(t) for t, _, _ in store.events(rec.id)]
            best = (rec.id, max(times) if times else float(rec.created_s))
    return best


def require_recent_check(store: Store, hours: float, now_s: float) -> None:
    """`NotReady` unless a lab check passed within `hours` before `now_s` (wall time)."""
    found = last_passing_check(store)
    if found is None:
        raise NotReady(f"the lab config asks for a passing lab check younger than {hours:g} h "
                       "and this store has none: run `normbox-lab lab check` first")
    run_id, at_s = found
    age_h = (now_s - at_s) / 3600.0
    if age_h > hours:
        raise NotReady(f"the last passing lab check (run {run_id}) is {age_h:.1f} h old; the "
                       f"lab config asks for one younger than {hours:g} h: run `normbox-lab "
                       "lab check` again")


__all__ = ["calibration_flag", "calibration_record", "last_passing_check",
           "require_recent_check"]
