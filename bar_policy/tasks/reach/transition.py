"""The command transition on the robot: a reach source's targets reach the policy along a minimum-jerk path.

The env moves the commanded target to each new target over ``ReachEnvConfig.target_transition_s``
(``bar_policy.tasks.reach.transition_point``); a file trained so carries the duration in
``bar.command_transition`` (``PolicyMetadata.command_transition_s``). ``TransitionCommands`` wraps any reach
source (sampled, file, stream) and applies the same path: whenever the source's value changes, the commanded
target starts a new move from where it is now to the new value. Before POLICY (the HOLD ramp) and at its
start (``begin``), the commanded target is ``initial`` (the fingertips of the default pose, where the ramp
leaves them), as after the env's reset. A stream that jumps is smoothed the same way, so a bad waypoint
never reaches the arm as a step.

The run log records what the policy saw (the commanded targets, under the source's names) and the source's
own values (``<name>_goal``): nothing is lost.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import CommandSource
from bar_policy.tasks.reach.shared import transition_point

if TYPE_CHECKING:
    from bar_policy.tasks.episodes import Policy

__all__ = ["TransitionCommands", "with_transition"]


class TransitionCommands(CommandSource):
    """A reach source whose value changes reach the policy along ``transition_point``'s path."""

    def __init__(self, inner: CommandSource, duration_s: float, initial: Mapping[str, np.ndarray]) -> None:
        """Wrap ``inner``.

        Args:
            inner: the source of the targets (its values are the goals).
            duration_s: length of each move, s (> 0; a file without a transition needs no wrapper).
            initial: the commanded targets before POLICY and at its start, one (3,) array per name, m.
        """
        if not duration_s > 0:
            raise ValueError(f"command transition must last > 0 s, got {duration_s}")
        missing = [n for n in inner.names if n not in initial]
        if missing:
            raise ValueError(f"initial targets lack {missing}; the source feeds {list(inner.names)}")
        self.inner = inner
        self.task = inner.task
        self.names = inner.names
        self.duration_s = float(duration_s)
        self._initial = {n: np.asarray(initial[n], dtype=np.float64).copy() for n in self.names}
        self._out = {n: v.copy() for n, v in self._initial.items()}
        self._from = dict(self._out)
        self._goal: dict[str, np.ndarray] | None = None
        self._t0: float | None = None
        self.moves = 0
        """New goals started (each a minimum-jerk move)."""

    @property
    def outside_count(self) -> int:  # type: ignore[override]
        """The inner source's count of targets outside the training workspace."""
        return self.inner.outside_count

    def begin(self, t: float) -> None:
        """POLICY starts at ``t`` s: the commanded targets restart at ``initial`` and move to the goals."""
        self.inner.begin(t)
        self._out = {n: v.copy() for n, v in self._initial.items()}
        self._goal = None
        self._t0 = t

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The commanded targets at run time ``t`` (s): one (3,) array per name, chest frame, m."""
        goal = self.inner(t)
        if self._t0 is None:  # called before POLICY (the HOLD ramp): the moves start from ``initial``
            self._t0 = t
        if self._goal is None or any(not np.array_equal(goal[n], self._goal[n]) for n in self.names):
            self._from = {n: v.copy() for n, v in self._out.items()}
            self._goal = {n: np.asarray(goal[n], dtype=np.float64).copy() for n in self.names}
            self._t0 = t
            self.moves += 1
        elapsed = t - self._t0
        self._out = {
            n: transition_point(self._from[n], self._goal[n], elapsed, self.duration_s) for n in self.names
        }
        return {n: v.copy() for n, v in self._out.items()}

    @property
    def log_fields(self) -> dict[str, tuple[tuple[int, ...], type]]:
        """The inner source's fields (the commanded targets) and ``<name>_goal`` per command name."""
        fields = dict(self.inner.log_fields)
        fields.update({f"{n}_goal": ((3,), np.float64) for n in self.names})
        return fields

    def record(self) -> dict[str, Any]:
        """The inner record with the commanded targets in place of the goals, and the goals beside them."""
        rec = dict(self.inner.record())
        if self._goal is not None:
            rec.update({n: v.copy() for n, v in self._out.items()})
            rec.update({f"{n}_goal": v.copy() for n, v in self._goal.items()})
        return rec

    def metadata(self) -> dict[str, Any]:
        """The inner source's description plus the transition's duration."""
        return {**self.inner.metadata(), "transition_s": self.duration_s}

    @property
    def hold_pose(self) -> np.ndarray | None:
        """The inner source's HOLD pose."""
        return self.inner.hold_pose

    @property
    def end_pose(self) -> np.ndarray | None:
        """The inner source's end pose."""
        return self.inner.end_pose

    def target_q(self) -> np.ndarray | None:
        """The inner source's reference (None for reach: chatter is measured on q_cmd itself)."""
        return self.inner.target_q()

    def finished(self, t: float) -> str | None:
        """The inner source's end."""
        return self.inner.finished(t)

    def describe(self) -> str:
        """One line for logs."""
        return f"{self.inner.describe()} with {self.duration_s:g} s minimum-jerk transitions"

    def close(self) -> None:
        """Close the inner source."""
        self.inner.close()

    def __getattr__(self, name: str) -> Any:
        """Other attributes (a stream's ``port``, ``messages``, ``bad_messages``) are the inner source's."""
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)


def with_transition(
    source: CommandSource, policy: Policy, initial: Mapping[str, np.ndarray]
) -> CommandSource:
    """``source`` in ``TransitionCommands`` when ``policy`` was trained with a transition, else itself.

    Args:
        source: the reach source.
        policy: the loaded policy (``metadata.command_transition_s``, s; 0 in files made before it).
        initial: the commanded targets at POLICY's start (the fingertips of the default pose), m.
    """
    duration = policy.metadata.command_transition_s
    return TransitionCommands(source, duration, initial) if duration > 0 else source
