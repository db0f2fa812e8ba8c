"""The calibration check: joint positions read against a known pose, before a run.

``bar-bus check-calibration`` reads the joints with the motors disabled while the robot rests in a named
pose (``arms_hanging``: the arms hang at their stops, a pose gravity holds without a person), and
``check_pose`` compares: beyond ``threshold`` on any joint the check fails with one line naming the worst
joint. No jax, no torch.
"""

from __future__ import annotations

import numpy as np

from bar_policy.robot.constants import RobotSpec

__all__ = ["DEFAULT_THRESHOLD_RAD", "check_pose"]

DEFAULT_THRESHOLD_RAD = 0.005
"""Largest error accepted, rad (5 mrad: the tracker's fingertips move ~0.6 mm per mrad at the shoulder)."""


def check_pose(
    robot: RobotSpec, q: np.ndarray, pose: np.ndarray, *, threshold: float, pose_name: str
) -> tuple[bool, str]:
    """``(ok, one line)``: every ``|q - pose| <= threshold`` (rad, canonical order, shape (num_joints,))."""
    err = np.abs(np.asarray(q, dtype=np.float64) - np.asarray(pose, dtype=np.float64))
    err = np.where(np.isfinite(err), err, np.inf)  # a joint that did not answer fails the check
    worst = int(np.argmax(err))
    name = robot.joint_names[worst]
    beyond = int((err > threshold).sum())
    if beyond:
        return False, (
            f"calibration check failed: {name} is {err[worst] * 1e3:.1f} mrad from the {pose_name} pose "
            f"(threshold {threshold * 1e3:.1f} mrad; {beyond} joint(s) beyond it): "
            "recalibrate (bar-bus calibrate)"
        )
    return True, (
        f"calibration check passed: every joint within {threshold * 1e3:.1f} mrad of the {pose_name} pose "
        f"(largest {err[worst] * 1e3:.1f} mrad ({name}))"
    )
