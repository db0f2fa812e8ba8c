"""The piano evaluation's results: each song's counts and figures, its scored ticks, the run's report.

``SongResult`` holds one song's counts and means (RoboPianist's per-tick precision, recall and F1), its
safety and smoothness, its key source's disagreements and its goal key-ticks per key colour; ``PianoEval``
sums the songs into the headline F1, the ship gate's input, the JSON form and the printed lines;
``SongTicks`` hands a song's scored ticks, as arrays, to analyses beyond the means. The per-colour recall
(the MJX evaluation's ``recall_black`` / ``recall_white``): a song's or a run's four counts
(``COLOUR_COUNTS``: goal key-ticks of each colour pressed and missed, from ``metrics.colour_counts``) give
each colour's pooled recall ``tp / (tp + fn)``: 1 where the colour has no goal key-tick (``metrics.scores``'
``zero_division=1`` rule), written ``-`` in the printed line. numpy only: the deploy side imports it
without jax.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bar_policy.quality.report import EpisodeQuality, quality_summary_line, summarise
from bar_policy.tasks.interfaces import EvalReport
from bar_policy.tasks.piano.metrics import Counts, scores
from bar_policy.tasks.piano.songs import Song

__all__ = ["COLOUR_COUNTS", "PianoEval", "SongResult", "SongTicks", "colour_recalls", "colour_text"]

COLOUR_COUNTS = ("true_pos_black", "false_neg_black", "true_pos_white", "false_neg_white")
"""The per-colour counts (``SongResult``'s fields, the env's metrics of the same names)."""


def colour_recalls(c: Mapping[str, int]) -> dict[str, float]:
    """``{"recall_black": r, "recall_white": r}`` of the counts ``c``, pooled (1 for a colour with none)."""
    return {
        f"recall_{colour}": float(scores(Counts(c[f"true_pos_{colour}"], 0, c[f"false_neg_{colour}"])).recall)
        for colour in ("black", "white")
    }


def colour_text(c: Mapping[str, int]) -> str:
    """``recall of goal key-ticks (pooled): black 0.512 of 41, white 0.915 of 3145`` (``- of 0``: none)."""

    def one(tp: int, fn: int) -> str:
        return f"{tp / (tp + fn):.3f} of {tp + fn}" if tp + fn else "- of 0"

    black = one(c["true_pos_black"], c["false_neg_black"])
    white = one(c["true_pos_white"], c["false_neg_white"])
    return f"recall of goal key-ticks (pooled): black {black}, white {white}"


@dataclass(frozen=True)
class SongResult:
    """One song."""

    song: str
    ticks: int
    scored: int
    """Policy ticks scored: those of the song's window (``metrics.song_window``), first note to last end."""
    true_pos: int
    false_pos: int
    false_neg: int
    precision: float
    """Mean over the song's policy ticks of each tick's precision (RoboPianist's; ``metrics``)."""
    recall: float
    """Mean of each tick's recall."""
    f1: float
    """Mean of each tick's F1: the headline figure."""
    faulted: bool
    end_reason: str
    quality: dict[str, Any] = field(default_factory=dict)
    """The run's safety and smoothness (``EpisodeQuality.to_dict``); its chatter is against the reference."""
    chatter_raw_mrad: float | None = None
    """Chatter of ``q_cmd`` itself over the policy ticks, mrad (not gated; None: too short to measure)."""
    keys: str = "sim"
    """Where the policy's ``key_pressed`` came from (``evaluate.EVAL_KEY_SOURCES``)."""
    keys_extra: int = 0
    """Key-ticks (scored ticks x keys) the source read down while the simulated key was up."""
    keys_missed: int = 0
    """Key-ticks the simulated key was down and the source read up."""
    keys_down: int = 0
    """Key-ticks the simulated key was down (the scale of ``keys_missed``)."""
    group: str = "held-out"
    """The song set it belongs to: ``held-out`` (gated on F1, safety and smoothness) or ``random`` (the
    random songs of the bank's kind: gated on their per-colour recall; their F1 and faults reported)."""
    true_pos_black: int = 0
    """Black goal key-ticks pressed (``metrics.colour_counts``)."""
    false_neg_black: int = 0
    """Black goal key-ticks missed."""
    true_pos_white: int = 0
    """White goal key-ticks pressed."""
    false_neg_white: int = 0
    """White goal key-ticks missed."""
    hand_load_kg: tuple[float, float] | None = None
    """The hand-load compensation's estimate per hand (left, right) at the song's end, kg: the piano's
    ``tare`` reads it in the count-in and keeps it (docs/robustness.md); None when the compensation is off."""
    hand_load_motion_mrad: float | None = None
    """The largest joint excursion while the fit ran (``HandLoadEstimator.motion_rad``), mrad: an arm that
    moved into its pose in the tare's count-in leaves its friction in the read; None when off."""

    def colour_counts(self) -> dict[str, int]:
        """The song's ``COLOUR_COUNTS`` (TP and FN of each key colour's goal key-ticks)."""
        return {k: int(getattr(self, k)) for k in COLOUR_COUNTS}

    @property
    def chatter_mrad(self) -> float | None:
        """Chatter of ``q_cmd`` minus the key-pose reference, mrad (the gate's; None: not measured)."""
        return self.quality.get("chatter_mrad")

    @property
    def f1_pooled(self) -> float:
        """F1 of the counts summed over the song, ``2 tp / (2 tp + fp + fn)`` (1 when all are 0)."""
        return float(scores(Counts(self.true_pos, self.false_pos, self.false_neg)).f1)

    @property
    def recall_black(self) -> float:
        """Recall of the song's black goal key-ticks, pooled (``colour_recalls``: 1 when it has none)."""
        return colour_recalls(self.colour_counts())["recall_black"]

    @property
    def recall_white(self) -> float:
        """Recall of the song's white goal key-ticks, pooled (1 when it has none)."""
        return colour_recalls(self.colour_counts())["recall_white"]


@dataclass(frozen=True)
class SongTicks:
    """One song's scored ticks as arrays (``evaluate``'s ``on_song``).

    ``SongResult``'s counts are those of ``down`` against ``goal``.
    """

    song: Song
    """The song as given (its file's times; ``steps`` index it as played, after the count-in)."""
    steps: np.ndarray
    """int, shape (ticks,): each scored tick's song step (``SongCommands``'s ``song_step``)."""
    down: np.ndarray
    """bool, shape (ticks, n_keys): the simulated keys down (what is scored)."""
    goal: np.ndarray
    """bool, shape (ticks, n_keys): the goal keys of the tick's step."""
    count_in_s: float
    """The count-in the song was played with (``bank.PlaybackConfig``)."""


@dataclass(frozen=True)
class PianoEval(EvalReport):
    """Every song's counts and the overall F1."""

    songs: list[SongResult]
    policy: str
    fingerprint: str
    random_songs: str = ""
    """How the ``random`` group's songs were drawn (count, seed, tempos), for the printed lines."""
    arrangements: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    """Song name -> its arrangement (``arrange.Arrangement.to_dict``: tempo, hands, every note shortened) for
    the songs played arranged (a MIDI file, or ``--tempo``); the others are played as written."""
    target: str = "C MuJoCo sim target"
    """The songs' target (``EpisodeRunner.target_label``, or the class of the one given)."""

    def group(self, group: str = "held-out") -> list[SongResult]:
        """The songs of one group (``SongResult.group``)."""
        return [s for s in self.songs if s.group == group]

    def f1(self, group: str = "held-out") -> float:
        """The headline: the mean over the group's songs' ticks of each tick's F1 (RoboPianist's)."""
        songs = self.group(group)
        ticks = sum(s.scored for s in songs)
        return sum(s.f1 * s.scored for s in songs if s.scored) / ticks if ticks else float("nan")

    def f1_pooled(self, group: str = "held-out") -> float:
        """F1 of the counts summed over the group's songs."""
        songs = self.group(group)
        c = Counts(*(sum(getattr(s, k) for s in songs) for k in ("true_pos", "false_pos", "false_neg")))
        return float(scores(c).f1)

    def colour_totals(self, group: str = "held-out") -> dict[str, int]:
        """The group's songs' ``COLOUR_COUNTS`` (TP and FN of each key colour's goal key-ticks) summed."""
        return {k: sum(getattr(s, k) for s in self.group(group)) for k in COLOUR_COUNTS}

    def recall_pct(self) -> dict[str, float]:
        """The gate's recall rows (``gate.RECALL_GROUPS``): ``"<group> <colour> keys"`` -> pooled recall, %.

        Only groups with songs (``--random-songs 0`` plays none: its rows are then not measured).
        """
        out = {}
        for group in ("held-out", "random"):
            if self.group(group):
                for name, r in colour_recalls(self.colour_totals(group)).items():
                    out[f"{group} {name.removeprefix('recall_')} keys"] = 100.0 * r
        return out

    def gate_report(self) -> dict[str, Any]:
        """F1 % over the held-out songs, their safety and smoothness, the per-colour recalls (gate input).

        Safety and smoothness are the held-out songs' (the random songs' faults are reported, not gated).
        """
        records = [EpisodeQuality.from_dict(s.quality) for s in self.group() if s.quality]
        return {
            "task": "piano",
            "quality": summarise(records),
            "episodes": [r.to_dict() for r in records],
            "success_pct": 100.0 * self.f1(),
            "recall_pct": self.recall_pct(),
        }

    def random_line(self) -> str | None:
        """The random songs in one line (None without them).

        F1 (step mean over their ticks, and mean over songs), pooled F1, the per-colour recall, faults and
        ticks at a cap.
        """
        songs = self.group("random")
        if not songs:
            return None
        mean = float(np.mean([s.f1 for s in songs if s.scored])) if any(s.scored for s in songs) else math.nan
        faulted = sum(s.faulted for s in songs)
        caps = sum(int(s.quality.get("cap_ticks", 0)) for s in songs)
        return (
            f"random songs ({self.random_songs or len(songs)}): F1 {self.f1('random'):.3f} (step mean over "
            f"their ticks; mean over songs {mean:.3f}), pooled {self.f1_pooled('random'):.3f}; "
            f"{colour_text(self.colour_totals('random'))}; {faulted} faulted, {caps} ticks at a cap"
        )

    def raw_chatter_line(self) -> str:
        """The chatter of ``q_cmd`` itself over the held-out songs that completed (not gated), one line."""
        done = [s for s in self.group() if not s.faulted and s.chatter_raw_mrad is not None]
        if not done:
            return "chatter of q_cmd itself (not gated): n/a"
        worst = max(done, key=lambda s: s.chatter_raw_mrad or 0.0)
        mean = float(np.mean([s.chatter_raw_mrad for s in done]))
        return (
            f"chatter of q_cmd itself (not gated; the gate's is against the key-pose reference): "
            f"mean {mean:.2f} mrad, worst {worst.chatter_raw_mrad:.2f} mrad ({worst.song})"
        )

    def hand_load_line(self) -> str | None:
        """The hand-load estimate over every song in one line (None when no song had the compensation)."""
        fitted = [s for s in self.songs if s.hand_load_kg is not None]
        if not fitted:
            return None
        read = np.array([s.hand_load_kg for s in fitted])
        lo, hi = read.min(axis=0), read.max(axis=0)
        moved = [s.hand_load_motion_mrad for s in fitted if s.hand_load_motion_mrad is not None]
        motion = f"; the arm moved up to {max(moved):.1f} mrad while fitting" if moved else ""
        return (
            f"hand load read (left / right, kg): mean {read[:, 0].mean():.3f} / {read[:, 1].mean():.3f}, "
            f"range {lo[0]:.3f}..{hi[0]:.3f} / {lo[1]:.3f}..{hi[1]:.3f} over {len(read)} songs{motion}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON form (each song's ``chatter_mrad``, against the reference, beside ``chatter_raw_mrad``)."""
        return {
            "policy": self.policy,
            "target": self.target,
            "obs_fingerprint": self.fingerprint,
            "f1": self.f1(),
            "f1_pooled": self.f1_pooled(),
            **colour_recalls(self.colour_totals()),
            "random_songs": self.random_songs,
            "random": {
                "f1": self.f1("random"),
                "f1_pooled": self.f1_pooled("random"),
                **colour_recalls(self.colour_totals("random")),
            }
            if self.group("random")
            else None,
            "songs": [
                {
                    **asdict(s),
                    "f1_pooled": s.f1_pooled,
                    **colour_recalls(s.colour_counts()),
                    "chatter_mrad": s.chatter_mrad,
                    "arrangement": self.arrangements.get(s.song),
                }
                for s in self.songs
            ],
            "gate_report": self.gate_report(),
        }

    def format(self) -> str:
        """Summary lines: one per song, the totals, the quality line and the gate."""
        lines = [f"piano on the {self.target}: policy {self.policy} [{self.fingerprint}]"]
        keys = sorted({s.keys for s in self.songs} - {"sim"})
        if keys:
            lines.append(f"key_pressed from {', '.join(keys)}; scored against the simulated keys")
        for s in self.group():
            end = "faulted" if s.faulted else "completed"
            figs = (
                f"precision {s.precision:.3f} recall {s.recall:.3f} F1 {s.f1:.3f} (pooled {s.f1_pooled:.3f})"
            )
            lines.append(f"  {s.song:26s} {figs}, {s.scored} ticks, {end}, {_chatter_text(s)}")
            lines.append(f"    {colour_text(s.colour_counts())}")
            if s.keys != "sim":
                lines.append(
                    f"    key_pressed ({s.keys}) against the simulated keys: {s.keys_extra} key-ticks down "
                    f"extra, {s.keys_missed} of {s.keys_down} missed"
                )
        lines.append(
            f"held-out songs: F1 {self.f1():.3f} (step mean, RoboPianist's), pooled {self.f1_pooled():.3f}; "
            f"{colour_text(self.colour_totals())}"
        )
        random = self.random_line()
        if random is not None:
            lines.append(random)
        lines.append(quality_summary_line(self.gate_report()["quality"]))
        lines.append(self.raw_chatter_line())
        load = self.hand_load_line()
        if load is not None:
            lines.append(load)
        lines.extend(self.gate_lines())
        return "\n".join(lines)


def _chatter_text(s: SongResult) -> str:
    """``chatter X mrad vs the key-pose reference (q_cmd itself Y)`` for one song's line."""

    def mrad(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.2f}"

    raw = mrad(s.chatter_raw_mrad)
    return f"chatter {mrad(s.chatter_mrad)} mrad vs the key-pose reference (q_cmd itself {raw})"
