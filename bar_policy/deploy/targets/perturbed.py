"""The sim target of a perturbed robot (``bar-deploy --perturb SPEC``, ``bar-deploy eval --perturb SPEC``).

``PerturbedSimTarget`` is a ``SimTarget`` whose model is ``robot.perturb.perturbed_scene`` of the task's
scene (masses, payloads, friction, damping, armature) and whose motors differ from the nominal ones
(``robot.perturb.MotorPerturbation``), the runtime none the wiser:

- ``offset_rad``: ``read_state`` returns ``q + offset``, and the firmware's MIT law acts on that same
  measured ``q + offset``;
- ``strength``: the joint receives ``strength * clip(law, cap)`` (the torque and its cap scaled); with
  implicit damping the Kd term Euler integrates is ``strength * Kd`` likewise. ``read_state``'s torque is
  the firmware's unscaled figure, as a motor's own torque reading would be;
- ``action_delay_ticks``: a command acts ``N`` writes after it was written; the first one written after a
  reset fills the line and acts at once (the reset state is one the motors were holding: an evaluation
  starts at the held pose as training's latency buffer starts full of the first action, and a robot's
  start has HOLD's commands in flight; an empty line's zero torque dropped a loaded arm for the first
  ticks, and the tare read the fall);
- ``obs_delay_ticks``: ``read_state`` returns the state of ``N`` ``advance`` calls ago (the reset state
  until then), stamped now (the host does not know the reading is old);
- ``push_n``: ``robot.perturb.Pusher`` writes ``xfrc_applied`` of the hands before every physics step.

The emulated bus takes the same perturbation in its emulator (``robstride.emulator_perturb``); a test runs
both on one command and compares.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import deque

import numpy as np

from bar_policy.deploy.targets.base import JointState
from bar_policy.deploy.targets.sim import SimConfig, SimTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand, mit_torque
from bar_policy.robot.params import RobotParams, motor_strength, scene_edit
from bar_policy.robot.perturb import MotorPerturbation, Pusher, perturbed_scene
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.robot.scene import SceneEdit

__all__ = ["PerturbedSimTarget", "sim_target"]

log = logging.getLogger(__name__)


class PerturbedSimTarget(SimTarget):
    """C MuJoCo sim target of a perturbed robot (module docstring)."""

    def __init__(
        self,
        mode: str = "arms",
        config: SimConfig | None = None,
        *,
        scene: SceneEdit | None = None,
        perturbation: Perturbation,
    ) -> None:
        self.perturbation = perturbation
        self.motors = MotorPerturbation.of(perturbation, load_robot(mode))
        """The per-joint strength and offset, the delays."""
        self._pusher: Pusher | None = None
        self._cmd_queue: deque[tuple[MitCommand, MitCommand]] = deque()
        self._prime = True
        """The next command written fills the delay line (the first after a reset)."""
        self._obs_queue: deque[JointState] = deque(maxlen=perturbation.obs_delay_ticks + 1)
        super().__init__(mode, config, scene=perturbed_scene(perturbation, scene))
        if perturbation.push_n > 0:
            self._pusher = Pusher(self.model, perturbation.push_n, perturbation.seed)
        log.info("sim target perturbed: %s", perturbation.describe())

    @property
    def pushes(self) -> int:
        """Pushes started so far (0 without ``push_n``)."""
        return 0 if self._pusher is None else self._pusher.pushes

    def reset(self, q: np.ndarray | None = None, dq: np.ndarray | None = None) -> None:
        """As ``SimTarget.reset``; also empties the delay lines and restarts the pushes."""
        super().reset(q, dq)
        self._latched = (self._cmd, self._wire_cmd)
        self._cmd_queue.clear()
        self._prime = True
        self._obs_queue.clear()
        self._obs_queue.append(self._measured())
        if self._pusher is not None:
            self._pusher.reset()
            self.data.xfrc_applied[:] = 0.0

    def _measured(self) -> JointState:
        return JointState(
            q=self._qpos[self._qadr] + self.motors.offset,
            dq=self._qvel[self._dadr].copy(),
            tau=self._tau.copy(),
            stamp=float(self.data.time),
        )

    def read_state(self) -> JointState:
        """The measured state (``q + offset``) of ``obs_delay_ticks`` advances ago, stamped now."""
        if self.motors.obs_delay_ticks == 0:
            return self._measured()
        return dataclasses.replace(self._obs_queue[0], stamp=float(self.data.time))

    def true_q(self) -> np.ndarray:
        """Where the joints really are, rad (no offset, no delay): what an evaluation scores."""
        return self._qpos[self._qadr].copy()

    def write_command(self, cmd: MitCommand) -> None:
        """Queue ``cmd``; the one written ``action_delay_ticks`` writes ago acts from the next step on."""
        super().write_command(cmd)
        if self._prime:  # the first command after a reset: the motors were holding it
            self._prime = False
            self._cmd_queue.extend([(self._cmd, self._wire_cmd)] * self.motors.action_delay_ticks)
        self._cmd_queue.append((self._cmd, self._wire_cmd))
        if len(self._cmd_queue) > self.motors.action_delay_ticks:
            self._latched = self._cmd_queue.popleft()
        self._cmd, self._wire_cmd = self._latched

    def applied_torque(self) -> np.ndarray:
        """The firmware's torque at the measured state (``q + offset``), capped, before ``strength``, N*m."""
        q = self._qpos[self._qadr] + self.motors.offset
        tau = mit_torque(self._wire_cmd, q, self._qvel[self._dadr])
        np.maximum(tau, self._neg_cap, out=tau)
        np.minimum(tau, self._cap, out=tau)
        return tau

    def step(self) -> None:
        """One physics step: ``strength * tau`` into ``qfrc_applied`` (``SimConfig.damping``), the push."""
        tau = self.applied_torque()
        s = self.motors.strength
        if self._implicit:
            d_law = np.where(np.abs(tau) < self._cap, self._wire_cmd.kd, 0.0) * s
            self._dof_damping[self._dadr] = self._mjcf_damping + d_law
            self._qfrc[self._dadr] = s * tau + d_law * self._qvel[self._dadr]
        else:
            self._qfrc[self._dadr] = s * tau
        if self._pusher is not None:
            self._pusher.apply(self.data)
        self._tau = tau
        self._mj_step(self.model, self.data)

    def advance(self, dt: float) -> None:
        """``SimTarget.advance``, then the measured state joins the observation delay line."""
        super().advance(dt)
        self._obs_queue.append(self._measured())

    def run_metadata(self) -> dict[str, object]:
        """The perturbation and the pushes made, for the run log."""
        return {"perturbation": self.perturbation.describe(), "pushes": self.pushes}


def sim_target(
    mode: str,
    config: SimConfig,
    *,
    scene: SceneEdit | None,
    perturbation: Perturbation | None,
    robot_params: RobotParams | None = None,
) -> SimTarget:
    """A ``SimTarget``, or a ``PerturbedSimTarget`` when ``perturbation`` is given and not nominal.

    ``robot_params`` (``bar-deploy --robot-params``): the identified robot is the model (its friction,
    damping, armature and payloads, ``robot.params.scene_edit``) and its motors' strength; a perturbation
    applies on top of it (its strength multiplies the file's).
    """
    if robot_params is None:
        if perturbation is None or perturbation.nominal:
            return SimTarget(mode, config, scene=scene)
        return PerturbedSimTarget(mode, config, scene=scene, perturbation=perturbation)
    target = PerturbedSimTarget(
        mode, config, scene=scene_edit(robot_params, scene), perturbation=perturbation or Perturbation()
    )
    strength = target.motors.strength * motor_strength(robot_params, load_robot(mode))
    target.motors = dataclasses.replace(target.motors, strength=strength)
    log.info("sim target of the identified robot (parameters sha256 %s)", robot_params.sha256[:16])
    return target
