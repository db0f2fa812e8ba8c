"""The observation inputs the runtime computes itself each tick: the robot's state and the previous action.

``joint_pos`` / ``joint_vel`` are the measured q and dq, ``actions`` the previous (clipped) policy output, and
``fingertip_pos_left`` / ``fingertip_pos_right`` the fingertip sites by C MuJoCo forward kinematics of the
measured q (``robot.kinematics``, the MJCF the env uses). Only the terms the policy's layout holds are
computed (no kinematics for a layout without fingertips). Command terms come from the task's command
source (``deploy.tasks``), never from here.

``joint_error_ema`` (the opt-in integral-like term, ``robot.error_ema``) is the one input with a state:
the runtime passes the joint command it wrote on the previous tick when that tick ran the policy, and
None otherwise (HOLD, DAMPING, the first POLICY tick), which resets the average to 0, as an env reset.
"""

from __future__ import annotations

import numpy as np

from bar_policy.obs.manager import ObservationManager
from bar_policy.robot.error_ema import error_ema_alpha, error_ema_step
from bar_policy.robot.kinematics import Kinematics

__all__ = ["RUNTIME_INPUTS", "StateInputs"]

RUNTIME_INPUTS = (
    "joint_pos",
    "joint_vel",
    "actions",
    "fingertip_pos_left",
    "fingertip_pos_right",
    "joint_error_ema",
)
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
        policy_dt: float = 0.02,
    ) -> None:
        """Computes the inputs of ``obs_manager``'s state terms.

        Args:
            obs_manager: the policy's layout.
            mode: joint set.
            kinematics: fingertip FK (built for ``mode`` when the layout needs it and none is given).
            policy_dt: the policy's period, s (the average's step, ``robot.error_ema``).
        """
        self._ema = "joint_error_ema" in obs_manager.term_names
        self._alpha = error_ema_alpha(policy_dt) if self._ema else 0.0
        self.error_ema = np.zeros(len(obs_manager.joint_names))
        """The ``joint_error_ema`` input of the last call, rad, (num_joints,) (0 without the term)."""
        needs_fk = any(n in obs_manager.term_names for n in _FK_TERMS)
        self.kinematics: Kinematics | None = None
        """Fingertip kinematics; None when the layout has no fingertip term."""
        if needs_fk:
            self.kinematics = kinematics if kinematics is not None else Kinematics(mode)

    def __call__(
        self, q: np.ndarray, dq: np.ndarray, last_action: np.ndarray, q_cmd_prev: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """The inputs for measured ``q``, ``dq`` (rad, rad/s, shape (n,)) and the previous action.

        ``q_cmd_prev``: the joint command (rad, (n,)) the policy's last tick wrote, None when the last tick
        did not run the policy (the average restarts at 0); used only by ``joint_error_ema``.
        """
        inputs = {"joint_pos": q, "joint_vel": dq, "actions": last_action}
        if self._ema:
            if q_cmd_prev is None:
                self.error_ema = np.zeros_like(self.error_ema)
            else:
                self.error_ema = error_ema_step(self.error_ema, q_cmd_prev, q, self._alpha)
            inputs["joint_error_ema"] = self.error_ema
        if self.kinematics is not None:
            left, right = self.kinematics.fingertips(q)
            inputs["fingertip_pos_left"] = left
            inputs["fingertip_pos_right"] = right
        return inputs
