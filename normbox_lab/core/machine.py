"""The machine a figure was measured on, in one line (`machine_header`).

Timings move with the machine (a ratio measured on an AVX-512 server and on an AVX2 laptop can
differ 2-3x) and with its load, and a first render in a process with an empty Dr.Jit kernel
cache pays for compiling every kernel.  Every bench prints this line first, so a figure always
says where it came from:

    machine: Intel(R) Xeon(R) Processor; x86_64 AVX-512; 2 cores (2 usable); load 1.36 / 0.45
    / 0.16 (1 / 5 / 15 min); Dr.Jit kernel cache warm (412 kernels in ~/.drjit)

Only the standard library: /proc/cpuinfo (Linux), `platform`, `os.getloadavg`, and the kernel
cache directory Dr.Jit's LLVM and CUDA backends write (``~/.drjit``).
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

#: where Dr.Jit keeps compiled kernels between processes (LLVM: *.llvm.bin, CUDA: *.cuda.bin);
#: Dr.Jit reads ``DRJIT_CACHE_DIR`` (a cold-cache measurement points it at an empty folder)
KERNEL_CACHE_DIR = Path(os.environ.get("DRJIT_CACHE_DIR") or Path.home() / ".drjit")


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU's model name ("model name" of /proc/cpuinfo; else `platform.processor()`)."""
    text = cpuinfo if cpuinfo is not None else _read("/proc/cpuinfo")
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("model name", "hardware", "cpu model") and value.strip():
            return value.strip()
    return platform.processor() or platform.machine() or "unknown CPU"


def vector_isa(cpuinfo: str | None = None, machine: str | None = None) -> str:
    """The widest SIMD instruction set the CPU offers: AVX-512, AVX2, AVX, SSE4.2, NEON
    (aarch64 "asimd"; "+SVE" when present) or "unknown"."""
    text = cpuinfo if cpuinfo is not None else _read("/proc/cpuinfo")
    flags: set[str] = set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("flags", "features"):
            flags.update(value.split())
    arch = (machine or platform.machine()).lower()
    if arch in ("aarch64", "arm64"):
        isa = "NEON" if ("asimd" in flags or not flags) else "unknown"
        return isa + ("+SVE" if "sve" in flags else "")
    for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"),
                       ("sse4_2", "SSE4.2")):
        if flag in flags:
            return name
    return "unknown"


def usable_cores() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def kernel_cache_count(directory: Path | None = None) -> int:
    """How many compiled kernels Dr.Jit's cache directory holds (0 when it does not exist)."""
    d = directory or KERNEL_CACHE_DIR
    try:
        return sum(1 for p in d.iterdir() if p.is_file())
    except OSError:
        return 0


def kernel_cache_state(directory: Path | None = None) -> str:
    """'cold (empty ~/.drjit)' or 'warm (N kernels in ~/.drjit)'."""
    d = directory or KERNEL_CACHE_DIR
    n = kernel_cache_count(d)
    where = str(d).replace(str(Path.home()), "~", 1)
    return f"cold (empty {where})" if n == 0 else f"warm ({n} kernels in {where})"


def machine_header(*, cpuinfo: str | None = None, machine: str | None = None,
                   load: tuple[float, float, float] | None = None,
                   cache_dir: Path | None = None, llvm_target: str | None = None) -> str:
    """One line: CPU model, vector ISA, cores (logical / usable by this process), the load
    average, and whether Dr.Jit's kernel cache was cold or warm.  Call it before the first
    render: afterwards the cache is warm by construction.  `llvm_target` (default:
    ``NORMBOX_LLVM_TARGET``, "" for none): the CPU the kernels are compiled for, when not the
    host's."""
    text = cpuinfo if cpuinfo is not None else _read("/proc/cpuinfo")
    arch = machine or platform.machine()
    if load is None:
        try:
            load = os.getloadavg()
        except OSError:
            load = (float("nan"),) * 3
    target = (os.environ.get("NORMBOX_LLVM_TARGET", "") if llvm_target is None
              else llvm_target).strip()
    isa = vector_isa(text, arch)
    if target:
        isa += f", kernels compiled for {target.partition(':')[0]} (NORMBOX_LLVM_TARGET)"
    return (f"machine: {cpu_model(text)}; {arch} {isa}; "
            f"{os.cpu_count() or 1} cores ({usable_cores()} usable); load "
            f"{load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1 / 5 / 15 min); "
            f"Dr.Jit kernel cache {kernel_cache_state(cache_dir)}")


def _read(path: str) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read()
    except OSError:
        return ""
