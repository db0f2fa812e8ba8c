"""A task's reward and termination terms as a table of rows, and the pure functions that evaluate it.

As mjlab's reward and termination managers read a task's ``RewardTermCfg`` / ``TerminationTermCfg``: each
task declares its terms in one table in its folder (``tasks/<task>/term_table.py``), one row per term
with its name, function, weight and parameters, and the robot env (``robot.py``) evaluates the table on
each control step and sums it. A row's function is a plain array function of named **signals**, the
step's quantities by name (the robot's, ``LiteRobotEnv.robot_signals``, and the task's,
``TaskStep.signals``): ``fn(*[signals[n] for n in inputs], **params)``.

The weights are the config's ``reward.scales.<name>`` (a table is built from the env's config on every
trace, ``TaskHooks.reward_terms``), so a program that takes the weights as an argument
(``envs.reward_weights.with_weights``) gets traced weights in its rows and one compiled program serves any
weights. A table lists exactly the config's weight fields, in their order (the env checks it when it is
built): the order is the summation order, so a reward is bit for bit the same as the sum written out.

Episode time-outs are the wrappers' (``episode_length``), not a termination term.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp

__all__ = ["RewardTerm", "TerminationTerm", "check_names", "reward_values", "terminated", "weighted_sum"]


@dataclass(frozen=True)
class RewardTerm:
    """One reward term: ``weight * fn(*signals[inputs], **params)`` per control step (not times dt).

    ``fn`` returns a non-negative scalar (a reward or a cost); the sign lives in ``weight``.
    """

    name: str
    """The term's name: the config's ``reward.scales`` field and the metric ``reward/<name>``."""
    fn: Callable[..., jax.Array]
    """The term's function (``envs.rewards`` or the task's own), pure, unbatched."""
    weight: Any
    """``config.reward.scales.<name>``: a float, or a traced scalar in a program that takes the weights."""
    inputs: tuple[str, ...] = ()
    """Names of the signals passed positionally to ``fn``, in its argument order."""
    params: Mapping[str, Any] = field(default_factory=dict)
    """Keyword constants of ``fn`` (length scales, radii, fractions: floats of the config)."""


@dataclass(frozen=True)
class TerminationTerm:
    """One termination: the episode ends on a step where ``fn(*signals[inputs], **params)`` is True."""

    name: str
    """The termination's name."""
    fn: Callable[..., jax.Array]
    """Boolean scalar function, pure, unbatched."""
    inputs: tuple[str, ...] = ()
    """Names of the signals passed positionally to ``fn``."""
    params: Mapping[str, Any] = field(default_factory=dict)
    """Keyword constants of ``fn``."""


def _call(kind: str, term: RewardTerm | TerminationTerm, signals: Mapping[str, jax.Array]) -> jax.Array:
    missing = [n for n in term.inputs if n not in signals]
    if missing:
        raise ValueError(f"{kind} term {term.name!r} needs signals {missing}; the step has {sorted(signals)}")
    return term.fn(*(signals[n] for n in term.inputs), **term.params)


def reward_values(terms: Sequence[RewardTerm], signals: Mapping[str, jax.Array]) -> dict[str, jax.Array]:
    """Each term's unweighted value, float32 scalar (a count or an indicator as its float), table order.

    Raises:
        ValueError: a term names a signal the step does not have (the term, the missing names and the
            step's signals in the message).
    """
    return {t.name: jnp.asarray(_call("reward", t, signals)).astype(jnp.float32) for t in terms}


def weighted_sum(
    terms: Sequence[RewardTerm], values: Mapping[str, jax.Array], valid: jax.Array | bool = True
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(reward, scaled)``: ``scaled[name] = weight * value`` (0 where not ``valid``), summed in table order.

    ``valid`` (boolean scalar): False zeroes every term (a non-finite physics state). The sum is Python's
    left fold from 0 over the table's order, the env's arithmetic before the table existed: a reward is
    the same float32 as ``((0 + s_1) + s_2) + ...`` written out.
    """
    scaled = {t.name: jnp.where(valid, values[t.name] * t.weight, 0.0) for t in terms}
    return sum(scaled.values()), scaled  # type: ignore[return-value]


def terminated(
    terms: Sequence[TerminationTerm], signals: Mapping[str, jax.Array]
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """``(end, fired)``: whether any termination fires (boolean scalar) and each one's own verdict.

    An empty table never ends an episode (``end`` is False).

    Raises:
        ValueError: a term names a signal the step does not have.
    """
    fired = {t.name: jnp.asarray(_call("termination", t, signals), dtype=bool) for t in terms}
    end = jnp.zeros((), bool)
    for v in fired.values():
        end = jnp.logical_or(end, v)
    return end, fired


def check_names(terms: Sequence[RewardTerm], names: Sequence[str], owner: str) -> None:
    """Raise unless the table's term names are ``names`` (the config's weight fields), in that order.

    Raises:
        ValueError: they differ (both lists in the message).
    """
    got = [t.name for t in terms]
    if got != list(names):
        raise ValueError(f"{owner}'s reward table lists {got}; its reward.scales fields are {list(names)}")
