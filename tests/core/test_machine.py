"""The machine header every bench prints first (normbox_lab.core.machine)."""

from __future__ import annotations

from normbox_lab.core import machine

XEON = """processor\t: 0
model name\t: Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz
flags\t\t: fpu sse sse4_2 avx avx2 fma avx512f avx512bw
"""
LAPTOP = "model name\t: AMD Ryzen 7 5800U\nflags\t\t: fpu sse4_2 avx avx2 fma\n"
GRAVITON = "processor\t: 0\nFeatures\t: fp asimd evtstrm aes sve\nCPU part\t: 0xd40\n"


def test_vector_isa_is_the_widest_the_flags_offer() -> None:
    assert machine.vector_isa(XEON, "x86_64") == "AVX-512"
    assert machine.vector_isa(LAPTOP, "x86_64") == "AVX2"
    assert machine.vector_isa("flags : sse sse4_2\n", "x86_64") == "SSE4.2"
    assert machine.vector_isa(GRAVITON, "aarch64") == "NEON+SVE"
    assert machine.vector_isa("", "x86_64") == "unknown"


def test_header_names_model_isa_cores_load_and_cache(tmp_path) -> None:
    cold = machine.machine_header(cpuinfo=XEON, machine="x86_64", load=(3.5, 2.25, 1.0),
                                  cache_dir=tmp_path / "none", llvm_target="")
    assert cold.startswith("machine: Intel(R) Xeon(R) Gold 6338 CPU @ 2.00GHz; x86_64 AVX-512; ")
    assert "load 3.50 / 2.25 / 1.00 (1 / 5 / 15 min)" in cold
    assert "cores (" in cold and cold.endswith("kernel cache cold (empty "
                                               f"{tmp_path / 'none'})")
    (tmp_path / "a.llvm.bin").write_bytes(b"x")
    (tmp_path / "b.llvm.bin").write_bytes(b"x")
    warm = machine.machine_header(cpuinfo=LAPTOP, machine="x86_64", load=(0.0, 0.0, 0.0),
                                  cache_dir=tmp_path, llvm_target="")
    assert "AMD Ryzen 7 5800U; x86_64 AVX2" in warm
    assert warm.endswith(f"kernel cache warm (2 kernels in {tmp_path})")


def test_header_names_the_llvm_target_the_kernels_are_compiled_for(tmp_path) -> None:
    line = machine.machine_header(cpuinfo=XEON, machine="x86_64", load=(0.0, 0.0, 0.0),
                                  cache_dir=tmp_path, llvm_target="haswell")
    assert "x86_64 AVX-512, kernels compiled for haswell (NORMBOX_LLVM_TARGET);" in line


def test_header_on_this_machine_is_one_line() -> None:
    line = machine.machine_header()
    assert line.startswith("machine: ") and "\n" not in line and "unknown CPU" not in line
