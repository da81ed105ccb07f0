"""The cs2000a emulator answers every command of the CS-2000/CS-2000A Communication
Specifications (exact replies, virtual clock), and ends a measurement inside the announced
time."""

from __future__ import annotations

import pytest

from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim.cs2000 import ANNOUNCE_MARGIN_S, CS2000AEmulator


def run(emu: CS2000AEmulator, clock: VirtualClock, duration_s: float) -> bytes:
    """Let `duration_s` pass, visiting every event of the emulator on the way (as the
    in-process port does); what it said meanwhile."""
    end = clock.now_s() + duration_s
    out = b""
    while True:
        nxt = emu.next_event_s()
        if nxt is None or nxt > end:
            break
        clock.advance(max(0.0, nxt - clock.now_s()))
        out += emu.take_output()
    clock.advance(end - clock.now_s())
    return out + emu.take_output()


def ask(emu: CS2000AEmulator, clock: VirtualClock, line: str) -> str:
    emu.feed(line.encode() + b"\n")
    return run(emu, clock, 1.0).decode()


@pytest.fixture
def remote():
    clock = VirtualClock()
    emu = CS2000AEmulator(clock, noise="off")
    assert ask(emu, clock, "RMTS,1") == "OK00\n"
    return emu, clock


def measure(emu: CS2000AEmulator, clock: VirtualClock) -> None:
    emu.feed(b"MEAS,1\n")
    assert run(emu, clock, 1.1) == b"OK00,002\n"         # 100 cd/m²: 1 s pre-measurement
    assert run(emu, clock, 5.0) == b"OK00\n"


def test_sync_mode(remote):
    emu, clock = remote
    assert ask(emu, clock, "SCMR") == "OK00,0\n"                       # factory: no sync
    assert ask(emu, clock, "SCMS,1,5994") == "OK00\n"
    assert ask(emu, clock, "SCMR") == "OK00,1,05994\n"
    assert ask(emu, clock, "SCMS,1,1999") == "ER17\n"                 # below 20.00 Hz
    assert ask(emu, clock, "SCMS,1,20001") == "ER17\n"
    assert ask(emu, clock, "SCMS,1") == "ER00\n"                      # internal needs f
    assert ask(emu, clock, "SCMS,3") == "ER17\n"
    assert ask(emu, clock, "SCMS,2") == "OK00\n"
    assert ask(emu, clock, "SCMR") == "OK00,2\n"
    measure(emu, clock)
    assert ask(emu, clock, "MEDR,0,0,1") == "OK00,2,2,001000000,0,0,0,0,00\n"


@pytest.mark.parametrize("setter, reader, good, bad, factory", [
    ("OBSS", "OBSR", "1", "2", "0"),
    ("CSMS", "CSMR", "5", "6", "0"),
    ("DIMS", "DIMR", "1", "2", "0"),
    ("BALS", "BALR", "0,1", "2,0", "1,1"),
    ("TGSL", "TGSR", "17", "21", "01"),
])
def test_display_and_target_settings(remote, setter, reader, good, bad, factory):
    emu, clock = remote
    assert ask(emu, clock, reader) == f"OK00,{factory}\n"
    assert ask(emu, clock, f"{setter},{good}") == "OK00\n"
    assert ask(emu, clock, reader) == f"OK00,{good.zfill(2) if setter == 'TGSL' else good}\n"
    assert ask(emu, clock, f"{setter},{bad}") == "ER17\n"
    assert ask(emu, clock, f"{reader},1") == "ER00\n"


def test_compensation_channels_lens_and_nd_need_their_factors(remote):
    emu, clock = remote
    assert ask(emu, clock, "UCCR") == "OK00,00\n"
    assert ask(emu, clock, "UCCS,03") == "ER05\n"                     # channel empty
    assert ask(emu, clock, "UCPR,03") == "ER05\n"
    assert ask(emu, clock, "UCPS,1,03,000,3F800000") == "OK00\n"
    assert ask(emu, clock, "UCPS,2,03,LAB WHITE ") == "OK00\n"
    assert ask(emu, clock, "UCPS,3,03") == "OK00\n"
    assert ask(emu, clock, "UCCS,03") == "OK00\n"
    assert ask(emu, clock, "UCCR") == "OK00,03\n"
    assert ask(emu, clock, "UCCD,03") == "OK00\n"
    assert ask(emu, clock, "UCCR") == "OK00,00\n"                     # deleted: factory
    assert ask(emu, clock, "UCCS,11") == "ER17\n"
    assert ask(emu, clock, "LNSS,1") == "ER05\n"
    assert ask(emu, clock, "ALFR") == "ER05\n"
    assert ask(emu, clock, "ALFS,1,000,3F800000") == "OK00\n"
    assert ask(emu, clock, "ALFS,3") == "OK00\n"
    assert ask(emu, clock, "LNSS,1") == "OK00\n"
    assert ask(emu, clock, "LNSR") == "OK00,1\n"
    assert ask(emu, clock, "NDFS,2") == "ER05\n"
    assert ask(emu, clock, "NFCS,3") == "ER17\n"                      # nothing staged
    assert ask(emu, clock, "NFCS,1,1,000,3DCCCCCD") == "OK00\n"
    assert ask(emu, clock, "NFCS,3") == "OK00\n"
    assert ask(emu, clock, "NDFS,2") == "OK00\n"
    assert ask(emu, clock, "NDFR") == "OK00,2\n"
    measure(emu, clock)
    assert ask(emu, clock, "MEDR,0,0,1") == "OK00,2,0,001000000,0,1,2,0,00\n"


def test_memory_and_targets(remote):
    emu, clock = remote
    assert ask(emu, clock, "STDS,05") == "ER20\n"                     # nothing measured
    measure(emu, clock)
    live = ask(emu, clock, "MEDR,2,0,101")
    assert ask(emu, clock, "STDS,05") == "OK00\n"
    assert ask(emu, clock, "TGDS,02") == "OK00\n"
    assert ask(emu, clock, "STDR,05,2,0,101") == live
    assert ask(emu, clock, "TGDR,02,2,0,101") == live
    assert ask(emu, clock, "STDR,06,2,0,101") == "ER20\n"
    assert ask(emu, clock, "STDR,05,1,0,5") == "ER17\n"
    assert ask(emu, clock, "STDR,100,2,0,101") == "ER17\n"
    assert ask(emu, clock, "STDD,05") == "OK00\n"
    assert ask(emu, clock, "STDR,05,2,0,101") == "ER20\n"
    assert ask(emu, clock, "TGAD") == "OK00\n"
    assert ask(emu, clock, "TGDR,02,2,0,101") == "ER20\n"
    assert ask(emu, clock, "STAD") == "OK00\n"


def test_baud_and_init(remote):
    emu, clock = remote
    assert ask(emu, clock, "BPSR") == "OK00,115200\n"
    assert ask(emu, clock, "BPSS,9600") == "OK00\n"
    assert ask(emu, clock, "BPSR") == "OK00,  9600\n"                  # 6 chars, right-aligned
    assert ask(emu, clock, "BPSS,1234") == "ER17\n"
    assert ask(emu, clock, "SPMS,1,0") == "OK00\n"
    measure(emu, clock)
    assert ask(emu, clock, "INIT,2") == "OK00\n"                       # settings only
    assert ask(emu, clock, "SPMR") == "OK00,2,01,2\n"                  # Multi Normal 1 s, auto
    assert ask(emu, clock, "BPSR") == "OK00,115200\n"
    assert ask(emu, clock, "MEDR,2,0,101").startswith("OK00,")         # data kept
    assert ask(emu, clock, "INIT,1") == "OK00\n"
    assert ask(emu, clock, "MEDR,2,0,101") == "ER20\n"
    assert ask(emu, clock, "INIT,3") == "ER17\n"


def test_old_firmware_lacks_baud_and_init():
    clock = VirtualClock()
    emu = CS2000AEmulator(clock, noise="off", firmware="1.01.0000")
    ask(emu, clock, "RMTS,1")
    assert ask(emu, clock, "BPSS,9600") == "ER00\n"
    assert ask(emu, clock, "INIT,0") == "ER00\n"


def test_unknown_command_er00(remote):
    emu, clock = remote
    assert ask(emu, clock, "FOOO,1") == "ER00\n"


def test_measurement_ends_inside_the_announced_time():
    clock = VirtualClock()
    emu = CS2000AEmulator(clock, noise="off")                        # 100 cd/m²
    emu.feed(b"RMTS,1\n")
    assert run(emu, clock, 0.1) == b"OK00\n"
    t0 = clock.now_s()
    emu.feed(b"MEAS,1\n")
    assert run(emu, clock, 1.0 + 0.05) == b"OK00,002\n"              # 1 s pre-measurement
    # the final OK00 comes ttt − margin after the first (both replies take the same
    # 0.02 s + transfer to cross the line)
    assert run(emu, clock, t0 + 1.0 + 2.0 - ANNOUNCE_MARGIN_S - clock.now_s()) == b""
    assert run(emu, clock, 0.05) == b"OK00\n"
    assert emu.measure_time_s(100.0) == pytest.approx(1.0 + 2.0 - ANNOUNCE_MARGIN_S)
