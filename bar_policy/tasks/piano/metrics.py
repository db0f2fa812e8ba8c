"""Key-press precision, recall and F1 of the piano task, counted as RoboPianist counts them.

Per control step: ``G`` the goal keys (the keys the song holds down then: ``songs.goal_keys(...)[:, 0]``),
``P`` the pressed keys (``keyboard.pressed`` of the key angles, or a deploy ``KeySource``). Then
``TP = |P & G|``, ``FP = |P - G|``, ``FN = |G - P|`` and

- precision ``TP / (TP + FP)``, recall ``TP / (TP + FN)``, F1 ``2 TP / (2 TP + FP + FN)`` (the same as
  ``2 P R / (P + R)`` where ``P + R > 0``, and 0 where both are 0);
- an empty denominator scores **1**: RoboPianist computes every step with scikit-learn's
  ``precision_recall_fscore_support(average="binary", zero_division=1)`` (Zakka et al. 2023,
  ``robopianist/wrappers/evaluation.py``, ``MidiEvaluationWrapper._compute_key_press_metrics``). So a step
  with no goal key and no key pressed (a rest played as a rest) scores P = R = F1 = 1; no goal key but a key
  pressed scores P = 0, R = 1, F1 = 0; goal keys with none pressed score P = 1, R = 0, F1 = 0.

Over an episode there are two aggregations (``episode_scores`` gives both):

- **step mean** (``precision``, ``recall``, ``f1``): the mean over the episode's steps of the per-step
  values. This is the figure RoboPianist reports (``np.mean`` of the per-step values; an episode ended early
  counts only the steps it ran). Rests played as rests count 1, so songs with many rests score higher.
- **pooled** (``*_pooled``): TP, FP and FN summed over the steps, then divided (a micro average, as
  frame-level transcription metrics are pooled); a rest counts only through its false presses.
  ``0 / 0`` scores 1 here too (an episode of rests with nothing pressed).

The headline figure of this project is the step mean ``f1``, for comparison with RoboPianist's published
numbers; the pooled figures are reported beside it because rests do not inflate them.

**Per key colour** (``colour_counts``; ``keys`` of ``step_counts`` and ``episode_scores``): the same counts
restricted to a subset of the keys (``keyboard.black_keys`` and its complement): a goal key, a pressed key
and a miss count only where the key is in the subset. The per-colour recall is pooled (``TP / (TP + FN)`` of
the summed counts): most steps have no black goal key, so a step mean would be mostly empty steps scored 1.

**The song's window** (``song_window``): a run is scored over the song only, from its first note's start
to its last note's end (the control steps ``[first, stop)`` of the goal table as played, count-in included:
the first row with a goal key, and one past the last). The start-up hold, the count-in before the first
note and the final hold after the last are not scored: keys pressed while the arms settle are not the
song's. ``bar-deploy eval``, the run summary of ``bar-deploy --song`` and the piano roll of
``bar-deploy plot`` all score these steps. (The MJX env scores every step of its episodes: its figures are
training signals, not this one.)

Every function is plain array arithmetic (``array_namespace``): numpy in, numpy out; jax in, jax out, safe
under ``jit`` and ``vmap`` (no Python branch on a value, only on static shapes); ``song_window`` is
host-side numpy (it returns Python ints).
"""

from __future__ import annotations

from typing import NamedTuple

from bar_policy._array import Array, array_namespace

__all__ = [
    "ColourCounts",
    "Counts",
    "EpisodeScores",
    "Scores",
    "colour_counts",
    "episode_scores",
    "scores",
    "song_window",
    "step_counts",
    "step_scores",
]


class Counts(NamedTuple):
    """Key counts of a step (or summed over steps), integer arrays of one shape."""

    tp: Array
    """Keys pressed that are goal keys."""
    fp: Array
    """Keys pressed that are not goal keys."""
    fn: Array
    """Goal keys not pressed."""


class ColourCounts(NamedTuple):
    """Key counts of a step restricted to the black keys and to the white keys (``colour_counts``)."""

    black: Counts
    """Counts over the black keys only."""
    white: Counts
    """Counts over the white keys only."""


class Scores(NamedTuple):
    """Precision, recall and F1 in [0, 1], float arrays of one shape."""

    precision: Array
    recall: Array
    f1: Array


class EpisodeScores(NamedTuple):
    """An episode's scores, both aggregations (the module docstring); float arrays of the batch shape."""

    precision: Array
    """Mean over steps of the per-step precision (RoboPianist's)."""
    recall: Array
    """Mean over steps of the per-step recall (RoboPianist's)."""
    f1: Array
    """Mean over steps of the per-step F1 (RoboPianist's; the headline figure)."""
    precision_pooled: Array
    """Precision of the summed counts."""
    recall_pooled: Array
    """Recall of the summed counts."""
    f1_pooled: Array
    """F1 of the summed counts."""


def _keys(x: Array) -> Array:
    """Bool of a bool or 0/1 array (``songs.goal_keys`` is float32 0/1)."""
    return x > 0.5


def step_counts(pressed: Array, goal: Array, keys: Array | None = None) -> Counts:
    """TP, FP and FN of each step, over every key or over the keys of ``keys``.

    Args:
        pressed: keys down, bool or 0/1, shape ``(..., n_keys)`` (keyboard order, lowest first).
        goal: goal keys, bool or 0/1, shape ``(..., n_keys)`` (broadcast against ``pressed``).
        keys: which keys count, bool or 0/1, shape ``(n_keys,)`` (default: all), e.g.
            ``keyboard.black_keys(config)``: a static mask, so the function stays jit- and vmap-safe.

    Returns:
        ``Counts`` of integer arrays, shape ``(...)`` (the broadcast batch shape).
    """
    if pressed.shape[-1:] != goal.shape[-1:]:
        raise ValueError(f"pressed {pressed.shape} and goal {goal.shape} must end in the same n_keys")
    if keys is not None and keys.shape != goal.shape[-1:]:
        raise ValueError(f"keys {keys.shape} must be (n_keys,) = {goal.shape[-1:]}")
    xp = array_namespace(pressed, goal)
    p, g = _keys(pressed), _keys(goal)
    if keys is not None:
        k = xp.asarray(_keys(keys))
        p, g = p & k, g & k
    return Counts(
        tp=xp.sum(p & g, axis=-1),
        fp=xp.sum(p & ~g, axis=-1),
        fn=xp.sum(~p & g, axis=-1),
    )


def colour_counts(pressed: Array, goal: Array, black: Array) -> ColourCounts:
    """TP, FP and FN of each step over the black keys and over the white keys (``step_counts``).

    Args:
        pressed: keys down, bool or 0/1, shape ``(..., n_keys)``.
        goal: goal keys, bool or 0/1, shape ``(..., n_keys)``.
        black: which keys are black, bool, shape ``(n_keys,)`` (``keyboard.black_keys(config)``).

    Returns:
        ``ColourCounts``; each count of shape ``(...)``. ``black + white`` is ``step_counts(pressed, goal)``.
    """
    xp = array_namespace(pressed, goal)
    b = xp.asarray(_keys(black))
    return ColourCounts(black=step_counts(pressed, goal, b), white=step_counts(pressed, goal, ~b))


def _ratio(num: Array, den: Array) -> Array:
    """``num / den``, and 1 where ``den`` is 0 (scikit-learn's ``zero_division=1``)."""
    xp = array_namespace(num, den)
    return xp.where(den > 0, num / xp.maximum(den, 1), 1.0)


def scores(counts: Counts) -> Scores:
    """Precision, recall and F1 of counts (one step's, or pooled), elementwise; ``0 / 0`` scores 1.

    ``F1 = 2 TP / (2 TP + FP + FN)``. Shapes: those of the counts.
    """
    tp, fp, fn = counts
    return Scores(_ratio(tp, tp + fp), _ratio(tp, tp + fn), _ratio(2 * tp, 2 * tp + fp + fn))


def step_scores(pressed: Array, goal: Array) -> Scores:
    """Per-step precision, recall and F1 (``scores(step_counts(pressed, goal))``), shape ``(...)``."""
    return scores(step_counts(pressed, goal))


def episode_scores(
    pressed: Array, goal: Array, valid: Array | None = None, keys: Array | None = None
) -> EpisodeScores:
    """Both episode aggregations of ``T`` steps (the module docstring), over every key or over ``keys``.

    Args:
        pressed: keys down per step, bool or 0/1, shape ``(..., T, n_keys)``.
        goal: goal keys per step, bool or 0/1, shape ``(..., T, n_keys)``.
        valid: which steps count, bool, shape ``(..., T)`` (default: all): a batch of episodes of different
            lengths (ended early, or padded) masks the steps after each one's end.
        keys: which keys count, bool, shape ``(n_keys,)`` (default: all; ``step_counts``): with
            ``keyboard.black_keys(config)``, ``recall_pooled`` is the black goal key-ticks' recall.

    Returns:
        ``EpisodeScores``, each of shape ``(...)``; NaN for an episode with no valid step.
    """
    xp = array_namespace(pressed, goal, *(() if valid is None else (valid,)))
    counts = step_counts(pressed, goal, keys)
    per_step = scores(counts)
    w = xp.ones(counts.tp.shape, dtype=bool) if valid is None else xp.broadcast_to(valid, counts.tp.shape)
    n = xp.sum(w, axis=-1)
    nan = float("nan")

    def mean(x: Array) -> Array:
        return xp.where(n > 0, xp.sum(xp.where(w, x, 0.0), axis=-1) / xp.maximum(n, 1), nan)

    pooled = scores(Counts(*(xp.sum(xp.where(w, c, 0), axis=-1) for c in counts)))
    return EpisodeScores(
        precision=mean(per_step.precision),
        recall=mean(per_step.recall),
        f1=mean(per_step.f1),
        precision_pooled=xp.where(n > 0, pooled.precision, nan),
        recall_pooled=xp.where(n > 0, pooled.recall, nan),
        f1_pooled=xp.where(n > 0, pooled.f1, nan),
    )


def song_window(goal: Array) -> tuple[int, int]:
    """The song's steps ``[first, stop)`` of a goal table: its first note's start to its last note's end.

    Args:
        goal: goal keys per control step, bool or 0/1, shape ``(T, n_keys)`` (a song as played:
            ``bank.song_bank``'s rows, count-in included).

    Returns:
        ``(first, stop)``: the first step with a goal key and one past the last (note ends are exclusive,
        as ``songs.goal_keys`` rounds them); ``(0, 0)`` for a table without a goal key (nothing is scored).
    """
    import numpy as np  # host-side: the window is a pair of Python ints

    rows = np.flatnonzero((np.asarray(goal) > 0.5).any(axis=-1))
    return (int(rows[0]), int(rows[-1]) + 1) if rows.size else (0, 0)
