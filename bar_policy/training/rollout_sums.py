"""The training rollouts' logged sums, one layout for both backends, and their per-window figures.

Each control step of a training rollout adds one float vector (``step_sums``) whose columns
(``SumLayout.columns``) are: the reward, the success ratio's numerator and denominator, the episodes that
ended and their summed lengths, each reward term (``reward/<term>``, the env's scaled per-step terms), then
the numerator and denominator of each other ratio of the task's ``eval_ratios`` (reach: ``final_distance``).
The brax rollout scans them and sums over its steps, envs and devices; the rsl-rl env accumulates them on
the device (``RslRlVecEnv.take_stats()["window"]``). The host reads them once per window (a brax epoch, an
rsl-rl iteration) and ``window_metrics`` turns them into the record's figures (names: ``log_tags``).

The ratios are rates over sparse events: reach's success rate counts target-segment ends, one per 125
control steps of an env, and the envs reset together, so a window of 24 steps often holds none. A window
without one does not report 0 %: ``RatioWindow`` carries the events over to the next window that has some,
so each reported rate is over at least one whole batch of events.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["RatioWindow", "SumLayout", "step_sums", "sum_layout", "window_metrics"]

_FIXED = ("reward", "success_rate/num", "success_rate/den", "episodes", "episode_steps")


@dataclass(frozen=True)
class SumLayout:
    """The columns of the rollouts' sum vector (see the module docstring)."""

    terms: tuple[str, ...]
    """Reward term names (the env's ``reward_names``; metrics ``reward/<term>``)."""
    ratios: tuple[str, ...]
    """The task's ratios besides ``success_rate`` (``eval_ratios``' keys, in its order)."""

    @property
    def columns(self) -> tuple[str, ...]:
        """Column names, in order."""
        ratio_cols = tuple(f"{r}/{p}" for r in self.ratios for p in ("num", "den"))
        return (*_FIXED, *(f"reward/{t}" for t in self.terms), *ratio_cols)

    def named(self, sums: Any) -> dict[str, float]:
        """A host sum vector (``len(columns)``,) as ``{column: value}``."""
        values = np.asarray(sums, dtype=np.float64).reshape(-1)
        if values.shape[0] != len(self.columns):
            raise ValueError(f"sum vector of {values.shape[0]} columns, layout has {len(self.columns)}")
        return dict(zip(self.columns, (float(v) for v in values), strict=True))


def sum_layout(task: Any) -> SumLayout:
    """The layout for ``task`` (the unwrapped env), computed on the host without tracing.

    Terms: ``task.reward_names`` (none for an env without a reward table); ratios: the keys of
    ``eval_ratios`` applied to zero metrics named ``task.metric_keys`` (and the reward terms).
    """
    from bar_policy.envs.base import eval_ratios

    terms = tuple(getattr(task, "reward_names", ()))
    keys = (*getattr(task, "metric_keys", ()), *(f"reward/{t}" for t in terms))
    zeros = {k: np.zeros(()) for k in keys}
    ratios = tuple(k for k in eval_ratios(task, zeros) if k != "success_rate") if keys else ()
    return SumLayout(terms=terms, ratios=ratios)


def step_sums(layout: SumLayout, task: Any, state: Any) -> Any:
    """One control step's sums over the batch, shape ``(len(layout.columns),)`` float32 (jax, traceable).

    ``state``: the batched env state after the step (``metrics`` of shape (B,), ``done``, and the batch
    wrapper's ``info["steps"]``: the episode's step count, which on the ``done`` step is its length).
    """
    import jax.numpy as jnp

    from bar_policy.envs.base import eval_ratios

    ratios = eval_ratios(task, state.metrics)
    num, den = ratios["success_rate"]
    done = state.done
    cols = [state.reward.sum(), num.sum(), den.sum(), done.sum(), (done * state.info["steps"]).sum()]
    cols += [state.metrics[f"reward/{t}"].sum() for t in layout.terms]
    for r in layout.ratios:
        n, d = ratios[r]
        cols += [n.sum(), d.sum()]
    return jnp.stack([jnp.asarray(c, jnp.float32) for c in cols])


class RatioWindow:
    """A ratio over windows of sparse events: numerators and denominators carried until events arrive.

    ``add(num, den)`` adds one window's sums; ``take()`` returns the ratio over everything added since the
    last ratio it returned, when that holds an event (denominator > 0), and starts over; otherwise the
    sums are kept and it returns the last ratio (None before the first).
    """

    def __init__(self) -> None:
        self.num = 0.0
        self.den = 0.0
        self.last: float | None = None

    def add(self, num: float, den: float) -> None:
        """Add a window's numerator and denominator."""
        self.num += float(num)
        self.den += float(den)

    def take(self) -> float | None:
        """The ratio since the last one returned (see the class docstring)."""
        if self.den > 0:
            self.last = self.num / self.den
            self.num = self.den = 0.0
        return self.last


def window_metrics(
    sums: dict[str, float],
    steps: int,
    episode_length: int,
    ratios: dict[str, RatioWindow],
) -> dict[str, float]:
    """One window's figures from its named sums (``SumLayout.named``): the record's keys (``log_tags``).

    Args:
        sums: the window's column sums.
        steps: env steps in the window (every env's steps).
        episode_length: control steps per episode: per-step means times it are per-episode figures.
        ratios: one ``RatioWindow`` per ratio name (created here on first use), kept across windows.

    Returns:
        ``episode_reward`` and each ``reward/<term>`` (mean per env step x ``episode_length``), each ratio
        (``RatioWindow.take``; absent until its first event), ``episode_length`` (the mean length of the
        episodes that ended, absent when none did).
    """
    steps = max(steps, 1)
    out = {"episode_reward": sums["reward"] * episode_length / steps}
    for k, v in sums.items():
        if k.startswith("reward/"):
            out[k] = v * episode_length / steps
    names = [k[: -len("/num")] for k in sums if k.endswith("/num")]
    for name in names:
        window = ratios.setdefault(name, RatioWindow())
        window.add(sums[f"{name}/num"], sums[f"{name}/den"])
        value = window.take()
        if value is not None:
            out[name] = value
    if sums["episodes"] > 0:
        out["episode_length"] = sums["episode_steps"] / sums["episodes"]
    return out
