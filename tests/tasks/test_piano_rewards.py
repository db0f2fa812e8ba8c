"""Reward terms of the piano task (bar_policy/tasks/piano/rewards.py), worked out by hand.

The Gaussian ``tolerance`` outside its bounds is ``0.1 ** (d ** 2)``, ``d`` the distance past the bound in
margins: 0.1 ** 0.81 = 10 ** -0.81 = 0.15488166, 0.1 ** 3.61 = 2.4547089e-4, 0.1 ** 0.16 = 0.69183097,
0.1 ** 0.04 = 0.91201084 (powers of ten to 8 digits). numpy float64: ``rel=1e-7`` (those 8 digits);
jax float32: ``rel=1e-5``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.envs import rewards as env_rewards
from bar_policy.tasks.piano import rewards as pr


def test_tolerance_by_hand() -> None:
    x = np.array([0.0, 0.05, 0.55, 1.05, -0.5, np.inf])
    # bounds [0, 0.05], margin 0.5: inside -> 1; 0.5 past the upper bound (d = 1) -> 0.1; d = 2 -> 1e-4;
    # 0.5 below the lower bound -> 0.1; infinitely far -> 0.
    np.testing.assert_allclose(pr.tolerance(x, 0.0, 0.05, 0.5), [1, 1, 0.1, 1e-4, 0.1, 0], rtol=1e-12)
    with pytest.raises(ValueError, match="margin"):
        pr.tolerance(x, 0.0, 0.05, 0.0)


def test_key_depression_clips() -> None:
    # White lever 150 mm: angle_max = 0.010 / 0.150; black 95 mm: 0.010 / 0.095 (docs/piano.md).
    full = pr.angle_max()
    assert full[60 - 23] == pytest.approx(0.010 / 0.150) and full[61 - 23] == pytest.approx(0.010 / 0.095)
    angles = np.array([0.5 * 0.010 / 0.150, 0.2, -0.01])  # half travel, past the soft limit, above rest
    got = pr.key_depression(angles, np.array([0.010 / 0.150, 0.010 / 0.095, 0.010 / 0.150]))
    np.testing.assert_allclose(got, [0.5, 1.0, 0.0], rtol=1e-12)


def test_goal_keys_pressed_by_hand() -> None:
    dep = np.array([1.0, 0.5, 0.0, 0.96, 0.3])
    # Goal keys 0 and 1: key 0 at the bottom -> 1; key 1 at half travel: 1 - 0.5 = 0.5 is 0.45 past the
    # bound 0.05, d = 0.45 / 0.5 = 0.9 -> 0.1 ** 0.81 = 0.15488166. Mean (1 + 0.15488166) / 2.
    assert pr.goal_keys_pressed(dep, np.array([1, 1, 0, 0, 0])) == pytest.approx(0.57744083, rel=1e-7)
    # Goal key 2 at rest: 1 - 0 is 0.95 past the bound, d = 1.9 -> 0.1 ** 3.61.
    assert pr.goal_keys_pressed(dep, np.array([0, 0, 1, 0, 0])) == pytest.approx(2.4547089e-4, rel=1e-7)
    # Key 3 at 0.96 is within 0.05 of the bottom: 1. No goal key: 0 (RoboPianist's).
    assert pr.goal_keys_pressed(dep, np.array([0, 0, 0, 1, 0])) == 1.0
    assert pr.goal_keys_pressed(dep, np.zeros(5)) == 0.0


def test_wrong_keys_pressed_counts() -> None:
    pressed = np.array([True, True, False, True, False])
    goal = np.array([1.0, 0.0, 0.0, 0.0, 1.0])
    assert pr.wrong_keys_pressed(pressed, goal) == 2.0  # keys 1 and 3
    assert pr.wrong_keys_pressed(pressed, pressed) == 0.0


SITES = np.array(
    [
        [0.0, 0.1, 0.006],  # 6 mm above the left fingertip
        [0.0, 0.05, 0.0],  # 50 mm right of it
        [0.03, -0.06, 0.0],  # from the right fingertip: (0.03, 0.04, 0), 50 mm (3-4-5)
        [0.0, -0.2, 0.0],  # 100 mm right of the right fingertip
    ]
)
TIPS = np.array([[0.0, 0.1, 0.0], [0.0, -0.1, 0.0]])  # left, right


def test_fingertip_to_goal_by_hand() -> None:
    goal = np.array([[1, 1, 0, 0], [0, 0, 1, 0]])  # left: keys 0 or 1 (nearest 0), right: key 2
    np.testing.assert_allclose(pr.fingertip_distance(TIPS, SITES, goal), [0.006, 0.05], rtol=1e-12)
    # Left 6 mm < 10 mm -> 1. Right 50 mm: 40 mm past, d = 0.4 -> 0.1 ** 0.16 = 0.69183097. Mean.
    assert pr.fingertip_to_goal(TIPS, SITES, goal) == pytest.approx((1 + 0.69183097) / 2, rel=1e-7)
    # Right on key 3, 100 mm: d = 0.9 -> 0.15488166; left without a goal is left out of the mean.
    right_only = np.array([[0, 0, 0, 0], [0, 0, 0, 1]])
    assert pr.fingertip_distance(TIPS, SITES, right_only)[0] == np.inf
    assert pr.fingertip_to_goal(TIPS, SITES, right_only) == pytest.approx(0.15488166, rel=1e-7)
    # Right 30 mm from key 2 (moved 20 mm towards it): 20 mm past, d = 0.2 -> 0.1 ** 0.04 = 0.91201084.
    tips = TIPS + np.array([[0, 0, 0], [0.012, 0.016, 0.0]])  # 20 mm along (0.6, 0.8, 0)
    right_on_2 = np.array([[0, 0, 0, 0], [0, 0, 1, 0]])
    assert pr.fingertip_to_goal(tips, SITES, right_on_2) == pytest.approx(0.91201084, rel=1e-7)
    assert pr.fingertip_to_goal(TIPS, SITES, np.zeros((2, 4))) == 0.0  # no goal: 0 (RoboPianist's)


def test_next_goal_picks_the_first_step_with_keys() -> None:
    window = np.array([[0, 0, 0, 0], [0, 1, 0, 0], [1, 0, 0, 0]], dtype=np.float32)  # (L + 1, n_keys)
    assert pr.next_goal(window).tolist() == [False, True, False, False]  # step 1: the next key
    window[0, 3] = 1.0
    assert pr.next_goal(window).tolist() == [False, False, False, True]  # a key now comes first
    assert pr.next_goal(np.zeros((3, 4))).tolist() == [False] * 4  # nothing ahead


def test_energy_and_action_rate_by_hand() -> None:
    # |2 * 0.5| + |-3 * 2| + |0.5 * -4| = 1 + 6 + 2 = 9 W.
    assert pr.energy(np.array([2.0, -3.0, 0.5]), np.array([0.5, 2.0, -4.0])) == pytest.approx(9.0)
    a, prev = np.array([0.1, -0.2]), np.array([0.3, 0.1])
    assert pr.action_rate(a, prev) == pytest.approx(0.04 + 0.09, rel=1e-12)  # 0.2^2 + 0.3^2
    # The same term as the robot env's (jax): float32 agreement.
    assert float(env_rewards.action_rate(jnp.asarray(a), jnp.asarray(prev))) == pytest.approx(0.13, rel=1e-6)


def test_jax_jit_vmap_agree_with_numpy() -> None:
    rng = np.random.default_rng(0)
    dep = rng.uniform(0, 1, (3, 6))
    goal = rng.uniform(0, 1, (3, 6)) > 0.5
    tips = rng.normal(0, 0.05, (3, 2, 3))
    hand_goal = rng.uniform(0, 1, (3, 2, 6)) > 0.6
    sites = rng.normal(0, 0.05, (6, 3))
    windows = rng.uniform(0, 1, (3, 4, 6)) > 0.8

    def terms(dep, goal, tips, hand_goal, window):
        return (
            pr.goal_keys_pressed(dep, goal),
            pr.wrong_keys_pressed(dep > 0.5, goal),
            pr.fingertip_to_goal(tips, jnp.asarray(sites), hand_goal),
            pr.next_goal(window),
        )

    got = jax.jit(jax.vmap(terms))(*map(jnp.asarray, (dep, goal, tips, hand_goal, windows)))
    want = (
        pr.goal_keys_pressed(dep, goal),
        pr.wrong_keys_pressed(dep > 0.5, goal),
        pr.fingertip_to_goal(tips, sites, hand_goal),
        pr.next_goal(windows),
    )
    for g, w in zip(got, want, strict=True):
        assert isinstance(g, jax.Array) and g.shape == w.shape
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-5, atol=1e-7)
    assert not any(math.isnan(float(x)) for x in np.asarray(got[2]))
