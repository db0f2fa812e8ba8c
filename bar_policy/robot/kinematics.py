"""Forward kinematics on the robot side with C MuJoCo (no jax): fingertip positions from joint angles.

The deploy runtime needs the fingertip positions for the observation (``fingertip_pos_left/right``); it
computes them from the measured joint angles with the same MJCF the env uses, so sim and real build the
observation identically.
"""

from __future__ import annotations

import numpy as np

from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.mjcf import load_model

__all__ = ["Kinematics"]


class Kinematics:
    """Fingertip forward kinematics of the Lite for one mode."""

    def __init__(self, mode: str = "arms") -> None:
        import mujoco

        self._mujoco = mujoco
        self.model = load_model(mode)
        self.data = mujoco.MjData(self.model)
        self._sites = [self.model.site(name).id for name in FINGERTIP_SITES]

    def fingertips(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Left and right fingertip positions in the chest frame, m, each shape (3,).

        Args:
            q: joint positions in canonical order, rad, shape (num_joints,).
        """
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.model.nq,):
            raise ValueError(f"q has shape {q.shape}, expected ({self.model.nq},)")
        self.data.qpos[:] = q
        self._mujoco.mj_kinematics(self.model, self.data)
        left, right = (self.data.site_xpos[i].copy() for i in self._sites)
        return left, right
