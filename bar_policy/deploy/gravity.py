"""Gravity compensation for the stop's damping: the model's gravity torque at the measured joint positions.

Damping alone (Kp = 0, Kd = 1 N*m*s/rad) lets the arms fall under gravity: about 1 rad in the default 1 s
of damping (docs/deploy.md, "Stopping"). ``GravityTorque(q)`` is the feed-forward ``tau_ff`` that holds the
arms against gravity: C MuJoCo's bias force at ``q`` with zero velocity (``mj_fwdPosition`` then
``mj_fwdVelocity``, whose recursive Newton-Euler ``mj_rne`` with ``qvel = 0`` leaves gravity alone in
``qfrc_bias``), clipped to the firmware torque caps. Every clipped joint is counted (``clip_count``,
joint-evaluations) and the first clip of each joint is logged: a cap is never raised, a clip never silent.

The model is the robot alone (``robot.scene.load_model(mode)``), the MJCF the sim target and the emulator
integrate; its joint frame is the deploy's joint frame (a calibrated real robot reports the same q).
"""

from __future__ import annotations

import logging

import numpy as np

from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import load_model

__all__ = ["STOP_DAMPING_KINDS", "CapClip", "GravityTorque"]

log = logging.getLogger(__name__)

STOP_DAMPING_KINDS = ("gravity", "plain")
"""``gravity``: damping with the gravity torque as ``tau_ff`` (the default); ``plain``: damping alone."""


class CapClip:
    """Feed-forward torques clipped to the firmware caps, never silently.

    Every clipped joint-evaluation is counted (``clip_count``), each joint's first clip logged, the largest
    torque asked kept (``max_abs``).
    """

    def __init__(self, what: str, joint_names: tuple[str, ...], cap: np.ndarray) -> None:
        """``what``: the torque's name in the log line (``gravity torque``); ``cap``: N*m, (n,)."""
        self.what = what
        self.joint_names = tuple(joint_names)
        self.cap = np.asarray(cap, dtype=np.float64)
        self.clip_count = 0
        """Joint-evaluations beyond the cap, clipped to it."""
        self.max_abs = np.zeros(len(self.joint_names))
        """Largest |torque| asked per joint before the clip, N*m."""
        self._logged: set[int] = set()

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        """``tau`` (N*m, (n,)) within +-cap (a new array where a joint was clipped)."""
        np.maximum(self.max_abs, np.abs(tau), out=self.max_abs)
        over = np.abs(tau) > self.cap
        if not over.any():
            return tau
        self.clip_count += int(over.sum())
        for i in np.flatnonzero(over):
            if int(i) not in self._logged:
                self._logged.add(int(i))
                log.warning(
                    "%s of %s clipped to its cap: %.4g -> %.4g N*m (further clips counted)",
                    self.what,
                    self.joint_names[i],
                    tau[i],
                    np.sign(tau[i]) * self.cap[i],
                )
        return np.clip(tau, -self.cap, self.cap)


class GravityTorque:
    """``tau_ff(q)``: the gravity torque of the robot of ``mode`` at joint positions q, within the caps."""

    def __init__(self, mode: str) -> None:
        import mujoco

        self._mj = mujoco
        robot = load_robot(mode)
        self.joint_names = tuple(robot.joint_names)
        self.model = load_model(mode)
        self.data = mujoco.MjData(self.model)
        index = RobotIndex.from_model(self.model, self.joint_names)
        self._qadr, self._dadr = index.qpos, index.dof
        self.calls = 0
        """Evaluations so far."""
        self._clip = CapClip("gravity torque", self.joint_names, robot.torque_cap)

    @property
    def cap(self) -> np.ndarray:
        """Firmware torque caps, N*m, (n,) (the clip's; settable)."""
        return self._clip.cap

    @cap.setter
    def cap(self, value: np.ndarray) -> None:
        self._clip.cap = np.asarray(value, dtype=np.float64)

    @property
    def clip_count(self) -> int:
        """Joint-evaluations whose gravity torque was beyond the cap and clipped to it."""
        return self._clip.clip_count

    @property
    def max_abs(self) -> np.ndarray:
        """Largest |gravity torque| asked per joint before the clip, N*m."""
        return self._clip.max_abs

    def raw(self, q: np.ndarray) -> np.ndarray:
        """The unclipped gravity torque at ``q`` (rad, (n,)), N*m, (n,): ``qfrc_bias`` with zero velocity."""
        d = self.data
        d.qpos[self._qadr] = q
        d.qvel[:] = 0.0
        self._mj.mj_fwdPosition(self.model, d)
        self._mj.mj_fwdVelocity(self.model, d)
        return d.qfrc_bias[self._dadr].copy()

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """The gravity torque at ``q`` clipped to +-cap, N*m, (n,); 0 where q is not finite (counted)."""
        q = np.asarray(q, dtype=np.float64)
        finite = np.isfinite(q)
        tau = self.raw(np.where(finite, q, 0.0))
        tau[~finite] = 0.0
        self.calls += 1
        return self._clip(tau)

    def record(self) -> dict[str, object]:
        """For the run log: evaluations, clipped joint-evaluations, the largest torque asked per joint."""
        return {
            "evaluations": self.calls,
            "clipped_joint_evaluations": self.clip_count,
            "max_abs_torque": {n: float(v) for n, v in zip(self.joint_names, self.max_abs, strict=True)},
        }
