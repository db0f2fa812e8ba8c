"""The ship gate: the thresholds a policy file must meet on held-out data before it ships, in one place.

A held-out report is a dict with the ``summarise`` figures of ``bar_policy.quality.report`` under
``"quality"``, every episode's record under ``"episodes"`` (``EpisodeQuality.to_dict``), and the task's
accuracy figures at the top level (``joint_error_rad``, ``fingertip_error_cm`` for tracking,
``success_pct`` for reach). ``check`` lists every miss, each naming the metric, its value and the threshold;
``train/ship.py`` refuses a file with any, and the trainer ranks iterates with ``score``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["GATES", "GateThresholds", "Miss", "check", "gate_for", "score", "thresholds_text"]


@dataclass(frozen=True, kw_only=True)
class GateThresholds:
    """What a policy must reach on held-out data (the sim target, C MuJoCo) to ship."""

    min_completion_pct: float = 100.0
    """Episodes (clips) that end without a fault, %: every one."""
    max_cap_share_pct: float = 0.5
    """Policy ticks with any joint at its torque cap, % of all ticks."""
    max_chatter_mrad: float = 5.0
    """Chatter (RMS above 5 Hz on the worst joint) of every episode, mrad."""
    max_joint_error_rad: float | None = None
    """Mean joint tracking error, rad (tracking)."""
    max_fingertip_error_cm: float | None = None
    """Mean fingertip tracking error, cm (tracking)."""
    min_success_pct: float | None = None
    """Task success, % (reach: target segments reached)."""


GATES: dict[str, GateThresholds] = {
    "track": GateThresholds(max_joint_error_rad=0.02, max_fingertip_error_cm=1.0),
    "reach": GateThresholds(min_success_pct=95.0),
}
"""Task name -> its gate."""


@dataclass(frozen=True)
class Miss:
    """One way a report misses the gate."""

    metric: str
    """The threshold's field name in ``GateThresholds`` (``max_chatter_mrad``, ...)."""
    safety: bool
    """A safety or smoothness miss (completion, torque caps, chatter), not an accuracy one."""
    text: str
    """One line naming the metric, its value and the threshold."""

    def __str__(self) -> str:
        return self.text


def gate_for(task: str) -> GateThresholds:
    """The gate of a task; ``ValueError`` naming the tasks that have one."""
    if task not in GATES:
        raise ValueError(f"no ship gate for task {task!r}; tasks with a gate: {sorted(GATES)}")
    return GATES[task]


def thresholds_text(task: str) -> str:
    """One line listing the task's thresholds (printed by ``ship.py`` and ``bar-deploy eval``)."""
    g = gate_for(task)
    parts = [f"{k}={v:g}" for k, v in asdict(g).items() if v is not None]
    return f"ship gate ({task}): " + ", ".join(parts)


def _bad(x: Any) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def _bound(
    out: list[Miss], metric: str, safety: bool, value: Any, limit: float, upper: bool, what: str, unit: str
) -> None:
    """Append a miss when ``value`` is missing or beyond ``limit`` (``upper``: at most; else at least)."""
    if _bad(value):
        out.append(Miss(metric, safety, f"{what}: not measured (the report lacks it; {metric}={limit:g})"))
    elif (value > limit) if upper else (value < limit):
        sign = ">" if upper else "<"
        out.append(Miss(metric, safety, f"{what} {value:.4g} {unit} {sign} {limit:g} {unit} ({metric})"))


def check(task: str, report: Mapping[str, Any]) -> list[Miss]:
    """Every way ``report`` misses the task's gate (empty: it passes).

    Args:
        task: a task of ``GATES``.
        report: ``{"quality": summarise(...), "episodes": [EpisodeQuality.to_dict(), ...], <accuracy>}``.
    """
    g = gate_for(task)
    q = report.get("quality")
    if not isinstance(q, Mapping):
        return [
            Miss("quality", True, "the report has no 'quality' figures (completion, torque caps, chatter)")
        ]
    out: list[Miss] = []
    faulted = [e.get("name") for e in report.get("episodes", []) if e.get("faulted")]
    what = "completion" + (
        f" ({len(faulted)} ended by a fault: {', '.join(map(str, faulted[:4]))})" * bool(faulted)
    )
    _bound(out, "min_completion_pct", True, q.get("completion_pct"), g.min_completion_pct, False, what, "%")
    _bound(out, "max_cap_share_pct", True, q.get("cap_share_pct"), g.max_cap_share_pct, True,
           "ticks at a torque cap", "%")  # fmt: skip
    episodes = report.get("episodes") or []
    if not episodes:
        out.append(Miss("max_chatter_mrad", True, "chatter: the report lists no episodes"))
    for ep in episodes:
        c = ep.get("chatter_mrad")
        if c is not None and c > g.max_chatter_mrad:
            out.append(Miss("max_chatter_mrad", True,
                            f"chatter {c:.2f} mrad on {ep.get('name')} ({ep.get('chatter_joint')}) > "
                            f"{g.max_chatter_mrad:g} mrad (max_chatter_mrad)"))  # fmt: skip
    if g.max_joint_error_rad is not None:
        _bound(out, "max_joint_error_rad", False, report.get("joint_error_rad"), g.max_joint_error_rad, True,
               "mean joint error", "rad")  # fmt: skip
    if g.max_fingertip_error_cm is not None:
        _bound(out, "max_fingertip_error_cm", False, report.get("fingertip_error_cm"),
               g.max_fingertip_error_cm, True, "mean fingertip error", "cm")  # fmt: skip
    if g.min_success_pct is not None:
        _bound(out, "min_success_pct", False, report.get("success_pct"), g.min_success_pct, False,
               "success", "%")  # fmt: skip
    return out


def score(task: str, report: Mapping[str, Any]) -> tuple[float, ...]:
    """Rank of a held-out evaluation (higher is better): safety misses, then accuracy misses, then accuracy.

    ``(-safety thresholds missed, -accuracy thresholds missed, accuracy, -cap share %, -worst chatter)``
    compared lexicographically (chatter on several episodes is one threshold missed). So an iterate that
    faults or chatters never beats one that does not, and among equally safe ones the more accurate wins;
    accuracy is ``success %`` (reach) or ``-joint error`` (tracking). NaN counts as worst.
    """
    q = report.get("quality") or {}
    misses = check(task, report)
    safety = {m.metric for m in misses if m.safety}
    accuracy = {m.metric for m in misses if not m.safety}

    def val(x: Any, worst: float) -> float:
        return worst if _bad(x) else float(x)

    acc = (
        val(report.get("success_pct"), -math.inf)
        if gate_for(task).min_success_pct is not None
        else -val(report.get("joint_error_rad"), math.inf)
    )
    return (
        -float(len(safety)),
        -float(len(accuracy)),
        acc,
        -val(q.get("cap_share_pct"), math.inf),
        -val(q.get("chatter_max_mrad"), math.inf),
    )
