"""thorlabs-apt-device (an outside client, GPL, dev extra only) drives the rotator-apt (K10CR1)
emulator over a pty and over TCP: parameters read at connect, identify, enable, home, absolute /
relative / velocity / jog moves, stop, polled status updates, close."""

from __future__ import annotations

import threading

import pytest
import serial
from served import served

aptdevice = pytest.importorskip(
    "thorlabs_apt_device.devices.aptdevice",
    reason="thorlabs-apt-device (dev extra) is not installed")
from thorlabs_apt_device.devices.aptdevice_motor import APTDevice_Motor
from thorlabs_apt_device.enums import EndPoint

STEPS_PER_DEG = 409600 / 3
# fast mechanics (200 °/s: APT velocity units still fit in 32 bits) so the client's real-time
# pace stays short
FAST = {"max_velocity_deg_s": "200", "acceleration_deg_s2": "2000",
        "home_velocity_deg_s": "200", "power_up_angle_deg": "-7"}
V_APT = round(200 * STEPS_PER_DEG * 53.68)
A_APT = round(2000 * STEPS_PER_DEG / 90.9)
TIMEOUT_S = 10.0


class Watched:
    """The client, with every message it processes recorded and announced to waiters."""

    def __init__(self, device: APTDevice_Motor) -> None:
        self.device = device
        self.messages: list = []
        self.changed = threading.Condition()
        original = device._process_message

        def process(message) -> None:          # runs on the client's own thread
            original(message)
            with self.changed:
                self.messages.append(message)
                self.changed.notify_all()

        device._process_message = process

    def until(self, predicate) -> None:
        with self.changed:
            assert self.changed.wait_for(predicate, timeout=TIMEOUT_S), "client never got there"

    def last(self, name: str):
        return [m for m in self.messages if m.msg == name][-1]

    @property
    def status(self) -> dict:
        return self.device.status_[0][0]


def _open(server, transport: str, monkeypatch) -> APTDevice_Motor:
    if transport == "tcp":
        # the client opens serial.Serial(port) itself; a socket:// URL needs serial_for_url
        monkeypatch.setattr(aptdevice.serial, "Serial",
                            lambda port, **kw: serial.serial_for_url(port, **kw))
    # "polled": the client asks MOT_REQ_STATUSUPDATE after each answer.  (Its "auto" mode
    # reads with a 0.1 s timeout, the very period of the controller's pushes, so its reader
    # never yields and its own commands wait until the pushes stop for lack of keep-alives.)
    return APTDevice_Motor(serial_port=server.url, controller=EndPoint.USB,
                           bays=(EndPoint.USB,), channels=(1,), status_updates="polled",
                           home=False)


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_ordinary_workflow(transport, monkeypatch):
    with served("rotator-apt", transport, **FAST) as server:
        emu = server.emulator
        client = Watched(_open(server, transport, monkeypatch))
        dev = client.device
        try:
            # parameters the client asks for at connect
            client.until(lambda: {"mot_get_velparams", "mot_get_genmoveparams",
                                  "mot_get_jogparams", "mot_get_homeparams"}
                         <= {m.msg for m in client.messages})
            assert (dev.velparams_[0][0]["max_velocity"],
                    dev.velparams_[0][0]["acceleration"]) == (V_APT, A_APT)
            assert dev.homeparams_[0][0]["home_velocity"] == V_APT
            assert dev.jogparams_[0][0]["step_size"] == round(5 * STEPS_PER_DEG)
            # polled status updates: powered up enabled, not homed
            client.until(lambda: client.status.get("msg") == "mot_get_statusupdate")
            assert client.status["channel_enabled"] and not client.status["homed"]

            dev.identify()
            dev.set_enabled(True)
            dev.home()
            client.until(lambda: any(m.msg == "mot_move_homed" for m in client.messages))
            client.until(lambda: client.status["homed"] and client.status["position"] == 0)
            assert emu.identify_count == 1
            assert emu.angle_deg() == pytest.approx(0.0, abs=1e-9)

            target = round(30 * STEPS_PER_DEG)
            dev.move_absolute(target)
            client.until(lambda: any(m.msg == "mot_move_completed" for m in client.messages))
            done = client.last("mot_move_completed")
            assert (done.position, done.velocity) == (target, 0)      # not −32768
            assert done.homed and done.channel_enabled and not done.moving_forward
            assert emu.angle_deg() == pytest.approx(30.0, abs=1e-5)

            dev.move_relative(round(-10 * STEPS_PER_DEG))
            client.until(lambda: [m.msg for m in client.messages].count(
                "mot_move_completed") == 2)
            assert client.last("mot_move_completed").position == round(20 * STEPS_PER_DEG)

            dev.set_jog_params(round(2.5 * STEPS_PER_DEG), A_APT, V_APT)
            client.until(lambda: dev.jogparams_[0][0]["step_size"] == round(2.5 * STEPS_PER_DEG))
            # thorlabs-apt-device's "reverse" is code 0x02: the counter goes up on a Kinesis
            # motor (its invert_direction_logic exists for this; see sim/rotator_apt.py)
            dev.move_jog("reverse")
            client.until(lambda: [m.msg for m in client.messages].count(
                "mot_move_completed") == 3)
            assert client.last("mot_move_completed").position == round(22.5 * STEPS_PER_DEG)

            dev.set_velocity_params(A_APT, V_APT // 100)               # 2 °/s
            client.until(lambda: dev.velparams_[0][0]["max_velocity"] == V_APT // 100)
            dev.move_velocity("forward")                               # code 0x01: down
            client.until(lambda: client.status["moving_forward"])
            dev.stop()
            client.until(lambda: any(m.msg == "mot_move_stopped" for m in client.messages))
            stopped = client.last("mot_move_stopped")
            assert not stopped.moving_forward and stopped.position < round(22.5 * STEPS_PER_DEG)
            assert emu.angle_deg() == pytest.approx(stopped.position / STEPS_PER_DEG, abs=1e-5)
        finally:
            dev.close()
