"""``bar-deploy eval`` for piano policies: each song on the C MuJoCo sim target, scored as RoboPianist does.

Each song runs from the held default pose (``held.held_pose``, as the env starts), with the policy from
the first tick (no ramp), through the deploy code path (``Runtime``, the safety supervisor, the firmware
MIT law in the sim), in the keyboard's scene with the simulated keys. At every policy tick the goal keys of
the song's step are compared with the keys down (``SongCommands.goal_now``, ``keys_down``): true
positives, false positives and false negatives are summed over the song (ticks before the first and after
the last note included, as the env counts every step), giving precision ``tp / (tp + fp)``, recall
``tp / (tp + fn)`` and F1 ``2 tp / (2 tp + fp + fn)``. The ship gate reads the F1 over every song
(``success_pct`` = 100 x F1) and the songs' safety and smoothness (chatter on q_cmd itself: the piano has
no joint reference).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bar_policy.deploy.policy import OnnxPolicy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.safety_config import Mode
from bar_policy.deploy.targets.sim import SimConfig, SimTarget, training_damping
from bar_policy.quality.report import EpisodeQuality, quality_summary_line, summarise
from bar_policy.tasks.interfaces import EvalReport
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.songs import Song
from bar_policy.tasks.piano.source import END_HOLD_S, SongCommands

__all__ = ["PianoEval", "SongResult", "evaluate", "f1_of"]


def f1_of(tp: int, fp: int, fn: int) -> tuple[float, float, float]:
    """(precision, recall, F1) of summed counts; a ratio with a zero denominator is 1 (nothing to miss)."""
    p = tp / (tp + fp) if tp + fp else 1.0
    r = tp / (tp + fn) if tp + fn else 1.0
    f = 2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 1.0
    return p, r, f


@dataclass(frozen=True)
class SongResult:
    """One song."""

    song: str
    ticks: int
    true_pos: int
    false_pos: int
    false_neg: int
    faulted: bool
    end_reason: str
    quality: dict[str, Any] = field(default_factory=dict)
    """The run's safety and smoothness (``EpisodeQuality.to_dict``)."""

    @property
    def scores(self) -> tuple[float, float, float]:
        """(precision, recall, F1)."""
        return f1_of(self.true_pos, self.false_pos, self.false_neg)


@dataclass(frozen=True)
class PianoEval(EvalReport):
    """Every song's counts and the overall F1."""

    songs: list[SongResult]
    policy: str
    fingerprint: str

    def totals(self) -> tuple[float, float, float]:
        """(precision, recall, F1) of the counts summed over the songs."""
        return f1_of(
            *(sum(getattr(s, k) for s in self.songs) for k in ("true_pos", "false_pos", "false_neg"))
        )

    def gate_report(self) -> dict[str, Any]:
        """F1 % over the songs, and their safety and smoothness (the ship gate's input)."""
        records = [EpisodeQuality.from_dict(s.quality) for s in self.songs if s.quality]
        return {
            "task": "piano",
            "quality": summarise(records),
            "episodes": [r.to_dict() for r in records],
            "success_pct": 100.0 * self.totals()[2],
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        p, r, f = self.totals()
        return {
            "policy": self.policy,
            "obs_fingerprint": self.fingerprint,
            "precision": p,
            "recall": r,
            "f1": f,
            "songs": [
                {**asdict(s), "precision": s.scores[0], "recall": s.scores[1], "f1": s.scores[2]}
                for s in self.songs
            ],
            "gate_report": self.gate_report(),
        }

    def format(self) -> str:
        """Summary lines: one per song, the totals, the quality line and the gate."""
        lines = [f"piano on the C MuJoCo sim target: policy {self.policy} [{self.fingerprint}]"]
        for s in self.songs:
            p, r, f = s.scores
            end = "faulted" if s.faulted else "completed"
            scores = f"precision {p:.3f} recall {r:.3f} F1 {f:.3f}"
            lines.append(f"  {s.song:28s} {scores} ({s.ticks} ticks, {end})")
        p, r, f = self.totals()
        lines.append(f"all songs: precision {p:.3f}, recall {r:.3f}, F1 {f:.3f}")
        lines.append(quality_summary_line(self.gate_report()["quality"]))
        lines.extend(self.gate_lines())
        return "\n".join(lines)


def evaluate(policy: OnnxPolicy, songs: list[Song], target: SimTarget | None = None) -> PianoEval:
    """Play each song once (see the module docstring)."""
    kb = compact_config()
    damping = training_damping(policy.metadata.randomization)
    sim = target or SimTarget(policy.robot.mode, SimConfig(damping=damping), scene=keyboard_scene(kb))
    q0 = held_pose(policy.robot.pose("piano_ready"), policy.robot.mode)  # as the env starts
    results = []
    for song in songs:
        sim.reset(q0)
        commands = SongCommands(song, kb, policy.policy_dt, keys=None)
        counts = np.zeros(3, np.int64)

        def score(k: int, t: float, rt: Runtime, c: SongCommands = commands, n: np.ndarray = counts) -> None:
            if rt.safety.mode != Mode.POLICY:  # the hold after the song's end is not scored
                return
            down, goal = c.record()["keys_down"], c.goal_now()
            n += (int(np.sum(down & goal)), int(np.sum(down & ~goal)), int(np.sum(~down & goal)))

        cfg = RuntimeConfig(
            control_dt=policy.policy_dt,
            duration=commands.song_steps * policy.policy_dt + END_HOLD_S + 1.0,
            start_mode="policy",
            damping_after_fault=0.0,
            handle_signals=False,
            safety=SafetyConfig(ramp_time=0.0),
        )
        res = Runtime(policy, sim, commands, cfg, on_tick=score).run()
        results.append(
            SongResult(
                song=song.name,
                ticks=int(res.ticks),
                true_pos=int(counts[0]),
                false_pos=int(counts[1]),
                false_neg=int(counts[2]),
                faulted=res.fault_count > 0,
                end_reason=res.end_reason,
                quality={**res.quality["episode"], "name": song.name},
            )
        )
    return PianoEval(songs=results, policy=str(policy.path), fingerprint=policy.obs_manager.fingerprint)
