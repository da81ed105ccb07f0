"""The protocol engine: declared keyed steps, exact dry-run/ETA, pause/abort, crash resume.

A protocol declares its whole plan up front as a list of `Step`s, each with a key unique in the
run and a kind (`steps.py`: move, wait-stable, prompt, calibrate, measure).  Only `measure`
steps produce readings; the others *establish state*: each declares the state variables it
sets (`sets`), and every step declares the state it needs (`requires`).  The engine executes
state steps lazily: before a measurement it runs — in plan order — the latest step before it
that sets each variable whose value is not known to be right.  In a fresh run this is exactly
the declared order; after a crash (physical state unknown) it replays precisely the moves and
prompts the first missing measurement needs, skips every committed key, and takes nothing twice.

This module is the public face of the engine; its parts:

    steps.py     Step, the step kinds (estimate / execute through capabilities), factories
    plan.py      Plan (validation, lazy-state bookkeeping, fingerprint), protocol loading
    estimate.py  dry run and ETA from the instruments' timing models
    retry.py     the fault policy: bounded retries, then the operator decides
    events.py    EngineEvent, PromptRequest, RunResult
    runner.py    Engine: runs a plan against a lab, committing every reading
    session.py   open_run(): lab + store + plan + operator + engine, new run or resume
"""

from __future__ import annotations

from normbox_lab.acquire.estimate import DryRun, StepEstimate, format_duration
from normbox_lab.acquire.events import EngineEvent, Operator, PromptRequest, RunResult
from normbox_lab.acquire.plan import (
    PROTOCOL_NAMES,
    Plan,
    PlanError,
    build_plan,
    coerce_param,
    load_protocol,
    resolve_parameters,
)
from normbox_lab.acquire.retry import RetryPolicy
from normbox_lab.acquire.runner import Engine, LabAccess
from normbox_lab.acquire.session import OpenRun, open_run
from normbox_lab.acquire.steps import (
    COMMIT_KINDS,
    KINDS,
    STEP_KINDS,
    Step,
    StepKind,
    calibrate,
    measure,
    move,
    prompt,
    wait_stable,
)

__all__ = [
    "COMMIT_KINDS",
    "KINDS",
    "PROTOCOL_NAMES",
    "STEP_KINDS",
    "DryRun",
    "Engine",
    "EngineEvent",
    "LabAccess",
    "OpenRun",
    "Operator",
    "Plan",
    "PlanError",
    "PromptRequest",
    "RetryPolicy",
    "RunResult",
    "Step",
    "StepEstimate",
    "StepKind",
    "build_plan",
    "calibrate",
    "coerce_param",
    "format_duration",
    "load_protocol",
    "measure",
    "move",
    "open_run",
    "prompt",
    "resolve_parameters",
    "wait_stable",
]
