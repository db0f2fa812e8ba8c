"""The hand load's inertia fed forward from a reference arm: the robot the policy trained on, run beside it.

The hand-load fit (``deploy.hand_load``) cancels a load's weight; its mass stays. 0.5 kg at a fingertip
multiplies the wrist roll's and pitch's inertia by about 7 (0.004 -> 0.030 kg*m^2 at the ready pose) and
doubles the shoulder roll's (0.16 + 0.19 kg*m^2): under the fixed Kp 50, Kd 2 the wrists turn from
overdamped (damping ratio 2.2) to underdamped (0.8) and the shoulders slow, so a press lands late and
rings. A feed-forward that restores the nominal arm's dynamics needs the acceleration the nominal arm
would have, and the MIT law's torque at the firmware's rate is not the runtime's to read.

So the runtime runs that arm: a C MuJoCo sim target of the nominal robot (``targets.sim.SimTarget``, the
same MIT law, wire quantisation and implicit damping as the sim target) in the task's scene
(``CommandSource.reference_scene``: the piano's keyboard, whose keys stop the reference's fingertip where
they stop the robot's), started at the measured state on POLICY's first tick and fed every command the
runtime writes, before any load feed-forward. Open loop: it is where the nominal robot would be under the
same commands. Each tick it advances one control period; its mean joint acceleration over the period,

    a_ref = (dq_ref(t + dt) - dq_ref(t)) / dt,

is what the nominal arm does next, and a point mass ``m`` at the point ``p`` of a hand needs the extra
joint torque

    tau = m J_p(q)^T J_p(q) a_ref      (that arm's joints; J_p: the point's translational Jacobian)

at the measured ``q``: the next command's ``tau_ff``, beside the fit's gravity torque. ``m`` is the hand-load
fit's current mass estimate per hand (none for a hand it reads at or below zero: a load lighter than
nothing has no inertia to cancel; counted), ``p`` the fingertip site (the fit's reference point; its
estimate of the load's centre, from a still count-in, is poorly excited and put the inertia at the wrong
place). Decisions measured (docs/robustness.md, "The load's inertia"): open loop, the scene's contacts in,
the fingertip as the point.

Bounds, never silent: the feed-forward is clipped to the firmware caps (``gravity.CapClip``, counted,
first clip logged). The reference is the nominal model (the robot alone plus the scene), as the fit's
gravity model is: a policy trained on identified parameters (``bar.robot_params``) runs it against the
nominal arm. numpy and MuJoCo, no jax.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from bar_policy.deploy.gravity import CapClip
from bar_policy.deploy.hand_load import HANDS, hand_arms
from bar_policy.deploy.targets.sim import SimConfig, SimTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand
from bar_policy.robot.scene import load_model

if TYPE_CHECKING:
    from bar_policy.robot.scene import SceneEdit

__all__ = ["LoadInertia"]


class LoadInertia:
    """The reference arm and the load's inertial feed-forward (module docstring), one ``step`` per tick."""

    def __init__(self, mode: str, control_dt: float, scene: SceneEdit | None = None) -> None:
        """The nominal robot of ``mode`` in ``scene`` (None: the robot alone), ``control_dt`` s a step."""
        robot = load_robot(mode)
        self.control_dt = control_dt
        self.reference = SimTarget(mode, SimConfig(), scene=scene)
        """The nominal arm the runtime's commands drive (``q_ref``, ``dq_ref``: ``reference.read_state``)."""
        self.model = load_model(mode)  # the robot alone: the Jacobians at the measured q
        self.data = mujoco.MjData(self.model)
        index = RobotIndex.from_model(self.model, robot.joint_names)
        self._qadr = index.qpos
        self.arms = hand_arms(robot.joint_names)
        self._arm_dofs = [index.dof[arm] for arm in self.arms]
        self.bodies = [self.model.body(body).id for _, body, _ in HANDS]
        self.sites = [self.model.site(site).id for _, _, site in HANDS]
        self.n = len(robot.joint_names)
        self._jac = np.zeros((3, self.model.nv))
        self.started = False
        self.steps = 0
        """Ticks the reference advanced."""
        self.massless_count = 0
        """Hand-ticks without a feed-forward because the hand's mass estimate was at or below zero."""
        self.max_deviation_rad = 0.0
        """Largest ``|q - q_ref|`` over the joints and ticks (both at the tick's instant), rad: how far the
        robot left the nominal arm."""
        self.clip = CapClip("load inertia feed-forward", robot.joint_names, robot.torque_cap)
        """The caps' clip of the feed-forward: ``clip_count``, ``max_abs`` (N*m per joint)."""

    def start(self, q: np.ndarray, dq: np.ndarray) -> None:
        """Put the reference at the measured state (rad, rad/s, (n,)): POLICY's first tick."""
        self.reference.reset(q, dq)
        self.started = True

    def step(self, cmd: MitCommand, q: np.ndarray, masses: np.ndarray) -> np.ndarray:
        """Advance the reference under ``cmd`` one period; the feed-forward at ``q``, N*m, (n,).

        ``cmd``: the command the runtime writes this tick, before any load feed-forward; ``q``: the
        measured positions, rad, (n,); ``masses``: the load per hand (left, right), kg, (2,).
        """
        ref = self.reference
        before = ref.read_state()  # the instant of the measured q
        self.max_deviation_rad = max(self.max_deviation_rad, float(np.max(np.abs(q - before.q))))
        ref.write_command(cmd)
        ref.advance(self.control_dt)
        self.steps += 1
        acc = (ref.read_state().dq - before.dq) / self.control_dt
        m, d = self.model, self.data
        d.qpos[self._qadr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        out = np.zeros(self.n)
        for arm, dofs, body, site, mass in zip(
            self.arms, self._arm_dofs, self.bodies, self.sites, masses, strict=True
        ):
            if not mass > 0.0:
                self.massless_count += 1
                continue
            mujoco.mj_jac(m, d, self._jac, None, d.site_xpos[site], body)
            jac = self._jac[:, dofs]
            out[arm] = float(mass) * (jac.T @ (jac @ acc[arm]))
        return self.clip(out)

    def record(self) -> dict[str, Any]:
        """For the run log: the ticks, the reference's deviation and every bound's count."""
        return {
            "steps": self.steps,
            "max_deviation_rad": self.max_deviation_rad,
            "massless_hand_ticks": self.massless_count,
            "clipped_joint_evaluations": self.clip.clip_count,
            "max_abs_feedforward_nm": [float(v) for v in self.clip.max_abs],
        }
