"""The injected clock: every piece of code that waits asks a Clock, never `time` directly.

`RealClock` is wall time.  `VirtualClock` keeps its own time that only moves when someone
sleeps on it (or calls `advance`); `time_scale` says how much real time one virtual second
costs (0 = instant, the default for tests; 1 = real time, for demos that should feel real).
"""

from __future__ import annotations

import threading
import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    def now_s(self) -> float:
        """Monotonic seconds (arbitrary origin)."""
        ...

    def wall_time_s(self) -> float:
        """Seconds since the Unix epoch, for timestamps on data."""
        ...

    def sleep(self, duration_s: float) -> None:
        """Wait `duration_s` seconds of this clock's time."""
        ...


class RealClock:
    def now_s(self) -> float:
        return time.monotonic()

    def wall_time_s(self) -> float:
        return time.time()

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class VirtualClock:
    """Deterministic clock for simulation and tests.

    Virtual time starts at `start_s` (wall timestamps at `epoch_s + now`).  `sleep(d)` moves
    virtual time forward by `d` and sleeps `d * time_scale` real seconds.  Thread-safe.
    """

    def __init__(self, time_scale: float = 0.0, start_s: float = 0.0,
                 epoch_s: float = 1_767_225_600.0) -> None:  # 2026-01-01T00:00:00Z
        if time_scale < 0:
            raise ValueError("time_scale must be >= 0")
        self.time_scale = float(time_scale)
        self._now_s = float(start_s)
        self._epoch_s = float(epoch_s)
        self._lock = threading.Lock()

    def now_s(self) -> float:
        with self._lock:
            return self._now_s

    def wall_time_s(self) -> float:
        return self._epoch_s + self.now_s()

    def advance(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError("cannot move time backwards")
        with self._lock:
            self._now_s += duration_s

    def sleep(self, duration_s: float) -> None:
        if duration_s <= 0:
            return
        if self.time_scale > 0:
            time.sleep(duration_s * self.time_scale)
        self.advance(duration_s)

    def sleep_until(self, when_s: float) -> None:
        self.sleep(when_s - self.now_s())


def make_clock(time_scale: float | None) -> Clock:
    """`None` → real clock; a number → virtual clock with that time scale."""
    return RealClock() if time_scale is None else VirtualClock(time_scale=time_scale)
