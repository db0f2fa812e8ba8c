"""Key-press precision, recall and F1 (bar_policy/tasks/piano/metrics.py), worked out by hand.

One 5-key episode of 6 steps, its counts and scores computed in the comments from the definitions
(P = TP / (TP + FP), R = TP / (TP + FN), F1 = 2 TP / (2 TP + FP + FN), an empty denominator scores 1);
then the same counts per key colour (3 white + 2 black keys) and their pooled recall.
float64 (numpy) results: ``rel=1e-12``; float32 (jax, x64 off): ``rel=1e-6`` (a few roundings of 6e-8).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.tasks.piano.keyboard import black_keys, compact_config, is_black
from bar_policy.tasks.piano.metrics import colour_counts, episode_scores, step_counts, step_scores


def _keys(*sets: set[int], n: int = 5) -> np.ndarray:
    out = np.zeros((len(sets), n), dtype=bool)
    for t, s in enumerate(sets):
        out[t, sorted(s)] = True
    return out


GOAL = _keys({0, 2}, set(), set(), {4}, {1, 2, 3}, {0, 1, 2, 3})
PRESSED = _keys({0, 1}, set(), {3}, set(), {1, 2, 3}, {0})
# step: TP FP FN -> P, R, F1
# 0: {0,1} vs {0,2}: 1 1 1 -> 1/2, 1/2, 2/4
# 1: rest played as a rest: 0 0 0 -> 1, 1, 1 (every denominator empty)
# 2: a press during a rest: 0 1 0 -> 0/1, 1 (empty), 0/1
# 3: a goal key missed, nothing pressed: 0 0 1 -> 1 (empty), 0/1, 0/1
# 4: all three right: 3 0 0 -> 1, 1, 6/6
# 5: one of four: 1 0 3 -> 1, 1/4, 2/5 (= 2 * 1 * 0.25 / 1.25)
STEP_P = [0.5, 1.0, 0.0, 1.0, 1.0, 1.0]
STEP_R = [0.5, 1.0, 1.0, 0.0, 1.0, 0.25]
STEP_F = [0.5, 1.0, 0.0, 0.0, 1.0, 0.4]


def test_step_counts_and_scores_by_hand() -> None:
    tp, fp, fn = step_counts(PRESSED, GOAL)
    assert tp.tolist() == [1, 0, 0, 0, 3, 1]
    assert fp.tolist() == [1, 0, 1, 0, 0, 0]
    assert fn.tolist() == [1, 0, 0, 1, 0, 3]
    p, r, f = step_scores(PRESSED, GOAL)
    np.testing.assert_allclose(p, STEP_P, rtol=1e-12)
    np.testing.assert_allclose(r, STEP_R, rtol=1e-12)
    np.testing.assert_allclose(f, STEP_F, rtol=1e-12)
    # 0/1 floats (songs.goal_keys is float32) count as the bools do.
    assert step_counts(PRESSED.astype(np.float32), GOAL.astype(np.float32)).tp.tolist() == tp.tolist()


def test_episode_both_aggregations_by_hand() -> None:
    s = episode_scores(PRESSED, GOAL)
    # Step mean (RoboPianist's): P (0.5 + 1 + 0 + 1 + 1 + 1) / 6 = 0.75; R (0.5 + 1 + 1 + 0 + 1 + 0.25) / 6
    # = 0.625; F1 (0.5 + 1 + 0 + 0 + 1 + 0.4) / 6 = 2.9 / 6.
    assert s.precision == pytest.approx(0.75, rel=1e-12)
    assert s.recall == pytest.approx(0.625, rel=1e-12)
    assert s.f1 == pytest.approx(2.9 / 6, rel=1e-12)
    # Pooled: TP 1+0+0+0+3+1 = 5, FP 1+0+1+0+0+0 = 2, FN 1+0+0+1+0+3 = 5: P 5/7, R 5/10, F1 10/17.
    assert s.precision_pooled == pytest.approx(5 / 7, rel=1e-12)
    assert s.recall_pooled == pytest.approx(0.5, rel=1e-12)
    assert s.f1_pooled == pytest.approx(10 / 17, rel=1e-12)


def test_valid_mask_batch_and_empty_episodes() -> None:
    rest = np.zeros_like(GOAL)
    pressed = np.stack([PRESSED, PRESSED, rest, PRESSED])
    goal = np.stack([GOAL, GOAL, rest, GOAL])
    valid = np.ones((4, 6), dtype=bool)
    valid[1, 3:] = False  # episode 1 ended after 3 steps
    valid[3] = False  # episode 3 never ran
    s = episode_scores(pressed, goal, valid)
    # Episode 1, steps 0-2: mean P (0.5 + 1 + 0) / 3, R (0.5 + 1 + 1) / 3, F1 (0.5 + 1 + 0) / 3;
    # pooled TP 1, FP 2, FN 1: P 1/3, R 1/2, F1 2 / (2 + 2 + 1) = 0.4.
    # Episode 2, six rests played as rests: 1 everywhere (pooled 0 / 0 scores 1 too). Episode 3: NaN.
    np.testing.assert_allclose(s.precision[:3], [0.75, 0.5, 1.0], rtol=1e-12)
    np.testing.assert_allclose(s.recall[:3], [0.625, 2.5 / 3, 1.0], rtol=1e-12)
    np.testing.assert_allclose(s.f1[:3], [2.9 / 6, 0.5, 1.0], rtol=1e-12)
    np.testing.assert_allclose(s.precision_pooled[:3], [5 / 7, 1 / 3, 1.0], rtol=1e-12)
    np.testing.assert_allclose(s.recall_pooled[:3], [0.5, 0.5, 1.0], rtol=1e-12)
    np.testing.assert_allclose(s.f1_pooled[:3], [10 / 17, 0.4, 1.0], rtol=1e-12)
    assert all(np.isnan(x[3]) for x in s)


def test_jax_jit_and_vmap_agree_with_numpy() -> None:
    pressed = np.stack([PRESSED, ~PRESSED])
    goal = np.stack([GOAL, GOAL])
    valid = np.array([[True] * 6, [True] * 4 + [False] * 2])
    want = episode_scores(pressed, goal, valid)
    got = jax.jit(jax.vmap(episode_scores))(jnp.asarray(pressed), jnp.asarray(goal), jnp.asarray(valid))
    for w, g in zip(want, got, strict=True):
        assert isinstance(g, jax.Array)
        np.testing.assert_allclose(np.asarray(g), w, rtol=1e-6)
    steps = jax.jit(step_scores)(jnp.asarray(PRESSED), jnp.asarray(GOAL))
    np.testing.assert_allclose(np.asarray(steps.f1), STEP_F, rtol=1e-6)


def test_refuses_mismatched_key_counts() -> None:
    with pytest.raises(ValueError, match="same n_keys"):
        step_counts(np.zeros((2, 5), bool), np.zeros((2, 4), bool))


# Per key colour: 5 keys as C4 C#4 D4 D#4 E4, so 0, 2, 4 white and 1, 3 black.
BLACK = np.array([False, True, False, True, False])
C_GOAL = _keys({0, 1}, {3, 4}, {1, 2}, {4}, set())
C_PRESSED = _keys({0}, {2, 3, 4}, {2}, set(), {1})
# step: black TP FP FN | white TP FP FN
# 0: goal {0,1} pressed {0}:       black 0 0 1 (1 missed) | white 1 0 0
# 1: goal {3,4} pressed {2,3,4}:   black 1 0 0            | white 1 1 0 (2 extra)
# 2: goal {1,2} pressed {2}:       black 0 0 1 (1 missed) | white 1 0 0
# 3: goal {4} pressed {}:          black 0 0 0            | white 0 0 1 (4 missed)
# 4: rest, 1 pressed:              black 0 1 0            | white 0 0 0
# Pooled: black TP 1, FN 2 -> recall_black 1/3; white TP 3, FN 1 -> recall_white 3/4. All keys: TP 4, FN 3
# -> 4/7 (the colours' counts add up to the keyboard's).


def test_colour_counts_by_hand() -> None:
    black, white = colour_counts(C_PRESSED, C_GOAL, BLACK)
    assert black.tp.tolist() == [0, 1, 0, 0, 0]
    assert black.fp.tolist() == [0, 0, 0, 0, 1]
    assert black.fn.tolist() == [1, 0, 1, 0, 0]
    assert white.tp.tolist() == [1, 1, 1, 0, 0]
    assert white.fp.tolist() == [0, 1, 0, 0, 0]
    assert white.fn.tolist() == [0, 0, 0, 1, 0]
    every = step_counts(C_PRESSED, C_GOAL)
    for b, w, a in zip(black, white, every, strict=True):
        np.testing.assert_array_equal(b + w, a)
    # Pooled over the episode (episode_scores with keys): 1/3 black, 3/4 white, 4/7 all.
    assert episode_scores(C_PRESSED, C_GOAL, keys=BLACK).recall_pooled == pytest.approx(1 / 3, rel=1e-12)
    assert episode_scores(C_PRESSED, C_GOAL, keys=~BLACK).recall_pooled == pytest.approx(0.75, rel=1e-12)
    assert episode_scores(C_PRESSED, C_GOAL).recall_pooled == pytest.approx(4 / 7, rel=1e-12)


def test_colour_without_black_goals_scores_one_not_nan() -> None:
    # Steps 3 and 4 only: no black goal key (step 4 presses black key 1: FP, not a recall term). Black TP 0,
    # FN 0: the pooled 0 / 0 scores 1 (the module's zero_division=1), not NaN; white TP 0, FN 1 -> 0.
    black = episode_scores(C_PRESSED[3:], C_GOAL[3:], keys=BLACK)
    white = episode_scores(C_PRESSED[3:], C_GOAL[3:], keys=~BLACK)
    assert black.recall_pooled == 1.0 and white.recall_pooled == 0.0
    assert black.precision_pooled == 0.0  # the black press of step 4: TP 0, FP 1


def test_colour_counts_jax_jit_and_vmap_agree_with_numpy() -> None:
    pressed = np.stack([C_PRESSED, ~C_PRESSED])
    goal = np.stack([C_GOAL, C_GOAL])
    want = colour_counts(pressed, goal, BLACK)
    fn = jax.jit(jax.vmap(lambda p, g: colour_counts(p, g, BLACK)))  # the mask static, as in the env
    got = fn(jnp.asarray(pressed), jnp.asarray(goal.astype(np.float32)))  # goal as the bank's 0/1 floats
    for w, g in zip(jax.tree.leaves(want), jax.tree.leaves(got), strict=True):
        assert isinstance(g, jax.Array)
        np.testing.assert_array_equal(np.asarray(g), w)
    ep = jax.jit(lambda p, g: episode_scores(p, g, keys=BLACK))(jnp.asarray(C_PRESSED), jnp.asarray(C_GOAL))
    assert float(ep.recall_pooled) == pytest.approx(1 / 3, rel=1e-6)


def test_black_keys_of_the_compact_keyboard() -> None:
    kb = compact_config()  # MIDI 36..84: four octaves of 5 black keys, then C6
    mask = black_keys(kb)
    assert mask.shape == (kb.n_keys,) == (49,) and mask.sum() == 20
    assert mask.tolist() == [is_black(m) for m in range(kb.lowest, kb.highest + 1)]
    with pytest.raises(ValueError, match=r"keys \(3,\) must be \(n_keys,\)"):
        step_counts(C_PRESSED, C_GOAL, np.ones(3, bool))
