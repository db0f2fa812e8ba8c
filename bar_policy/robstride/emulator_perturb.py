"""The emulator as a hidden robot: ``RobstrideEmulator`` of a perturbed Lite the host does not know about.

``PerturbedEmulator`` answers on the bus like ``RobstrideEmulator``; its MuJoCo model and its motors are
those of ``robot.perturb`` (``bar-deploy --target real --can-interface virtual --perturb SPEC`` /
``--emulate-perturb SPEC``, ``bar-bus ... --emulate --emulate-perturb SPEC``). The same perturbation as the
sim target (``deploy.targets.perturbed``), on the firmware side of the bus:

- model: ``perturbed_scene`` (masses, payloads, friction, damping, armature);
- ``offset_rad``: added to each motor's true homing offset (raw frame: ``direction * offset``), so the
  feedback reads ``q + offset`` after the host's calibration and the firmware's law acts on it;
- ``strength``: the joint receives ``strength`` times the firmware's capped torque; the feedback's torque
  is the firmware's own (unscaled);
- ``action_delay_ticks``: the motors act on the commands of ``N`` control periods (``control_dt``) ago,
  on the physics clock (zero torque before any); lockstep makes this exactly ``N`` command rounds. After an
  evaluation's start (``prime_delay``, after the teleport) the start's damping rounds (Kp 0) act at once
  and the first holding command fills the line, acting at once, as the first command on the perturbed sim
  target (the state set is one the motors were holding);
- ``obs_delay_ticks``: the feedback reports the joint state of ``N`` control periods ago (the state at a
  teleport, ``set_joint_positions``, until then);
- ``push_n``: ``robot.perturb.Pusher`` on the hands before every physics step.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.params import RobotParams, motor_strength, scene_edit
from bar_policy.robot.perturb import MotorPerturbation, Pusher, perturbed_scene
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.robot.scene import SceneEdit
from bar_policy.robstride.emulator import RobstrideEmulator
from bar_policy.robstride.firmware import EmulatedMotor, JointReading

__all__ = ["PerturbedEmulator", "emulator"]

log = logging.getLogger(__name__)

_EPS_T = 1e-9
"""Slack on physics-time comparisons, s (the clock is a sum of 2 ms steps)."""


class PerturbedEmulator(RobstrideEmulator):
    """``RobstrideEmulator`` of a perturbed robot (module docstring). Other arguments as the emulator's."""

    def __init__(
        self,
        robot: RobotSpec,
        channels: Mapping[str, str],
        *,
        perturbation: Perturbation,
        scene: SceneEdit | None = None,
        offsets: Mapping[str, float] | None = None,
        control_dt: float = 0.02,
        **kwargs: Any,
    ) -> None:
        self.perturbation = perturbation
        self.motor_perturbation = MotorPerturbation.of(perturbation, robot)
        mp = self.motor_perturbation
        base = dict(offsets or {})
        true_offsets = {
            j.name: float(base.get(j.name, 0.0)) + j.direction * float(mp.offset[j.index])
            for j in robot.joints
        }
        self._cmd_hist: deque[tuple[float, np.ndarray]] = deque()
        self._prime = False
        """The next holding command fills the delay line (``prime_delay``: an evaluation's start)."""
        self._obs_hist: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque()
        super().__init__(
            robot,
            channels,
            scene=perturbed_scene(perturbation, scene),
            offsets=true_offsets,
            control_dt=control_dt,
            **kwargs,
        )
        self.control_dt = self.n_substeps * float(self.model.opt.timestep)
        """The delays' tick, s (physics per command round)."""
        p = perturbation
        self._pusher = Pusher(self.model, p.push_n, p.seed) if p.push_n > 0 else None
        self._snapshot(reset=True)
        log.info("emulated robot perturbed (hidden from the host): %s", perturbation.describe())

    @property
    def pushes(self) -> int:
        """Pushes started so far (0 without ``push_n``)."""
        return 0 if self._pusher is None else self._pusher.pushes

    # -- delays --------------------------------------------------------------------------------------
    def _delayed_cmd(self, cmd: np.ndarray) -> np.ndarray:
        """The command matrix (5, motors) of ``action_delay_ticks`` periods ago; records ``cmd`` now."""
        n = self.motor_perturbation.action_delay_ticks
        if n == 0:
            return cmd
        t = float(self.data.time)
        hist = self._cmd_hist
        if self._prime:  # an evaluation's first hold: the motors were holding it
            if not np.any(cmd[2] > 0):  # row 2, Kp: the start's damping rounds act at once
                return cmd
            self._prime = False
            hist.append((t - n * self.control_dt, cmd))
        if hist and abs(hist[-1][0] - t) < _EPS_T:
            hist[-1] = (t, cmd)
        else:
            hist.append((t, cmd))
        due = t - n * self.control_dt + _EPS_T
        while len(hist) >= 2 and hist[1][0] <= due:
            hist.popleft()
        return hist[0][1] if hist[0][0] <= due else np.zeros_like(cmd)

    def _snapshot(self, *, reset: bool = False) -> None:
        """Record the joint state for the feedback's delay line (lock held)."""
        if self.motor_perturbation.obs_delay_ticks == 0:
            return
        if reset:
            self._obs_hist.clear()
        self._obs_hist.append(
            (
                float(self.data.time),
                self.data.qpos[self._qadr].copy(),
                self.data.qvel[self._dadr].copy(),
                self._tau_raw.copy(),
            )
        )
        due = float(self.data.time) - self.motor_perturbation.obs_delay_ticks * self.control_dt + _EPS_T
        while len(self._obs_hist) >= 2 and self._obs_hist[1][0] <= due:
            self._obs_hist.popleft()

    def _joint(self, m: EmulatedMotor) -> JointReading | None:
        """What ``m`` reports of its joint: the state ``obs_delay_ticks`` periods ago."""
        if m.joint is None or self.motor_perturbation.obs_delay_ticks == 0:
            return super()._joint(m)
        _, q, dq, tau = self._obs_hist[0]
        return JointReading(q=float(q[m.joint]), dq=float(dq[m.joint]), tau_raw=float(tau[m.joint]))

    def set_joint_positions(self, q: Any, *, scene_at_rest: bool = False) -> None:
        """As ``RobstrideEmulator.set_joint_positions``; the delay lines restart at the new state."""
        with self._lock:
            super().set_joint_positions(q, scene_at_rest=scene_at_rest)
            self._cmd_hist.clear()
            self._snapshot(reset=True)

    def prime_delay(self) -> None:
        """The next holding command (Kp > 0) fills the action delay line and acts at once.

        An evaluation's start (``EmulatedBusTarget.reset``): its teleported state is one the motors were
        holding; the real target's start-up damping rounds before that command act at once.
        """
        with self._lock:
            self._cmd_hist.clear()
            self._prime = True

    # -- physics -------------------------------------------------------------------------------------
    def _command_matrix(self, cmd: np.ndarray) -> np.ndarray:
        """The law acts on the commands of ``action_delay_ticks`` periods ago."""
        return self._delayed_cmd(cmd)

    def applied_torques(self) -> np.ndarray:
        """Torque each joint motor applies now, joint frame, canonical order, N*m: ``strength`` x the law."""
        return self.motor_perturbation.strength * super().applied_torques()

    def _step(self, n: int) -> None:
        """``n`` physics steps: ``strength`` times the firmware torque, the pushes; then the delay line."""
        pusher = self._pusher
        self._run(
            n,
            strength=self.motor_perturbation.strength,
            before=None if pusher is None else (lambda: pusher.apply(self.data)),
        )
        self._snapshot()


def emulator(
    robot: RobotSpec,
    channels: Mapping[str, str],
    *,
    perturbation: Perturbation | None,
    robot_params: RobotParams | None = None,
    **kwargs: Any,
) -> RobstrideEmulator:
    """A ``RobstrideEmulator``, or a ``PerturbedEmulator`` when ``perturbation`` is given and not nominal.

    ``robot_params``: the emulated robot is the identified one (``robot.params``: its model edits and its
    motors' strength), with ``perturbation`` on top (its strength multiplies the file's).
    """
    if robot_params is None:
        if perturbation is None or perturbation.nominal:
            return RobstrideEmulator(robot, channels, **kwargs)
        return PerturbedEmulator(robot, channels, perturbation=perturbation, **kwargs)
    kwargs["scene"] = scene_edit(robot_params, kwargs.get("scene"))
    emu = PerturbedEmulator(robot, channels, perturbation=perturbation or Perturbation(), **kwargs)
    mp = emu.motor_perturbation
    emu.motor_perturbation = replace(mp, strength=mp.strength * motor_strength(robot_params, robot))
    log.info("emulated robot from the parameters file (sha256 %s)", robot_params.sha256[:16])
    return emu
