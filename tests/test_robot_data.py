"""The packaged joint table against the reference (lite-model.md section 2), written out independently."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bar_policy.robot import ROBSTRIDE_MODELS, load_robot, robstride_spec
from bar_policy.robot.constants import robot_from_ros2_control

PI = math.pi
# idx, name, can id, bus, model, dir, lower, upper, torque cap, current cap  (lite-model.md section 2)
REFERENCE = [
    (0, "left_shoulder_pitch", 11, "can0", "rs-02", -1, -PI, PI / 4, 17, 27),
    (1, "left_shoulder_roll", 12, "can0", "rs-00", -1, -PI / 2, 1.91986, 14, 16),
    (2, "left_shoulder_yaw", 13, "can0", "rs-00", 1, -PI / 2, PI / 2, 14, 16),
    (3, "left_elbow_pitch", 14, "can0", "rs-00", -1, -2.35619, 0.0, 14, 16),
    (4, "left_wrist_yaw", 15, "can0", "rs-05", 1, -PI / 2, PI / 2, 4.0, 14),
    (5, "left_wrist_roll", 16, "can0", "rs-05", -1, -0.698132, 0.698132, 4.0, 14),
    (6, "left_wrist_pitch", 17, "can0", "rs-05", -1, -PI / 4, PI / 4, 4.0, 14),
    (7, "right_shoulder_pitch", 21, "can1", "rs-02", 1, -PI, PI / 4, 17, 27),
    (8, "right_shoulder_roll", 22, "can1", "rs-00", -1, -1.91986, PI / 2, 14, 16),
    (9, "right_shoulder_yaw", 23, "can1", "rs-00", 1, -PI / 2, PI / 2, 14, 16),
    (10, "right_elbow_pitch", 24, "can1", "rs-00", 1, -2.35619, 0.0, 14, 16),
    (11, "right_wrist_yaw", 25, "can1", "rs-05", 1, -PI / 2, PI / 2, 4.0, 14),
    (12, "right_wrist_roll", 26, "can1", "rs-05", 1, -0.698132, 0.698132, 4.0, 14),
    (13, "right_wrist_pitch", 27, "can1", "rs-05", -1, -PI / 4, PI / 4, 4.0, 14),
]


def test_arms_table_matches_reference() -> None:
    robot = load_robot("arms")
    assert robot.num_joints == 14
    for idx, name, can_id, bus, model, direction, lo, hi, tcap, ccap in REFERENCE:
        j = robot.joints[idx]
        assert (j.index, j.name, j.can_id, j.can_interface, j.model, j.direction) == (
            idx,
            name,
            can_id,
            bus,
            model,
            direction,
        )
        assert j.lower == pytest.approx(lo, abs=1e-5) and j.upper == pytest.approx(hi, abs=1e-5)
        assert (j.torque_limit, j.current_limit) == (tcap, ccap)
        # First-activation gains of the hardware spec: Kp 50, Kd 2 on every arm joint.
        assert (j.kp, j.kd) == (50.0, 2.0)
        # Armature (lite-model.md 4.2): 0.005 for the rs-02 shoulder pitch, 0.002 elsewhere.
        assert j.armature == (0.005 if model == "rs-02" else 0.002)
        assert j.frictionloss == 0.1


def test_neck_mode_appends_three_joints() -> None:
    arms, neck = load_robot("arms"), load_robot("arms_neck")
    assert neck.joint_names[:14] == arms.joint_names
    assert neck.joint_names[14:] == ("neck_yaw", "neck_roll", "neck_pitch")
    assert [(j.kp, j.kd) for j in neck.joints[14:]] == [(30.0, 1.0)] * 3
    assert neck.upper[14:] == pytest.approx([PI / 4, PI / 6, PI / 6])


def test_arrays_and_caps() -> None:
    robot = load_robot("arms")
    assert robot.torque_cap.tolist() == [17, 14, 14, 14, 4, 4, 4] * 2
    assert robot.can_ids.tolist() == [11, 12, 13, 14, 15, 16, 17, 21, 22, 23, 24, 25, 26, 27]
    assert robot.direction.tolist() == [-1, -1, 1, -1, 1, -1, -1, 1, -1, 1, 1, 1, 1, -1]


def test_poses() -> None:
    robot = load_robot("arms")
    np.testing.assert_array_equal(robot.pose("zero"), np.zeros(14))
    hang = robot.pose("arms_hanging")
    # Arms hanging: shoulder roll exactly at its limit (-pi/2 left lower, +pi/2 right upper).
    assert hang[1] == robot.lower[1] and hang[8] == robot.upper[8]
    piano = robot.pose("piano_ready")
    assert piano.tolist() == [0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3, 0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3]
    assert np.all(piano >= robot.lower) and np.all(piano <= robot.upper)
    with pytest.raises(ValueError, match="valid poses"):
        robot.pose("t_pose")


@pytest.mark.parametrize(
    ("model", "v", "t", "kp", "kd"),
    [  # manuals' MIT ranges (robstride-protocol.md 4.1, column M)
        ("rs-00", 33, 14, 500, 5),
        ("rs-01", 44, 17, 500, 5),
        ("rs-02", 44, 17, 500, 5),
        ("rs-03", 20, 60, 5000, 100),
        ("rs-04", 15, 120, 5000, 100),
        ("rs-05", 50, 5.5, 500, 5),
        ("rs-06", 50, 36, 5000, 100),
    ],
)
def test_robstride_ranges(model: str, v: float, t: float, kp: float, kd: float) -> None:
    s = robstride_spec(model)
    assert (s.p_max, s.v_max, s.t_max, s.kp_max, s.kd_max) == (4 * PI, v, t, kp, kd)


def test_identified_armature_ratio() -> None:
    # Identified J is 3-7x the description armature (robstride-protocol.md 8.1).
    robot = load_robot("arms")
    ratios = {j.model: robstride_spec(j.model).armature_identified / j.armature for j in robot.joints}
    assert ratios["rs-00"] == pytest.approx(7.45) and ratios["rs-05"] == pytest.approx(3.39)
    assert len(ROBSTRIDE_MODELS) == 7


def test_bad_inputs_name_the_choices() -> None:
    with pytest.raises(ValueError, match=r"valid models: \['rs-00'"):
        robstride_spec("rs-99")
    with pytest.raises(ValueError, match="valid modes"):
        load_robot("legs")


def test_reads_upstream_ros2_control_shape() -> None:
    # The upstream file's shape: groups name their interface through `args`; limits/gains live elsewhere.
    upstream = {
        "args": {"can_interface_left": "can0", "can_interface_right": "can1"},
        "groups": [
            {"name": "left_arm", "can_interface_arg": "can_interface_left"},
            {"name": "right_arm", "can_interface_arg": "can_interface_right"},
        ],
        "modes": {"arms": ["left_arm", "right_arm"]},
        "joints": [
            {
                "name": "a",
                "group": "left_arm",
                "can_id": 11,
                "model": "rs-02",
                "direction": -1,
                "torque_limit": 17,
                "current_limit": 27,
            },
            {
                "name": "b",
                "group": "right_arm",
                "can_id": 21,
                "model": "rs-05",
                "direction": 1,
                "torque_limit": 0,
                "current_limit": 0,
            },
        ],
    }
    extra = {
        "lower": -1.0,
        "upper": 1.0,
        "kp": 20.0,
        "kd": 1.0,
        "armature": 0.01,
        "frictionloss": 0.0,
        "sim_effort": 5.0,
    }
    robot = robot_from_ros2_control(upstream, "arms", joint_extras={"a": extra, "b": extra})
    assert robot.joint_names == ("a", "b")
    assert [j.can_interface for j in robot.joints] == ["can0", "can1"]
    # A cap of 0 means "skip the firmware write"; the law then clips at the model's range (rs-05: 5.5).
    assert robot.torque_cap.tolist() == [17.0, 5.5]
    with pytest.raises(ValueError, match="lacks keys"):
        robot_from_ros2_control(upstream, "arms")


def test_validation_rejects_inconsistent_rows() -> None:
    base = {
        "groups": [{"name": "g", "can_interface": "can0"}],
        "modes": {"arms": ["g"]},
        "joints": [],
    }
    row = {
        "name": "x",
        "group": "g",
        "can_id": 11,
        "model": "rs-05",
        "direction": 1,
        "lower": -1,
        "upper": 1,
        "torque_limit": 4,
        "current_limit": 1,
        "kp": 1,
        "kd": 0,
        "armature": 0,
        "frictionloss": 0,
        "sim_effort": 1,
    }
    with pytest.raises(ValueError, match="duplicate joint names"):
        robot_from_ros2_control({**base, "joints": [row, {**row, "can_id": 12}]})
    with pytest.raises(ValueError, match="direction must be"):
        robot_from_ros2_control({**base, "joints": [{**row, "direction": 0}]})
    with pytest.raises(ValueError, match="exceeds rs-05"):
        robot_from_ros2_control({**base, "joints": [{**row, "torque_limit": 6}]})
