"""Raw env throughput: the batched env alone (no policy, no learning), to set beside training steps/s."""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["raw_env_steps_per_second"]


def raw_env_steps_per_second(
    env: Any,
    wrap_fn: Callable[..., Any],
    *,
    num_envs: int = 4096,
    steps: int = 100,
    randomizer: Callable[..., Any] | None = None,
    repeats: int = 3,
) -> dict[str, float]:
    """Env steps/s of ``steps`` batched env steps (zero actions, ``lax.scan`` under one jit) on device 0.

    Args:
        env: the unwrapped env.
        wrap_fn: ``wrap_for_brax_training``.
        num_envs: batch size.
        steps: control steps per timed call.
        randomizer: domain randomiser, as in training.
        repeats: timed calls (the best is reported).

    Returns:
        ``{"env_steps_per_s", "compile_s", "num_envs", "steps"}``.
    """
    rfn = None
    if randomizer is not None:
        rfn = functools.partial(randomizer, rng=jax.random.split(jax.random.PRNGKey(1), num_envs))
    w = wrap_fn(env, episode_length=int(env.episode_length), action_repeat=1, randomization_fn=rfn)
    zeros = jnp.zeros((num_envs, env.action_size))

    @jax.jit
    def roll(state: Any) -> Any:
        return jax.lax.scan(lambda s, _: (w.step(s, zeros), None), state, None, length=steps)[0]

    state = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(0), num_envs))
    t0 = time.perf_counter()
    state = jax.block_until_ready(roll(state))
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        state = jax.block_until_ready(roll(state))
        best = min(best, time.perf_counter() - t0)
    return {
        "env_steps_per_s": num_envs * steps / best,
        "compile_s": compile_s,
        "num_envs": num_envs,
        "steps": steps,
    }
