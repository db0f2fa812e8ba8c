"""What the safety and smoothness metrics (``bar_policy.quality``) see of a robot env at one tick.

A pure function of the env's state and the policy's action: the MJX evaluation during training
(``training.eval_quality``) and the rsl-rl adapter vmap it over their slots.
"""

from __future__ import annotations

from typing import Any

import jax

from bar_policy.envs.base import State
from bar_policy.robot.mit import mit_torque

__all__ = ["quality_signals"]


def quality_signals(env: Any, state: State, action: jax.Array) -> dict[str, jax.Array]:
    """The tick's signals of ``env`` (a ``LiteRobotEnv``, not imported: its module imports this one).

    Returns ``demand`` (the unclipped MIT torque of the command this step applies, at the measured
    state: the supervisor's saturation test on the robot, N*m), ``q`` (true positions, rad),
    ``action`` (the applied action) and ``signal`` (the chatter signal: ``q_cmd - q_ref`` when the task
    has a reference, else ``q_cmd``, rad), each shape (n,).
    """
    info, data = state.info, state.data
    applied, _, cmd = env._command(info, action)
    q_cmd = env.q_command(applied)
    ref = env.task_reference(info)
    q, dq = env.robot_q(data), env.robot_dq(data)
    return {
        "demand": mit_torque(cmd, q + info["encoder_offset"], dq),
        "q": q,
        "action": applied,
        "signal": q_cmd if ref is None else q_cmd - ref,
    }
