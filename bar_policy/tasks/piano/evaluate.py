"""``bar-deploy eval`` for piano policies: each song on the C MuJoCo sim target, scored as RoboPianist does.

Each song runs from the held default pose (``held.held_pose``, as the env starts), with the policy from
the first tick (no ramp), through the deploy code path (the runner ``bar-deploy eval`` hands in,
``tasks.episodes.EpisodeRunner``: ``Runtime``, the safety supervisor, the firmware MIT law in the sim), in
the keyboard's scene with the simulated keys, each song with the env's count-in (``bank.PlaybackConfig``).
At every policy tick the goal keys of the song's step are compared with the keys down
(``SongCommands.goal_now``, ``keys_down``): true positives, false positives and false negatives give each
tick's precision, recall and F1 (``metrics``; the count-in's ticks and those after the last note included,
as the env counts every step: each such tick with no key down scores 1, which the pooled F1 ignores). A
song's figures are the means over its ticks (RoboPianist's), with the F1 of the summed counts beside them
(pooled), and the recall of its black and of its white goal key-ticks (pooled, as the MJX evaluation's
``recall_black`` / ``recall_white``; 1 in the JSON, ``-`` in the lines, for a song without a goal key of
that colour). The ship gate reads the mean F1 over every song's ticks (``success_pct`` = 100 x F1) and the
songs' safety and smoothness.

Chatter: the gate's is measured on ``q_cmd`` minus the song's key-pose reference (``reference.py``: the
key-pose prior's command for the tick's goal keys, through the policy's action filter; the source's
``target_q``), as the tracker's is on ``q_cmd`` minus its clip. The key-pose prior alone (a zero MLP)
commands the reference exactly and scores ~0; on ``q_cmd`` itself it scores 6-10 mrad, its keystrokes'
harmonics at 5-8 Hz. Each song's line also prints the chatter of ``q_cmd`` itself (``chatter_raw_mrad``,
not gated; both in ``--json``), and a line after the quality line gives its worst and mean over the
songs that completed (docs/piano.md, "Chatter against the key-pose reference").

Key sources (``keys``, ``bar-deploy eval --keys``): the policy's ``key_pressed`` comes from ``sim`` (the
simulated keys, the default), ``kinematic`` (the fingertips' forward kinematics of the measured q, what the
mock and real targets use without a keyboard) or ``sim-midi`` (the simulated keys' presses and releases
turned into ``mido`` note messages and fed in memory to ``MidiKeys``: the MIDI path end to end, without a
port). The score always counts the simulated keys, the keys that really went down (``SongCommands``'s
``truth``); each song also counts the ticks' keys where the source and the simulated keys disagree.
"""

from __future__ import annotations

import math
import queue
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bar_policy.quality.metrics import chatter_mrad
from bar_policy.quality.report import EpisodeQuality, quality_summary_line, summarise
from bar_policy.tasks.episodes import EpisodeRunner, Policy
from bar_policy.tasks.interfaces import EvalReport
from bar_policy.tasks.piano import colour
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.key_input import KeySource, MidiKeys, SimKeys
from bar_policy.tasks.piano.keyboard import KeyboardConfig, black_keys, compact_config
from bar_policy.tasks.piano.keys import KinematicKeys
from bar_policy.tasks.piano.metrics import Counts, colour_counts, episode_scores, scores, step_counts
from bar_policy.tasks.piano.reference import KeyPoseReference
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.songs import Song
from bar_policy.tasks.piano.source import END_HOLD_S, SongCommands, sim_keys

__all__ = ["EVAL_KEY_SOURCES", "PianoEval", "SimMidiKeys", "SongResult", "SongTicks", "evaluate"]

EVAL_KEY_SOURCES = ("sim", "kinematic", "sim-midi")
"""Where the policy's ``key_pressed`` can come from in the evaluation (module docstring)."""


class SimMidiKeys(MidiKeys):
    """The simulated keys played into ``MidiKeys`` as ``mido`` note messages, in memory.

    Each ``read`` turns the simulated keys' changes since the previous read into ``note_on`` (velocity 64) and
    ``note_off`` messages, queues them and reads them back through ``MidiKeys``, so the notes' numbering, the
    latch and the message handling are those of a MIDI keyboard. A change is seen at a control tick: a tap
    shorter than a tick between two reads is not sent.
    """

    def __init__(self, sim: SimKeys, config: KeyboardConfig) -> None:
        """``sim``: the simulated keys of the sim target, on ``config``."""
        import mido  # a deploy extra, imported when this source is asked for

        self._queue: queue.Queue = queue.Queue()
        super().__init__(self._queue, config)
        self._message = mido.Message
        self._sim = sim
        self._was = np.zeros(self.n_keys, bool)

    def read(self, t_s: float) -> np.ndarray:
        """Send the simulated keys' presses and releases since the last read, then read them as MIDI."""
        now = self._sim.read(t_s)
        for i in np.flatnonzero(now != self._was):
            note = self.config.lowest + int(i)
            kind = "note_on" if now[i] else "note_off"
            self._queue.put(self._message(kind, note=note, velocity=64 if now[i] else 0))
        self._was = now
        return super().read(t_s)


@dataclass(frozen=True)
class SongResult:
    """One song."""

    song: str
    ticks: int
    scored: int
    """Policy ticks scored (the hold after the song is not)."""
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
    """Where the policy's ``key_pressed`` came from (``EVAL_KEY_SOURCES``)."""
    keys_extra: int = 0
    """Key-ticks (scored ticks x keys) the source read down while the simulated key was up."""
    keys_missed: int = 0
    """Key-ticks the simulated key was down and the source read up."""
    keys_down: int = 0
    """Key-ticks the simulated key was down (the scale of ``keys_missed``)."""
    true_pos_black: int = 0
    """Black goal key-ticks pressed (``metrics.colour_counts``)."""
    false_neg_black: int = 0
    """Black goal key-ticks missed."""
    true_pos_white: int = 0
    """White goal key-ticks pressed."""
    false_neg_white: int = 0
    """White goal key-ticks missed."""

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
        """Recall of the song's black goal key-ticks, pooled (``colour.recalls``: 1 when it has none)."""
        return colour.recalls(colour.counts_of(self))["recall_black"]

    @property
    def recall_white(self) -> float:
        """Recall of the song's white goal key-ticks, pooled (1 when it has none)."""
        return colour.recalls(colour.counts_of(self))["recall_white"]


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

    def f1(self) -> float:
        """The headline: the mean over every song's ticks of each tick's F1 (RoboPianist's)."""
        ticks = sum(s.scored for s in self.songs)
        return sum(s.f1 * s.scored for s in self.songs) / ticks if ticks else float("nan")

    def f1_pooled(self) -> float:
        """F1 of the counts summed over every song."""
        c = Counts(*(sum(getattr(s, k) for s in self.songs) for k in ("true_pos", "false_pos", "false_neg")))
        return float(scores(c).f1)

    def colour_totals(self) -> dict[str, int]:
        """Every song's ``colour.COLOUR_COUNTS`` (TP and FN of each key colour's goal key-ticks) summed."""
        return {k: sum(getattr(s, k) for s in self.songs) for k in colour.COLOUR_COUNTS}

    def gate_report(self) -> dict[str, Any]:
        """F1 % over the songs, and their safety and smoothness (the ship gate's input)."""
        records = [EpisodeQuality.from_dict(s.quality) for s in self.songs if s.quality]
        return {
            "task": "piano",
            "quality": summarise(records),
            "episodes": [r.to_dict() for r in records],
            "success_pct": 100.0 * self.f1(),
        }

    def raw_chatter_line(self) -> str:
        """The chatter of ``q_cmd`` itself over the songs that completed (not gated), one line."""
        done = [s for s in self.songs if not s.faulted and s.chatter_raw_mrad is not None]
        if not done:
            return "chatter of q_cmd itself (not gated): n/a"
        worst = max(done, key=lambda s: s.chatter_raw_mrad or 0.0)
        mean = float(np.mean([s.chatter_raw_mrad for s in done]))
        return (
            f"chatter of q_cmd itself (not gated; the gate's is against the key-pose reference): "
            f"mean {mean:.2f} mrad, worst {worst.chatter_raw_mrad:.2f} mrad ({worst.song})"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON form (each song's ``chatter_mrad``, against the reference, beside ``chatter_raw_mrad``)."""
        return {
            "policy": self.policy,
            "obs_fingerprint": self.fingerprint,
            "f1": self.f1(),
            "f1_pooled": self.f1_pooled(),
            **colour.recalls(self.colour_totals()),
            "songs": [
                {
                    **asdict(s),
                    "f1_pooled": s.f1_pooled,
                    **colour.recalls(colour.counts_of(s)),
                    "chatter_mrad": s.chatter_mrad,
                }
                for s in self.songs
            ],
            "gate_report": self.gate_report(),
        }

    def format(self) -> str:
        """Summary lines: one per song, the totals, the quality line and the gate."""
        lines = [f"piano on the C MuJoCo sim target: policy {self.policy} [{self.fingerprint}]"]
        keys = sorted({s.keys for s in self.songs} - {"sim"})
        if keys:
            lines.append(f"key_pressed from {', '.join(keys)}; scored against the simulated keys")
        for s in self.songs:
            end = "faulted" if s.faulted else "completed"
            figs = (
                f"precision {s.precision:.3f} recall {s.recall:.3f} F1 {s.f1:.3f} (pooled {s.f1_pooled:.3f})"
            )
            lines.append(f"  {s.song:26s} {figs}, {s.scored} ticks, {end}, {_chatter_text(s)}")
            lines.append(f"    {colour.text(colour.counts_of(s))}")
            if s.keys != "sim":
                lines.append(
                    f"    key_pressed ({s.keys}) against the simulated keys: {s.keys_extra} key-ticks down "
                    f"extra, {s.keys_missed} of {s.keys_down} missed"
                )
        lines.append(
            f"all songs: F1 {self.f1():.3f} (step mean, RoboPianist's), pooled {self.f1_pooled():.3f}; "
            f"{colour.text(self.colour_totals())}"
        )
        lines.append(quality_summary_line(self.gate_report()["quality"]))
        lines.append(self.raw_chatter_line())
        lines.extend(self.gate_lines())
        return "\n".join(lines)


def evaluate(
    policy: Policy,
    songs: list[Song],
    target: Any = None,
    *,
    runner: EpisodeRunner,
    playback: PlaybackConfig | None = None,
    keys: str = "sim",
    on_song: Callable[[SongResult, SongTicks], None] | None = None,
) -> PianoEval:
    """Play each song once on ``target`` (default: ``runner``'s in the keyboard's scene; module docstring).

    ``playback``: the count-in (default ``PlaybackConfig()``, the env's and ``bar-deploy``'s). ``keys``: where
    the policy's ``key_pressed`` comes from, one of ``EVAL_KEY_SOURCES`` (the score counts the simulated
    keys whatever it is). ``on_song``: called after each song with its result and its scored ticks as arrays
    (``SongTicks``), for analyses beyond the means. Raises ``ValueError`` for another ``keys``, naming the
    valid ones.
    """
    if keys not in EVAL_KEY_SOURCES:
        raise ValueError(f"keys = {keys!r}; valid: {', '.join(EVAL_KEY_SOURCES)}")
    kb = compact_config()
    sim = target or runner.target(scene=keyboard_scene(kb))
    q0 = held_pose(policy.robot.pose("piano_ready"), policy.robot.mode)  # as the env starts
    reference = KeyPoseReference.for_policy(policy, kb)
    pb = PlaybackConfig() if playback is None else playback
    fingertips = None
    if keys == "kinematic":  # one model build for every song
        from bar_policy.robot.kinematics import Kinematics

        fingertips = Kinematics(policy.robot.mode).fingertips
    results = []
    for song in songs:
        sim.reset(q0)
        source, truth = _key_sources(keys, sim, kb, fingertips)
        commands = SongCommands(song, kb, policy.policy_dt, source, playback, reference, truth=truth)
        downs: list[np.ndarray] = []
        reads: list[np.ndarray] = []
        goals: list[np.ndarray] = []
        q_cmds: list[np.ndarray] = []
        steps: list[int] = []

        def score(
            k: int,
            t: float,
            rt: Any,
            c: SongCommands = commands,
            d: list = downs,
            r: list = reads,
            g: list = goals,
            qc: list = q_cmds,
            st: list = steps,
        ) -> None:
            if rt.safety.mode != runner.policy_mode:  # the hold after the song's end is not scored
                return
            d.append(c.scored_keys())  # the simulated keys, whatever fed key_pressed
            rec = c.record()
            r.append(rec["keys_down"])  # what fed key_pressed
            st.append(rec["song_step"])
            g.append(c.goal_now())
            qc.append(rt.last_command.q)  # the tick's q_cmd as the supervisor wrote it

        duration = commands.song_steps * policy.policy_dt + END_HOLD_S + 1.0
        res = runner.run(sim, commands, duration, on_tick=score)
        commands.close()
        down = np.array(downs, bool).reshape(-1, kb.n_keys)
        read = np.array(reads, bool).reshape(-1, kb.n_keys)
        goal = np.array(goals, bool).reshape(-1, kb.n_keys)
        counts = step_counts(down, goal)
        by_colour = colour_counts(down, goal, black_keys(kb))
        ep = episode_scores(down, goal)
        raw = chatter_mrad(np.array(q_cmds), policy.policy_dt) if q_cmds else math.nan
        result = SongResult(
            song=song.name,
            ticks=int(res.ticks),
            scored=len(downs),
            true_pos=int(np.sum(counts.tp)),
            false_pos=int(np.sum(counts.fp)),
            false_neg=int(np.sum(counts.fn)),
            precision=float(ep.precision),
            recall=float(ep.recall),
            f1=float(ep.f1),
            faulted=res.fault_count > 0,
            end_reason=res.end_reason,
            quality={**res.quality["episode"], "name": song.name},
            chatter_raw_mrad=_finite(raw),
            keys=keys,
            keys_extra=int(np.sum(read & ~down)),
            keys_missed=int(np.sum(down & ~read)),
            keys_down=int(np.sum(down)),
            true_pos_black=int(np.sum(by_colour.black.tp)),
            false_neg_black=int(np.sum(by_colour.black.fn)),
            true_pos_white=int(np.sum(by_colour.white.tp)),
            false_neg_white=int(np.sum(by_colour.white.fn)),
        )
        results.append(result)
        if on_song is not None:
            on_song(result, SongTicks(song, np.array(steps, int), down, goal, pb.count_in_s))
    return PianoEval(songs=results, policy=str(policy.path), fingerprint=policy.obs_manager.fingerprint)


def _key_sources(
    keys: str, sim: Any, kb: KeyboardConfig, fingertips: Callable[[np.ndarray], Any] | None
) -> tuple[KeySource | None, KeySource | None]:
    """The song's ``key_pressed`` source and the simulated keys it is scored against (``truth``).

    ``sim``: (None, None): the runtime attaches the simulated keys, which both feed and score. Otherwise the
    truth is the sim target's keys read as ``attach`` reads them (the hinge now), so the scores compare.
    ``fingertips``: the robot's forward kinematics, for ``kinematic`` (built once per evaluation).
    """
    if keys == "sim":
        return None, None
    truth = sim_keys(sim, kb)
    if keys == "sim-midi":  # its own reader: each SimKeys counts what it reads
        return SimMidiKeys(sim_keys(sim, kb), kb), truth
    assert fingertips is not None, "kinematic keys need the robot's fingertips"
    return KinematicKeys(kb, fingertips), truth


def _finite(x: float) -> float | None:
    """``x`` as a float, None for NaN (a window too short to measure)."""
    x = float(x)
    return None if np.isnan(x) else x


def _chatter_text(s: SongResult) -> str:
    """``chatter X mrad vs the key-pose reference (q_cmd itself Y)`` for one song's line."""

    def mrad(x: float | None) -> str:
        return "n/a" if x is None else f"{x:.2f}"

    raw = mrad(s.chatter_raw_mrad)
    return f"chatter {mrad(s.chatter_mrad)} mrad vs the key-pose reference (q_cmd itself {raw})"
