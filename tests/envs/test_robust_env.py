"""The robot env's robustness switches on a stepped env: observation latency and motor strength.

Each test compiles one or two env steps on the CPU (tens of seconds): run this file alone, niced.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy import envs


def _config(**actuator):
    """Nominal LiteReach (no noise, no randomisation) without wire quantisation, with ``actuator`` set."""
    cfg = envs.nominal_config()
    return replace(cfg, actuator=replace(cfg.actuator, quantize_wire=False, **actuator))


@pytest.fixture(scope="module")
def delayed():
    """(env, jit reset, jit step) with one step of observation latency and strength 0.8 on every joint."""
    env = envs.load("LiteReach", config=_config(obs_latency_steps=(1, 1), strength=(0.8, 0.8)))
    return env, jax.jit(env.reset), jax.jit(env.step)


def test_observation_latency_shows_the_previous_state(delayed):
    env, reset, step = delayed
    state = reset(jax.random.PRNGKey(0))
    assert int(state.info["obs_latency"]) == 1
    sl_q, sl_v = env.obs_manager.term_slice("joint_pos"), env.obs_manager.term_slice("joint_vel")
    default = env.default_pose
    action = 0.3 * jnp.ones(env.action_size)
    states = [state]
    for _ in range(3):
        states.append(step(states[-1], action))
    # Reset: the buffer holds the reset state. Step k: the state of step k-1 (joint_pos = q - default,
    # joint_vel = 0.1 dq; float32 subtraction and scaling: 1e-6).
    for k, s in enumerate(states):
        seen = states[max(k - 1, 0)].data
        np.testing.assert_allclose(np.asarray(s.obs[sl_q]), np.asarray(seen.qpos) - default, atol=1e-6)
        np.testing.assert_allclose(np.asarray(s.obs[sl_v]), 0.1 * np.asarray(seen.qvel), atol=1e-6)
    # The arm moved between steps, so the delayed observation is not the current one.
    assert np.abs(np.asarray(states[2].data.qpos - states[1].data.qpos)).max() > 1e-3
    # The last action is not delayed (the policy's own output, here through reach's action low-pass): it is
    # this step's applied action, which differs from the previous step's.
    seen_action = np.asarray(states[3].obs[env.obs_manager.term_slice("actions")])
    np.testing.assert_array_equal(seen_action, np.asarray(states[3].info["last_act"]))
    assert np.abs(seen_action - np.asarray(states[2].info["last_act"])).max() > 1e-3


def test_strength_equals_scaled_gains_below_the_cap(delayed):
    # Below the cap, s * (Kp e - Kd dq) = (s Kp) e - (s Kd) dq: strength 0.8 and Kp, Kd x0.8 are the same
    # torque (the implicit Kd term too: s Kd both ways), so the two envs move alike. Small action: no cap.
    # float32 over 40 physics steps of products reordered: 1e-5 rad.
    env, reset, step = delayed
    scaled = envs.load(
        "LiteReach", config=_config(obs_latency_steps=(1, 1), kp_scale=(0.8, 0.8), kd_scale=(0.8, 0.8))
    )
    s_reset, s_step = jax.jit(scaled.reset), jax.jit(scaled.step)
    a, b = reset(jax.random.PRNGKey(0)), s_reset(jax.random.PRNGKey(0))
    np.testing.assert_allclose(np.asarray(a.info["strength"]), 0.8)
    np.testing.assert_allclose(np.asarray(b.info["kp"]), 0.8 * env.kp, rtol=1e-6)
    assert "strength" not in b.info  # the default draws none
    action = 0.05 * jnp.ones(env.action_size)
    start = np.asarray(a.data.qpos)
    for _ in range(4):
        a, b = step(a, action), s_step(b, action)
        np.testing.assert_allclose(np.asarray(a.data.qpos), np.asarray(b.data.qpos), atol=1e-5)
    assert np.abs(np.asarray(a.data.qpos) - start).max() > 1e-2  # it moved: the comparison has content


def test_factor_share_reaches_the_reset():
    # ``randomization.factor_share`` 0: every episode factor as the default actuator draws it (strength 1,
    # no observation latency, action latency in 0..2 with a buffer for it), the reset's keys as
    # ``randomize.episode_draws`` takes them. A reset only: no step compiled.
    from bar_policy.envs.randomize import episode_draws

    cfg = _config(strength=(0.8, 1.0), latency_steps=(0, 1), obs_latency_steps=(0, 1))
    cfg = replace(cfg, randomization=replace(cfg.randomization, factor_share=0.0))
    env = envs.load("LiteReach", config=cfg)
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    info = jax.jit(jax.vmap(env.reset))(keys).info
    np.testing.assert_array_equal(np.asarray(info["strength"]), 1.0)
    np.testing.assert_array_equal(np.asarray(info["obs_latency"]), 0)
    assert info["act_buf"].shape == (8, 3, 14) and info["obs_buf"].shape == (8, 2, 2, 14)
    ks = jax.vmap(lambda k: jax.random.split(k, 8))(keys)
    ref = jax.vmap(lambda k: episode_draws(cfg.actuator, 0.0, k, 14, None))(ks)
    np.testing.assert_array_equal(np.asarray(info["latency"]), np.asarray(ref["latency"]))
    np.testing.assert_array_equal(np.asarray(info["encoder_offset"]), np.asarray(ref["encoder_offset"]))
