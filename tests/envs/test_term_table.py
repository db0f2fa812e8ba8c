"""The reward and termination tables (``envs.term_table``, ``tasks/<task>/term_table.py``), by hand.

Pure: no env is built and nothing is compiled (the tables are functions of a config; the rows' functions
are evaluated eagerly on small hand-made signals).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.envs import rewards
from bar_policy.envs.robot import NON_FINITE
from bar_policy.envs.term_table import (
    RewardTerm,
    TerminationTerm,
    check_names,
    reward_values,
    terminated,
    weighted_sum,
)
from bar_policy.envs.terminations import farther_than

U = 2.0**-24
"""Half a float32 ulp at 1 (the unit roundoff)."""


def _hand_table() -> tuple[RewardTerm, ...]:
    return (
        RewardTerm("action_rate", rewards.action_rate, 0.5, ("action", "last_action")),
        RewardTerm("joint_vel", rewards.joint_vel, -0.25, ("dq",)),
        RewardTerm("success", rewards.success, 2.0, ("dl", "dr"), {"radius": 0.03}),
    )


def _hand_signals() -> dict[str, jnp.ndarray]:
    return {
        "action": jnp.array([0.5, -1.0, 0.25], jnp.float32),
        "last_action": jnp.array([0.0, 1.0, 0.25], jnp.float32),
        "dq": jnp.array([1.0, 2.0], jnp.float32),
        "dl": jnp.float32(0.01),
        "dr": jnp.float32(0.02),
        "unused": jnp.float32(9.0),
    }


def test_the_sum_is_each_weight_times_its_term_by_hand():
    table = _hand_table()
    values = reward_values(table, _hand_signals())
    # action_rate = 0.5^2 + (-2)^2 + 0 = 4.25; joint_vel = 1 + 4 = 5; success = 1 (both within 3 cm).
    assert {k: float(v) for k, v in values.items()} == {"action_rate": 4.25, "joint_vel": 5.0, "success": 1.0}
    assert all(v.dtype == jnp.float32 for v in values.values())  # the indicator as its float
    total, scaled = weighted_sum(table, values)
    # 0.5 * 4.25 = 2.125, -0.25 * 5 = -1.25, 2 * 1 = 2: dyadic, so every product and sum is exact in
    # float32 and the comparison is exact.
    assert {k: float(v) for k, v in scaled.items()} == {
        "action_rate": 2.125,
        "joint_vel": -1.25,
        "success": 2.0,
    }
    assert float(total) == 2.875
    assert list(scaled) == ["action_rate", "joint_vel", "success"]  # the table's order


def test_an_invalid_step_scores_zero_on_every_term():
    table = _hand_table()
    total, scaled = weighted_sum(table, reward_values(table, _hand_signals()), jnp.bool_(False))
    assert float(total) == 0.0 and all(float(v) == 0.0 for v in scaled.values())


def test_a_missing_signal_is_named():
    table = (RewardTerm("joint_vel", rewards.joint_vel, -1.0, ("dq_true",)),)
    with pytest.raises(
        ValueError, match=r"reward term 'joint_vel' needs signals \['dq_true'\]; the step has"
    ):
        reward_values(table, _hand_signals())


def test_terminations_fire_each_on_its_own_and_any_ends_the_episode():
    table = (NON_FINITE, TerminationTerm("lost", farther_than, ("dist",), {"limit": 0.25}))
    near = {"finite": jnp.bool_(True), "dist": jnp.array([0.1, 0.2])}
    end, fired = terminated(table, near)
    assert not bool(end) and fired == {"non_finite": False, "lost": False}
    end, fired = terminated(table, {**near, "dist": jnp.array([0.1, 0.26])})
    assert bool(end) and {k: bool(v) for k, v in fired.items()} == {"non_finite": False, "lost": True}
    end, fired = terminated(table, {**near, "finite": jnp.bool_(False)})
    assert bool(end) and {k: bool(v) for k, v in fired.items()} == {"non_finite": True, "lost": False}
    # A limit of 0 disables the distance termination (the track config's "0 disables").
    assert not bool(farther_than(jnp.array([5.0]), 0.0))
    end, fired = terminated((), near)
    assert not bool(end) and fired == {}


def test_a_table_that_is_not_the_config_s_weights_is_refused():
    table = _hand_table()
    check_names(table, ["action_rate", "joint_vel", "success"], "Toy")
    with pytest.raises(
        ValueError, match=r"Toy's reward table lists \['action_rate', 'joint_vel', 'success'\]"
    ):
        check_names(table, ["joint_vel", "action_rate", "success"], "Toy")  # the order is the sum's


def _distinct(cfg):
    """``cfg`` with weight i + 1 on the i-th weight field: a row reading another term's weight shows."""
    scales = cfg.reward.scales
    w = {f.name: float(i + 1) for i, f in enumerate(dataclasses.fields(scales))}
    return dataclasses.replace(cfg, reward=dataclasses.replace(cfg.reward, scales=type(scales)(**w))), w


def _configs():
    from bar_policy.tasks.piano.env import default_config as piano_config
    from bar_policy.tasks.piano.term_table import reward_terms as piano_terms
    from bar_policy.tasks.reach.env import default_config as reach_config
    from bar_policy.tasks.reach.term_table import reward_terms as reach_terms
    from bar_policy.tasks.track.config import default_config as track_config
    from bar_policy.tasks.track.term_table import reward_terms as track_terms

    return [
        ("reach", reach_config(), reach_terms),
        ("track", track_config(), track_terms),
        ("piano", piano_config(), piano_terms),
    ]


@pytest.mark.parametrize("task", ["reach", "track", "piano"])
def test_each_task_s_table_lists_exactly_the_config_s_weights_in_order(task):
    _, cfg, table_of = next(c for c in _configs() if c[0] == task)
    cfg, w = _distinct(cfg)
    table = table_of(cfg.reward)
    assert [t.name for t in table] == list(w)
    assert {t.name: t.weight for t in table} == w  # each row weighs its own term


def test_reach_s_total_is_the_hand_sum_of_its_weighted_terms():
    """Reach's own table on a small state whose terms are worked out by hand, default weights."""
    from bar_policy.tasks.reach.env import default_config
    from bar_policy.tasks.reach.term_table import reward_terms

    cfg = default_config()
    table = reward_terms(cfg.reward)
    lo = np.array([-1.0, -2.0, 0.0], np.float32)
    hi = np.array([1.0, 0.0, 1.0], np.float32)
    signals = {
        "dist_left": jnp.float32(0.0),  # on target: each kernel is 1 - tanh(0) = 1
        "dist_right": jnp.float32(0.03),  # fine: 1 - tanh(1); coarse: 1 - tanh(0.2); not a success
        "action": jnp.array([0.5, -0.5, 0.0], jnp.float32),
        "last_action": jnp.array([0.25, -0.5, 0.5], jnp.float32),
        "last_last_action": jnp.array([0.0, 0.0, 0.0], jnp.float32),
        # soft range (fraction 0.95): joint 0 [-0.95, 0.95], joint 2 [0.025, 0.975]: 1.0 is 0.05 over,
        # 0.0 is 0.025 under, joint 1 is inside.
        "q": jnp.array([1.0, -1.0, 0.0], jnp.float32),
        "q_lower": lo,
        "q_upper": hi,
        "dq": jnp.array([2.0, -1.0, 0.0], jnp.float32),
        "tau_sq": jnp.float32(1.5),
        "near_cap": jnp.float32(0.25),
        "q_wrist": jnp.array([0.1, -0.2], jnp.float32),
        "q_wrist_default": jnp.array([0.0, 0.0], jnp.float32),
    }
    hand = {
        "reach_coarse": 0.5 * (1.0 + (1.0 - math.tanh(0.03 / 0.15))),
        "reach_fine": 0.5 * (1.0 + (1.0 - math.tanh(1.0))),
        "success": 0.0,
        "action_rate": 0.25**2 + 0.0 + 0.5**2,
        "action_accel": (0.5 - 0.5) ** 2 + (-0.5 + 1.0) ** 2 + (0.0 - 1.0) ** 2,
        "joint_limit": 0.05 + 0.025,
        "torque": 1.5,
        "torque_near_cap": 0.25,
        "joint_vel": 5.0,
        "wrist_posture": 0.3,
    }
    s = cfg.reward.scales
    expected = sum(getattr(s, k) * v for k, v in hand.items())
    total, scaled = weighted_sum(table, reward_values(table, signals))
    # Each scaled term is float32 arithmetic on values of order 1: the weight's rounding to float32, a
    # few roundings in the term (tanh and its argument: 4; sums of 3 squares: 3 + 3), the product: at most
    # 10 roundings of its size; the total adds 9 more of the sum of magnitudes. Bound (10 + 9) U sum|w v|,
    # used as 32 U sum|w v| (1.1e-6 here); a wrong weight or term moves the total by >= 5e-4.
    size = sum(abs(getattr(s, k) * v) for k, v in hand.items())
    for k, v in hand.items():
        assert float(scaled[k]) == pytest.approx(getattr(s, k) * v, abs=16 * U * max(abs(v), 1.0)), k
    assert abs(float(total) - expected) <= 32 * U * size


def test_track_s_termination_is_its_configured_distance():
    from bar_policy.tasks.track.config import default_config
    from bar_policy.tasks.track.term_table import termination_terms

    cfg = dataclasses.replace(default_config(), termination_distance=0.1)
    (lost,) = termination_terms(cfg)
    assert lost.name == "lost" and lost.params == {"limit": 0.1}
    end, _ = terminated((lost,), {"body_dist": jnp.array([0.05, 0.11])})
    assert bool(end)
    end, _ = terminated((lost,), {"body_dist": jnp.array([0.05, 0.09])})
    assert not bool(end)


def test_an_env_whose_table_is_not_its_weights_is_refused_when_built():
    from bar_policy.tasks.reach.env import LiteReach, nominal_config

    class Swapped(LiteReach):
        def reward_terms(self):
            first, second, *rest = super().reward_terms()
            return (second, first, *rest)

    with pytest.raises(ValueError, match=r"Swapped's reward table lists \['reach_fine', 'reach_coarse', "):
        Swapped(nominal_config())
