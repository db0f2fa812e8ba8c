"""The piano roll of a run: the goal keys against the keys down, per policy tick (``bar-deploy plot``).

The title's figures are those of the run summary and ``bar-deploy eval``: the ticks that ran the policy
(the log's ``mode``) and lie in the song's window (``metrics.song_window``, the log's
``song_window_steps``: its first note's start to its last note's end), scored by ``tally.KeyTally``. The
start-up hold and the final hold are drawn, between dashed lines, but not scored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.tasks.piano.keyboard import black_keys, compact_config, note_name
from bar_policy.tasks.piano.metrics import song_window
from bar_policy.tasks.piano.tally import KeyTally

__all__ = ["piano_roll", "roll_tally"]


def roll_tally(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> KeyTally:
    """The logged ticks a run scores, as the run summary scores them (module docstring).

    ``arrays``: the log's ``goal_keys`` and ``keys_down`` (bool, (ticks, n_keys)), ``song_step`` (int,
    (ticks,)) and ``mode`` (int, (ticks,); without it every tick counts as POLICY). ``meta``: the run's
    metadata; its ``command_source.song_window_steps`` is the window (a log without it: the window of the
    logged goal rows, by song step) and ``mode_names.POLICY`` the mode's value.
    """
    goal = np.asarray(arrays["goal_keys"], bool)
    down = np.asarray(arrays["keys_down"], bool)
    steps = np.asarray(arrays.get("song_step", np.arange(len(goal))), int).reshape(-1)
    source = meta.get("command_source") if isinstance(meta.get("command_source"), dict) else {}
    window = source.get("song_window_steps")
    if window is None:  # the logged goal rows by song step (every step of the song is logged once or more)
        rows = np.zeros((int(steps.max(initial=-1)) + 1, goal.shape[1]), bool)
        rows[steps] |= goal
        window = song_window(rows)
    policy = (meta.get("mode_names") or {}).get("POLICY")
    mode = arrays.get("mode")
    in_policy = (
        np.ones(len(goal), bool) if policy is None or mode is None else np.asarray(mode).reshape(-1) == policy
    )
    tally = KeyTally(black_keys(compact_config()), (int(window[0]), int(window[1])))
    for i in np.flatnonzero(in_policy):
        tally.add(int(steps[i]), down[i], goal[i])
    return tally


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
    tally = roll_tally(arrays, meta)
    source = meta.get("command_source") if isinstance(meta.get("command_source"), dict) else {}
    song = source.get("song", "?")
    if tally.ticks:
        _, _, f1 = tally.means()
        scored = np.isin(np.asarray(arrays.get("song_step", np.arange(len(t))), int).reshape(-1), tally.steps)
        for edge in (t[scored].min(), t[scored].max()):
            ax.axvline(float(edge), color="k", linestyle="--", linewidth=0.8)
        figure = f"F1 {f1:.3f} over the song's {tally.ticks} ticks (between the dashed lines)"
    else:
        figure = "no tick of the song scored"
    ax.set_title(f"piano roll - {song}: goal grey, hit green, wrong red; {figure}", fontsize=9)
    path = out / "piano_roll.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return [path]
