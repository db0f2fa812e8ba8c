"""The motors' CAN watchdog ``canTimeout`` (0x7028): frame encoding, arming at activation, the emulator's
trips, a driver killed with SIGKILL in a real subprocess, and the ``bar-bus watchdog`` bench probe."""

from __future__ import annotations

import logging
import math
import os
import signal
import time

import can
import numpy as np
import pytest

from bar_policy.deploy.targets.base import TargetError
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.bus_types import MotorConfig
from bar_policy.robstride.errors import DisabledError
from bar_policy.robstride.tools import main

from .bridge import SocketcandBridge
from .conftest import assert_ends_with_damping_then_stop
from .helpers import Child
from .helpers import make_target as _make_target

LEFT = [11, 12, 13, 14, 15, 16, 17]
RIGHT = [21, 22, 23, 24, 25, 26, 27]
# Type-18 write of canTimeout = 4000 ticks (0.2 s at 50 us per tick), worked by hand from section 5.1:
# id = (18 << 24) | (host 0xFD << 8) | motor id; payload = index 0x7028 little-endian (28 70), two zero
# bytes, then the u32 value little-endian: 4000 = 0x00000FA0 -> A0 0F 00 00.
ARM_PAYLOAD = bytes.fromhex("28700000a00f0000")
WINDOW = 0.2
LATE = 0.1  # scheduling tolerance of the emulator's thread: passive within 300 ms of the last frame


def make_target(robot, channels, **kw):
    """``helpers.make_target`` with the robot's own watchdog (``DEFAULT_CAN_TIMEOUT``, 0.2 s), which these
    tests are about, in place of the other tests' generous one (``helpers.TEST_CAN_TIMEOUT``)."""
    group_kw = {"can_timeout": proto.DEFAULT_CAN_TIMEOUT, **kw.pop("group_kw", {})}
    return _make_target(robot, channels, group_kw=group_kw, **kw)


def _write_id(can_id: int) -> int:
    return (18 << 24) | (0xFD << 8) | can_id


def _read_id(can_id: int) -> int:
    return (17 << 24) | (0xFD << 8) | can_id


def _watchdog_frames(listener, comm: int) -> list[can.Message]:
    """Host requests of type ``comm`` (17 read, 18 write) that address canTimeout."""
    make = _read_id if comm == 17 else _write_id
    return [
        m
        for m in listener.collect()
        if m.arbitration_id == make(m.arbitration_id & 0xFF) and bytes(m.data[:2]) == b"\x28\x70"
    ]


def test_units_and_frame_layout():
    assert proto.CAN_TIMEOUT_TICK == 50e-6
    assert proto.can_timeout_ticks(1.0) == 20000  # the manual's "20000 = 1 s"
    assert proto.can_timeout_ticks(0.2) == 4000  # what s2015-turtle writes for 0.2 s
    assert proto.can_timeout_ticks(0.0) == 0
    frame = proto.write_param_frame(11, proto.PARAM_CAN_TIMEOUT, 4000)
    assert frame == (0x1200FD0B, ARM_PAYLOAD)
    assert (
        proto.DEFAULT_CAN_TIMEOUT == 0.2
        and MotorConfig(name="a", can_id=11, model="rs-02").can_timeout == 0.2
    )


@pytest.mark.parametrize("bad", [-0.2, 0.005, 10.5, math.nan, math.inf])
def test_bad_watchdog_values_are_refused(bad):
    msg = r"a: can_timeout must be 0 \(leave the motors' watchdog setting\) or 0\.01\.\.10 s, got"
    with pytest.raises(ValueError, match=msg):
        MotorConfig(name="a", can_id=11, model="rs-02", can_timeout=bad)


def _hold(robot, q):
    return MitCommand.position(np.asarray(q) + 0.1, robot.kp, robot.kd)  # 0.1 rad off: a holding torque


def test_activation_arms_every_motor_before_enabling(robot, channels, listeners, make_emulator, caplog):
    emu = make_emulator()
    caplog.set_level(logging.INFO, logger="bar_policy.robstride")
    with make_target(robot, channels) as target:
        target.write_command(_hold(robot, target.read_state().q))
    assert target.can_timeout == 0.2
    for iface, ids in (("can0", LEFT), ("can1", RIGHT)):
        frames = listeners[iface].collect()
        writes = [
            (k, m) for k, m in enumerate(frames) if m.arbitration_id >> 24 == 18 and m.data[:2] == b"\x28\x70"
        ]
        assert [(m.arbitration_id, bytes(m.data)) for _, m in writes] == [
            (_write_id(i), ARM_PAYLOAD) for i in ids
        ]
        first_enable = next(k for k, m in enumerate(frames) if m.arbitration_id >> 24 == 3)
        assert max(k for k, _ in writes) < first_enable  # armed before any motor is enabled
    assert {m.params[0x7028] for m in emu.motors.values()} == {4000}
    assert "wrote canTimeout=4000 ticks (0.2 s) to can_id=11 (left_shoulder_pitch) on can0" in caplog.text
    assert "wrote canTimeout=4000 ticks (0.2 s) to can_id=27 (right_wrist_pitch) on can1" in caplog.text


def test_zero_skips_the_watchdog_entirely(robot, channels, listeners, make_emulator, caplog):
    emu = make_emulator()
    caplog.set_level(logging.INFO, logger="bar_policy.robstride")
    with make_target(robot, channels, group_kw={"can_timeout": 0.0}) as target:
        target.write_command(_hold(robot, target.read_state().q))
    assert target.can_timeout == 0.0
    for lst in listeners.values():
        lst.collect()
        assert _watchdog_frames(lst, 17) == [] and _watchdog_frames(lst, 18) == []
    assert {m.params[0x7028] for m in emu.motors.values()} == {0}  # the power-on value, untouched
    assert "skipped canTimeout (0) for can_id=11 (left_shoulder_pitch) on can0" in caplog.text


def test_dry_run_checks_support_but_writes_nothing(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    with make_target(robot, channels, dry_run=True) as target:
        target.read_state()
    reads = _watchdog_frames(listeners["can0"], 17)
    assert sorted(m.arbitration_id & 0xFF for m in reads) == LEFT
    assert _watchdog_frames(listeners["can0"], 18) == [] and _watchdog_frames(listeners["can1"], 18) == []
    assert {m.params[0x7028] for m in emu.motors.values()} == {0}


def test_firmware_without_can_timeout_is_refused_before_anything_is_written(
    robot, channels, listeners, make_emulator
):
    emu = make_emulator()
    del emu.motor("left_elbow_pitch").params[0x7028]  # an old firmware: the read is refused (status 1)
    target = make_target(robot, channels)
    msg = r"canTimeout of left_elbow_pitch \(id 14\).*firmware without canTimeout.*--can-timeout 0"
    with pytest.raises(TargetError, match=msg):
        target.start()
    for lst in listeners.values():
        assert lst.host_frames((1, 3, 18)) == []  # nothing written, nothing enabled
    assert not any(emu.enabled().values())


def test_emulated_watchdog_trips_after_the_window_and_the_target_says_why(
    robot, channels, listeners, make_emulator
):
    emu = make_emulator()
    target = make_target(robot, channels)
    target.start()
    hold = _hold(robot, target.read_state().q)
    for _ in range(5):
        target.write_command(hold)
    assert all(emu.enabled().values()) and np.all(np.abs(emu.applied_torques()) > 0)
    time.sleep(WINDOW + 0.15)  # the host falls silent
    for m in emu.motors.values():
        ((last, trip),) = m.watchdog_trips
        assert WINDOW <= trip - last < WINDOW + LATE, (m.name, trip - last)
    assert not any(emu.enabled().values())
    np.testing.assert_array_equal(emu.applied_torques(), 0.0)
    with pytest.raises(
        TargetError,
        match=r"left run mode while commanded: left_shoulder_pitch \(reset\).*"
        r"the CAN watchdog tripped",
    ) as info:
        target.write_command(hold)
    cause = info.value.__cause__
    assert isinstance(cause, DisabledError) and sorted(cause.can_ids) == LEFT + RIGHT
    for iface, ids in (("can0", LEFT), ("can1", RIGHT)):
        assert_ends_with_damping_then_stop(listeners[iface], ids)
    target.close()


def test_microsecond_units_would_fail_at_once(robot, channels, make_emulator):
    """The conflicting reading (4000 us = 4 ms) trips between two 50 Hz ticks: refused at once."""
    make_emulator(watchdog_tick=1e-6)
    target = make_target(robot, channels)
    with pytest.raises(TargetError, match="left run mode"):
        target.start()  # may already fail: enable and the damping round more than 4 ms apart
        q = target.read_state().q
        time.sleep(0.02)
        target.write_command(_hold(robot, q))
    target.close()


def test_sigkilled_driver_leaves_the_motors_passive_in_time(robot, channels, listeners, make_emulator):
    """A real subprocess drives both arms through a loopback bridge and is killed with SIGKILL: no clean-up,
    no stop frame. Every emulated motor disables itself 0.2 s after the last frame it heard."""
    emu = make_emulator()
    with SocketcandBridge(channels) as bridge:
        child = Child(["drive", str(WINDOW)], bridge.port)
        try:
            child.wait_for("RUNNING")
            assert all(emu.enabled().values())
            assert {m.params[0x7028] for m in emu.motors.values()} == {4000}
            assert np.all(np.abs(emu.applied_torques()) > 0)  # holding 0.1 rad off
            os.kill(child.proc.pid, signal.SIGKILL)
            assert child.proc.wait(timeout=10) == -signal.SIGKILL
            end = time.monotonic() + 2.0
            while any(emu.enabled().values()) and time.monotonic() < end:
                time.sleep(0.01)
        finally:
            child.kill()
            child.finish()
    for m in emu.motors.values():
        ((last, trip),) = m.watchdog_trips
        assert WINDOW <= trip - last < WINDOW + LATE, (m.name, trip - last)
    assert not any(emu.enabled().values())
    np.testing.assert_array_equal(emu.applied_torques(), 0.0)
    for lst in listeners.values():
        host = lst.host_frames((1, 3, 4))
        first_enable = next(k for k, m in enumerate(host) if m.arbitration_id >> 24 == 3)
        assert all(m.arbitration_id >> 24 != 4 for m in host[first_enable:])  # no stop frame: no clean-up
    # a frame now is answered as by a disabled motor: reset mode, zero torque, and it stays disabled
    probe = listeners["can0"].bus
    probe.send(
        can.Message(arbitration_id=0x01000000 | (32767 << 8) | 11, data=bytes.fromhex("7fff7fff0fff0000"))
    )
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        msg = probe.recv(timeout=0.1)
        if msg is not None and msg.arbitration_id >> 24 == 2 and (msg.arbitration_id >> 8) & 0xFF == 11:
            fb = proto.decode_reply(msg.arbitration_id, bytes(msg.data), models={11: "rs-02"})
            assert fb.mode == 0 and fb.torque == pytest.approx(0.0, abs=1e-3)
            break
    else:
        raise AssertionError("no feedback from id 11")
    assert not emu.enabled()["left_shoulder_pitch"]


def _watchdog_argv(channels: dict[str, str]) -> list[str]:
    """``bar-bus watchdog`` on motor 11 of can0 with a 0.2 s window."""
    return [
        "watchdog",
        "--can-interface",
        "virtual",
        "--channel",
        channels["can0"],
        "--id",
        "11",
        "--reply-timeout",
        "0.2",
    ]


def test_bar_bus_watchdog_brackets_the_window(channels, make_emulator, listeners, capsys):
    emu = make_emulator()
    argv = _watchdog_argv(channels)
    assert main([*argv, "--silences", "0.1,0.3"]) == 0
    out = capsys.readouterr().out
    assert "still running" in out.splitlines()[1] and "tripped (reset mode)" in out.splitlines()[2]
    assert "consistent with 0.2 s = 4000 ticks of 50 us" in out
    assert emu.motor(11).params[0x7028] == 4000 and len(emu.motor(11).watchdog_trips) == 1
    assert not any(emu.enabled().values())
    assert_ends_with_damping_then_stop(listeners["can0"], [11])


def test_bar_bus_watchdog_flags_a_window_shorter_than_configured(channels, make_emulator, capsys):
    make_emulator(watchdog_tick=1e-6)  # a firmware that counts microseconds
    argv = _watchdog_argv(channels)
    assert main([*argv, "--silences", "0.1,0.3"]) == 1
    assert "tripped after every silence, even 0.1" in capsys.readouterr().out
