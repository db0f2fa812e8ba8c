"""The MIT law's Kp / Kd a policy runs on, by name: one table of gain profiles for training and deploy.

A policy file runs on fixed gains (it outputs ``q_cmd`` for a fixed spring and damper), and the runtime
refuses a file whose gains are not the robot data's for the profile it names (``bar.gains``; none: ``robot``),
so a file trained on other gains never runs on a wrong law silently.

- ``robot``: the joint table's (``robot.constants``: Humanoid Control's first-activation gains, Kp 50 and
  Kd 2 on every arm joint, the neck 30 and 1).
- ``stiff``: the table's Kp x ``STIFF_KP_FACTOR`` (2) and Kd x ``STIFF_KD_FACTOR`` (1.5): Kp 100, Kd 3 on an
  arm joint. A press against a joint's Coulomb friction ``f`` stops ``f / Kp`` short of its command and
  starts only once the spring's torque exceeds it; the piano's black-key onsets are where that shows
  (docs/gains.md). The damping ratio at a shoulder stays about as it was (Kd / 2 sqrt(Kp I):
  x 1.5 / sqrt(2) = x 1.06).
- ``actuator``: derived from each joint's armature (``actuators.armature_gains``, BeyondMimic's recipe).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from bar_policy.robot.actuators import armature_gains

if TYPE_CHECKING:
    from bar_policy.robot.constants import RobotSpec

__all__ = ["GAINS", "STIFF_KD_FACTOR", "STIFF_KP_FACTOR", "profile_gains"]

GAINS = ("robot", "stiff", "actuator")
"""Valid gain profiles (``RobotEnvConfig.gains``, a file's ``bar.gains``)."""

STIFF_KP_FACTOR = 2.0
"""``stiff``: Kp as a multiple of the joint table's."""
STIFF_KD_FACTOR = 1.5
"""``stiff``: Kd as a multiple of the joint table's."""


def profile_gains(robot: RobotSpec, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(kp, kd)`` of profile ``name`` for ``robot``'s joints: N*m/rad and N*m*s/rad, shape (n,) each.

    Raises ``ValueError`` for an unknown name, listing the valid ones.
    """
    if name == "robot":
        return np.asarray(robot.kp, np.float64), np.asarray(robot.kd, np.float64)
    if name == "stiff":
        return STIFF_KP_FACTOR * np.asarray(robot.kp, np.float64), STIFF_KD_FACTOR * np.asarray(
            robot.kd, np.float64
        )
    if name == "actuator":
        kp, kd = armature_gains(robot.armature)
        return np.asarray(kp, np.float64), np.asarray(kd, np.float64)
    raise ValueError(f"unknown gain profile {name!r}; valid: {', '.join(GAINS)}")
