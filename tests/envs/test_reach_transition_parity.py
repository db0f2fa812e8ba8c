"""Parity of the command transition: the env's commanded targets equal the deploy wrapper's, tick by tick.

The env (jax, float32) and ``tasks.reach.transition.TransitionCommands`` (numpy, float64) both call
``tasks.reach.transition_point``; this runs the nominal env across a target resampling and feeds the env's
own goals, at the same ticks, to the wrapper (started at the deploy side's default-pose fingertips).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bar_policy.robot.kinematics import Kinematics
from bar_policy.tasks.reach.commands import SampledCommands
from bar_policy.tasks.reach.transition import TransitionCommands

NAMES = ("target_pos_left", "target_pos_right")


class _EnvGoals(SampledCommands):
    """The env's goal after step k, from t = k dt on."""

    def __init__(self, goals: list[dict[str, np.ndarray]], dt: float) -> None:
        super().__init__(NAMES)
        self.goals, self.dt = goals, dt

    def _values(self, t: float) -> dict[str, np.ndarray]:
        return {n: v.copy() for n, v in self.goals[round(t / self.dt)].items()}


def test_env_and_deploy_targets_agree(nominal_env, nominal_fns) -> None:
    env = nominal_env
    reset, step = nominal_fns
    s = reset(jax.random.PRNGKey(3))
    a = jnp.zeros(14, jnp.float32)
    n = env.config.resample_steps + 60  # across one resampling and most of the next move
    targets, goals = [], []
    for k in range(n + 1):
        if k:
            s = step(s, a)
        targets.append({f"target_pos_{h}": np.asarray(s.info[f"target_{h}"]) for h in ("left", "right")})
        goals.append(
            {f"target_pos_{h}": np.asarray(s.info[f"goal_{h}"], np.float64) for h in ("left", "right")}
        )
    left, right = Kinematics("arms").fingertips(np.asarray(env.default_pose, np.float64))
    src = TransitionCommands(
        _EnvGoals(goals, env.dt),
        env.config.target_transition_s,
        {"target_pos_left": left, "target_pos_right": right},
    )
    src.begin(0.0)
    for k in range(n + 1):
        out = src(k * env.dt)
        for name in NAMES:
            # float32 env vs float64 deploy: the start (C MuJoCo FK in both, rounded to float32: 3e-8) and
            # a few float32 roundings of |x| <= 0.42 m (eps32 * 0.42 = 5e-8 each): 1e-6 covers them.
            np.testing.assert_allclose(out[name], targets[k][name], rtol=0, atol=1e-6, err_msg=f"tick {k}")
    assert src.moves == 2  # the first goal at tick 0 and the resampled one
