"""How many Dr.Jit kernels a piece of work compiled, and how long that took (`KernelLog`).

A first run on a new machine pays for compiling every kernel (10-25 s each on a 2-core AVX2
CPU), and a kernel that is compiled again in a second run with the same options is a bug: some
per-run value was baked into it as a literal.  Dr.Jit records every launch when
`JitFlag.KernelHistory` is on; `dr.kernel_history()` returns the records and clears them.
Each record says whether the kernel was compiled (``cache_hit`` 0), loaded from the on-disk
cache (``cache_disk`` 1) or found in memory, and its compile time (``backend_time``, ms).

The records hold each kernel's IR, so a long run would pile up gigabytes: `KernelLog` drains
them from a background thread and keeps only counts and sums.  Dr.Jit is imported only when a
log starts, and only if the process already imported it or asks to (`start(import_drjit=...)`).
"""

from __future__ import annotations

import sys
import threading
from dataclasses import dataclass, field
from typing import Any


@dataclass
class KernelStats:
    """Counts and times of the Dr.Jit kernel launches of one piece of work."""

    launches: int = 0           # every launch (compiled, from disk, from memory)
    compiled: int = 0           # compiled by LLVM / NVRTC in this process
    from_disk: int = 0          # loaded from Dr.Jit's on-disk kernel cache
    compile_s: float = 0.0      # back-end (LLVM) time of the compiled kernels
    codegen_s: float = 0.0      # Dr.Jit's own IR generation, every launch
    ir_ops_max: int = 0         # the largest compiled kernel's operation count
    hashes: set[str] = field(default_factory=set)      # the compiled kernels' hashes

    def add(self, record: dict[str, Any], ir_dir: str | None = None) -> None:
        self.launches += 1
        h = record.get("hash")
        if not h:                   # memsets, reductions: no compiled code
            return
        self.codegen_s += float(record.get("codegen_time", 0.0)) / 1000.0
        if not record.get("cache_hit"):
            self.compiled += 1
            self.compile_s += float(record.get("backend_time", 0.0)) / 1000.0
            self.ir_ops_max = max(self.ir_ops_max, int(record.get("operation_count", 0)))
            self.hashes.add(str(h))
            if ir_dir and record.get("ir") is not None:
                from pathlib import Path

                Path(ir_dir).mkdir(parents=True, exist_ok=True)
                (Path(ir_dir) / f"{h}.ll").write_text(record["ir"].getvalue())
        elif record.get("cache_disk"):
            self.from_disk += 1

    def __sub__(self, other: KernelStats) -> KernelStats:
        return KernelStats(self.launches - other.launches, self.compiled - other.compiled,
                           self.from_disk - other.from_disk, self.compile_s - other.compile_s,
                           self.codegen_s - other.codegen_s, self.ir_ops_max,
                           self.hashes - other.hashes)

    def copy(self) -> KernelStats:
        return KernelStats(self.launches, self.compiled, self.from_disk, self.compile_s,
                           self.codegen_s, self.ir_ops_max, set(self.hashes))

    def line(self) -> str:
        """'compile 12.3 s (8 kernels compiled, 3 from the disk cache, 412 launches)'."""
        return (f"compile {self.compile_s:.1f} s ({self.compiled} kernels compiled, "
                f"{self.from_disk} from the disk cache, {self.launches} launches)")


class KernelLog:
    """Drains Dr.Jit's kernel history into `KernelStats` while it runs.

        log = KernelLog(); log.start()
        before = log.snapshot(); ...work...; stage = log.snapshot() - before
        log.stop()
    """

    def __init__(self, poll_s: float = 0.5) -> None:
        import os

        self.poll_s = float(poll_s)
        #: ``NORMBOX_KERNEL_IR_DIR``: write each compiled kernel's IR there (<hash>.ll), to
        #: diff two runs and find the value that was baked into a kernel as a literal
        self.ir_dir = os.environ.get("NORMBOX_KERNEL_IR_DIR") or None
        self.total = KernelStats()
        self._dr: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def active(self) -> bool:
        return self._dr is not None

    def start(self, *, import_drjit: bool = True) -> bool:
        """Turn the history on (True), or do nothing when Dr.Jit is not importable (or not yet
        imported and `import_drjit` is False)."""
        if self._dr is not None:
            return True
        if "drjit" not in sys.modules and not import_drjit:
            return False
        try:
            import drjit as dr
        except ImportError:
            return False
        self._dr = dr
        dr.kernel_history()                 # drop what came before
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        self._stop.clear()
        self._thread = threading.Thread(target=self._poll, name="kernel-log", daemon=True)
        self._thread.start()
        return True

    def _poll(self) -> None:
        while not self._stop.wait(self.poll_s):
            self.drain()

    def drain(self) -> None:
        if self._dr is None:
            return
        records = self._dr.kernel_history()
        with self._lock:
            for r in records:
                self.total.add(r, self.ir_dir)

    def snapshot(self) -> KernelStats:
        """The totals so far (drained first)."""
        self.drain()
        with self._lock:
            return self.total.copy()

    def stop(self) -> KernelStats:
        if self._dr is None:
            return self.total.copy()
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.drain()
        self._dr.set_flag(self._dr.JitFlag.KernelHistory, False)
        self._dr = None
        return self.total.copy()
