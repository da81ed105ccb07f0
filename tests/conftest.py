"""Many tests open drivers on ``sim://`` ports directly, without building a simulated lab
(which is what registers the emulators' transports in the product): register them once here.
`test_transport.py` checks, in fresh interpreters, that a real lab never loads the simulator
and that a simulated lab registers its transports by itself.

The tests sit in one folder per room (instruments, sim, acquire, predict, analyze, images, tui,
campaign, core, project); the helpers they share (`wire`, `served`, `pilot`, `engine_fakes`,
`fuzz`, `report_fixtures`, `kernel_paths`) stay here, on the import path of every folder."""

import sys
from pathlib import Path

from normbox_lab.sim.transport import register_url_scheme

sys.path.insert(0, str(Path(__file__).resolve().parent))
register_url_scheme()


# --- fixtures shared by several test files ---------------------------------------------------

import pytest


@pytest.fixture
def fake_drivers(monkeypatch, tmp_path):
    """Every driver of the simulated-lab template that `engine_fakes` fakes is replaced in the
    driver registry (deterministic timing); the working directory is `tmp_path`."""
    from engine_fakes import FAKE_DRIVERS

    from normbox_lab.acquire import registry

    monkeypatch.setattr(registry, "DRIVERS", {**registry.DRIVERS, **FAKE_DRIVERS})
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture
def lab_env(monkeypatch, tmp_path):
    """Real CS-1000A driver + emulator; fake stage/lamp drivers (deterministic timing)."""
    from engine_fakes import FAKE_DRIVERS

    from normbox_lab.acquire import registry

    fakes = {name: FAKE_DRIVERS[name] for name in ("apt-k10cr1", "zaber", "sphere-scpi")}
    monkeypatch.setattr(registry, "DRIVERS", {**registry.DRIVERS, **fakes})
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture(autouse=True)
def _scripted_ports_are_used_up():
    """Every `wire.ScriptedPort` a test made has seen every exchange of its script by the end
    of the test (unless the test called `leave_unfinished()`): like pymeasure's
    ``expected_protocol``, a script is a specification, not a suggestion."""
    import wire

    wire.LIVE.clear()
    yield
    ports = [p for p in wire.LIVE if not p.unfinished_ok]
    wire.LIVE.clear()
    for port in ports:
        port.assert_done()


def pytest_sessionstart(session):
    """``NORMBOX_LLVM_TARGET=haswell`` compiles every Dr.Jit kernel of the run for an AVX2 CPU
    (the user's 2-core machine), whatever this host's ISA: set before any test renders."""
    import os

    if os.environ.get("NORMBOX_LLVM_TARGET"):
        import mitsuba as mi

        from normbox_lab.predict.mitsuba_setup import apply_llvm_target

        mi.set_variant("llvm_ad_mono")
        apply_llvm_target()


def pytest_terminal_summary(terminalreporter):
    """The machine the run was on (your machine is not the user's): CPU, vector ISA, cores,
    load, and the LLVM target Dr.Jit compiled for; printed even under ``-q``."""
    import os

    from normbox_lab.core.machine import machine_header

    terminalreporter.write_line(machine_header().replace("machine:", "machine (end of run):", 1))
    if os.environ.get("NORMBOX_LLVM_TARGET"):
        from normbox_lab.predict.mitsuba_setup import llvm_target

        terminalreporter.write_line(f"Dr.Jit LLVM target: {llvm_target()} "
                                    "(NORMBOX_LLVM_TARGET)")
