"""Which Mitsuba spectral variant works on this machine?  (`python -m normbox_lab.predict.mitsuba_setup`)

`llvm_ad_spectral` aborts the whole process (not an exception) when only libLLVM 15 is present
on some CPUs, so it is probed in a child process.  The answer is cached in
`.cache/mitsuba-variant` and may be forced with the environment variable
``NORMBOX_MITSUBA_VARIANT``.  Order of preference: cuda_ad_spectral (a GPU), llvm_ad_spectral,
scalar_spectral.

The fast renderer (mono) and the MIST triplet check (RGB) use the companion variant of the
spectral one, `jit_variant("mono" | "rgb")`; `in_variant` selects one for a block.

Your machine is not the user's: Dr.Jit compiles its LLVM kernels for the host CPU (16 lanes
with AVX-512, 8 with AVX2, 4 with NEON).  ``NORMBOX_LLVM_TARGET=haswell`` (any LLVM CPU name,
optionally ``cpu:features:width``) makes it compile for another one, so a kernel's behaviour
and compile time on an AVX2 machine can be reproduced on an AVX-512 one
(`apply_llvm_target`; `llvm_target` reports what is in force).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

PREFERENCE = ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")
CACHE = Path(".cache") / "mitsuba-variant"

_PROBE = """
import sys, mitsuba as mi, drjit as dr
mi.set_variant(sys.argv[1])
scene = mi.load_dict({"type": "scene", "integrator": {"type": "path"},
    "sensor": {"type": "perspective", "film": {"type": "specfilm", "width": 2, "height": 2,
               "component_format": "float32",
               "band": {"type": "spectrum", "value": [(400.0, 1.0), (700.0, 1.0)]}}},
    "emitter": {"type": "constant"}})
img = mi.render(scene, spp=1)
import numpy as np
print(float(np.mean(np.array(img))))
"""


def probe(variant: str, timeout_s: float = 120.0) -> bool:
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE, variant], capture_output=True,
                             timeout=timeout_s, text=True, check=False)
    except subprocess.TimeoutExpired:
        return False
    return res.returncode == 0


def choose_variant(use_cache: bool = True) -> str:
    forced = os.environ.get("NORMBOX_MITSUBA_VARIANT")
    if forced:
        return forced
    if use_cache and CACHE.exists():
        cached = CACHE.read_text().strip()
        if cached in PREFERENCE:
            return cached
    for variant in PREFERENCE:
        if probe(variant):
            try:
                CACHE.parent.mkdir(parents=True, exist_ok=True)
                CACHE.write_text(variant + "\n")
            except OSError:
                pass
            return variant
    raise RuntimeError("no Mitsuba spectral variant works here (is `mitsuba` installed?)")


#: the environment variable that forces each companion variant
FORCE_ENV = {"mono": "NORMBOX_FAST_VARIANT", "rgb": "NORMBOX_TRIPLET_VARIANT"}


def jit_variant(kind: str, preferred: str | None = None) -> str:
    """The `kind` ("mono": the fast renderer, "rgb": the triplet check) variant matching the
    project's spectral one: cuda_ad_spectral → cuda_ad_<kind>, llvm_ad_spectral →
    llvm_ad_<kind>; scalar_spectral → scalar_rgb, but llvm_ad_mono (the band path tracer needs
    a JIT variant).  `preferred`, else $NORMBOX_FAST_VARIANT / $NORMBOX_TRIPLET_VARIANT, wins."""
    if kind not in FORCE_ENV:
        raise ValueError(f"variant kind {kind!r}: one of {sorted(FORCE_ENV)}")
    if preferred:
        return preferred
    forced = os.environ.get(FORCE_ENV[kind])
    if forced:
        return forced
    try:
        spectral = choose_variant()
    except RuntimeError:
        spectral = "scalar_spectral"
    if kind == "mono" and spectral.startswith("scalar"):
        spectral = "llvm_ad_spectral"
    return spectral.replace("_spectral", f"_{kind}")


_AVX2 = "+avx2,+fma,+f16c,+bmi,+bmi2,+lzcnt,+popcnt,+sse4.2,+cx16,+movbe,+aes,+pclmul,+xsave"
_AVX512 = "+avx512f,+avx512vl,+avx512dq,+avx512bw,+avx512cd," + _AVX2
#: LLVM CPU name → (features, vector width) for `NORMBOX_LLVM_TARGET` given as a bare name
LLVM_TARGETS = {"haswell": (_AVX2, 8), "znver2": (_AVX2, 8), "skylake-avx512": (_AVX512, 16)}
_TARGET_APPLIED: list[str] = []


def _drjit_core() -> Any:
    import ctypes

    import drjit as dr

    return ctypes.CDLL(str(Path(dr.__path__[0]) / "libdrjit-core.so"))


def llvm_target() -> tuple[str, int] | None:
    """(LLVM CPU name, vector width) Dr.Jit's LLVM back end compiles for, or None when it
    cannot be read (no LLVM back end, another Dr.Jit build)."""
    import ctypes

    try:
        lib = _drjit_core()
        cpu = lib._Z19jit_llvm_target_cpuv
        width = lib._Z21jit_llvm_vector_widthv
    except (OSError, AttributeError, ImportError):
        return None
    cpu.restype, width.restype = ctypes.c_char_p, ctypes.c_uint32
    name = cpu()
    return (name.decode() if name else "?"), int(width())


def apply_llvm_target() -> str | None:
    """Compile Dr.Jit's LLVM kernels for `NORMBOX_LLVM_TARGET` (once per process, after an
    LLVM variant is set); the target in force, or None when the variable is unset."""
    import ctypes

    spec = os.environ.get("NORMBOX_LLVM_TARGET", "").strip()
    if not spec:
        return None
    if _TARGET_APPLIED:
        return _TARGET_APPLIED[0]
    cpu, _, rest = spec.partition(":")
    if rest:
        features, _, width_text = rest.rpartition(":")
        width = int(width_text)
    elif cpu in LLVM_TARGETS:
        features, width = LLVM_TARGETS[cpu]
    else:
        raise ValueError(f"NORMBOX_LLVM_TARGET={spec!r}: give one of {sorted(LLVM_TARGETS)} "
                         "or cpu:features:width")
    setter = _drjit_core()._Z19jit_llvm_set_targetPKcS0_j
    setter.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    setter.restype = None
    setter(cpu.encode(), features.encode(), int(width))
    _TARGET_APPLIED.append(f"{cpu} ({width} lanes)")
    return _TARGET_APPLIED[0]


@contextlib.contextmanager
def in_variant(variant: str) -> Iterator[Any]:
    """Select a Mitsuba variant for a block, restoring the caller's (if one was set)."""
    import mitsuba as mi

    old = mi.variant()
    if old != variant:
        mi.set_variant(variant)
    if variant.startswith("llvm"):
        apply_llvm_target()
    try:
        yield mi
    finally:
        if old and old != variant:
            mi.set_variant(old)


def main() -> int:
    variant = choose_variant(use_cache=False)
    if variant == "scalar_spectral":
        print("WARNING: Mitsuba's llvm_ad_spectral does not run here (libLLVM ≥ 16 missing? "
              "as root: apt-get install -y libllvm19). Falling back to scalar_spectral: "
              "rendering works but is much slower.", file=sys.stderr)
    print(f"mitsuba variant: {variant}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
