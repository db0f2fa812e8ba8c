"""Reward weights as a program's input: an env's ``config.reward.scales``, read out and put back.

A robot env weights its reward terms by ``config.reward.scales.<name>`` while it is traced: the task's
term table (``tasks/<task>/term_table.py``) is built from the env's config on every trace, each row's
weight read from those fields (``LiteRobotEnv.step_with_model``). Read from the config, the weights become
constants of every compiled program, so a run that changes one weight compiles every program again (a
cold start). With :func:`with_weights`, a program takes the weights as an argument instead. The env's
config is copied with the argument's traced values in place of the floats, and the reward arithmetic is
the same, so the program's code does not depend on the weights' values and a compiled program serves any
of them (``training.brax.programs``).

An env without ``config.reward.scales`` (the tests' toy env) has no weights: :func:`weights` is empty and
:func:`with_weights` returns the env itself.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["weights", "with_weights"]


def _scales(env: Any) -> Any | None:
    """``env.config.reward.scales`` (a dataclass of floats), or None when the env has none."""
    scales = getattr(getattr(getattr(env, "config", None), "reward", None), "scales", None)
    return scales if dataclasses.is_dataclass(scales) else None


def weights(env: Any) -> dict[str, np.float32]:
    """The env's reward weights by term name, in the config's field order, as float32 scalars.

    Empty for an env without ``config.reward.scales``.
    """
    scales = _scales(env)
    if scales is None:
        return {}
    return {f.name: np.float32(getattr(scales, f.name)) for f in dataclasses.fields(scales)}


def with_weights(env: Any, values: Mapping[str, Any]) -> Any:
    """A shallow copy of ``env`` whose ``config.reward.scales`` holds ``values`` (traced scalars or floats).

    ``values`` must name exactly the env's terms (:func:`weights`'s keys); an empty mapping for an env
    without weights returns ``env`` itself. Only the config is replaced: the env reads the weights from
    it at every step, and nothing it built from its config at construction depends on them.

    Raises:
        ValueError: ``values`` names other terms than the env's (both lists in the message).
    """
    scales = _scales(env)
    names = [] if scales is None else [f.name for f in dataclasses.fields(scales)]
    if sorted(values) != sorted(names):
        raise ValueError(
            f"reward weights {sorted(values)} do not match {type(env).__name__}'s terms {sorted(names)}"
        )
    if scales is None:
        return env
    cfg = env.config
    reward = dataclasses.replace(cfg.reward, scales=dataclasses.replace(scales, **dict(values)))
    out = copy.copy(env)
    out.config = dataclasses.replace(cfg, reward=reward)
    return out
