"""What the engine tells the world: events for subscribers, prompts for the operator, and the
result of a run segment."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class EngineEvent:
    kind: str           # run-started, step-started, step-finished, reading-stored, prompt,
                        # answer, warning, fault, suspended, unsuspended, paused, resumed,
                        # progress, estimates (after a skip: the remaining readings' expected
                        # times, again), run-finished
    run_id: int | None
    key: str = ""
    time_s: float = 0.0  # the lab clock (virtual seconds in a simulation)
    data: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PromptRequest:
    id: int
    key: str
    kind: str                 # "operator" (a prompt step) or "fault"
    message: str
    choices: tuple[str, ...]  # ("ok",) for a prompt step; ("retry", "skip", "abort") for faults
    data: Mapping[str, Any] = field(default_factory=dict)


Operator = Callable[[PromptRequest], str]


@dataclass(frozen=True)
class RunResult:
    run_id: int
    uuid: str
    status: str                  # done | paused | interrupted (skipped readings) | aborted
    taken: int                   # readings committed in this segment
    done: int                    # readings committed in total
    planned: int
    skipped: tuple[str, ...]
    elapsed_s: float             # lab-clock seconds of this segment


def fault_text(data: Mapping[str, Any]) -> str:
    """A fault or warning event in words: "no answer to MES within 5 s (InstrumentTimeout)",
    never a dict or a repr (a fault event carries the exception's repr,
    "InstrumentTimeout('…')"); the role the message starts with is left out."""
    import re

    error = str(data.get("message") or data.get("error") or "")
    kind = ""
    match = re.fullmatch(r"(\w+)\((['\"])(.*)\2\)", error, flags=re.DOTALL)
    if match:
        kind, error = match.group(1), match.group(3).replace("\\'", "'")
    role = str(data.get("role", ""))
    error = error.removeprefix(f"{role}: ") if role else error
    return f"{error} ({kind})" if kind else error


__all__ = ["EngineEvent", "Operator", "PromptRequest", "RunResult", "fault_text"]
