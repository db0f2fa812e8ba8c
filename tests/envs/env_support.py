"""Support for the env tests: the batch size of the wrapped fixtures, and a C MuJoCo (float64) reference of
the env's physics (same MJCF, same firmware law, same damping treatment, numpy only)."""

from __future__ import annotations

import mujoco
import numpy as np

from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand, firmware_torque, quantize_command, wire_ranges
from bar_policy.robot.mjcf import load_model

BATCH = 8
"""Batch of the wrapped-env tests (small: CPU)."""


def c_rollout(
    q_cmds: np.ndarray,
    q0: np.ndarray,
    *,
    mode: str = "arms",
    dt: float = 0.002,
    n_substeps: int = 10,
    kp_scale: float = 1.0,
    kd_scale: float = 1.0,
    mass_scale: float = 1.0,
    damping: str = "implicit",
    quantize_wire: bool = True,
    qvel0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run the MIT law in C MuJoCo. ``q_cmds`` shape (T, n): one command per control step.

    Returns (qpos, qvel) after every control step, shape (T, n) each.
    """
    robot = load_robot(mode)
    m = load_model(mode)
    m.opt.timestep = dt
    m.body_mass[:] *= mass_scale
    m.body_inertia[:] *= mass_scale
    d = mujoco.MjData(m)
    d.qpos[:] = q0
    if qvel0 is not None:
        d.qvel[:] = qvel0
    ranges = wire_ranges(robot.models)
    cap = robot.torque_cap
    base_damping = m.dof_damping.copy()
    qs, vs = [], []
    for q_cmd in q_cmds:
        cmd = MitCommand.position(q_cmd, robot.kp * kp_scale, robot.kd * kd_scale)
        if quantize_wire:
            cmd = quantize_command(cmd, ranges)
        for _ in range(n_substeps):
            tau = firmware_torque(cmd, d.qpos.copy(), d.qvel.copy(), ranges, cap, quantize_wire=False)
            if damping == "implicit":
                d_law = np.where(np.abs(tau) < cap, cmd.kd, 0.0)
                m.dof_damping[:] = base_damping + d_law
                d.qfrc_applied[:] = tau + d_law * d.qvel
            else:
                d.qfrc_applied[:] = tau
            mujoco.mj_step(m, d)
            if not np.all(np.isfinite(d.qvel)) or np.abs(d.qvel).max() > 1e4:
                qs.append(np.full(m.nq, np.nan))
                vs.append(np.full(m.nv, np.nan))
                return np.array(qs), np.array(vs)
        qs.append(d.qpos.copy())
        vs.append(d.qvel.copy())
    return np.array(qs), np.array(vs)
