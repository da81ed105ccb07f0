"""Independent jobs shared between this process and children on the machine's idle cores.

The fit (one job per material) and the report (one SVG per figure) are independent pieces of
work whose results do not depend on where they run: `Offload` queues them, `children` child
processes (``python -m normbox_lab.analyze.offload_worker MODULE:FUNCTION``: plain
subprocesses fed pickles over stdin/stdout, not multiprocessing's, which imports the caller's
``__main__`` again) each take the next one as they finish one, and this process takes them
too (`take`).  A job a child could not do (an exception, a child that died) is done again
here by `finish_here`, so it raises here what it raises.

How many children: `idle_children()`, the cores this process may use that are idle by the
1-minute load average, less this process.  On a loaded machine a child only adds its start-up
and the pickles (the fit at load 4.5-5.8 on the 2-core M-Xeon-512: 33-37 s wall with a child,
24-33 s without), so there it is none.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Callable, Hashable
from typing import Any


def idle_children() -> int:
    """Child processes worth starting now: the usable cores idle by the 1-minute load
    average (this process counts as one of the load), less this process; 0 in a daemonic
    process (it may not start children)."""
    import multiprocessing
    import os

    from normbox_lab.core.machine import usable_cores

    if multiprocessing.current_process().daemon:
        return 0
    cores = usable_cores()
    try:
        busy = max(0.0, os.getloadavg()[0] - 1.0)
    except OSError:                        # no load average here: take the cores as idle
        busy = 0.0
    return max(0, min(cores, int(cores - busy + 0.5)) - 1)


class Offload:
    """A queue of keyed jobs, `children` child processes running ``job`` ("module:function",
    called with each job's payload) and this process's share (`take`, `finish`)."""

    def __init__(self, job: str, children: int) -> None:
        self._job = job
        self._cond = threading.Condition()
        self._queue: deque[tuple[Hashable, Any]] = deque()
        self._closed = False
        self.results: dict[Hashable, Any] = {}
        self._failed: list[tuple[Hashable, Any]] = []
        self._children = [_Child(self, job) for _ in range(max(0, children))]

    def submit(self, key: Hashable, payload: Any) -> None:
        with self._cond:
            self._queue.append((key, payload))
            self._cond.notify()

    def take(self) -> tuple[Hashable, Any] | None:
        """The next queued job for this process, or None when none is queued."""
        with self._cond:
            return self._queue.popleft() if self._queue else None

    def finish(self, key: Hashable, result: Any) -> None:
        with self._cond:
            self.results[key] = result
            self._cond.notify_all()

    def done(self, key: Hashable) -> bool:
        with self._cond:
            return key in self.results

    def finish_here(self, work: Callable[[Any], Any]) -> dict[Hashable, Any]:
        """No more jobs: the queued ones done here with `work` (the children take theirs
        meanwhile), the children waited for and ended, the jobs they failed done here;
        every job's result, by key."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        try:
            while (item := self.take()) is not None:
                self.finish(item[0], work(item[1]))
            for child in self._children:
                child.thread.join()
            for key, payload in self._failed:
                self.finish(key, work(payload))
        finally:
            self.close()
        return self.results

    def close(self) -> None:
        """End the children (each ends at the end of its input)."""
        with self._cond:
            self._closed = True
            self._queue.clear()
            self._cond.notify_all()
        for child in self._children:
            child.close()

    # -- the children's side -------------------------------------------------------------------
    def _next_for_child(self) -> tuple[Hashable, Any] | None:
        with self._cond:
            while not self._queue and not self._closed:
                self._cond.wait()
            return self._queue.popleft() if self._queue else None

    def _child_failed(self, key: Hashable, payload: Any) -> None:
        with self._cond:
            self._failed.append((key, payload))


class _Child:
    """One child process and the thread that feeds it jobs, one at a time."""

    def __init__(self, offload: Offload, job: str) -> None:
        self.offload = offload
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "normbox_lab.analyze.offload_worker", job],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.thread = threading.Thread(target=self._feed, name="offload-child", daemon=True)
        self.thread.start()

    def _feed(self) -> None:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        while (item := self.offload._next_for_child()) is not None:
            key, payload = item
            try:
                pickle.dump(payload, self.proc.stdin)
                self.proc.stdin.flush()
                status, result = pickle.load(self.proc.stdout)
            except (OSError, EOFError, pickle.UnpicklingError):
                status, result = "lost", None
            if status == "ok":
                self.offload.finish(key, result)
                continue
            self.offload._child_failed(key, payload)
            if status == "lost":           # the child is gone: the rest are this process's
                return

    def close(self) -> None:
        if self.proc.stdin is not None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
