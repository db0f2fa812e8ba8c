"""Reach command sources: the base ``ReachSource`` (workspace check, run-log fields) and sampled targets.

The file and stream sources are ``command_file.py`` and ``command_stream.py``; the CLI's factory and the
formats are ``commands.py``.
"""

from __future__ import annotations

import abc
import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bar_policy._files import InputError, shorten
from bar_policy.tasks.interfaces import CommandSource
from bar_policy.tasks.reach.shared import ReachTargetConfig, sample_targets

__all__ = [
    "COMMAND_SIZES",
    "DEFAULT_RESAMPLE_PERIOD",
    "CommandError",
    "ReachSource",
    "SampledCommands",
]

log = logging.getLogger("bar_policy.deploy.commands")  # the command sources' logger, as before the move

DEFAULT_RESAMPLE_PERIOD = 2.5
"""Resampling period of ``sampled`` targets, s (the env's ``ReachEnvConfig.resample_period_s``)."""

COMMAND_SIZES: dict[str, int] = {"target_pos_left": 3, "target_pos_right": 3}
"""Command terms a source can feed, with their sizes."""


class CommandError(InputError):
    """A command source is misconfigured or its input is malformed.

    ``FileCommands`` raises only this for a malformed file (empty, truncated, not UTF-8, invalid or too
    deeply nested JSON, wrong keys, types or shapes), naming the file; echoed values are cut to
    ``_files.ECHO_LIMIT`` characters.
    """


def _check_names(names: tuple[str, ...]) -> None:
    unknown = [n for n in names if n not in COMMAND_SIZES]
    if unknown:
        raise CommandError(f"no command source can feed terms {unknown}; known: {sorted(COMMAND_SIZES)}")


def _vector(name: str, value: Any, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CommandError(
            f"{where}: {name} must be a list of {COMMAND_SIZES[name]} numbers, got {shorten(repr(value))}"
        ) from None
    if v.shape != (COMMAND_SIZES[name],):
        raise CommandError(f"{where}: {name} must have {COMMAND_SIZES[name]} numbers, got shape {v.shape}")
    if not np.isfinite(v).all():
        raise CommandError(f"{where}: {name} has non-finite values {v.tolist()}")
    return v


class ReachSource(CommandSource):
    """Feeds the reach targets (a subset of ``COMMAND_SIZES``), one dict per control tick."""

    task = "reach"

    def __init__(self, names: tuple[str, ...], workspace: ReachTargetConfig | None = None) -> None:
        _check_names(tuple(names))
        self.names = tuple(names)
        self.workspace = workspace or ReachTargetConfig()
        self.outside_count = 0
        """Targets seen outside the training workspace (not clipped)."""
        self._warned_outside = False
        self._last: dict[str, np.ndarray] = {}
        lo, hi = self.workspace.low, self.workspace.high
        mirror = np.array([1.0, -1.0, 1.0])
        right = (np.minimum(lo * mirror, hi * mirror) - 1e-9, np.maximum(lo * mirror, hi * mirror) + 1e-9)
        self._boxes = {n: (lo - 1e-9, hi + 1e-9) if n == "target_pos_left" else right for n in self.names}

    @abc.abstractmethod
    def _values(self, t: float) -> dict[str, np.ndarray]:
        """The commands at run time ``t``."""

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The commands at run time ``t`` (s): one array per name, shape (3,), chest frame, m."""
        values = self._values(t)
        self._check_workspace(values)
        self._last = values
        return values

    @property
    def log_fields(self) -> dict[str, tuple[tuple[int, ...], type]]:
        """Every target, each tick: name -> ((3,), float64)."""
        return {n: ((COMMAND_SIZES[n],), np.float64) for n in self.names}

    def record(self) -> dict[str, np.ndarray]:
        """The targets of the last call."""
        return dict(self._last)

    def _check_workspace(self, values: Mapping[str, np.ndarray]) -> None:
        for name, v in values.items():
            lo, hi = self._boxes[name]
            if (v < lo).any() or (v > hi).any():
                self.outside_count += 1
                if not self._warned_outside:
                    self._warned_outside = True
                    log.warning(
                        "%s %s is outside the training workspace [%s, %s]; used as is (further ones counted)",
                        name,
                        np.round(v, 4).tolist(),
                        np.round(lo, 3).tolist(),
                        np.round(hi, 3).tolist(),
                    )


class SampledCommands(ReachSource):
    """Targets drawn like training's, resampled every ``period`` s, from a seeded generator."""

    def __init__(
        self,
        names: tuple[str, ...],
        *,
        seed: int = 0,
        period: float = DEFAULT_RESAMPLE_PERIOD,
        workspace: ReachTargetConfig | None = None,
    ) -> None:
        super().__init__(names, workspace)
        if not (math.isfinite(period) and period > 0):
            raise CommandError(f"resample period must be > 0 s, got {period}")
        self.seed = seed
        self.period = period
        self._rng = np.random.default_rng(seed)
        self._index = -1
        self._current: dict[str, np.ndarray] = {}

    def _values(self, t: float) -> dict[str, np.ndarray]:
        k = max(math.floor(t / self.period + 1e-9), 0)
        while self._index < k:  # draw every period in order, so the sequence depends on the seed only
            left, right = sample_targets(self._rng.random(6), self.workspace)
            self._current = {"target_pos_left": left, "target_pos_right": right}
            self._index += 1
        return {n: self._current[n].copy() for n in self.names}

    def describe(self) -> str:
        """One line for logs."""
        return f"sampled(seed={self.seed}, period={self.period:g} s)"
