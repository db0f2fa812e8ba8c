"""The observation inputs the runtime computes itself each tick: the robot's state and the previous action.

``joint_pos`` / ``joint_vel`` are the measured q and dq, ``actions`` the previous (clipped) policy output, and
``fingertip_pos_left`` / ``fingertip_pos_right`` the fingertip sites by C MuJoCo forward kinematics of the
measured q (``robot.kinematics``, the MJCF the env uses). Only the terms the policy's layout holds are
computed (no kinematics for a layout without fingertips). Command terms come from the task's command
source (``deploy.tasks``), never from here.
"""

from __future__ import annotations

import numpy as np

from bar_policy.obs.manager import ObservationManager
from bar_policy.robot.kinematics import Kinematics

__all__ = ["RUNTIME_INPUTS", "StateInputs"]

RUNTIME_INPUTS = ("joint_pos", "joint_vel", "actions", "fingertip_pos_left", "fingertip_pos_right")
"""Observation inputs the runtime computes each tick (measured q and dq, the previous action, fingertip
forward kinematics). Command-category terms come from the command source."""

_FK_TERMS = ("fingertip_pos_left", "fingertip_pos_right")


class StateInputs:
    """Computes the runtime's inputs for one observation layout."""

    def __init__(
        self,
        obs_manager: ObservationManager,
        mode: str,
        kinematics: Kinematics | None = None,
    ) -> None:
        """Computes the inputs of ``obs_manager``'s state terms.

        Args:
            obs_manager: the policy's layout.
            mode: joint set.
            kinematics: fingertip FK (built for ``mode`` when the layout needs it and none is given).
        """
        needs_fk = any(n in obs_manager.term_names for n in _FK_TERMS)
        self.kinematics: Kinematics | None = None
        """Fingertip kinematics; None when the layout has no fingertip term."""
        if needs_fk:
            self.kinematics = kinematics if kinematics is not None else Kinematics(mode)

    def __call__(self, q: np.ndarray, dq: np.ndarray, last_action: np.ndarray) -> dict[str, np.ndarray]:
        """The inputs for measured ``q``, ``dq`` (rad, rad/s, shape (n,)) and the previous action."""
        inputs = {"joint_pos": q, "joint_vel": dq, "actions": last_action}
        if self.kinematics is not None:
            left, right = self.kinematics.fingertips(q)
            inputs["fingertip_pos_left"] = left
            inputs["fingertip_pos_right"] = right
        return inputs
