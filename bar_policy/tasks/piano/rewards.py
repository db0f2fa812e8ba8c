"""Reward terms of the piano task: small pure functions, each a non-negative reward or cost.

As in ``bar_policy.envs.rewards`` the sign lives only in the weight (the task's ``reward.scales``: rewards
positive, costs negative). The terms follow RoboPianist (Zakka et al. 2023,
``robopianist/suite/tasks/piano_with_shadow_hands.py``), which uses dm_control's ``tolerance`` with a
Gaussian sigmoid (``tolerance`` here):

- ``goal_keys_pressed`` (reward, [0, 1]): for each goal key, ``tolerance(1 - depression)`` with full
  reward within ``KEY_CLOSE`` of the bottom, averaged over the goal keys; 0 at a step with no goal key
  (RoboPianist: 0.5 x this).
- ``wrong_keys_pressed`` (cost, a count): pressed keys that are not goal keys. RoboPianist takes the
  other 0.5 of its key reward away when *any* is pressed; a count also tells one wrong key from five.
- ``fingertip_to_goal`` (reward, [0, 1]): per hand, ``tolerance`` of the distance from its fingertip to
  the nearest of its goal keys' top sites, averaged over the hands that have one (RoboPianist's
  fingering reward, with one finger per hand); 0 when no hand has.
- ``energy`` (cost, W): ``sum |tau * dq|`` (RoboPianist: ``5e-3 x`` this).
- ``action_rate`` (cost): ``sum (a_t - a_{t-1})^2``, the same as ``bar_policy.envs.rewards.action_rate``
  (redefined here so numpy can call it: that module imports jax).

Every function is plain array arithmetic (``array_namespace``): numpy or jax, unbatched or with leading
batch axes, safe under ``jit`` and ``vmap``. ``angle_max`` is numpy (the keyboard's constants).
"""

from __future__ import annotations

import math

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy.tasks.piano.keyboard import KeyboardConfig, default_config, key_table

__all__ = [
    "FINGER_CLOSE",
    "FINGER_MARGIN",
    "KEY_CLOSE",
    "KEY_MARGIN",
    "VALUE_AT_MARGIN",
    "action_rate",
    "angle_max",
    "energy",
    "fingertip_distance",
    "fingertip_to_goal",
    "goal_keys_pressed",
    "key_depression",
    "next_goal",
    "tolerance",
    "wrong_keys_at_black_goal",
    "wrong_keys_pressed",
]

KEY_CLOSE = 0.05
"""A goal key within this fraction of its travel from the bottom scores 1 (RoboPianist's
``_KEY_CLOSE_ENOUGH_TO_PRESSED``)."""
KEY_MARGIN = 0.5
"""Fraction of travel beyond ``KEY_CLOSE`` at which a goal key scores ``VALUE_AT_MARGIN`` (RoboPianist:
``10 * KEY_CLOSE``). At the press threshold (half travel) a goal key scores ``0.1**0.81 = 0.155``."""
FINGER_CLOSE = 0.01
"""A fingertip within this distance of its goal key's top site scores 1, m (RoboPianist's
``_FINGER_CLOSE_ENOUGH_TO_KEY``). The fingertip sphere (6 mm) resting on the key is 6 mm away."""
FINGER_MARGIN = 0.1
"""Distance beyond ``FINGER_CLOSE`` at which a fingertip scores ``VALUE_AT_MARGIN``, m (RoboPianist:
``10 * FINGER_CLOSE``)."""
VALUE_AT_MARGIN = 0.1
"""``tolerance`` at ``margin`` outside the bounds (dm_control's default)."""


def tolerance(
    x: Array, lower: float, upper: float, margin: float, value_at_margin: float = VALUE_AT_MARGIN
) -> Array:
    """dm_control's ``tolerance`` with the Gaussian sigmoid: 1 inside ``[lower, upper]``, falling outside.

    Outside, with ``d`` the distance to the nearer bound over ``margin``:
    ``exp(-(d s)^2 / 2)``, ``s = sqrt(-2 ln value_at_margin)``, i.e. ``value_at_margin ** (d^2)``: 0.1 at
    ``d = 1``, 1e-4 at ``d = 2``; 0 at an infinite ``x``. Elementwise, the shape of ``x``; the bounds,
    ``margin`` and ``value_at_margin`` are Python floats (static under ``jit``).
    """
    if margin <= 0.0 or not 0.0 < value_at_margin < 1.0:
        raise ValueError(f"need margin > 0 and 0 < value_at_margin < 1; got {margin}, {value_at_margin}")
    xp = array_namespace(x)
    d = xp.where(x < lower, lower - x, x - upper) / margin
    scale = math.sqrt(-2.0 * math.log(value_at_margin))
    outside = xp.exp(-0.5 * (d * scale) ** 2)
    return xp.where((x >= lower) & (x <= upper), 1.0, outside)


def angle_max(config: KeyboardConfig | None = None) -> np.ndarray:
    """Each key's hinge angle at full travel, rad, shape (n_keys,) (keyboard order; numpy)."""
    cfg = default_config() if config is None else config
    return np.array([k.angle_max for k in key_table(cfg)])


def key_depression(angles: Array, full: Array) -> Array:
    """Fraction of its travel each key is down: ``clip(angle / angle_max, 0, 1)``, shape of ``angles``.

    ``angles``: key hinge angles, rad, ``(..., n_keys)`` (the ``piano_key*_angle`` sensors, or the keys'
    ``qpos``); ``full``: ``angle_max(config)``, rad, ``(n_keys,)``. MuJoCo's joint limits are soft, so an
    angle may pass them slightly: clipped (as RoboPianist does).
    """
    xp = array_namespace(angles, full)
    return xp.clip(angles / full, 0.0, 1.0)


def goal_keys_pressed(
    depression: Array, goal: Array, close: float = KEY_CLOSE, margin: float = KEY_MARGIN
) -> Array:
    """Reward in [0, 1]: mean over the goal keys of ``tolerance(1 - depression, 0, close, margin)``.

    Args:
        depression: ``key_depression``, in [0, 1], shape ``(..., n_keys)``.
        goal: goal keys now, bool or 0/1, shape ``(..., n_keys)`` (``songs.goal_keys(...)[t, 0]``).
        close: fraction of travel from the bottom that scores 1.
        margin: fraction of travel beyond ``close`` that scores ``VALUE_AT_MARGIN``.

    Returns:
        Shape ``(...)``; 0 at a step without a goal key (RoboPianist's).
    """
    xp = array_namespace(depression, goal)
    g = goal > 0.5
    per_key = tolerance(1.0 - depression, 0.0, close, margin)
    n = xp.sum(g, axis=-1)
    return xp.sum(xp.where(g, per_key, 0.0), axis=-1) / xp.maximum(n, 1)


def wrong_keys_pressed(pressed: Array, goal: Array) -> Array:
    """Cost: the number of pressed keys that are not goal keys, float, shape ``(...)``.

    ``pressed`` (``keyboard.pressed``) and ``goal``: bool or 0/1, shape ``(..., n_keys)``.
    """
    xp = array_namespace(pressed, goal)
    return xp.sum((pressed > 0.5) & ~(goal > 0.5), axis=-1) * 1.0


def wrong_keys_at_black_goal(pressed: Array, goal: Array, black_goal: Array) -> Array:
    """The wrong-key count (``wrong_keys_pressed``) at a step whose goal holds a black key, else 0, ``(...)``.

    ``pressed``, ``goal`` and ``black_goal`` (the goal's black keys): bool or 0/1, shape ``(..., n_keys)``.
    A second weight on it moves the wrong-key cost at black goals alone: pressing a black key between two
    raised white ones brushes neighbours more often than a white press does (docs/piano.md, "Black keys").
    """
    xp = array_namespace(pressed, goal, black_goal)
    any_black = xp.any(black_goal > 0.5, axis=-1)
    return xp.where(any_black, wrong_keys_pressed(pressed, goal), 0.0)


def deviation_at_black_goal(action: Array, reference: Array, black_goal: Array) -> Array:
    """Cost: ``sum((action - reference)^2)`` at a step whose goal holds a black key, else 0, ``(...)``.

    ``action``: the applied action, ``reference``: the key-pose reference's (the prior's action through the
    same filter), action units, shape ``(..., n)``; ``black_goal``: the goal's black keys, bool or 0/1,
    ``(..., n_keys)``. A residual trained on the prior gives up its black presses while it gains precision
    elsewhere (docs/piano.md, "What moves the trained residual"); a weight on this holds it near the prior
    where the black keys are played and leaves it free at every other step.
    """
    xp = array_namespace(action, reference, black_goal)
    return _deviation_where(xp.any(black_goal > 0.5, axis=-1), action, reference)


def deviation_at_rest(action: Array, reference: Array, hand_goal: Array) -> Array:
    """Cost: ``sum((action - reference)^2)`` at a step where neither hand has a goal key in view, else 0.

    ``action``, ``reference``: as ``deviation_at_black_goal``'s, ``(..., n)``; ``hand_goal``: each hand's
    next goal keys (``next_goal``), bool or 0/1, ``(..., 2, n_keys)``: all 0 in the count-in and in a rest
    longer than the view. The runtime's hand-load tare fits on the count-in's still ticks; a residual that
    moves the arm there under joint friction leaves a spring torque the fit reads as load
    (docs/robustness.md, "The count-in's residual and the tare"). A weight on this pulls the rest toward
    the prior; at -8 and -32 it left the count-in's motion at 25-28 mrad (43.8 without), the tare's
    misread in place (docs/robust_training.md).
    """
    xp = array_namespace(action, reference, hand_goal)
    return _deviation_where(~xp.any(hand_goal > 0.5, axis=(-2, -1)), action, reference)


def _deviation_where(mask: Array, action: Array, reference: Array) -> Array:
    """``sum((action - reference)^2)`` over the last axis where ``mask`` (bool ``(...)``), else 0."""
    xp = array_namespace(mask, action, reference)
    return xp.where(mask, xp.sum(xp.square(action - reference), axis=-1), 0.0)


def fingertip_distance(fingertips: Array, key_sites: Array, hand_goal: Array) -> Array:
    """Distance from each hand's fingertip to the nearest of that hand's goal keys, m; inf for none.

    Args:
        fingertips: fingertip site positions (left, right), m, shape ``(..., 2, 3)``.
        key_sites: the keys' top sites (``piano_key{m}_top``, moving with the key, or at rest:
            ``Key.site``), m, shape ``(..., n_keys, 3)`` or ``(n_keys, 3)``.
        hand_goal: each hand's goal keys, bool or 0/1, shape ``(..., 2, n_keys)`` (``next_goal`` of each
            hand's own goal window).

    Returns:
        Shape ``(..., 2)``.
    """
    xp = array_namespace(fingertips, key_sites, hand_goal)
    diff = fingertips[..., :, None, :] - key_sites[..., None, :, :]  # (..., 2, n_keys, 3)
    dist = xp.sqrt(xp.sum(diff * diff, axis=-1))
    return xp.min(xp.where(hand_goal > 0.5, dist, xp.inf), axis=-1)


def fingertip_to_goal(
    fingertips: Array,
    key_sites: Array,
    hand_goal: Array,
    close: float = FINGER_CLOSE,
    margin: float = FINGER_MARGIN,
) -> Array:
    """Reward in [0, 1]: ``tolerance(fingertip_distance, 0, close, margin)``, mean over hands with a goal.

    Arguments as ``fingertip_distance``; ``close`` and ``margin`` in m. Returns shape ``(...)``; 0 when
    neither hand has a goal key (RoboPianist's).
    """
    xp = array_namespace(fingertips, key_sites, hand_goal)
    has = xp.any(hand_goal > 0.5, axis=-1)  # (..., 2)
    per_hand = tolerance(fingertip_distance(fingertips, key_sites, hand_goal), 0.0, close, margin)
    return xp.sum(xp.where(has, per_hand, 0.0), axis=-1) / xp.maximum(xp.sum(has, axis=-1), 1)


def next_goal(window: Array) -> Array:
    """The keys of the first step of a goal window that has any: where a hand should be, or be heading.

    ``window``: one hand's goal keys now and ahead, bool or 0/1, shape ``(..., L + 1, n_keys)``
    (``songs.goal_keys`` of the hand's own notes). Returns bool ``(..., n_keys)``: row ``j`` of the window
    for the smallest ``j`` with a key down; all False when no key is down in the window.
    """
    xp = array_namespace(window)
    w = window > 0.5
    has = xp.any(w, axis=-1)  # (..., L + 1)
    first = xp.argmax(has, axis=-1)  # the first True (0 when none)
    pick = xp.arange(w.shape[-2]) == first[..., None]  # (..., L + 1)
    return xp.any(w & pick[..., None], axis=-2)


def energy(tau: Array, dq: Array) -> Array:
    """Cost: mechanical power ``sum |tau * dq|`` over joints, W.

    ``tau``: joint torques, N*m; ``dq``: joint velocities, rad/s; both ``(..., n_joints)``. Returns ``(...)``.
    """
    xp = array_namespace(tau, dq)
    return xp.sum(xp.abs(tau * dq), axis=-1)


def action_rate(action: Array, last_action: Array) -> Array:
    """Cost: ``sum (a_t - a_{t-1})^2`` over joints, action units (actions in [-1, 1]); shape ``(...)``."""
    xp = array_namespace(action, last_action)
    d = action - last_action
    return xp.sum(d * d, axis=-1)
