"""``joint_error_ema``: the MJX env and the deploy runtime's inputs give the same term for the same states.

The nominal reach env with the opt-in term steps 40 control steps of smooth actions; the runtime's
``StateInputs`` (``deploy.inputs``) is then fed the states the env reached and the commands of the actions
it applied, as the runtime feeds it (None before the first policy step). The env's observation term
(float32) and the runtime's (float64) must agree to float32 rounding; both must be the average worked out
here. Off by default: the env's layout is then the golden one.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bar_policy import envs
from bar_policy.deploy.inputs import StateInputs
from bar_policy.obs.manager import ObservationManager


def test_env_and_runtime_give_the_same_term() -> None:
    config = envs.apply_overrides(
        envs.nominal_config(envs.default_config("LiteReach")), ["joint_error_ema=true"]
    )
    env = envs.load("LiteReach", config=config)
    om = env.obs_manager
    assert (om.schema.name, om.schema.version, om.term_names[-1]) == ("lite_reach_arms", 2, "joint_error_ema")
    assert (
        ObservationManager.for_task("reach", "arms").schema
        == ObservationManager.golden("lite_reach_arms").schema
    )
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    s = reset(jax.random.PRNGKey(1))
    t = np.arange(40)[:, None] * 0.02
    acts = (0.5 * np.sin(2 * np.pi * 0.8 * t + np.linspace(0, 3, 14)[None])).astype(np.float32)
    inputs = StateInputs(om, "arms", policy_dt=env.dt)
    q = np.asarray(env.robot_q(s.data), np.float64)
    z_rt = inputs(q, np.zeros(14), np.zeros(14), None)["joint_error_ema"]
    z_env = np.asarray(om.split(s.obs)["joint_error_ema"]) / 10.0
    np.testing.assert_array_equal(z_env, 0.0)
    np.testing.assert_array_equal(z_rt, 0.0)
    z_hand = np.zeros(14)
    lower, upper = env.robot.lower, env.robot.upper
    for a in acts:
        s = step(s, jnp.asarray(a))
        applied = np.asarray(s.info["last_act"], np.float64)  # after the env's 3 Hz action filter
        q_cmd = np.clip(env.default_pose.astype(np.float64) + env.action_scale * applied, lower, upper)
        q = np.asarray(env.robot_q(s.data), np.float64)
        z_rt = inputs(q, np.zeros(14), applied, q_cmd)["joint_error_ema"]
        z_hand = z_hand + 0.04 * ((q_cmd - q) - z_hand)
        z_env = np.asarray(om.split(s.obs)["joint_error_ema"], np.float64) / 10.0
        # float32 env: q_cmd and q below 3 rad (ulp 2.4e-7), the average's 40 updates each rounding
        # to ulp(|z|) < 3e-8, the term x10 then /10: well inside 1e-6 rad.
        np.testing.assert_allclose(z_env, z_rt, rtol=0, atol=1e-6)
        np.testing.assert_allclose(z_rt, z_hand, rtol=0, atol=1e-12)
    assert np.abs(z_rt).max() > 1e-2  # the motion leaves a tracking error to average
