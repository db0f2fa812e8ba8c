"""Per-episode safety and smoothness records and their summary over a set of episodes (numpy only).

``QualityMeter`` accumulates one episode tick by tick on the deploy side (``bar-deploy`` runs, ``eval``);
the MJX evaluation computes the same quantities with ``bar_policy.quality.metrics`` on device and fills
``EpisodeQuality`` records from them. ``summarise`` turns records into the figures every report prints
and the gate (``bar_policy.quality.gate``) checks:

- ``completion_pct``: episodes that ended without a fault, %;
- ``cap_share_pct``: policy ticks with any joint at its torque cap, % of all ticks;
- ``limit_share_pct``: policy ticks with any joint within ``LIMIT_MARGIN_RAD`` of a limit, %;
- ``action_rate``: mean ``sum_j (a_t - a_{t-1})^2`` per tick, action units squared;
- ``chatter_max_mrad`` / ``chatter_mean_mrad``: the worst and the mean chatter of the episodes that
  completed, mrad (a faulted episode's chatter stays in its record; episodes that faulted or were too short
  to measure are counted in ``chatter_unmeasured``), as the MJX evaluation counts them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from bar_policy.quality import metrics as qm

__all__ = ["EpisodeQuality", "QualityMeter", "quality_summary_line", "run_quality_line", "summarise"]


@dataclass(frozen=True)
class EpisodeQuality:
    """One episode's (clip's, run's) counts and chatter."""

    name: str
    """The episode's label (clip name, ``episode-3``, the run)."""
    ticks: int
    """Policy ticks measured."""
    faulted: bool
    """A fault ended the episode early."""
    cap_ticks: int
    """Ticks with any joint at its torque cap."""
    limit_ticks: int
    """Ticks with any joint near a limit."""
    action_rate_sum: float
    """Sum over ticks of ``sum_j (a_t - a_{t-1})^2`` (ticks after the first)."""
    chatter_mrad: float
    """Chatter of the episode's signal, mrad (NaN: too short to measure)."""
    fault: str = ""
    """The fault that ended it (empty when none)."""
    chatter_joint: str = ""
    """The joint with the worst chatter."""

    def to_dict(self) -> dict[str, Any]:
        """JSON form (NaN as None: JSON has no NaN)."""
        d = asdict(self)
        d["chatter_mrad"] = None if math.isnan(self.chatter_mrad) else self.chatter_mrad
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EpisodeQuality:
        """Inverse of ``to_dict``."""
        c = d.get("chatter_mrad")
        return cls(**{**d, "chatter_mrad": math.nan if c is None else float(c)})


class QualityMeter:
    """Accumulate one episode's quality tick by tick (numpy; the deploy side).

    Args:
        cap: firmware torque cap per joint, N*m, shape (n,).
        lower, upper: joint limits, rad, shape (n,).
        dt: policy tick, s.
        joint_names: names for the worst-chatter joint.
    """

    def __init__(
        self, cap: np.ndarray, lower: np.ndarray, upper: np.ndarray, dt: float, joint_names: Sequence[str]
    ) -> None:
        self.cap = np.asarray(cap, dtype=float)
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        self.dt = float(dt)
        self.joint_names = tuple(joint_names)
        self._signal: list[np.ndarray] = []
        self._last_action: np.ndarray | None = None
        self.ticks = 0
        self.cap_ticks = 0
        self.limit_ticks = 0
        self.action_rate_sum = 0.0

    def update(
        self,
        demand: np.ndarray,
        q: np.ndarray,
        action: np.ndarray,
        signal: np.ndarray,
        reported: np.ndarray | None = None,
    ) -> None:
        """Count one policy tick.

        Args:
            demand: unclipped MIT torque demand, N*m, (n,).
            q: measured joint positions, rad, (n,).
            action: the policy's action this tick (after any filter: what was applied), (n,).
            signal: the chatter signal, rad, (n,): ``q_cmd - q_ref`` (tracking) or ``q_cmd`` (reach).
            reported: the torque the motors report, N*m, (n,) (``JointState.tau``); None: the demand alone
                (``quality.metrics.at_cap``).
        """
        self.ticks += 1
        rep = None if reported is None else np.asarray(reported, dtype=float)
        self.cap_ticks += int(np.any(qm.at_cap(np.asarray(demand, dtype=float), self.cap, reported=rep)))
        self.limit_ticks += int(np.any(qm.near_limit(np.asarray(q, dtype=float), self.lower, self.upper)))
        a = np.asarray(action, dtype=float)
        if self._last_action is not None:
            self.action_rate_sum += float(qm.action_rate(np.stack([self._last_action, a]))[0])
        self._last_action = a
        self._signal.append(np.asarray(signal, dtype=float))

    def finish(self, name: str, fault: str = "") -> EpisodeQuality:
        """The episode's record (``fault``: what ended it early, empty when nothing did)."""
        chatter, joint = math.nan, ""
        if self._signal:
            per_joint = qm.highpass_rms(np.stack(self._signal), self.dt)
            if np.all(np.isfinite(per_joint)):
                j = int(np.argmax(per_joint))
                chatter, joint = 1000.0 * float(per_joint[j]), self.joint_names[j]
        return EpisodeQuality(
            name=name,
            ticks=self.ticks,
            faulted=bool(fault),
            cap_ticks=self.cap_ticks,
            limit_ticks=self.limit_ticks,
            action_rate_sum=self.action_rate_sum,
            chatter_mrad=chatter,
            fault=fault,
            chatter_joint=joint,
        )


def summarise(episodes: Sequence[EpisodeQuality]) -> dict[str, Any]:
    """The summary figures of ``episodes`` (see the module docstring); tick-weighted shares."""
    n = len(episodes)
    ticks = sum(e.ticks for e in episodes)
    rate_ticks = sum(max(e.ticks - 1, 0) for e in episodes)
    done = [e for e in episodes if not e.faulted and not math.isnan(e.chatter_mrad)]
    measured = [e.chatter_mrad for e in done]
    worst = max(done, key=lambda e: e.chatter_mrad, default=None)
    return {
        "episodes": n,
        "completed": sum(not e.faulted for e in episodes),
        "completion_pct": 100.0 * sum(not e.faulted for e in episodes) / n if n else math.nan,
        "ticks": ticks,
        "cap_share_pct": 100.0 * sum(e.cap_ticks for e in episodes) / ticks if ticks else math.nan,
        "limit_share_pct": 100.0 * sum(e.limit_ticks for e in episodes) / ticks if ticks else math.nan,
        "action_rate": sum(e.action_rate_sum for e in episodes) / rate_ticks if rate_ticks else math.nan,
        "chatter_max_mrad": max(measured) if measured else math.nan,
        "chatter_mean_mrad": float(np.mean(measured)) if measured else math.nan,
        "chatter_worst_episode": worst.name if worst is not None else "",
        "chatter_unmeasured": n - len(measured),
    }


def run_quality_line(quality: dict[str, Any]) -> str:
    """One line of a run's safety and smoothness (``RunResult.quality``: its episode and summary)."""
    ep, q = quality.get("episode") or {}, quality.get("summary") or {}
    if not q:
        return "quality: no POLICY tick"
    chatter = ep.get("chatter_mrad")
    ended = "ended by a fault" if ep.get("faulted") else "completed"
    text = "n/a (too short)" if chatter is None else f"{chatter:.2f} mrad ({ep.get('chatter_joint')})"
    return (
        f"quality over {q['ticks']} POLICY ticks: {ended}; at a torque cap {q['cap_share_pct']:.2f} % of "
        f"ticks; near a joint limit {q['limit_share_pct']:.2f} %; action rate {q['action_rate']:.3g}; "
        f"chatter {text}"
    )


def quality_summary_line(q: dict[str, Any]) -> str:
    """One line of ``summarise`` figures over several episodes (``bar-deploy eval``)."""
    if not q.get("episodes"):
        return "quality: no episode"
    worst = f" ({q['chatter_worst_episode']})" if q.get("chatter_worst_episode") else ""
    return (
        f"quality: {q['completed']}/{q['episodes']} completed; at a torque cap {q['cap_share_pct']:.2f} % "
        f"of ticks; near a joint limit {q['limit_share_pct']:.2f} %; action rate {q['action_rate']:.3g}; "
        f"chatter mean {q['chatter_mean_mrad']:.2f} mrad, worst {q['chatter_max_mrad']:.2f} mrad{worst}"
    )
