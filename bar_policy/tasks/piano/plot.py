"""The piano roll of a run: the goal keys against the keys down, per policy tick (``bar-deploy plot``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.tasks.piano.keyboard import compact_config, note_name

__all__ = ["piano_roll"]


def piano_roll(arrays: dict[str, np.ndarray], meta: dict[str, Any], out: Path) -> list[Path]:
    """``piano_roll.png``: goal keys (grey), keys down on a goal (green) and off one (red), over time.

    Needs the log's ``goal_keys`` and ``keys_down`` (``SongCommands``); nothing is drawn without them.
    """
    if "goal_keys" not in arrays or "keys_down" not in arrays:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    goal = np.asarray(arrays["goal_keys"], bool)
    down = np.asarray(arrays["keys_down"], bool)
    t = np.asarray(arrays["t"], np.float64)
    kb = compact_config()
    img = np.ones((goal.shape[1], goal.shape[0], 3))
    img[goal.T] = (0.75, 0.75, 0.75)
    img[(down & goal).T] = (0.1, 0.6, 0.1)
    img[(down & ~goal).T] = (0.85, 0.1, 0.1)
    fig, ax = plt.subplots(figsize=(10, 6))
    extent = (
        float(t[0]),
        float(t[-1]) if len(t) > 1 else float(t[0]) + 1.0,
        kb.lowest - 0.5,
        kb.highest + 0.5,
    )
    ax.imshow(img, aspect="auto", origin="lower", extent=extent, interpolation="nearest")
    ticks = [m for m in range(kb.lowest, kb.highest + 1) if m % 12 == 0]
    ax.set_yticks(ticks, [note_name(m) for m in ticks])
    ax.set_xlabel("t (s)")
    ax.set_ylabel("key")
    tp, fp, fn = int((down & goal).sum()), int((down & ~goal).sum()), int((~down & goal).sum())
    f1 = 2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 1.0
    song = (
        meta.get("command_source", {}).get("song", "?")
        if isinstance(meta.get("command_source"), dict)
        else "?"
    )
    ax.set_title(
        f"piano roll - {song}: goal grey, hit green, wrong red; F1 {f1:.3f} over the run", fontsize=9
    )
    path = out / "piano_roll.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return [path]
