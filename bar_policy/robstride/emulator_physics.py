"""The MuJoCo side of the emulator: every enabled motor's MIT law into ``qfrc_applied``, stepped.

Each MuJoCo step (2 ms) the MIT law of every enabled motor, ``firmware_torque`` (the one shared actuator
model) with the motor's ``limit_torque`` as the cap, goes into ``qfrc_applied``; disabled motors apply
nothing. Torques go to the robot joints' dofs only (found by name, ``RobotIndex``), so a task's scene with
more joints runs too. ``RobstrideEmulator`` (``emulator``: buses, threads, clock, the firmware side of the
protocol) inherits this from ``EmulatorPhysics`` and owns the state it runs on (the attributes annotated
below).

The law's damping term (``damping``): the firmware evaluates the law inside its own loop, many times per 2
ms step, so a motor damps as a continuous ``Kd`` would. Each mode puts a share of the ``Kd`` of every
unsaturated enabled motor into Euler's implicit joint damping and keeps the force at the step's start
exactly the firmware torque (``qfrc_applied = tau + share Kd dq``, the passive ``-share Kd dq`` cancelling
it), so each step solves ``(M + h share Kd) dv = h tau``: that share of the damping force acts at the
step's end velocity, the rest at its start:

- ``trapezoid`` (the default, share 1/2): the damping force at the step's mean velocity, second order
  (Crank-Nicolson); a wrist's fast mode decays by ``(1 - x/2) / (1 + x/2)`` per step, ``x = h Kd / mu``,
  against the continuous law's ``exp(-x)``: the nearest of the three to a fast firmware, and what the
  identification's fit assumes of a real motor (``robstride.identify.round_samples``);
- ``implicit`` (share 1): the force at the step's end velocity, first order, ``1 / (1 + x)``: the sim
  target's default and the MJX env's treatment, the same numbers;
- ``explicit`` (share 0): the torque held for the step, a 500 Hz law (mujoco_ros2_control's update),
  ``1 - x``: it rings in the wrist mode (docs/physics.md) and, under Coulomb friction, stalls a wrist where
  a motor would not (docs/can.md, "The law's damping in the emulator").
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import mujoco
import numpy as np

from bar_policy.robot.actuators import robstride_spec
from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.mit import MitCommand, WireRanges, firmware_torque, wire_ranges
from bar_policy.robstride.firmware import EmulatedMotor

__all__ = ["EMULATOR_DAMPING", "EmulatorPhysics"]

EMULATOR_DAMPING = ("trapezoid", "implicit", "explicit")
"""How the emulator integrates the law's damping term (module docstring); the first is the default."""

_IMPLICIT_SHARE = {"trapezoid": 0.5, "implicit": 1.0, "explicit": 0.0}
"""Share of the law's ``Kd`` each mode hands to Euler's implicit joint damping."""

_Static = tuple[list[EmulatedMotor], np.ndarray, np.ndarray, WireRanges, np.ndarray]
"""Constants of the joint motors: motors, joint index, direction, wire ranges, T_max (N*m)."""


class EmulatorPhysics:
    """Physics of the emulated motors' joints (the lock is the emulator's; see the module docstring)."""

    robot: RobotSpec
    model: mujoco.MjModel
    data: mujoco.MjData
    damping: str  # one of EMULATOR_DAMPING
    _mjcf_damping: np.ndarray  # the scene's own dof damping at the robot joints (dof_damping[_dadr])
    motors: dict[tuple[str, int], EmulatedMotor]
    _qadr: np.ndarray  # qpos address per robot joint, canonical order (RobotIndex.qpos)
    _dadr: np.ndarray  # dof address per robot joint (RobotIndex.dof): qvel, qfrc_applied
    _tau_raw: np.ndarray
    _lock: threading.RLock
    _stop: threading.Event
    _static_cache: _Static | None

    def _joint_motors(self) -> list[EmulatedMotor]:
        return [m for m in self.motors.values() if m.joint is not None]

    def _static(self) -> _Static:
        """Per-motor constants of the joint motors (cached): motors, joint index, direction, ranges, T_max."""
        if self._static_cache is None:
            ms = self._joint_motors()
            self._static_cache = (
                ms,
                np.array([m.joint for m in ms], dtype=np.int64),
                np.array([m.direction for m in ms], dtype=np.float64),
                wire_ranges([m.model for m in ms]),
                np.array([robstride_spec(m.model).t_max for m in ms]),
            )
        return self._static_cache

    def _command_matrix(self, cmd: np.ndarray) -> np.ndarray:
        """The MIT command matrix (5, motors) the law acts on: the motors' latest commands.

        A hook for a robot whose commands arrive late (``emulator_perturb``).
        """
        return cmd

    def _law(self) -> tuple[Callable[[], np.ndarray], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The motors' MIT law at the present state (lock held).

        Returns the torque function (the raw, motor-frame torque of every joint motor, 0 for disabled
        ones), the joint index and direction per motor, each motor's ``Kd`` (0 when disabled, N*m*s/rad)
        and its cap (N*m).
        """
        ms, idx, d, ranges, t_max = self._static()
        off = np.array([m.offset for m in ms])
        on = np.array([m.enabled for m in ms], dtype=np.float64)
        cmd = self._command_matrix(np.array([m.cmd for m in ms], dtype=np.float64).T)
        cap = np.clip(np.array([float(m.params[0x700B]) for m in ms]), 0.0, t_max)
        mit = MitCommand(cmd[0], cmd[1], cmd[2], cmd[3], cmd[4])
        qadr, dadr = self._qadr[idx], self._dadr[idx]

        def torque() -> np.ndarray:
            q_raw = d * self.data.qpos[qadr] + off
            dq_raw = d * self.data.qvel[dadr]
            return on * firmware_torque(mit, q_raw, dq_raw, ranges, cap, quantize_wire=False)

        return torque, idx, d, on * cmd[3], cap

    def _run(
        self, n: int, strength: np.ndarray | None = None, before: Callable[[], None] | None = None
    ) -> None:
        """``n`` physics steps under the law (lock held), its damping integrated as ``self.damping`` says.

        ``strength`` (per joint motor, None: 1) scales the torque the joint receives and so the damping it
        is integrated with; ``before`` runs before each ``mj_step`` (the pushes).
        """
        torque, idx, d, kd, cap = self._law()
        dadr = self._dadr[idx]
        s = np.ones(len(idx)) if strength is None else strength
        share = _IMPLICIT_SHARE[self.damping]
        implicit = share > 0.0
        base = self._mjcf_damping[idx]
        tau_raw = np.zeros(len(idx))
        for _ in range(n):
            tau_raw = torque()
            self.data.qfrc_applied[:] = 0.0
            tau = s * d * tau_raw
            if implicit:
                # The passive force -D dq cancels the + D dq: the force is the firmware torque; Euler
                # integrates D implicitly. A saturated motor's torque does not depend on dq: no D.
                law_d = share * s * kd * (np.abs(tau_raw) < cap)
                self.model.dof_damping[dadr] = base + law_d
                tau = tau + law_d * self.data.qvel[dadr]
            self.data.qfrc_applied[dadr] = tau
            if before is not None:
                before()
            mujoco.mj_step(self.model, self.data)
        if implicit:
            self.model.dof_damping[dadr] = base
        self._tau_raw[idx] = tau_raw

    def _step(self, n: int) -> None:
        """``n`` physics steps with the latest commands (lock held)."""
        self._run(n)

    def applied_torques(self) -> np.ndarray:
        """Torque every joint motor applies at the present state, joint frame, canonical order, N*m.

        Zero for a disabled motor (stopped, or tripped by its watchdog).
        """
        with self._lock:
            torque, idx, d, _, _ = self._law()
            out = np.zeros(self.robot.num_joints)
            out[idx] = d * torque()
            return out

    def _physics_loop(self) -> None:
        """Step physics at the wall-clock rate, in chunks of the steps that are due.

        It sleeps between chunks whatever the lag (so the receiver threads always get the lock), and drops
        time rather than spiral when it falls more than 0.1 s behind (a loaded host).
        """
        dt = float(self.model.opt.timestep)
        sim_wall = time.perf_counter()
        while not self._stop.is_set():
            due = int((time.perf_counter() - sim_wall) / dt)
            if due > int(0.1 / dt):
                sim_wall = time.perf_counter() - dt
                due = 1
            if due > 0:
                with self._lock:
                    self._step(due)
                sim_wall += due * dt
            time.sleep(max(0.0002, sim_wall + dt - time.perf_counter()))
