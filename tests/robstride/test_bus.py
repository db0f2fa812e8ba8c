"""Bus layer against the emulator: scan, refusal to enable, cap writes, calibration frames, tolerance."""

from __future__ import annotations

import logging
import math
import re
import struct
import time

import can
import numpy as np
import pytest

from bar_policy.deploy.targets.base import TargetError
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.activation import write_caps
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.bus_types import MotorConfig
from bar_policy.robstride.calibration import Calibration, JointCalibration
from bar_policy.robstride.errors import InitializationError

from .helpers import TEST_TIMEOUT, make_group, make_target

LSB_P = 8 * math.pi / 65535  # one position step, rad


def test_scan_finds_exactly_the_motors_and_extras(robot, channels, make_emulator):
    make_emulator(extra_ids={"can1": [40]})
    group = make_group(robot, channels)
    try:
        found = {b.interface: b.scan(range(1, 64)) for b in group.buses}
    finally:
        group.shutdown()
    assert list(found["can0"]) == [11, 12, 13, 14, 15, 16, 17]
    assert list(found["can1"]) == [21, 22, 23, 24, 25, 26, 27, 40]
    assert all(len(uid) == 8 for uid in found["can0"].values())


@pytest.mark.parametrize(
    ("setup", "match"),
    [
        ({"absent": ["left_elbow_pitch"]}, r"missing \[\(14, 'left_elbow_pitch'\)\]"),
        ({"extra_ids": {"can1": [30]}}, r"unknown devices \[30\]"),
        ({"models": {"left_wrist_yaw": "rs-02"}}, r"left_wrist_yaw \(id 15\) reports limit_torque=17"),
    ],
    ids=["missing-id", "extra-unknown-id", "wrong-model"],
)
def test_refuses_to_enable_on_wrong_scan(robot, channels, listeners, make_emulator, setup, match):
    emu = make_emulator(**setup)
    target = make_target(robot, channels)
    with pytest.raises(TargetError) as info:
        target.start()  # closes its buses itself
    assert isinstance(info.value.__cause__, InitializationError)
    assert re.search(match, str(info.value.__cause__)), str(info.value.__cause__)
    for lst in listeners.values():
        # nothing that changes a motor went out: no enable (3), MIT (1), parameter write (18), zero (6)
        assert lst.host_frames((1, 3, 6, 18)) == []
    assert not any(emu.enabled().values())


def test_cap_writes_exact_frames_and_logs(robot, channels, listeners, make_emulator, caplog):
    emu = make_emulator()
    group = make_group(robot, channels)
    caplog.set_level(logging.INFO, logger="bar_policy.robstride.bus")
    try:
        for bus in group.buses:
            write_caps(bus)
    finally:
        group.shutdown()
    writes = listeners["can0"].host_frames((18,))
    expected = []
    for j in robot.joints[:7]:
        for index, value in ((0x700B, j.torque_limit), (0x7018, j.current_limit)):
            # (18 << 24) | (0xFD << 8) | id ; index LE, 2 zero bytes, float32 LE
            expected.append(((18 << 24) | (0xFD << 8) | j.can_id, struct.pack("<HHf", index, 0, value)))
    assert [(m.arbitration_id, bytes(m.data)) for m in writes] == expected
    assert emu.motor(11).params[0x700B] == 17.0 and emu.motor(15).params[0x700B] == 4.0
    assert emu.motor(15).params[0x7018] == 14.0
    assert "wrote torque_limit=17.0 to can_id=11 (left_shoulder_pitch) on can0" in caplog.text
    assert "wrote current_limit=14.0 to can_id=27 (right_wrist_pitch) on can1" in caplog.text


def test_cap_of_zero_skips_the_write(robot, channels, listeners, make_emulator, caplog):
    emu = make_emulator()
    motors = [
        MotorConfig(name="a", can_id=11, model="rs-02", torque_limit=0.0, current_limit=5.0),
        MotorConfig(name="b", can_id=12, model="rs-00", torque_limit=9.0, current_limit=0.0),
    ]
    caplog.set_level(logging.INFO, logger="bar_policy.robstride.bus")
    with RobstrideBus(
        can.Bus(interface="virtual", channel=channels["can0"]),
        motors,
        interface="can0",
        reply_timeout=TEST_TIMEOUT,
    ) as bus:
        written = write_caps(bus)
    assert written == [(11, "current_limit", 5.0), (12, "torque_limit", 9.0)]
    frames = [
        (m.arbitration_id & 0xFF, struct.unpack("<HHf", bytes(m.data))[0])
        for m in listeners["can0"].host_frames((18,))
    ]
    assert frames == [(11, 0x7018), (12, 0x700B)]
    assert emu.motor(11).params[0x700B] == 17.0  # untouched power-on value (rs-02 T_max)
    assert "skipped torque_limit (cap 0) for can_id=11 (a)" in caplog.text


def test_direction_and_homing_offsets(robot, channels, make_emulator):
    rng = np.random.default_rng(3)
    offsets = dict(zip(robot.joint_names, rng.uniform(-0.4, 0.4, robot.num_joints), strict=True))
    q_true = robot.pose("piano_ready")
    emu = make_emulator(offsets=offsets, initial_q=q_true)
    d = robot.direction
    off = np.array([offsets[n] for n in robot.joint_names])
    # 1) zero calibration: q_read = d * raw = d * (d * q + off) = q + d * off
    group = make_group(robot, channels)
    try:
        r0 = group.poll_disabled(strict=True)
    finally:
        group.shutdown()
    np.testing.assert_allclose(r0.q, q_true + d * off, atol=LSB_P)
    # 2) the right calibration: q_read = q_true within one position step
    cal = Calibration(
        joints={
            j.name: JointCalibration(
                name=j.name, can_id=j.can_id, direction=j.direction, homing_offset=offsets[j.name]
            )
            for j in robot.joints
        }
    )
    group = make_group(robot, channels, calibration=cal)
    try:
        r1 = group.poll_disabled(strict=True)
        np.testing.assert_allclose(r1.q, emu.joint_positions(), atol=LSB_P)
        assert np.all(r1.mode == 0) and np.all(r1.faults == 0) and np.all(r1.temperature == 30.0)
        # commands: joint q_cmd -> raw = d * q + off on the wire (decoded by the motor's own ranges)
        frames = group.mit_frames(MitCommand.position(q_true, 10.0, 0.5))
        for bus_frames, joints in zip(frames, (robot.joints[:7], robot.joints[7:]), strict=True):
            for f, j in zip(bus_frames, joints, strict=True):
                s = proto.decode_request(*f).setpoint(j.model)
                assert abs(s.q - (j.direction * q_true[j.index] + offsets[j.name])) <= LSB_P
    finally:
        group.shutdown()


def test_clamps_are_counted_and_logged(robot, channels, caplog):
    group = make_group(robot, channels)
    caplog.set_level(logging.WARNING, logger="bar_policy.robstride.bus")
    try:
        cmd = MitCommand.position(np.full(14, 20.0), 600.0, 0.5)  # q > 4*pi and Kp > 500 everywhere
        group.mit_frames(cmd)
        group.mit_frames(cmd)
    finally:
        group.shutdown()
    for bus in group.buses:
        assert bus.clamps.by_field == {"q": 14, "dq": 0, "kp": 14, "kd": 0, "tau": 0}
    assert caplog.text.count("clamped MIT q=") == 14  # logged once per id and field, counted always


def test_garbage_and_active_reports_are_tolerated(robot, channels, make_emulator):
    emu = make_emulator()
    target = make_target(robot, channels)
    target.start()
    try:
        emu.garbage_per_round = 3
        emu.inject("left_shoulder_roll", active_reports=True)
        for _ in range(5):
            target.write_command(MitCommand.damping(target.read_state().q, 1.0))
        ignored = sum(b.ignored_frames for b in target.group.buses)
        assert ignored >= 5 * 3  # at least the garbage of 5 rounds on one bus was seen and ignored
        assert not target.stopped
    finally:
        target.close()


def test_replies_queued_past_the_deadline_still_count(robot, channels, make_emulator):
    # a host thread descheduled past its deadline must not discard replies that did arrive
    make_emulator()
    group = make_group(robot, channels)
    try:
        deadlines = [bus.send_round(bus.stop_frames()) for bus in group.buses]
        time.sleep(0.05)
        for bus, deadline in zip(group.buses, deadlines, strict=True):
            reading = bus.collect_round(deadline - 1.0)  # long past
            assert np.all(reading.mode == 0) and not np.isnan(reading.q).any()
    finally:
        group.shutdown()
