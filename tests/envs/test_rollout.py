"""The batched training wrapper: long random rollout with randomisation, auto-reset, episode bookkeeping."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from env_support import BATCH


def test_random_rollout_10s_no_nan_and_auto_reset(wrapped, dr_env):
    _, reset, step = wrapped
    s = reset(jax.random.split(jax.random.PRNGKey(0), BATCH))
    key = jax.random.PRNGKey(1)
    ep = dr_env.episode_length  # 50 steps = 1 s
    n_steps = 500  # 10 s of simulated time, jerky uniform random actions
    max_v = 0.0
    for t in range(1, n_steps + 1):
        key, k = jax.random.split(key)
        s = step(s, jax.random.uniform(k, (BATCH, 14), minval=-1.0, maxval=1.0))
        if t % 25 == 0 or t % ep in (0, 1):
            assert np.all(np.isfinite(np.asarray(s.obs))), t
            assert np.all(np.isfinite(np.asarray(s.reward))), t
            max_v = max(max_v, float(jnp.abs(s.data.qvel).max()))
            steps = np.asarray(s.info["steps"])
            if t % ep == 0:
                # Every env hits the time limit together: done, truncation, fresh episode state.
                np.testing.assert_array_equal(s.done, 1.0)
                np.testing.assert_array_equal(s.info["truncation"], 1.0)
                np.testing.assert_array_equal(steps, ep)
                np.testing.assert_array_equal(s.info["episode_metrics"]["length"], ep)
                np.testing.assert_array_equal(s.info["step"], 0)  # the env's own counter was reset
                np.testing.assert_array_equal(s.info["last_act"], 0.0)
            else:
                np.testing.assert_array_equal(s.done, 0.0)  # never a non-finite termination
                np.testing.assert_array_equal(steps, t % ep)
    # Jerky random actions with the MIT law stay physically sane (wrists can spin fast, not explode).
    assert max_v < 100.0


def test_episode_metrics_accumulate(wrapped):
    _, reset, step = wrapped
    s = reset(jax.random.split(jax.random.PRNGKey(5), BATCH))
    rewards = []
    for _ in range(3):
        s = step(s, jnp.zeros((BATCH, 14)))
        rewards.append(np.asarray(s.reward))
    np.testing.assert_allclose(s.info["episode_metrics"]["sum_reward"], np.sum(rewards, axis=0), rtol=1e-5)
    np.testing.assert_array_equal(s.info["episode_metrics"]["length"], 3.0)
