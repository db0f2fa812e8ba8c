"""``bar-deploy eval --perturb suite``: the task's evaluation on every row of the robustness suite, one table.

Each row of ``robot.perturb_suite.SUITE`` runs the task's own evaluation (``DeployTask.evaluate``, the same
episodes, clips or songs as a plain ``bar-deploy eval``) on the sim target of the perturbed robot
(``targets.perturbed``), or on the emulated bus whose robot is the perturbed one (``--target bus``,
``deploy.episodes.BusEpisodes``), and is judged by the task's ship gate (``quality.gate.check``) as far as
the row's ``gating`` says. The table: perturbation, completion %, the task's metrics (``task_metrics``:
track, the mean fingertip and joint errors; reach, the median segment-end distance and the success %; piano,
F1 %), ticks at a torque cap %, the worst episode's chatter (mrad), the verdict (PASS, MISS, or ``report``
for a row not judged) and the first metric's ratio to the nominal row's.

``train/ship.py`` runs the suite's rows (``--robustness ROWS``, default every row) through ``run_suite``
after the nominal gate, records each row's verdict in the published JSON and refuses a file that misses a
gated row.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bar_policy.quality.gate import Miss, check, thresholds_text
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.robot.perturb_suite import SUITE, SuiteRow

if TYPE_CHECKING:
    from bar_policy.robot.params import RobotParams

__all__ = [
    "SAFETY_METRICS",
    "RowResult",
    "SuiteResult",
    "evaluate_perturbed",
    "row_verdict",
    "run_suite",
    "task_metrics",
]

SAFETY_METRICS = frozenset({"min_completion_pct", "max_cap_share_pct"})
"""The thresholds a ``safety`` row is judged on (completion and torque caps)."""


def row_verdict(task: str, report: Mapping[str, Any], gating: str) -> tuple[str, list[Miss]]:
    """``(verdict, misses that count)`` of one row's gate report under its ``gating``.

    ``all``: every miss of ``check``; ``safety``: only completion and caps; ``none``: ``report`` (the
    misses are still returned, for the text, but do not fail the row).
    """
    misses = check(task, report)
    if gating == "none":
        return "report", misses
    if gating == "safety":
        misses = [m for m in misses if m.metric in SAFETY_METRICS]
    return ("PASS" if not misses else "MISS"), misses


def task_metrics(report: Mapping[str, Any]) -> list[tuple[str, float | None]]:
    """The accuracy figures of one evaluation's gate report, the ratio's first: ``[(column, value), ...]``.

    track: mean fingertip error (cm), mean joint error (rad); reach: the median segment-end distance over
    both hands (cm, the report's ``median_end_cm``), success %; piano (and any other task): its
    ``success_pct`` (piano: 100 x F1).
    """
    if "fingertip_error_cm" in report:
        return [
            ("fingertip cm", report.get("fingertip_error_cm")),
            ("joint rad", report.get("joint_error_rad")),
        ]
    if "median_end_cm" in report:
        return [("median end cm", report.get("median_end_cm")), ("success %", report.get("success_pct"))]
    return [("F1 %" if report.get("task") == "piano" else "success %", report.get("success_pct"))]


def _chatter(report: Mapping[str, Any]) -> float | None:
    eps = report.get("episodes") or []
    values = [e.get("chatter_mrad") for e in eps if e.get("chatter_mrad") is not None]
    if values:
        return max(values)
    return (report.get("quality") or {}).get("chatter_max_mrad")


@dataclass
class RowResult:
    """One evaluated row."""

    row: SuiteRow
    report: dict[str, Any]
    """The task's gate report (``EvalResult.gate_report()``)."""
    verdict: str
    misses: list[Miss]
    metrics: list[tuple[str, float | None]]
    """The task's accuracy figures (``task_metrics``); the first is the ratio's."""
    ratio: float | None = None
    """The first metric over the nominal row's (None without a nominal figure)."""

    @property
    def metric(self) -> float | None:
        """The first metric's value."""
        return self.metrics[0][1]

    def cells(self) -> list[str]:
        """The row's table cells."""
        q = self.report.get("quality") or {}

        def f(x: Any, fmt: str) -> str:
            return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)

        return [
            self.row.name,
            f(q.get("completion_pct"), ".1f"),
            *(f(v, ".3g") for _, v in self.metrics),
            f(q.get("cap_share_pct"), ".2f"),
            f(_chatter(self.report), ".2f"),
            self.verdict,
            f(self.ratio, ".2f"),
        ]

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``--json``)."""
        return {
            "name": self.row.name,
            "spec": self.row.spec,
            "gating": self.row.gating,
            "verdict": self.verdict,
            "misses": [str(m) for m in self.misses],
            "metrics": dict(self.metrics),
            "ratio_to_nominal": self.ratio,
            "gate_report": {k: v for k, v in self.report.items() if k != "episodes"},
        }


@dataclass
class SuiteResult:
    """Every row, and the policy's verdict over the gated rows."""

    task: str
    policy: str
    rows: list[RowResult] = field(default_factory=list)
    target: str = "C MuJoCo sim target"
    """The rows' target (``EpisodeRunner.target_label``)."""

    @property
    def passed(self) -> bool:
        """True when no gated row misses."""
        return all(r.verdict != "MISS" for r in self.rows)

    def format(self) -> str:
        """The table, each row's misses, the verdict."""
        names = [n for n, _ in self.rows[0].metrics] if self.rows else ["metric"]
        head = ["perturbation", "completion %", *names, "caps %", "chatter mrad", "gate", "ratio"]
        body = [r.cells() for r in self.rows]
        widths = [max(len(str(c)) for c in col) for col in zip(head, *body, strict=True)]
        line = "  ".join

        def fmt(cells: Sequence[str]) -> str:
            pairs = enumerate(zip(cells, widths, strict=True))
            return line(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in pairs)

        out = [f"robustness suite: policy {self.policy} ({self.task}), {self.target}"]
        out.append(thresholds_text(self.task))
        out += [fmt(head), fmt(["-" * w for w in widths]), *(fmt(b) for b in body)]
        for r in self.rows:
            tag = {"MISS": "MISS", "report": "not gated"}.get(r.verdict)
            if tag:
                out += [f"  {r.row.name} ({tag}): {m}" for m in r.misses]
        gated = sum(r.verdict != "report" for r in self.rows)
        missed = [r.row.name for r in self.rows if r.verdict == "MISS"]
        out.append(
            f"suite: PASS ({gated} gated rows)"
            if not missed
            else f"suite: MISS on {len(missed)} of {gated} gated rows: {', '.join(missed)}"
        )
        return "\n".join(out)

    def to_dict(self) -> dict[str, Any]:
        """JSON form (``--json``)."""
        return {
            "task": self.task,
            "policy": self.policy,
            "target": self.target,
            "passed": self.passed,
            "rows": [r.to_dict() for r in self.rows],
        }


def run_suite(
    policy: Any,
    task: Any,
    args: argparse.Namespace,
    make_runner: Callable[[Perturbation], Any],
    rows: Sequence[SuiteRow] = SUITE,
    progress: Callable[[str], None] | None = None,
) -> SuiteResult:
    """Evaluate ``policy`` on every row; ``make_runner(perturbation)`` gives the row's episode runner.

    Args:
        policy: the loaded policy.
        task: its deploy task (``evaluate(policy, args, runner)``, ``name``).
        args: the eval options (episodes, clips, ...), the same for every row.
        make_runner: the episode runner of a perturbed robot (``SimEpisodes(policy, perturbation=p)``; a
            context manager, left after the row's evaluation).
        rows: the suite (default ``SUITE``).
        progress: called with a line as each row ends.
    """
    out = SuiteResult(task=task.name, policy=str(getattr(policy, "path", "")))
    nominal: float | None = None
    for row in rows:
        with make_runner(row.perturbation) as runner:
            result = task.evaluate(policy, args, runner)
        out.target = runner.target_label
        report = result.gate_report()
        verdict, misses = row_verdict(task.name, report, row.gating)
        metrics = task_metrics(report)
        name, value = metrics[0]
        r = RowResult(row, report, verdict, misses, metrics)
        if not row.spec:
            nominal = value
        if nominal and value is not None:
            r.ratio = value / nominal
        out.rows.append(r)
        if progress is not None:
            progress(f"  {row.name}: {verdict} ({name} {'n/a' if value is None else format(value, '.3g')})")
    return out


def evaluate_perturbed(
    policy: Any,
    task: Any,
    args: argparse.Namespace,
    perturb: Perturbation | str,
    say: Callable[[str], None],
    *,
    progress: bool = True,
    robot_params: RobotParams | None = None,
    hand_load: str | None = None,
    load_inertia: bool | None = None,
    target: str = "sim",
) -> Any:
    """``bar-deploy eval --perturb``: the suite (``"suite"``) or one perturbed evaluation (its result).

    ``say`` gets the perturbation's line and, with ``progress`` (``bar-deploy eval`` without ``--quiet``),
    each suite row as it ends or each episode's progress line of one perturbed evaluation.
    ``robot_params`` (``--robot-params``): every row perturbs that identified robot instead of the model.
    ``hand_load`` (``--hand-load``): the runs' hand-load compensation (None: the task's).
    ``load_inertia`` (``--load-inertia``): the runs' load-inertia feed-forward (None: the task's).
    ``target`` (``--target``, a key of ``deploy.episodes.RUNNERS``): ``bus``, the emulated bus's robot is
    the perturbed one (``BusEpisodes``); ``sim``, the sim target's.
    """
    from bar_policy.deploy.episodes import RUNNERS, SimEpisodes

    kind = RUNNERS[target]

    def runner(p: Perturbation, say: Callable[[str], None] | None = None) -> SimEpisodes:
        return kind(
            policy,
            perturbation=p,
            robot_params=robot_params,
            say=say,
            hand_load=hand_load,
            load_inertia=load_inertia,
        )

    if perturb == "suite":
        say(f"robustness suite: {len(SUITE)} rows, each the task's whole evaluation")
        return run_suite(policy, task, args, runner, progress=(lambda s: say(s)) if progress else None)
    assert isinstance(perturb, Perturbation)
    where = "emulated bus" if target == "bus" else "sim target"
    say(f"perturbed {where} (hidden from the policy): {perturb.describe()}")
    with runner(perturb, say if progress else None) as episodes:
        return task.evaluate(policy, args, episodes)
