"""The fault policy: bounded retries of transient faults, then an operator decision.

Transient faults (`InstrumentTimeout`, `ProtocolError`, a dropped port) are retried up to
`RetryPolicy.attempts` times, each after the instrument's `recover()` (when it is
Recoverable); a persistent fault (or one that keeps coming back) goes to the operator: retry,
skip this reading, or abort the run — or to a fixed answer (`persistent="skip"|"abort"`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from normbox_lab.core.errors import InstrumentError, InstrumentTimeout, OperatorAbort, ProtocolError

T = TypeVar("T")


@dataclass(frozen=True)
class RetryPolicy:
    attempts: int = 3                      # tries per step for a transient fault
    transient: tuple[type[BaseException], ...] = (InstrumentTimeout, ProtocolError, OSError)
    persistent: str = "prompt"             # prompt | skip | abort (what to do without asking)


class Skip(Exception):
    """The operator chose to skip the current measurement."""


class StopAtPrompt(Exception):
    """`Engine.stop()` while the engine waited for an answer (no operator callable)."""


def run_with_retry(action: Callable[[], T], *, key: str, policy: RetryPolicy,
                   aborted: Callable[[], bool],
                   on_fault: Callable[[BaseException, int, bool], None],
                   recover: Callable[[], None],
                   decide: Callable[[BaseException, int], str]) -> T:
    """Run `action`; on an instrument fault call `on_fault(exc, attempt, transient)`, then
    retry (after `recover()`) while the policy allows, else ask `decide(exc, attempt)` →
    "retry" (start counting again), "skip" (raise `Skip`) or "abort" (raise `OperatorAbort`)."""
    attempt = 0
    while True:
        if aborted():
            raise OperatorAbort("abort requested")
        attempt += 1
        try:
            return action()
        except OperatorAbort:
            raise
        except (InstrumentError, OSError) as exc:
            if aborted():
                raise OperatorAbort("abort requested") from exc
            transient = isinstance(exc, policy.transient)
            on_fault(exc, attempt, transient)
            if transient and attempt < policy.attempts:
                recover()
                continue
            choice = decide(exc, attempt)
            if choice == "retry":
                attempt = 0
                recover()
                continue
            if choice == "skip":
                raise Skip(key) from exc
            raise OperatorAbort(f"operator aborted after {type(exc).__name__} at {key}") \
                from exc


__all__ = ["RetryPolicy", "Skip", "StopAtPrompt", "run_with_retry"]
