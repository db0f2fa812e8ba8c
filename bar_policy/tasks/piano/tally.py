"""A song run's scored ticks: the keys down against the goal keys, over the song's window only.

``SongCommands`` keeps one (``tally``) and adds a tick after every tick that ran the policy
(``CommandSource.after_policy_tick``: the runtime calls it when the tick ends in POLICY) whose song step
lies in the song's window (``metrics.song_window``: its first note's start to its last note's end; the
start-up hold, the count-in's silence and the final hold are not scored). ``bar-deploy eval`` reads its
figures for each song and the run's figure (``SongFigure``, which ``bar-deploy --song`` prints after its
``end:`` line) prints them (``lines``), so both count
the same ticks the same way; ``bar-deploy plot``'s piano roll scores the logged ticks of the same window
(``plot.py``). numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bar_policy.tasks.interfaces import RunFigure
from bar_policy.tasks.piano.metrics import Counts, colour_counts, episode_scores, scores, step_counts
from bar_policy.tasks.piano.results import colour_text

__all__ = ["KeyTally", "SongFigure"]


@dataclass
class KeyTally:
    """Keys down and goal keys of each scored tick (bool rows of ``n_keys``), and their figures."""

    black: np.ndarray
    """Which keys are black, bool, shape (n_keys,) (``keyboard.black_keys``)."""
    window: tuple[int, int]
    """The song's control steps ``[first, stop)`` (``metrics.song_window``), count-in included."""
    _down: list[np.ndarray] = field(default_factory=list)
    _goal: list[np.ndarray] = field(default_factory=list)
    _steps: list[int] = field(default_factory=list)

    def in_window(self, step: int) -> bool:
        """True for a song step of the window (a tick that is scored)."""
        return self.window[0] <= step < self.window[1]

    def add(self, step: int, down: np.ndarray, goal: np.ndarray) -> bool:
        """Score one tick at song step ``step`` if it lies in the window; True when it was added."""
        if not self.in_window(step):
            return False
        self._down.append(np.asarray(down, bool).copy())
        self._goal.append(np.asarray(goal, bool).copy())
        self._steps.append(int(step))
        return True

    # -- the ticks ---------------------------------------------------------------------------------
    @property
    def ticks(self) -> int:
        """Ticks scored."""
        return len(self._steps)

    @property
    def down(self) -> np.ndarray:
        """bool, shape (ticks, n_keys): the keys down at each scored tick."""
        return np.array(self._down, bool).reshape(-1, len(self.black))

    @property
    def goal(self) -> np.ndarray:
        """bool, shape (ticks, n_keys): the goal keys of each scored tick's step."""
        return np.array(self._goal, bool).reshape(-1, len(self.black))

    @property
    def steps(self) -> np.ndarray:
        """int, shape (ticks,): each scored tick's song step."""
        return np.array(self._steps, int)

    # -- the figures -------------------------------------------------------------------------------
    def counts(self) -> Counts:
        """TP, FP and FN summed over the scored ticks (Python ints)."""
        c = step_counts(self.down, self.goal)
        return Counts(int(np.sum(c.tp)), int(np.sum(c.fp)), int(np.sum(c.fn)))

    def colour(self) -> dict[str, int]:
        """``results.COLOUR_COUNTS``: the goal key-ticks of each colour pressed and missed."""
        c = colour_counts(self.down, self.goal, self.black)
        return {
            "true_pos_black": int(np.sum(c.black.tp)),
            "false_neg_black": int(np.sum(c.black.fn)),
            "true_pos_white": int(np.sum(c.white.tp)),
            "false_neg_white": int(np.sum(c.white.fn)),
        }

    def means(self) -> tuple[float, float, float]:
        """Precision, recall and F1, means over the scored ticks (RoboPianist's); NaN with none scored."""
        ep = episode_scores(self.down, self.goal)
        return float(ep.precision), float(ep.recall), float(ep.f1)

    def lines(self, name: str, dt: float) -> list[str]:
        """The run summary's lines: the song's window, precision, recall, F1 and the per-colour recall."""
        first, stop = self.window
        span = f"{first * dt:.2f}-{stop * dt:.2f} s"
        where = f"song {name!r} from its first note to its last note's end ({span})"
        if not self.ticks:
            return [f"{where}: no tick scored (the run ended before the song's first note)"]
        p, r, f1 = self.means()
        pooled = float(scores(self.counts()).f1)
        return [
            f"{where}: precision {p:.3f} recall {r:.3f} F1 {f1:.3f} (step means over {self.ticks} ticks; "
            f"pooled F1 {pooled:.3f})",
            f"  {colour_text(self.colour())}",
        ]


class SongFigure(RunFigure):
    """The piano's figure of a ``bar-deploy --song`` run: ``KeyTally.lines`` of the song's tally.

    The tally is fed by the runtime (``SongCommands.after_policy_tick``: the ticks that ended in POLICY,
    those ``bar-deploy eval`` scores), not by ``on_tick``, so the run and the evaluation count alike.
    """

    def __init__(self, tally: KeyTally, song: str, dt: float) -> None:
        """``tally``: the run's ``SongCommands.tally``; ``song``: its name; ``dt``: the control period, s."""
        self.tally = tally
        self.song = song
        self.dt = dt

    def on_tick(self, k: int, t: float, rt: object) -> None:
        """Nothing: the runtime feeds the tally (class docstring)."""

    def line(self) -> str:
        """``piano: song ...: precision, recall, F1`` and the per-colour recall on a second line."""
        first, *rest = self.tally.lines(self.song, self.dt)
        return "\n".join([f"piano: {first}", *rest])

    def to_dict(self) -> dict[str, object]:
        """The window (steps), ticks, means, pooled counts and per-colour counts."""
        p, r, f1 = self.tally.means() if self.tally.ticks else (float("nan"),) * 3
        return {
            "window_steps": list(self.tally.window),
            "ticks": self.tally.ticks,
            "precision": p,
            "recall": r,
            "f1": f1,
            "counts": dict(zip(("tp", "fp", "fn"), self.tally.counts(), strict=True)),
            **self.tally.colour(),
        }
