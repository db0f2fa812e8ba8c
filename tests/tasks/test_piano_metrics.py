"""Key-press precision, recall and F1 (bar_policy/tasks/piano/metrics.py), worked out by hand.

One 5-key episode of 6 steps, its counts and scores computed in the comments from the definitions
(P = TP / (TP + FP), R = TP / (TP + FN), F1 = 2 TP / (2 TP + FP + FN), an empty denominator scores 1).
float64 (numpy) results: ``rel=1e-12``; float32 (jax, x64 off): ``rel=1e-6`` (a few roundings of 6e-8).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.tasks.piano.metrics import episode_scores, step_counts, step_scores


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
