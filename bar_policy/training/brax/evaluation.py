"""The evaluation program's episodes (per device): the deterministic policy on every env slot, its figures.

``training.brax.programs`` maps ``evaluate`` over the mesh as the ``evaluate`` program; the algorithm's side
(``training.brax.learner``: brax's PPO) only lends its policy (``make_policy``). Every step's task ratios
(``envs.base.eval_ratios``) and rewards count while a slot's episode is alive (up to and including its first
``done``), as brax's evaluator counts episode metrics; sums are reduced over the mesh axis ``AXIS``
(``training.parallel``), so the results are global. Safety and smoothness (``training.eval_quality``:
completion, torque-cap and joint-limit shares, action rate, chatter) are measured on the same episodes,
with the definitions the deploy side uses.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from bar_policy.envs.base import eval_ratios
from bar_policy.training import eval_quality
from bar_policy.training.parallel import AXIS

__all__ = ["evaluate"]


def evaluate(
    make_policy: Callable[..., Any],
    params: Any,
    env: Any,
    env_state: Any,
    key: jax.Array,
    episode_length: int,
) -> dict[str, jax.Array]:
    """Deterministic episodes of ``episode_length`` steps from ``env_state`` (this device's slots).

    Args:
        make_policy: brax's ``make_inference_fn(networks)`` (``Learner.make_policy``).
        params: replicated ``(normalizer, policy)`` params.
        env: the batched env of this device's slots, without auto-reset.
        env_state: its reset state.
        key: the policy's key (a deterministic policy ignores it).
        episode_length: control steps per episode.

    Returns:
        ``{"episode_reward", "episode_reward_std", <ratio>..., "quality/<figure>"...}`` (scalars): mean
        and std of the episode returns over every slot, per ratio the sum of its numerators / the sum of
        its denominators, and the quality figures.
    """
    policy = make_policy(params, deterministic=True)
    task = env.unwrapped
    robot = task.robot
    f32 = lambda x: jnp.asarray(x, dtype=jnp.float32)  # noqa: E731
    limits = {"cap": f32(robot.torque_cap), "lower": f32(robot.lower), "upper": f32(robot.upper)}

    def step(c: tuple, t: jax.Array) -> tuple:
        s, alive, qc = c
        action, _ = policy(s.obs, key)
        sig = jax.vmap(task.quality_signals)(s, action)
        ns = env.step(s, action)
        sums = {
            k: ((n * alive).sum(), (d * alive).sum()) for k, (n, d) in eval_ratios(task, ns.metrics).items()
        }
        terminated = ns.done * (1.0 - ns.info["truncation"])
        qc, _ = eval_quality.update(qc, sig, alive, terminated, t == 0, dt=task.dt, **limits)
        return (ns, alive * (1.0 - ns.done), qc), (ns.reward * alive, sums, sig["signal"])

    alive = jnp.ones(env_state.reward.shape)
    qc = eval_quality.init(alive.shape[0], task.action_size)
    (_, _, qc), (rewards, sums, signals) = jax.lax.scan(
        step, (env_state, alive, qc), jnp.arange(episode_length)
    )
    ret = rewards.sum(axis=0)
    n_eps = jax.lax.psum(jnp.float32(ret.shape[0]), AXIS)
    mean = jax.lax.psum(ret.sum(), AXIS) / n_eps
    var = jax.lax.psum(((ret - mean) ** 2).sum(), AXIS) / n_eps
    out = {"episode_reward": mean, "episode_reward_std": jnp.sqrt(var)}
    for k, (n, d) in sums.items():
        out[k] = jax.lax.psum(n.sum(), AXIS) / jnp.maximum(jax.lax.psum(d.sum(), AXIS), 1.0)
    out.update(eval_quality.finish(qc, signals, task.dt))
    return out
