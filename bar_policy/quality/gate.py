"""The ship gate: the thresholds a policy file must meet on held-out data before it ships, in one place.

A held-out report is a dict with the ``summarise`` figures of ``bar_policy.quality.report`` under
``"quality"``, every episode's record under ``"episodes"`` (``EpisodeQuality.to_dict``; optional: without them
chatter is judged on the summary's worst episode, as the MJX evaluation reports it), and the task's accuracy
figures at the top level (``joint_error_rad``, ``fingertip_error_cm`` for tracking, ``success_pct`` for reach
and the piano, the piano's ``recall_pct``: recall % per named group, reach's ``median_end_cm``).
``check`` lists every miss, each naming the metric, its value and the threshold; ``train/ship.py`` refuses
a file with any, and the trainer ranks iterates with ``score`` (by ``excess``: how far beyond the
thresholds, summed).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

__all__ = [
    "GateThresholds",
    "Miss",
    "check",
    "excess",
    "gate_for",
    "gates",
    "register_gate",
    "score",
    "thresholds_text",
]


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
    max_median_end_cm: float | None = None
    """Median, over every target segment's end and both hands, of the fingertip's distance to its target,
    cm (reach: the accuracy success hides, as a 3 cm success radius passes a 2 cm policy)."""
    min_recall_pct: float | None = None
    """Recall of every group of ``recall_groups``, %: each at least this (piano: the goal key-ticks of each
    key colour, on the held-out songs and on random songs)."""
    recall_groups: tuple[str, ...] = ()
    """The groups the report's ``recall_pct`` mapping must hold (group name -> recall %); a group it lacks
    is a miss (not measured)."""


_GATES: dict[str, GateThresholds] = {}
"""Task name -> its gate, filled by ``register_gate`` (the task registry registers every task's)."""


def register_gate(task: str, thresholds: GateThresholds) -> None:
    """Make ``thresholds`` the gate of ``task``.

    ``bar_policy.tasks.registry`` calls it for every task whose record names a gate (``TaskRecord.gate``,
    the task's ``gate.py``), so each task keeps its thresholds in its own folder and this module imports
    no task. Raises ``TypeError`` for anything but a ``GateThresholds``.
    """
    if not isinstance(thresholds, GateThresholds):
        raise TypeError(f"task {task!r}: the gate is a {type(thresholds).__name__}, not GateThresholds")
    _GATES[task] = thresholds


def gates() -> dict[str, GateThresholds]:
    """Task name -> its gate, as registered."""
    return dict(_GATES)


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
    if task not in _GATES:
        raise ValueError(
            f"no ship gate for task {task!r}; tasks with a gate: {sorted(_GATES)} (importing "
            "bar_policy.tasks.registry registers every task's)"
        )
    return _GATES[task]


def thresholds_text(task: str) -> str:
    """One line listing the task's thresholds (printed by ``ship.py`` and ``bar-deploy eval``)."""
    g = gate_for(task)
    parts = [
        f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}=({', '.join(v)})"
        for k, v in asdict(g).items()
        if v is not None and v != ()
    ]
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
        task: a task of ``gates()``.
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
    _bound(
        out,
        "max_cap_share_pct",
        True,
        q.get("cap_share_pct"),
        g.max_cap_share_pct,
        True,
        "ticks at a torque cap",
        "%",
    )
    episodes = report.get("episodes") or []
    for ep in episodes:
        c = ep.get("chatter_mrad")
        if c is not None and c > g.max_chatter_mrad:
            out.append(
                Miss(
                    "max_chatter_mrad",
                    True,
                    f"chatter {c:.2f} mrad on {ep.get('name')} ({ep.get('chatter_joint')}) > "
                    f"{g.max_chatter_mrad:g} mrad (max_chatter_mrad)",
                )
            )
    if not episodes:  # a summary without per-episode records (the MJX evaluation): its worst episode
        worst = f" on {q['chatter_worst_episode']}" if q.get("chatter_worst_episode") else ""
        _bound(
            out,
            "max_chatter_mrad",
            True,
            q.get("chatter_max_mrad"),
            g.max_chatter_mrad,
            True,
            f"chatter of the worst episode{worst}",
            "mrad",
        )
    if g.max_joint_error_rad is not None:
        _bound(
            out,
            "max_joint_error_rad",
            False,
            report.get("joint_error_rad"),
            g.max_joint_error_rad,
            True,
            "mean joint error",
            "rad",
        )
    if g.max_fingertip_error_cm is not None:
        _bound(
            out,
            "max_fingertip_error_cm",
            False,
            report.get("fingertip_error_cm"),
            g.max_fingertip_error_cm,
            True,
            "mean fingertip error",
            "cm",
        )
    if g.min_success_pct is not None:
        _bound(
            out, "min_success_pct", False, report.get("success_pct"), g.min_success_pct, False, "success", "%"
        )
    if g.max_median_end_cm is not None:
        _bound(
            out,
            "max_median_end_cm",
            False,
            report.get("median_end_cm"),
            g.max_median_end_cm,
            True,
            "median segment-end distance",
            "cm",
        )
    if g.min_recall_pct is not None:
        recalls = report.get("recall_pct") or {}
        for group in g.recall_groups:
            what = f"recall of {group}"
            _bound(out, "min_recall_pct", False, recalls.get(group), g.min_recall_pct, False, what, "%")
    return out


def excess(task: str, report: Mapping[str, Any]) -> float:
    """How far ``report`` is from the gate: the sum over thresholds of the relative excess, 0 when it passes.

    For a bound ``value <= limit``: ``max(0, value / limit - 1)``; for ``value >= limit``:
    ``max(0, 1 - value / limit)``; chatter counts on the worst episode; a figure not measured counts 1. So
    twice the allowed cap share adds 1, a fingertip error of 1.5 cm against 1 cm adds 0.5, 98 % completion
    adds 0.02.
    """
    g = gate_for(task)
    q = report.get("quality") or {}
    eps = report.get("episodes") or []
    chatter = (
        max((e.get("chatter_mrad") or 0.0 for e in eps), default=None) if eps else q.get("chatter_max_mrad")
    )
    pairs = [
        (q.get("completion_pct"), g.min_completion_pct, False),
        (q.get("cap_share_pct"), g.max_cap_share_pct, True),
        (chatter, g.max_chatter_mrad, True),
        (report.get("joint_error_rad"), g.max_joint_error_rad, True),
        (report.get("fingertip_error_cm"), g.max_fingertip_error_cm, True),
        (report.get("success_pct"), g.min_success_pct, False),
        (report.get("median_end_cm"), g.max_median_end_cm, True),
        *(
            ((report.get("recall_pct") or {}).get(group), g.min_recall_pct, False)
            for group in g.recall_groups
        ),
    ]
    total = 0.0
    for value, limit, upper in pairs:
        if limit is None:
            continue
        if _bad(value):
            total += 1.0
        elif upper:
            total += max(0.0, float(value) / limit - 1.0)
        else:
            total += max(0.0, 1.0 - float(value) / limit)
    return total


def score(task: str, report: Mapping[str, Any]) -> tuple[float, ...]:
    """Rank of a held-out evaluation (higher is better): ``(-excess, accuracy)``.

    ``excess`` (0 for a report that passes the gate) weighs safety and accuracy thresholds alike, each by how
    far beyond it the figure is, so an early iterate that barely moves (no chatter, no accuracy) does not
    beat a later one that tracks well and chatters a little; among reports that pass, the more accurate
    wins: accuracy is ``success %`` (reach) or ``-joint error`` (tracking). NaN counts as worst.
    """
    acc_key = "success_pct" if gate_for(task).min_success_pct is not None else "joint_error_rad"
    value = report.get(acc_key)
    acc = -math.inf if _bad(value) else (float(value) if acc_key == "success_pct" else -float(value))
    return (-excess(task, report), acc)
