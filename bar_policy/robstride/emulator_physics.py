"""The MuJoCo side of the emulator: every enabled motor's MIT law into ``qfrc_applied``, stepped.

Each MuJoCo step (2 ms) the MIT law of every enabled motor, ``firmware_torque`` (the one shared actuator
model) with the motor's ``limit_torque`` as the cap, goes into ``qfrc_applied``; disabled motors apply
nothing. Torques go to the robot joints' dofs only (found by name, ``RobotIndex``), so a task's scene with
more joints runs too. ``RobstrideEmulator`` (``emulator``: buses, threads, clock, the firmware side of the
protocol) inherits this from ``EmulatorPhysics`` and owns the state it runs on (the attributes annotated
below).

The law over a step (``damping``): the firmware evaluates the law inside its own loop, many times per 2 ms
step, so over a step a motor applies the law's mean, as a continuous law would. Each mode hands part of the
law's dependence on the state to Euler's implicit joint damping ``D`` (of every unsaturated enabled
motor: a saturated one's torque does not depend on the state) and adds to ``qfrc_applied`` what cancels
it at the step's start, so that the force acting over the step is the law at

- ``trapezoid`` (the default): the step's mean state, ``(q_k + q_{k+1}) / 2`` and ``(dq_k + dq_{k+1}) /
  2`` (``D = Kd / 2 + h Kp / 2``; Euler's position update is ``q_{k+1} = q_k + h dq_{k+1}``): second order,
  the nearest of the three to a fast firmware, and the law the identification's fit reads at each round
  (``robstride.identify.round_samples``); a wrist's fast mode (``x = h Kd / mu``) decays by about ``(1 - x
  /2) / (1 + x/2)`` per step against the continuous law's ``exp(-x)``;
- ``implicit``: the start position and the end velocity (``D = Kd``): first order, ``1 / (1 + x)``; the
  sim target's default and the MJX env's treatment, the same numbers;
- ``explicit``: the start state (``D = 0``), held for the step: a 500 Hz law (mujoco_ros2_control's
  update), ``1 - x``, which rings in the wrist mode (docs/physics.md) and, under Coulomb friction, stalls
  a wrist where a motor would not (docs/can.md, "The law over a step in the emulator").

The torque a motor reports is the law at the step's start state, as a motor's reading at that instant.
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

_IMPLICIT_SHARE = {"trapezoid": (0.5, 0.5), "implicit": (1.0, 0.0), "explicit": (0.0, 0.0)}
"""Per mode ``(a, b)``: Euler's implicit damping takes ``a Kd + b h Kp`` of each motor's law, the damping
term at ``(1 - a) dq_k + a dq_{k+1}`` and the spring's at ``q_k + b h dq_{k+1}`` (module docstring)."""

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
        ones), the joint index and direction per motor, each motor's gains ``(Kp, Kd)``, shape (2, motors),
        0 when disabled (N*m/rad, N*m*s/rad), and its cap (N*m).
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

        return torque, idx, d, on * cmd[2:4], cap

    def _run(
        self, n: int, strength: np.ndarray | None = None, before: Callable[[], None] | None = None
    ) -> None:
        """``n`` physics steps under the law (lock held), integrated as ``self.damping`` says.

        ``strength`` (per robot joint, canonical order; None: 1) scales the torque the joint receives and so
        the part Euler integrates implicitly; ``before`` runs before each ``mj_step`` (the pushes).
        """
        torque, idx, d, gains, cap = self._law()
        dadr = self._dadr[idx]
        s = np.ones(len(idx)) if strength is None else np.asarray(strength)[idx]
        a, b = _IMPLICIT_SHARE[self.damping]
        h = float(self.model.opt.timestep)
        kd_share, law_damping = s * a * gains[1], s * (a * gains[1] + b * h * gains[0])
        base = self._mjcf_damping[idx]
        tau_raw = np.zeros(len(idx))
        for _ in range(n):
            tau_raw = torque()
            self.data.qfrc_applied[:] = 0.0
            tau = s * d * tau_raw
            if a > 0.0:
                # Euler solves M dv = h (qfrc_applied - D dq_{k+1}) (its passive -D dq, implicit): with
                # D = a Kd + b h Kp and qfrc_applied = tau + a Kd dq_k, the force over the step is the law
                # at q_k + b h dq_{k+1} and (1 - a) dq_k + a dq_{k+1} (module docstring).
                unsat = np.abs(tau_raw) < cap
                self.model.dof_damping[dadr] = base + unsat * law_damping
                tau = tau + unsat * kd_share * self.data.qvel[dadr]
            self.data.qfrc_applied[dadr] = tau
            if before is not None:
                before()
            mujoco.mj_step(self.model, self.data)
        if a > 0.0:
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
