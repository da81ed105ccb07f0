import pytest
import serial

from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim import core
from normbox_lab.sim.transport import open_port


class Echo(core.LineEmulator):
    """Answers every line after a fixed processing time."""

    device_name = "echo-test"
    device_faults = ("busy",)

    def on_line(self, line, terminator):
        if self.faults.fires("busy"):
            self.emit(b"BUSY\n")
        else:
            self.emit(b"OK," + line + b"\n", delay_s=3.0)


core.register("echo-test", lambda clock, faults, seed, world, **o: Echo(clock, faults, seed))


@pytest.fixture(autouse=True)
def fresh_context():
    core.CONTEXT.reset(VirtualClock())
    yield
    core.CONTEXT.reset()


def test_virtual_clock():
    c = VirtualClock(start_s=10.0)
    c.sleep(2.5)
    assert c.now_s() == 12.5
    c.sleep_until(20.0)
    assert c.now_s() == 20.0
    with pytest.raises(ValueError):
        c.advance(-1)


def test_read_jumps_virtual_time_to_the_reply():
    port = open_port("sim://echo-test", timeout=10)
    clock = core.CONTEXT.clock
    port.write(b"HI\n")
    assert port.readline() == b"OK,HI\n"
    assert clock.now_s() == pytest.approx(3.0)
    port.timeout = 1.0
    port.write(b"X\n")
    assert port.readline() == b""                      # timed out after 1 virtual second
    assert clock.now_s() == pytest.approx(4.0)
    port.timeout = 5.0
    assert port.readline() == b"OK,X\n"                # arrives 3 s after it was sent
    assert clock.now_s() == pytest.approx(6.0)


def test_instance_survives_reopen_and_keys_separate_devices():
    a = open_port("sim://echo-test?key=one")
    b = open_port("sim://echo-test?key=two")
    assert a.emulator is not b.emulator
    a.close()
    assert open_port("sim://echo-test?key=one").emulator is a.emulator
    with pytest.raises(serial.SerialException, match="unknown simulated device"):
        open_port("sim://nothing")


def test_fault_spec_parsing_and_determinism():
    inj = core.FaultInjector("no-reply@2,garble=0.5:1,late-reply=1.0:7.5", seed=4)
    assert [inj.fires("no-reply") for _ in range(3)] == [False, True, False]
    assert inj.parameter("late-reply", 5.0) == 7.5 and inj.fires("late-reply")
    again = core.FaultInjector("garble=0.5", seed=4)
    first = [core.FaultInjector("garble=0.5", seed=4).fires("garble") for _ in range(1)]
    assert first == [again.fires("garble")]
    with pytest.raises(ValueError, match="unknown fault kind"):
        core.FaultInjector("melt=1", known_kinds=core.TRANSPORT_FAULTS)
    with pytest.raises(ValueError):
        core.FaultInjector("garble=2")


def test_transport_faults_through_the_port():
    port = open_port("sim://echo-test?faults=no-reply@1,garble@2,truncate@3,busy@4&seed=1",
                     timeout=5)
    port.write(b"A\n")
    assert port.readline() == b""                      # no reply
    port.write(b"B\n")
    garbled = port.readline()
    assert garbled != b"OK,B\n" and len(garbled) == len(b"OK,B\n")
    port.write(b"C\n")
    assert not port.readline().endswith(b"\n")         # truncated: no terminator
    port.reset_input_buffer()
    port.write(b"D\n")
    assert port.readline() == b"BUSY\n"                # device-level fault
    port.write(b"E\n")
    assert port.readline() == b"OK,E\n"


def test_disconnect_then_reconnect():
    port = open_port("sim://echo-test?faults=disconnect@1:2.0", timeout=1)
    port.write(b"A\n")
    with pytest.raises(serial.SerialException, match="disconnected"):
        port.readline()
    with pytest.raises(serial.SerialException):
        port.write(b"B\n")
    core.CONTEXT.clock.sleep(2.0)
    port.write(b"C\n")
    port.timeout = 5
    assert port.readline() == b"OK,C\n"
