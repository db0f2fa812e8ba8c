"""The black goal keys' extra press reward (``term_table``'s ``key_press_black``), worked out by hand.

Kernel (``rewards.goal_keys_pressed``): a goal key at depression ``x`` scores 1 for ``x >= 0.95`` and
``0.1 ** (((0.95 - x) / 0.5) ** 2)`` below; at ``x = 0.5``: ``0.1 ** 0.81 = 0.154882`` (float64 here: the
sums are compared to 1e-12).
"""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy.envs import rewards  # noqa: F401 - first: term_table is imported through the registry
from bar_policy.envs.term_table import RewardTerm
from bar_policy.tasks.piano.keyboard import black_keys, compact_config
from bar_policy.tasks.piano.preset import PIANO
from bar_policy.tasks.piano.term_table import RewardConfig, RewardScales, reward_terms

KB = compact_config()
BLACK = black_keys(KB)
HALF = 0.1**0.81  # a goal key at the press threshold (half travel)


def _key_rewards(scales: RewardScales, depression: np.ndarray, goal: np.ndarray) -> dict[str, float]:
    """The two press rows of the table, weighted, on the env's signals (``black_goal_keys`` = goal x mask)."""
    signals = {"key_depression": depression, "goal_keys": goal, "black_goal_keys": goal * BLACK}
    rows = [
        t for t in reward_terms(RewardConfig(scales=scales)) if t.name in ("key_press", "key_press_black")
    ]
    return {t.name: float(t.weight * t.fn(*(signals[i] for i in t.inputs), **t.params)) for t in rows}


def test_a_black_goal_earns_the_extra_press_reward() -> None:
    c4, cs4, e4 = 60 - KB.lowest, 61 - KB.lowest, 64 - KB.lowest
    assert BLACK[cs4] and not BLACK[c4] and not BLACK[e4]
    depression = np.zeros(KB.n_keys)
    depression[cs4], depression[e4] = 1.0, 0.5
    goal = np.zeros(KB.n_keys)
    goal[[cs4, e4]] = 1.0
    on = RewardScales(key_press_black=1.0)
    # C#4 (black) at the bottom, E4 (white) at half travel: key_press is the mean over both goal keys,
    # (1 + HALF) / 2; key_press_black the mean over the black one alone, 1.
    r = _key_rewards(on, depression, goal)
    assert r["key_press"] == pytest.approx((1 + HALF) / 2, rel=1e-12)
    assert r["key_press_black"] == pytest.approx(1.0, rel=1e-12)
    # C#4 at half travel alone: both rows HALF; a white goal alone (C4 down): nothing extra.
    goal[:], depression[:] = 0.0, 0.0
    goal[cs4], depression[cs4] = 1.0, 0.5
    assert _key_rewards(on, depression, goal) == pytest.approx({"key_press": HALF, "key_press_black": HALF})
    goal[:], depression[:] = 0.0, 0.0
    goal[c4], depression[c4] = 1.0, 1.0
    assert _key_rewards(on, depression, goal) == {"key_press": 1.0, "key_press_black": 0.0}
    # The default weight 0 leaves the table's sum as it was.
    assert RewardScales().key_press_black == 0.0
    assert _key_rewards(RewardScales(), depression, goal)["key_press_black"] == 0.0


def test_wrong_keys_at_a_black_goal_carry_their_own_weight() -> None:
    c4, cs4, d4, ds4, e4 = (m - KB.lowest for m in (60, 61, 62, 63, 64))
    rows = {
        t.name: t
        for t in reward_terms(RewardConfig(scales=RewardScales(wrong_keys_black_goal=0.25)))
        if t.name in ("wrong_keys", "wrong_keys_black_goal")
    }

    def cost(goal_keys: list[int], down: list[int]) -> dict[str, float]:
        goal, pressed = np.zeros(KB.n_keys), np.zeros(KB.n_keys)
        goal[goal_keys], pressed[down] = 1.0, 1.0
        signals = {"keys_down": pressed, "goal_keys": goal, "black_goal_keys": goal * BLACK}
        return {n: float(t.weight * t.fn(*(signals[i] for i in t.inputs))) for n, t in rows.items()}

    # Goal C#4 (black), down C#4, C4 and D4: two wrong keys, -0.5 each, 0.25 each given back: -0.5 in all.
    assert cost([cs4], [cs4, c4, d4]) == {"wrong_keys": -1.0, "wrong_keys_black_goal": 0.5}
    # Goal E4 (white), down E4 and D#4: one wrong key at a white goal: no relief.
    assert cost([e4], [e4, ds4]) == {"wrong_keys": -0.5, "wrong_keys_black_goal": 0.0}
    # A chord of both colours counts as a black goal; no goal at all does not.
    assert cost([c4, ds4], [c4, ds4, d4]) == {"wrong_keys": -0.5, "wrong_keys_black_goal": 0.25}
    assert cost([], [d4]) == {"wrong_keys": -0.5, "wrong_keys_black_goal": 0.0}
    assert RewardScales().wrong_keys_black_goal == 0.0


def test_the_piano_preset_sets_it_and_the_override_reaches_the_env_config() -> None:
    from bar_policy import envs

    assert PIANO["env_overrides"] == (
        "reward.scales.key_press_black=1.0",
        "reward.scales.wrong_keys_black_goal=0.25",
        "actuator.encoder_offset=0.002",
        "gains=stiff",
    )
    cfg = envs.apply_overrides(envs.default_config("LitePiano"), PIANO["env_overrides"])
    assert cfg.gains == "stiff"  # Kp 100, Kd 3 (robot.gains)
    assert cfg.reward.scales.key_press_black == 1.0 and cfg.reward.scales.key_press == 1.0
    # A wrong key at a black goal tick costs -0.5 + 0.25, half of one elsewhere.
    assert cfg.reward.scales.wrong_keys + cfg.reward.scales.wrong_keys_black_goal == -0.25
    assert cfg.actuator.encoder_offset == 0.002


def _row(name: str, weight: float) -> RewardTerm:
    """The reward table's row ``name`` with its weight set to ``weight``."""
    (row,) = [t for t in reward_terms(RewardConfig(scales=RewardScales(**{name: weight}))) if t.name == name]
    return row


def test_deviation_from_the_reference_costs_at_black_goals_only() -> None:
    cs4, e4 = 61 - KB.lowest, 64 - KB.lowest
    row = _row("prior_deviation_black", -0.5)
    assert row.inputs == ("action", "reference_action", "black_goal_keys")
    reference = np.linspace(-0.5, 0.5, 14)
    action = reference.copy()
    action[2], action[9] = action[2] + 0.25, action[9] - 0.5  # 0.0625 + 0.25 = 0.3125 action units^2

    def cost(goal_keys: list[int], a: np.ndarray) -> float:
        goal = np.zeros(KB.n_keys)
        goal[goal_keys] = 1.0
        signals = {"action": a, "reference_action": reference, "black_goal_keys": goal * BLACK}
        return float(row.weight * row.fn(*(signals[i] for i in row.inputs)))

    assert cost([cs4], action) == pytest.approx(-0.5 * 0.3125, rel=1e-12)  # a black goal: the cost
    assert cost([cs4, e4], action) == pytest.approx(-0.5 * 0.3125, rel=1e-12)  # a chord with a black key
    assert cost([e4], action) == 0.0  # a white goal alone: free
    assert cost([], action) == 0.0
    assert cost([cs4], reference) == 0.0  # on the reference: nothing
    assert RewardScales().prior_deviation_black == 0.0


def test_deviation_from_the_reference_costs_at_rest_only() -> None:
    """Neither hand with a goal key in view (the count-in, where the tare fits): the squared deviation;
    any goal key of either hand in view: nothing."""
    cs4 = 61 - KB.lowest
    row = _row("prior_deviation_rest", -2.0)
    assert row.inputs == ("action", "reference_action", "hand_goal")
    reference = np.linspace(-0.5, 0.5, 14)
    action = reference.copy()
    action[0], action[13] = action[0] - 0.1, action[13] + 0.3  # 0.01 + 0.09 = 0.1 action units^2

    def cost(hand: int | None, a: np.ndarray) -> float:
        hand_goal = np.zeros((2, KB.n_keys))
        if hand is not None:
            hand_goal[hand, cs4] = 1.0
        signals = {"action": a, "reference_action": reference, "hand_goal": hand_goal}
        return float(row.weight * row.fn(*(signals[i] for i in row.inputs)))

    assert cost(None, action) == pytest.approx(-2.0 * 0.1, rel=1e-12)
    assert cost(0, action) == 0.0 and cost(1, action) == 0.0  # a goal in view of either hand: free
    assert cost(None, reference) == 0.0
    assert RewardScales().prior_deviation_rest == 0.0
