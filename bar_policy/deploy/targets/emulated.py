"""The real target over an emulated Robstride bus, in lockstep: the sim2sim path through the CAN code.

``EmulatedBusTarget`` is what ``bar-deploy --target real --can-interface virtual --emulate lockstep`` builds
(``RealTarget`` on python-can ``virtual`` buses + an in-process ``RobstrideEmulator``), presented as a
synchronous, resettable target for the evaluations (``tasks.reach.evaluate``, ``tasks.track.evaluate``) and
the benchmarks (``bench/reach_emulator.py``, ``bench/track_fidelity.py``):

- every command round (``write_command``: one MIT frame and one reply per motor on both buses) advances one
  control period of the emulator's MuJoCo physics, so a run goes faster than real time and is repeatable;
- the state the policy sees went through the 16-bit feedback codec (``read_state`` returns the replies of
  the last round: the post-step state; ``refresh_on_read`` is off);
- ``reset(q)`` teleports the emulated joints to ``q`` at rest (and a task scene's joints, the piano's keys,
  to their rest) and starts a fresh ``RealTarget`` on them: scan, cap writes, watchdog, enable and one
  damping round (20 ms of physics: the only difference in the initial condition from the sim target, which
  also starts at the reference velocity when given one);
- ``scene``: a task's additions to the emulator's MuJoCo scene (the piano's keyboard), whose simulated
  parts a command source reads through ``companions`` (the emulator: ``model``, ``data``), as on
  ``--target real --can-interface virtual``.

The emulator applies the MIT law over each physics step at the step's mean state, as a firmware that runs
the law far faster than the bus does (``robstride.emulator_physics``, ``trapezoid``); the sim target
integrates it as the policy trained (``targets.sim``). Channels are unique per instance (``virtual``
channels are process-wide), so several can coexist.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import can
import numpy as np

from bar_policy.deploy.targets.base import JointState, StopReport, Target
from bar_policy.deploy.targets.real import RealTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand
from bar_policy.robot.params import RobotParams
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.robot.scene import SceneEdit
from bar_policy.robstride.emulator import RobstrideEmulator
from bar_policy.robstride.emulator_perturb import emulator
from bar_policy.robstride.group import RobstrideGroup

__all__ = ["LOCKSTEP_CAN_TIMEOUT", "EmulatedBusTarget"]

LOCKSTEP_CAN_TIMEOUT = 2.0
"""CAN watchdog armed on the emulated motors, s. It runs on the wall clock while lockstep physics does not:
at the deploy default (0.2 s) a stall of the evaluating process (a loaded CPU, a garbage collection) would
disable the motors mid-clip; 2 s keeps the arming path (the 0x7028 write) with room for such stalls."""


class EmulatedBusTarget(Target):
    """``RealTarget`` + lockstep emulator as a synchronous, resettable target (module docstring)."""

    synchronous = True

    def __init__(
        self,
        mode: str = "arms",
        control_dt: float = 0.02,
        *,
        reply_timeout: float = 0.2,
        can_timeout: float = LOCKSTEP_CAN_TIMEOUT,
        scene: SceneEdit | None = None,
        perturbation: Perturbation | None = None,
        robot_params: RobotParams | None = None,
    ) -> None:
        """Start the emulator (the real target starts on ``reset``).

        Args:
            mode: joint set.
            control_dt: physics per command round, s (the policy's period).
            reply_timeout: reply deadline per round on the virtual bus, s.
            can_timeout: the motors' CAN watchdog armed at start (wall clock), s.
            scene: a task's additions to the emulator's scene (None: the robot alone).
            perturbation: the emulated robot differs from the model so (``robot.perturb_spec``), hidden
                from the real target (``robstride.emulator_perturb``); None: the nominal robot.
            robot_params: the emulated robot is that identified one (``robot.params``, ``--robot-params``),
                ``perturbation`` on top; None: the description's robot.
        """
        self.robot = load_robot(mode)
        super().__init__(self.robot.joint_names)
        key = f"emulated-{id(self)}-{time.monotonic_ns()}"
        interfaces = sorted({j.can_interface for j in self.robot.joints})
        self.channels = {i: f"{key}-{i}" for i in interfaces}
        self.control_dt = control_dt
        """Physics per command round, s."""
        self.reply_timeout = reply_timeout
        self.perturbation = None if perturbation is None or perturbation.nominal else perturbation
        self.can_timeout = can_timeout
        self.emu = emulator(
            self.robot,
            self.channels,
            mode="lockstep",
            control_dt=control_dt,
            scene=scene,
            perturbation=perturbation,
            robot_params=robot_params,
        ).start()
        self.inner: RealTarget | None = None
        self._stop_torque: Callable[[np.ndarray], np.ndarray] | None = None

    def reset(self, q: np.ndarray | None = None, dq: np.ndarray | None = None) -> None:
        """Teleport the emulated joints to ``q`` (default ``piano_ready``) at rest, start a fresh real target.

        ``dq`` is accepted for the evaluations' reset interface and not used (the emulator starts at rest).
        """
        if self.inner is not None:
            self.inner.close()
            self.inner = None
        q0 = self.robot.pose("piano_ready") if q is None else np.asarray(q, float)
        self.emu.set_joint_positions(q0, scene_at_rest=True)
        buses = {i: can.Bus(interface="virtual", channel=c) for i, c in self.channels.items()}
        group = RobstrideGroup.from_robot(
            self.robot, buses, reply_timeout=self.reply_timeout, can_timeout=self.can_timeout
        )
        self.inner = RealTarget(
            self.robot, group, refresh_on_read=False, damping_hold_s=0.0, scan_ids=range(1, 33)
        )
        self.inner.use_stop_torque(self._stop_torque)
        self.emu.frozen = True  # the activation's damping round takes no time: the episode starts at q0
        try:
            self.inner.start()
        finally:
            self.emu.frozen = False
        prime = getattr(self.emu, "prime_delay", None)
        if prime is not None:  # the evaluation's first command acts at once (a perturbed emulator's delay)
            prime()

    @property
    def companions(self) -> tuple[RobstrideEmulator, ...]:
        """The emulator: its ``model`` and ``data`` hold the scene's simulated parts (the piano's keys)."""
        return (self.emu,)

    def _target(self) -> RealTarget:
        if self.inner is None:
            self.reset()
        assert self.inner is not None
        return self.inner

    def read_state(self) -> JointState:
        """The last round's feedback (the post-step state in lockstep)."""
        return self._target().read_state()

    def true_q(self) -> np.ndarray:
        """What an evaluation scores (``tasks.episodes.true_q``), rad.

        With a perturbation the emulator's true joints (the host reads them offset and late); without one
        the reading, as before.
        """
        if self.perturbation is None:
            return self.read_state().q
        return self.emu.joint_positions()

    def write_command(self, cmd: MitCommand) -> None:
        """One command round = one control period of physics."""
        self._target().write_command(cmd)

    def now(self) -> float:
        """Emulator physics time, s."""
        return self.emu.sim_time

    def safe_stop(
        self, q: np.ndarray | None = None, kd: float = 1.0, *, hold_s: float | None = None
    ) -> StopReport:
        """Damping, then stop frames on the buses; which motors replied (``RealTarget.safe_stop``).

        Lockstep: the damping is held for ``hold_s`` s of physics (one command round per control period,
        at the measured q with the stop torque), then the stop frames.
        """
        inner = self._target()
        rounds = 0 if hold_s is None or inner.stopped else round(hold_s / self.control_dt)
        for _ in range(rounds):
            try:
                q_now = inner.read_state().q
                cmd = MitCommand.damping(q_now if q is None else q, kd)
                if self._stop_torque is not None:
                    cmd = cmd._replace(tau_ff=np.asarray(self._stop_torque(q_now), dtype=np.float64))
                inner.write_command(cmd)
            except Exception:  # the inner target stopped itself (driver error): its report stands
                break
        return inner.safe_stop(q, kd, hold_s=0.0)

    def use_stop_torque(self, tau_ff: Callable[[np.ndarray], np.ndarray] | None) -> None:
        """The damping torque of the safe stop (``Target.use_stop_torque``), kept across ``reset``."""
        self._stop_torque = tau_ff
        if self.inner is not None:
            self.inner.use_stop_torque(tau_ff)

    def close(self) -> None:
        """Close the real target and the emulator (safe to call twice)."""
        if self.inner is not None:
            self.inner.close()
            self.inner = None
        self.emu.close()
