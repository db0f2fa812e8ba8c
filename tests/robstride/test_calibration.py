"""Calibration maths (hand-computed) and the file format."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bar_policy.robstride.calibration import (
    Calibration,
    JointCalibration,
    SweepRecorder,
    homing_offset,
)
from bar_policy.robstride.errors import InitializationError


def test_homing_offset_direction_minus_one():
    # left_shoulder_pitch: direction -1, limits [-pi, 0.785398]; true offset 0.2817.
    # raw = d * joint + offset: joint -pi -> raw pi + 0.2817 = 3.42329; joint 0.785398 -> -0.50370.
    # direction frame s = -raw: s_min = -3.42329, s_max = 0.50370
    # (s_min - lower) = -3.42329 + 3.14159 = -0.2817; (s_max - upper) = 0.50370 - 0.78540 = -0.2817
    # offset = d * mean = -1 * -0.2817 = 0.2817
    raw_min, raw_max = -0.785398 + 0.2817, math.pi + 0.2817
    assert homing_offset(raw_min, raw_max, -math.pi, 0.785398, -1) == pytest.approx(0.2817, abs=1e-12)


def test_homing_offset_direction_plus_one_asymmetric_sweep():
    # left_shoulder_yaw: direction +1, limits [-1.5708, 1.5708]; swept raw [-1.4708, 1.6908]:
    # offsets from the limits 0.1 and 0.12 -> mean 0.11 -> offset +0.11
    assert homing_offset(-1.4708, 1.6908, -1.5708, 1.5708, 1) == pytest.approx(0.11, abs=1e-12)
    # the argument order of the extremes does not matter
    assert homing_offset(1.6908, -1.4708, -1.5708, 1.5708, 1) == pytest.approx(0.11, abs=1e-12)
    with pytest.raises(ValueError):
        homing_offset(0, 1, 0, 1, 2)


def test_sweep_recorder_recovers_true_offsets(robot):
    rng = np.random.default_rng(1)
    true = rng.uniform(-0.5, 0.5, robot.num_joints)
    d = robot.direction
    rec = SweepRecorder(robot)
    # sweep every joint over its full URDF range in 50 samples, in raw motor coordinates
    for a in np.linspace(0.0, 1.0, 50):
        joint = robot.lower + a * (robot.upper - robot.lower)
        rec.update(d * joint + true)
    rec.update(np.full(robot.num_joints, np.nan))  # a missing sample is skipped
    res = rec.result()
    got = res.calibration.offsets(robot)
    np.testing.assert_allclose(got, true, atol=1e-12)
    assert res.kept == () and res.warnings == () and len(res.swept) == robot.num_joints


def test_short_sweep_keeps_prior_and_long_sweep_warns(robot):
    prior = Calibration.zeros(robot)
    prior = Calibration(
        robot=prior.robot,
        joints={
            **prior.joints,
            "left_elbow_pitch": JointCalibration(
                name="left_elbow_pitch", can_id=14, direction=-1, homing_offset=0.42
            ),
        },
    )
    rec = SweepRecorder(robot)
    i_elbow, i_wroll = robot.index("left_elbow_pitch"), robot.index("left_wrist_roll")
    q = np.zeros(robot.num_joints)
    rec.update(q)
    q2 = q.copy()
    q2[i_elbow] = 0.3  # 0.3 rad < 0.5 rad threshold: prior kept
    q2[i_wroll] = 2.5  # 2.5 rad > URDF range 1.396 + 0.3: warning
    rec.update(q2)
    res = rec.result(prior, sweep_threshold=0.5)
    assert res.calibration.joints["left_elbow_pitch"].homing_offset == 0.42
    assert "left_elbow_pitch" in res.kept and res.swept == ("left_wrist_roll",)
    assert len(res.warnings) == 1 and "left_wrist_roll" in res.warnings[0]


def test_file_round_trip_and_lite_format(tmp_path, robot):
    cal = Calibration.zeros(robot)
    path = tmp_path / "cal.json"
    cal.save(path)
    data = json.loads(path.read_text())
    assert data["joints"]["left_shoulder_pitch"] == {"id": 11, "direction": -1, "homing_offset": 0.0}
    assert Calibration.load(path) == cal
    # a bare {joint: {...}} mapping (Lite-Lowlevel style) loads too
    bare = {
        n: {"id": j.can_id, "direction": j.direction, "homing_offset": 0.1}
        for n, j in zip(robot.joint_names, robot.joints, strict=True)
    }
    path.write_text(json.dumps(bare))
    np.testing.assert_allclose(Calibration.load(path).offsets(robot), 0.1)


def test_file_errors_name_the_problem(tmp_path, robot):
    with pytest.raises(InitializationError, match="cannot read"):
        Calibration.load(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("[1, 2]")
    with pytest.raises(InitializationError, match="invalid calibration"):
        Calibration.load(tmp_path / "bad.json")
    cal = Calibration.zeros(robot)
    joints = dict(cal.joints)
    joints["left_wrist_yaw"] = JointCalibration(
        name="left_wrist_yaw", can_id=15, direction=-1, homing_offset=0
    )
    with pytest.raises(InitializationError, match="left_wrist_yaw"):
        Calibration(joints=joints).offsets(robot)  # direction disagrees with the robot data (+1)
    del joints["left_wrist_yaw"]
    with pytest.raises(InitializationError, match="lacks joints"):
        Calibration(joints=joints).offsets(robot)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("direction", -1.9, "'direction' = -1.9 must be 1 or -1"),  # was truncated to -1
        ("direction", 1.0, "'direction' = 1.0 must be 1 or -1"),  # a float, even an integral one
        ("direction", 2, "'direction' = 2 must be 1 or -1"),
        ("direction", True, "'direction' = True must be 1 or -1"),
        ("id", 11.5, r"'id' = 11.5 is not a CAN id \(an integer 0..127\)"),
        ("id", "11", r"'id' = '11' is not a CAN id \(an integer 0..127\)"),
        ("id", 128, r"'id' = 128 is not a CAN id \(an integer 0..127\)"),
        ("homing_offset", "0.2", "'homing_offset' = '0.2' must be a finite number of radians"),
        ("homing_offset", 1e400, "'homing_offset' = inf must be a finite number of radians"),  # JSON 1e400
    ],
)
def test_calibration_values_are_checked_exactly(tmp_path, robot, key, value, message):
    """Every value is taken as written or refused with one line naming the joint, the key and the choices."""
    cal = json.loads(Calibration.zeros(robot).to_json())
    cal["joints"]["left_shoulder_pitch"][key] = value
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(cal))  # json writes 1e400 as Infinity, which the reader maps to inf
    with pytest.raises(InitializationError, match=f"joint 'left_shoulder_pitch': {message}") as err:
        Calibration.load(path)
    assert "\n" not in str(err.value)


def test_calibration_written_values_load_unchanged(tmp_path, robot):
    """An integral id and direction and a finite offset (an int too) are kept exactly."""
    cal = json.loads(Calibration.zeros(robot).to_json())
    cal["joints"]["left_shoulder_pitch"]["homing_offset"] = 1  # JSON int: 1.0 rad
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(cal))
    j = Calibration.load(path).joints["left_shoulder_pitch"]
    assert (j.can_id, j.direction, j.homing_offset) == (11, -1, 1.0)
