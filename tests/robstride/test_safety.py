"""Every fault path ends with damping frames, then stop frames, on both buses (seen by a listener node)."""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy.deploy.targets.base import TargetError
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride.errors import (
    CommandError,
    FaultError,
    OperationError,
    TimeoutError,
    UnexpectedDeviceError,
)

from .conftest import assert_ends_with_damping_then_stop
from .helpers import make_target

LEFT = [11, 12, 13, 14, 15, 16, 17]
RIGHT = [21, 22, 23, 24, 25, 26, 27]


def _hold(target, robot):
    return MitCommand.position(robot.pose("arms_hanging"), robot.kp, robot.kd)


def _run_to_fault(robot, channels, make_emulator, fault):
    emu = make_emulator()
    target = make_target(robot, channels)
    target.start()
    for _ in range(3):
        target.read_state()
        target.write_command(_hold(target, robot))
    cmd = _hold(target, robot)
    if fault == "dropped reply":
        emu.inject("left_elbow_pitch", drop_replies=1)
    elif fault == "fault bits":
        emu.inject("right_wrist_roll", fault_bits=0b000100)  # overtemperature
    elif fault == "fault frame":
        emu.inject("left_shoulder_pitch", fault_word=1 << 3)  # overvoltage
    elif fault == "wrong id":
        emu.inject("left_wrist_yaw", reply_as=99)
    elif fault == "bus silence":
        emu.silence("can1")
    elif fault == "non-finite command":
        cmd = cmd._replace(q=np.where(np.arange(14) == 4, np.nan, cmd.q))
    elif fault == "wrong shape":
        cmd = cmd._replace(kp=np.ones(3))
    with pytest.raises(TargetError) as info:
        target.write_command(cmd)
    return emu, target, info.value.__cause__


@pytest.mark.parametrize(
    "fault",
    [
        "dropped reply",
        "fault bits",
        "fault frame",
        "wrong id",
        pytest.param("bus silence", marks=pytest.mark.slow),  # ~18 s: each silent motor's stop waits 2 s
        "non-finite command",
        "wrong shape",
    ],
)
def test_fault_ends_in_damping_then_stop(robot, channels, listeners, make_emulator, fault):
    emu, target, cause = _run_to_fault(robot, channels, make_emulator, fault)
    try:
        if fault == "dropped reply":
            assert (
                isinstance(cause, TimeoutError)
                and cause.missing == (14,)
                and "left_elbow_pitch" in str(cause)
            )
        elif fault == "fault bits":
            assert isinstance(cause, FaultError) and cause.faults == {26: 0b100}
            assert "right_wrist_roll (id 26): overtemperature" in str(cause)
        elif fault == "fault frame":
            assert (
                isinstance(cause, FaultError) and cause.fault_words == {11: 8} and "overvoltage" in str(cause)
            )
        elif fault == "wrong id":
            assert isinstance(cause, UnexpectedDeviceError) and cause.can_ids == (99,)
        elif fault == "bus silence":
            assert isinstance(cause, TimeoutError) and cause.missing == tuple(RIGHT)
        else:
            assert isinstance(cause, CommandError)
        assert target.stopped and not target.enabled
        assert_ends_with_damping_then_stop(listeners["can0"], LEFT)
        assert_ends_with_damping_then_stop(listeners["can1"], RIGHT)
        if fault != "bus silence":  # a silent bus's motors never heard the stop
            assert not any(emu.enabled().values())
        with pytest.raises(TargetError, match="stopped"):
            target.write_command(_hold(target, robot))  # never re-enables silently
    finally:
        target.close()
    # close() after a stop sends nothing more
    assert_ends_with_damping_then_stop(listeners["can0"], LEFT)


def test_keyboard_interrupt_mid_round(robot, channels, listeners, make_emulator):
    make_emulator()
    target = make_target(robot, channels)
    target.start()
    bus = target.group.buses[1]
    original = bus.collect_round

    def interrupted(*a, **k):
        bus.collect_round = original
        raise KeyboardInterrupt

    bus.collect_round = interrupted
    with pytest.raises(KeyboardInterrupt):
        target.write_command(_hold(target, robot))
    target.close()
    assert_ends_with_damping_then_stop(listeners["can0"], LEFT)
    assert_ends_with_damping_then_stop(listeners["can1"], RIGHT)


def test_exception_between_ticks_and_close(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    with pytest.raises(RuntimeError, match="policy blew up"), make_target(robot, channels) as target:
        target.write_command(_hold(target, robot))
        raise RuntimeError("policy blew up")
    assert target.stopped
    assert_ends_with_damping_then_stop(listeners["can0"], LEFT)
    assert_ends_with_damping_then_stop(listeners["can1"], RIGHT)
    assert not any(emu.enabled().values())


def test_safe_stop_holds_damping_then_stops(robot, channels, listeners, make_emulator):
    make_emulator()
    target = make_target(robot, channels, damping_hold_s=0.2)
    target.start()
    target.safe_stop(kd=2.0)
    target.close()
    # at least two damping rounds (held 200 ms at <= 10 ms spacing), then the stops
    frames = listeners["can0"].host_frames((1, 4))
    assert [m.arbitration_id >> 24 for m in frames[-7:]] == [4] * 7
    assert sum(1 for m in frames[-28:-7] if m.arbitration_id >> 24 == 1) >= 14
    assert_ends_with_damping_then_stop(listeners["can1"], RIGHT, kd=2.0)


def test_dry_run_enables_nothing(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    target = make_target(robot, channels, dry_run=True)
    target.start()
    s = target.read_state()
    np.testing.assert_allclose(s.q, robot.pose("arms_hanging"), atol=1e-3)
    target.write_command(_hold(target, robot))  # encoded, decoded and logged; not sent
    target.close()
    for lst in listeners.values():
        assert lst.host_frames((1, 3, 6, 18)) == []  # no MIT, enable, zero or parameter write
        assert len(lst.host_frames((4,))) == 14  # activation poll + one read_state poll, 7 motors each
    assert not any(emu.enabled().values())


def test_lost_interface_still_stops_the_other_bus(robot, channels, listeners, make_emulator):
    make_emulator()
    target = make_target(robot, channels)
    target.start()
    target.group.buses[1].bus.shutdown()  # can1 adapter gone: every send / receive on it fails
    with pytest.raises(TargetError) as info:
        target.write_command(_hold(target, robot))
    assert isinstance(info.value.__cause__, OperationError) and "can1" in str(info.value.__cause__)
    target.close()
    assert_ends_with_damping_then_stop(listeners["can0"], LEFT)  # the healthy bus still got both
