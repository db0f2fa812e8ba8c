"""The gain profiles (``robot.gains``): values worked out by hand from the joint table and the
Lite-Description recipe, and the refusal of an unknown name."""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.gains import GAINS, profile_gains


def test_profiles_by_hand() -> None:
    """``robot``: the table's Kp 50 / Kd 2 on the arms, 30 / 1 on the neck (lite-model.md, first-activation
    gains); ``stiff``: twice the Kp and 1.5 times the Kd (100 / 3, 60 / 1.5); ``actuator``: ``J w^2`` and
    ``2 zeta J w`` at 10 Hz, zeta 2: 0.005 kg*m^2 -> 19.74 / 1.257, 0.002 -> 7.896 / 0.5027."""
    robot = load_robot("arms_neck")
    arm = np.array([not n.startswith("neck") for n in robot.joint_names])
    kp, kd = profile_gains(robot, "robot")
    np.testing.assert_array_equal(kp, np.where(arm, 50.0, 30.0))
    np.testing.assert_array_equal(kd, np.where(arm, 2.0, 1.0))
    kp, kd = profile_gains(robot, "stiff")
    np.testing.assert_array_equal(kp, np.where(arm, 100.0, 60.0))
    np.testing.assert_array_equal(kd, np.where(arm, 3.0, 1.5))
    arms = load_robot("arms")
    kp, kd = profile_gains(arms, "actuator")
    w = 2 * np.pi * 10.0
    shoulder = np.array([n.endswith("shoulder_pitch") for n in arms.joint_names])
    j = np.where(shoulder, 0.005, 0.002)  # the MJCF's armature
    np.testing.assert_allclose(kp, j * w * w, rtol=1e-12)
    np.testing.assert_allclose(kd, 2 * 2 * j * w, rtol=1e-12)
    np.testing.assert_allclose(kp[shoulder][0], 19.739, atol=1e-3)


def test_an_unknown_profile_is_refused_naming_the_valid_ones() -> None:
    assert GAINS == ("robot", "stiff", "actuator")
    with pytest.raises(ValueError, match=r"unknown gain profile 'soft'; valid: robot, stiff, actuator"):
        profile_gains(load_robot("arms"), "soft")
