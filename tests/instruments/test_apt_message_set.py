"""The rotator-apt (K10CR1) emulator answers every request of the APT Communications Protocol
that a K10CR1 answers, and carries out the short-form, velocity and jog moves.  Requests are
encoded and replies decoded with thorlabs-apt-protocol (the codec the product uses), a check
independent of the emulator's own struct codec; a few frames are also written out by hand."""

from __future__ import annotations

import struct

import pytest
import thorlabs_apt_protocol as apt

from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim.rotator_apt import AptRotatorEmulator

STEPS = 409600 / 3
DEV, HOST, CH = 0x50, 0x01, 1


def replies(emu: AptRotatorEmulator) -> list:
    unpacker = apt.Unpacker()
    unpacker.feed(emu.take_output())
    return list(unpacker)


def ask(emu: AptRotatorEmulator, frame: bytes):
    emu.feed(frame)
    got = replies(emu)
    assert len(got) == 1, got
    return got[0]


def homed(clock: VirtualClock) -> AptRotatorEmulator:
    emu = AptRotatorEmulator(clock)
    emu.feed(apt.mot_move_home(DEV, HOST, CH))
    clock.advance(2.0)                        # from 0°: the switch approach takes 1.26 s
    assert [m.msg for m in replies(emu)] == ["mot_move_homed"]
    return emu


def test_powers_up_enabled_and_moves_without_an_enable_message():
    clock = VirtualClock()
    emu = AptRotatorEmulator(clock, power_up_angle_deg=-3.0)
    state = ask(emu, apt.mod_req_chanenablestate(DEV, HOST, CH))
    assert (state.msg, state.enabled) == ("mod_get_chanenablestate", True)
    emu.feed(apt.mot_move_home(DEV, HOST, CH))
    clock.advance(3.0)
    assert [m.msg for m in replies(emu)] == ["mot_move_homed"]
    # disabled: motion commands are ignored, as the controller ignores them
    emu.feed(apt.mod_set_chanenablestate(DEV, HOST, CH, 2))
    emu.feed(apt.mot_move_absolute(DEV, HOST, CH, round(10 * STEPS)))
    clock.advance(5.0)
    assert replies(emu) == [] and emu.angle_deg() == pytest.approx(0.0)


def test_every_parameter_request_gets_its_reply():
    clock = VirtualClock()
    emu = homed(clock)
    v_apt, a_apt = round(10 * STEPS * 53.68), round(10 * STEPS / 90.9)
    expected = {
        apt.mot_req_poscounter: ("mot_get_poscounter", {"position": 0}),
        apt.mot_req_enccounter: ("mot_get_enccounter", {"encoder_count": 0}),
        apt.mot_req_velparams: ("mot_get_velparams",
                                {"min_velocity": 0, "acceleration": a_apt,
                                 "max_velocity": v_apt}),
        apt.mot_req_jogparams: ("mot_get_jogparams",
                                {"jog_mode": 2, "step_size": round(5 * STEPS),
                                 "acceleration": a_apt, "max_velocity": v_apt,
                                 "stop_mode": 2}),
        apt.mot_req_homeparams: ("mot_get_homeparams",
                                 {"home_dir": 2, "limit_switch": 1,
                                  "home_velocity": round(5 * STEPS * 53.68),
                                  "offset_distance": 0}),
        apt.mot_req_genmoveparams: ("mot_get_genmoveparams", {"backlash_distance": 0}),
        apt.mot_req_powerparams: ("mot_get_powerparams",
                                  {"rest_factor": 50, "move_factor": 100}),
        apt.mot_req_moverelparams: ("mot_get_moverelparams", {"relative_distance": 0}),
        apt.mot_req_moveabsparams: ("mot_get_moveabsparams", {"absolute_position": 0}),
        apt.mot_req_limswitchparams: ("mot_get_limswitchparams",
                                      {"cw_hardlimit": 2, "ccw_hardlimit": 2,
                                       "soft_limit_mode": 1}),
        apt.mot_req_statusupdate: ("mot_get_statusupdate",
                                   {"position": 0, "enc_count": 0, "homed": True,
                                    "channel_enabled": True}),
        apt.mot_req_dcstatusupdate: ("mot_get_dcstatusupdate",
                                     {"position": 0, "velocity": 0, "homed": True}),
    }
    for request, (name, values) in expected.items():
        reply = ask(emu, request(DEV, HOST, CH))
        assert reply.msg == name and reply.chan_ident == CH
        assert {k: getattr(reply, k) for k in values} == values, name
        assert reply.source == DEV and reply.dest == HOST


def test_status_bits_request_written_out_by_hand():
    emu = homed(VirtualClock())
    emu.feed(bytes.fromhex("290401005001"))          # MOT_REQ_STATUSBITS, channel 1
    out = emu.take_output()
    assert out[:6] == bytes.fromhex("2a040600" "8150")  # MOT_GET_STATUSBITS, 6 data bytes
    chan, bits = struct.unpack_from("<HL", out, 6)
    assert chan == 1 and bits == 0x80000000 | 0x400 | 0x100   # enabled, homed, connected


def test_set_messages_are_read_back():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_set_powerparams(DEV, HOST, CH, 20, 80))
    emu.feed(apt.mot_set_genmoveparams(DEV, HOST, CH, 1000))
    emu.feed(apt.mot_set_limswitchparams(DEV, HOST, CH, 3, 3, 100, 200, 2))
    emu.feed(apt.mot_set_homeparams(DEV, HOST, CH, 1, 4, round(2 * STEPS * 53.68), 500))
    emu.feed(apt.mot_set_poscounter(DEV, HOST, CH, 12345))
    assert replies(emu) == []                                # set messages: no reply
    power = ask(emu, apt.mot_req_powerparams(DEV, HOST, CH))
    assert (power.rest_factor, power.move_factor) == (20, 80)
    assert ask(emu, apt.mot_req_genmoveparams(DEV, HOST, CH)).backlash_distance == 1000
    lim = ask(emu, apt.mot_req_limswitchparams(DEV, HOST, CH))
    assert (lim.cw_softlimit, lim.ccw_softlimit, lim.soft_limit_mode) == (100, 200, 2)
    home = ask(emu, apt.mot_req_homeparams(DEV, HOST, CH))
    assert (home.home_dir, home.limit_switch, home.offset_distance) == (1, 4, 500)
    assert ask(emu, apt.mot_req_poscounter(DEV, HOST, CH)).position == 12345
    assert ask(emu, apt.mot_req_enccounter(DEV, HOST, CH)).encoder_count == 0


def test_short_form_moves_use_the_stored_parameters():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_set_moveabsparams(DEV, HOST, CH, round(20 * STEPS)))
    short_abs = apt.mot_move_absolute(DEV, HOST, CH)
    assert short_abs == bytes.fromhex("530401005001")         # header only
    emu.feed(short_abs)
    clock.advance(10.0)
    done = replies(emu)
    assert [m.msg for m in done] == ["mot_move_completed"]
    assert done[0].position == round(20 * STEPS) and done[0].velocity == 0
    emu.feed(apt.mot_set_moverelparams(DEV, HOST, CH, round(-5 * STEPS)))
    emu.feed(apt.mot_move_relative(DEV, HOST, CH))
    clock.advance(10.0)
    assert [m.position for m in replies(emu)] == [round(15 * STEPS)]
    assert emu.angle_deg() == pytest.approx(15.0, abs=1e-5)


def test_completed_status_block_layout():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_move_absolute(DEV, HOST, CH, round(30 * STEPS)))    # 30° = 0x3E8000
    clock.advance(10.0)
    out = emu.take_output()
    # 0x0464, 14 data bytes: chan, position, velocity (word), reserved (word), status bits
    assert out[:6] == bytes.fromhex("64040e008150")
    chan, pos, velocity, reserved, bits = struct.unpack_from("<HlhHL", out, 6)
    assert (chan, pos, velocity, reserved) == (1, 0x3E8000, 0, 0)
    assert bits == 0x80000000 | 0x400 | 0x100


def test_velocity_move_runs_until_stopped():
    """Direction 0x02 increases the position counter, 0x01 decreases it (Kinesis motors, as
    pylablib's KinesisMotor drives them); the "forward"/"reverse" bits follow the codes."""
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_move_velocity(DEV, HOST, CH, 2))          # code 2: counts up, 10 °/s
    clock.advance(3.0)                                          # 1 s ramp: 5° + 10°
    status = ask(emu, apt.mot_req_dcstatusupdate(DEV, HOST, CH))
    assert status.moving_reverse and not status.moving_forward
    assert status.position == round(25 * STEPS)
    assert status.velocity == round(10 * STEPS / 2048)
    stopped = ask(emu, apt.mot_move_stop(DEV, HOST, CH, 1))    # immediate
    assert stopped.msg == "mot_move_stopped" and not stopped.moving_reverse
    assert emu.angle_deg() == pytest.approx(25.0, abs=1e-6)
    emu.feed(apt.mot_move_velocity(DEV, HOST, CH, 1))          # code 1: counts down
    clock.advance(2.0)
    assert ask(emu, apt.mot_req_dcstatusupdate(DEV, HOST, CH)).moving_forward
    assert emu.angle_deg() == pytest.approx(25.0 - 15.0, abs=1e-6)
    # a profiled stop decelerates: 10 °/s at 10 °/s² runs on 5° in 1 s, then MOVE_STOPPED
    emu.feed(apt.mot_move_stop(DEV, HOST, CH, 2))
    assert replies(emu) == []
    clock.advance(0.5)
    assert emu.angle_deg() == pytest.approx(10.0 - (5.0 - 1.25), abs=1e-6)
    clock.advance(0.6)
    assert [m.msg for m in replies(emu)] == ["mot_move_stopped"]
    assert emu.angle_deg() == pytest.approx(5.0, abs=1e-6)


def test_continuous_rotation_and_optional_limit_switches():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_move_absolute(DEV, HOST, CH, round(400 * STEPS)))   # no limits: 400°
    clock.advance(60.0)
    assert [m.msg for m in replies(emu)] == ["mot_move_completed"]
    assert emu.angle_deg() == pytest.approx(400.0, abs=1e-5)           # µstep rounding
    lim = AptRotatorEmulator(clock, limit_min_deg=-170.0, limit_max_deg=170.0)
    lim.feed(apt.mot_move_velocity(DEV, HOST, CH, 2))          # counts up into the switch
    clock.advance(60.0)
    end = replies(lim)
    assert [m.msg for m in end] == ["mot_move_stopped"] and end[0].reverse_limit_switch
    assert lim.angle_deg() == pytest.approx(170.0, abs=1e-6)


def test_rehoming_clears_homed_and_takes_time_from_zero():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_move_home(DEV, HOST, CH))                 # already at 0°: re-home
    clock.advance(0.1)
    status = ask(emu, apt.mot_req_dcstatusupdate(DEV, HOST, CH))
    assert status.homing and not status.homed                  # 0x200 set, 0x400 clear
    clock.advance(1.0)
    assert replies(emu) == []                                  # still approaching the switch
    clock.advance(0.3)
    assert [m.msg for m in replies(emu)] == ["mot_move_homed"]
    assert ask(emu, apt.mot_req_dcstatusupdate(DEV, HOST, CH)).homed


def test_bow_index_request_is_answered():
    emu = AptRotatorEmulator(VirtualClock())
    got = ask(emu, apt.mot_req_bowindex(DEV, HOST, CH))
    assert (got.msg, got.bow_index) == ("mot_get_bowindex", 0)
    emu.feed(apt.mot_set_bowindex(DEV, HOST, CH, 3))
    assert ask(emu, apt.mot_req_bowindex(DEV, HOST, CH)).bow_index == 3


def test_jog_step_and_continuous_jog():
    clock = VirtualClock()
    emu = homed(clock)
    emu.feed(apt.mot_move_jog(DEV, HOST, CH, 2))              # one 5° step, counts up
    clock.advance(5.0)
    assert [(m.msg, m.position) for m in replies(emu)] == \
        [("mot_move_completed", round(5 * STEPS))]
    v_apt, a_apt = round(2 * STEPS * 53.68), round(10 * STEPS / 90.9)
    emu.feed(apt.mot_set_jogparams(DEV, HOST, CH, 1, 0, 0, a_apt, v_apt, 2))   # continuous
    emu.feed(apt.mot_move_jog(DEV, HOST, CH, 1))              # code 1: counts down
    clock.advance(2.0)                                          # 0.2 s ramp, then 2 °/s
    status = ask(emu, bytes.fromhex("290401005001"))
    assert status.jogging_forward and status.moving_forward
    ask(emu, apt.mot_move_stop(DEV, HOST, CH, 1))
    assert emu.angle_deg() == pytest.approx(5.0 - (2.0 * 2.0 - 0.2), abs=1e-3)


def test_unknown_messages_are_ignored():
    emu = AptRotatorEmulator(VirtualClock())
    emu.feed(bytes.fromhex("ee0701005001"))
    emu.feed(apt.mot_req_poscounter(DEV, HOST, CH))
    assert [m.msg for m in replies(emu)] == ["mot_get_poscounter"]
