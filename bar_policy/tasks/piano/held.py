"""The pose the robot holds when it is told to hold ``piano_ready``: the arms sag under gravity at Kp.

With the MIT law and no feed-forward torque, a joint commanded to ``q0`` at rest settles where its spring
carries the gravity torque: ``Kp (q0 - q) = g(q)`` (``g``: MuJoCo's ``qfrc_bias`` at zero velocity). At the
Lite's Kp of 50 N m/rad the fingertips end 19.7 mm below the exact pose (docs/piano.md): the keyboard is
placed for this pose, the piano env starts its episodes in it and the sim evaluation starts its songs in
it, so no episode begins with the hands falling onto the keys. Friction (0.1 N m) leaves up to 2 mrad of
play around it, which a fixed-point solve does not model.
"""

from __future__ import annotations

import mujoco
import numpy as np

from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import load_model

__all__ = ["HoldingTorque", "held_pose"]


class HoldingTorque:
    """Joint torques holding a pose still on the robot-alone model: gravity, and a key pushing a tip up."""

    def __init__(self, mode: str = "arms") -> None:
        self.model = load_model(mode)
        self.data = mujoco.MjData(self.model)
        self.index = RobotIndex.from_model(self.model, load_robot(mode).joint_names)
        self.sites = {
            h: self.model.site(s).id for h, s in zip(("left", "right"), FINGERTIP_SITES, strict=True)
        }

    def __call__(self, q: np.ndarray, hand: str | None = None, up_force: float = 0.0) -> np.ndarray:
        """``g(q) - J^T (0, 0, up_force)`` at ``hand``'s fingertip (None: gravity alone), N m, shape (n,)."""
        m, d = self.model, self.data
        d.qpos[self.index.qpos] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        tau = d.qfrc_bias[self.index.dof].copy()
        if hand is not None and up_force:
            jac = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jac, None, self.sites[hand])
            tau -= up_force * jac[2, self.index.dof]
        return tau


def held_pose(
    q0: np.ndarray, mode: str = "arms", iterations: int = 50, kp: np.ndarray | None = None
) -> np.ndarray:
    """Joint positions (rad, canonical order, shape (n,)) where the robot's springs at ``q0`` hold gravity.

    Fixed-point iteration ``q <- q0 - g(q) / Kp`` on the robot-alone model (a contraction: the gravity
    torque's slope is well below Kp for these arms); joint limits clip the result. ``kp``: the springs'
    Kp, N*m/rad, shape (n,); None: the joint table's.
    """
    robot = load_robot(mode)
    gravity = HoldingTorque(mode)
    kp = np.asarray(robot.kp if kp is None else kp, np.float64)
    q0 = np.asarray(q0, np.float64)
    q = q0.copy()
    for _ in range(iterations):
        q = np.clip(q0 - gravity(q) / kp, robot.lower, robot.upper)
    return q
