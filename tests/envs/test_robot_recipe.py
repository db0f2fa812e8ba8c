"""The robot env's training-recipe options: gains from the armature, quality signals, the action filter."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy import envs
from bar_policy.robot.constants import load_robot


def test_actuator_gains_follow_the_armature_recipe():
    env = envs.load("LiteReach", config=dataclasses.replace(envs.nominal_config(), gains="actuator"))
    # Kp = J (2 pi 10)^2, Kd = 2 * 2 * J * 2 pi 10: J = 0.005 (rs-02 shoulder pitch) -> 19.739, 1.2566;
    # J = 0.002 (every other arm joint) -> 7.8957, 0.50265 (lite-model.md section 2.1's table).
    w = 20 * math.pi
    kp = np.where(np.isin(np.arange(14), [0, 7]), 0.005 * w * w, 0.002 * w * w)
    np.testing.assert_allclose(env.kp, kp, rtol=1e-6)
    np.testing.assert_allclose(env.kp[[0, 1]], [19.7392, 7.8957], rtol=1e-4)
    np.testing.assert_allclose(env.kd[[0, 1]], [1.25664, 0.502655], rtol=1e-4)
    with pytest.raises(ValueError, match="unknown gains 'soft'; valid: \\['robot', 'stiff', 'actuator'\\]"):
        dataclasses.replace(envs.nominal_config(), gains="soft")
    # The stiff profile: twice the table's Kp, 1.5 times its Kd (robot.gains), by hand 100 and 3.
    stiff = envs.load("LiteReach", config=dataclasses.replace(envs.nominal_config(), gains="stiff"))
    np.testing.assert_array_equal(stiff.kp, 100.0)
    np.testing.assert_array_equal(stiff.kd, 3.0)


def test_action_filter_config_is_validated():
    with pytest.raises(ValueError, match="Nyquist frequency 25 Hz"):
        dataclasses.replace(envs.nominal_config(), action_filter_hz=30.0)


def test_quality_signals_are_the_law_of_the_applied_command(nominal_env, nominal_fns):
    """Nominal reach at its reset (q = piano_ready, dq = 0, last action 0), action 0.5 on every joint: the
    3 Hz filter applies alpha * 0.5 (alpha = 1 - exp(-2 pi 3 0.02) = 0.3141), q_cmd = default + 0.8 * that
    (clipped to the limits), demand = Kp (quantised q_cmd - q) with Kp = 50."""
    reset, _ = nominal_fns
    s = reset(jax.random.PRNGKey(0))
    sig = jax.jit(nominal_env.quality_signals)(s, jnp.full(14, 0.5, jnp.float32))
    robot = load_robot("arms")
    q = np.asarray(s.data.qpos, np.float64)
    applied = (1.0 - math.exp(-2.0 * math.pi * 3.0 * 0.02)) * 0.5
    q_cmd = np.clip(robot.pose("piano_ready") + 0.8 * applied, robot.lower, robot.upper)
    # The truncating 16-bit wire grid moves q_cmd by < 8 pi / 65535 = 3.8e-4 rad (Kp * that = 0.0192 N*m)
    # and Kp by < 500 / 65535 = 0.0076 N*m/rad (times |q_cmd - q| <= 0.4 rad: 0.0031 N*m).
    bound = 50 * 8 * math.pi / 65535 + 0.4 * 500 / 65535 + 1e-4
    np.testing.assert_allclose(sig["demand"], 50.0 * (q_cmd - q), atol=bound)
    np.testing.assert_allclose(sig["action"], applied, atol=1e-7)  # float32 on 0.157
    np.testing.assert_allclose(sig["signal"], q_cmd, atol=1e-6)  # reach: the chatter signal is q_cmd
    np.testing.assert_allclose(sig["q"], q)
