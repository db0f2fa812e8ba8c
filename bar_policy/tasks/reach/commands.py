"""Reach command sources: where the reach task's command terms (the fingertip targets) come from at run time.

A source is called once per control tick with the run time ``t`` (s since the start) and returns one array
per command name (``target_pos_left``, ``target_pos_right``: shape (3,), chest frame, m). Nothing is
hard-coded in the runtime; the CLI picks a source with ``--commands``:

- ``sampled`` / ``sampled:PERIOD``: targets drawn like training's (``sample_targets`` on uniform variates),
  resampled every ``PERIOD`` s (default ``DEFAULT_RESAMPLE_PERIOD``), seeded.
- ``file:PATH``: a timed sequence, held from each entry's time to the next (zero-order hold; before the first
  entry the first is used, after the last the last is held). Formats:
  JSON ``[{"t": 0.0, "target_pos_left": [x, y, z], "target_pos_right": [x, y, z]}, ...]`` (or
  ``{"commands": [...]}``); CSV with a header ``t,<name>_x,<name>_y,<name>_z,...``; NPZ with ``t`` (K,) and
  one (K, 3) array per command name.
- ``stream:stdin`` / ``stream:udp:PORT``: JSON lines ``{"target_pos_left": [...], "target_pos_right": [...]}``
  (either key alone updates that target) from stdin, or UDP datagrams on 127.0.0.1:PORT (loopback only).
  Until the first message the targets are the ``initial`` values (the fingertips at the default pose); a bad
  line is logged and counted, and the previous targets stay.

Targets outside the training workspace are not clipped: each is counted and logged (first time per source).
Every source is a ``tasks.interfaces.CommandSource`` of task ``reach``; the run log records its targets each
tick.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping

import numpy as np

from bar_policy.tasks.interfaces import CommandSource
from bar_policy.tasks.reach.command_file import FileCommands
from bar_policy.tasks.reach.command_stream import StreamCommands
from bar_policy.tasks.reach.shared import ReachTargetConfig
from bar_policy.tasks.reach.sources import (
    COMMAND_SIZES,
    DEFAULT_RESAMPLE_PERIOD,
    CommandError,
    ReachSource,
    SampledCommands,
)

__all__ = [
    "COMMAND_SIZES",
    "DEFAULT_RESAMPLE_PERIOD",
    "CommandError",
    "CommandSource",
    "FileCommands",
    "ReachSource",
    "SampledCommands",
    "StreamCommands",
    "make_command_source",
]

_SPECS = "sampled, sampled:PERIOD, file:PATH, stream:stdin, stream:udp:PORT"


def make_command_source(
    spec: str,
    names: tuple[str, ...],
    *,
    seed: int = 0,
    initial: Mapping[str, np.ndarray] | None = None,
    workspace: ReachTargetConfig | None = None,
) -> ReachSource:
    """Build a source from a CLI spec.

    Specs: ``sampled[:PERIOD]``, ``file:PATH``, ``stream:stdin``, ``stream:udp:PORT``.

    Args:
        spec: the spec string.
        names: command term names of the policy's layout.
        seed: seed of ``sampled``.
        initial: targets before the first stream message (required for ``stream``).
        workspace: training target workspace (for ``sampled`` and the outside-workspace count).

    Raises:
        CommandError: naming the valid specs.
    """
    kind, _, rest = spec.partition(":")
    if kind == "sampled":
        if not rest:
            return SampledCommands(names, seed=seed, workspace=workspace)
        try:
            period = float(rest)
        except ValueError:
            raise CommandError(f"sampled:PERIOD needs a period in s, got {rest!r}") from None
        return SampledCommands(names, seed=seed, period=period, workspace=workspace)
    if kind == "file" and rest:
        return FileCommands(names, rest, workspace=workspace)
    if kind == "stream" and rest:
        if initial is None:
            raise CommandError("stream commands need initial targets")
        if rest == "stdin":
            return StreamCommands(names, initial, stdin=sys.stdin, workspace=workspace)
        sub, _, port = rest.partition(":")
        if sub == "udp":
            try:
                p = int(port)
            except ValueError:
                raise CommandError(f"stream:udp:PORT needs an integer port, got {port!r}") from None
            return StreamCommands(names, initial, udp_port=p, workspace=workspace)
    raise CommandError(f"unknown command source {spec!r}; valid: {_SPECS}")
