"""Sim2sim tracking errors of a tracking policy (``bar-deploy eval``, ``bench/track_fidelity.py``).

The protocol is the fidelity bench's MJX column (``bench/track_fidelity.py``), through exactly the deploy
code path (the runner the caller hands in, ``tasks.episodes.EpisodeRunner``; the runtime's is
``deploy.episodes.SimEpisodes``: ``Runtime`` with the observation manager, action clip, safety supervisor,
the target's MIT law):

- each clip runs once: the target is reset on the clip's first frame at the reference velocity (the env's
  reset at phase 0; a target whose ``reset`` takes no velocity starts at rest), the policy runs from the
  first tick (no ramp, phase 0 at tick 0) for ``last + hold_s / dt`` ticks: the whole clip, then
  ``hold_s`` on its held last frame;
- after each tick's physics the measured state is compared with the frame that tick arrives at,
  ``min(k + 1, last)``, as the env's metrics are: ``joint_error`` (mean |q - q_ref|, rad),
  ``body_pos_error`` (mean distance of the tracked bodies, m), ``fingertip_error`` (mean over both
  fingertips, m), ``success`` (joint error <= 0.05 rad and fingertip error <= 2 cm), ``lost`` (a tracked
  body more than 0.25 m off); body poses by C MuJoCo kinematics (``robot.kinematics``);
- a fault ends the clip (counted in ``faults``; its steps so far are kept, so the means of a clip that
  faulted cover less of it). The supervisor's torque-saturation fault (a joint at its cap for > 0.5 s) has
  no counterpart in the env, which only clips at the cap: the runner's safety config can relax it for a
  physics-only comparison (``bench/track_fidelity.py --saturation-time``).

Means are frame-weighted over all steps (``summarise``), for all clips and for the random clips, the named
gestures and each clip family (``motion.families``) apart.
Latency, gain scaling and observation noise of training are not modelled: compare
with the MJX column on nominal physics.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bar_policy.motion.clip import Clip
from bar_policy.motion.families import FAMILIES, family_of
from bar_policy.motion.library import CLIP_SETS, clip_set, clip_set_id
from bar_policy.quality import EpisodeQuality
from bar_policy.quality import summarise as summarise_quality
from bar_policy.quality.report import quality_summary_line
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.kinematics import Kinematics
from bar_policy.tasks.episodes import EpisodeRunner, Policy, report_progress, true_q
from bar_policy.tasks.interfaces import EvalReport
from bar_policy.tasks.track.reference import load_motion, reference_for
from bar_policy.tasks.track.shared import (
    LOST_DISTANCE,
    SUCCESS_FINGERTIP_M,
    SUCCESS_JOINT_RAD,
    ReferenceTable,
)

__all__ = [
    "DEFAULT_HOLD_S",
    "METRICS",
    "ClipResult",
    "TrackEvalResult",
    "clip_columns",
    "eval_clips",
    "evaluate_track",
    "group_columns",
    "step_errors",
    "summarise",
]

DEFAULT_HOLD_S = 0.5
"""Seconds of tracking the held last frame after each clip."""
METRICS = ("joint_error", "body_pos_error", "fingertip_error", "success", "lost")
"""Per-step metrics (the env's names)."""


def step_errors(kin: Kinematics, q: np.ndarray, table: ReferenceTable, frame: int) -> dict[str, float]:
    """The env's per-step metrics of measured ``q`` (rad, (n,)) against ``table``'s ``frame``."""
    pos, _, tips = kin.trajectory(np.asarray(q, dtype=np.float64)[None], table.body_names, FINGERTIP_SITES)
    dist = np.linalg.norm(pos[0] - table.body_pos[frame], axis=-1)
    joint = float(np.mean(np.abs(q - table.joint_pos[frame])))
    tip = float(np.mean(np.linalg.norm(tips[0] - table.fingertip_pos[frame], axis=-1)))
    return {
        "joint_error": joint,
        "body_pos_error": float(np.mean(dist)),
        "fingertip_error": tip,
        "success": float(joint <= SUCCESS_JOINT_RAD and tip <= SUCCESS_FINGERTIP_M),
        "lost": float(np.max(dist) > LOST_DISTANCE),
    }


@dataclass(frozen=True)
class ClipResult:
    """One clip on one target: sums over its steps (divide by ``steps`` for means)."""

    clip: str
    steps: int
    sums: dict[str, float]
    faulted: bool = False
    end_reason: str = ""
    cap_dwell: str = ""
    """A target that does not stop on a fault (the MJX env): when a joint's torque demand first stayed at
    its cap longer than the supervisor allows, and which joints; empty when it never did."""
    quality: dict[str, Any] = field(default_factory=dict)
    """The clip's safety and smoothness (``EpisodeQuality.to_dict``; empty when not measured)."""

    def mean(self, key: str) -> float:
        """Mean of a metric over the clip's steps."""
        return self.sums[key] / max(self.steps, 1)


def summarise(results: Sequence[ClipResult], label: str) -> dict[str, Any]:
    """Frame-weighted means over ``results``: errors in rad and cm, success in %, lost steps, faults."""
    steps = sum(r.steps for r in results)
    tot = {k: sum(r.sums[k] for r in results) for k in METRICS}
    n = max(steps, 1)
    return {
        "group": label,
        "clips": len(results),
        "steps": steps,
        "joint_error_rad": tot["joint_error"] / n,
        "body_pos_error_cm": 100 * tot["body_pos_error"] / n,
        "fingertip_error_cm": 100 * tot["fingertip_error"] / n,
        "success_pct": 100 * tot["success"] / n,
        "lost_steps": int(tot["lost"]),
        "faults": sum(r.faulted for r in results),
        "cap_dwell_clips": sum(bool(r.cap_dwell) or "torque_saturation" in r.end_reason for r in results),
    }


def clip_columns(r: ClipResult) -> tuple[Any, ...]:
    """A clip's row of the clip table up to its fault column.

    Clip, steps, joint rad, body cm, tip cm, success %, lost steps.
    """
    return (
        r.clip,
        r.steps,
        r.mean("joint_error"),
        100 * r.mean("body_pos_error"),
        100 * r.mean("fingertip_error"),
        100 * r.mean("success"),
        int(r.sums["lost"]),
    )


def group_columns(g: Mapping[str, Any]) -> tuple[Any, ...]:
    """A group's row of the clip table (one of ``groups``), as ``clip_columns`` then its faults."""
    return (
        "= " + g["group"],
        g["steps"],
        g["joint_error_rad"],
        g["body_pos_error_cm"],
        g["fingertip_error_cm"],
        g["success_pct"],
        g["lost_steps"],
        g["faults"],
    )


def groups(results: Sequence[ClipResult]) -> list[dict[str, Any]]:
    """``summarise`` over all clips, then per group when there are several.

    The groups: the random clips, the named gestures and each clip family (``motion.families.family_of``),
    in that order.
    """
    by_group: dict[str, list[ClipResult]] = {}
    for r in results:
        by_group.setdefault(family_of(r.clip), []).append(r)
    out = [summarise(results, "all")]
    if len(by_group) > 1:
        order = ["random", "gestures", *FAMILIES]
        out += [summarise(by_group[g], g) for g in order if g in by_group]
    return out


@dataclass(frozen=True)
class TrackEvalResult(EvalReport):
    """Every clip's sums and the frame-weighted means."""

    policy: str
    fingerprint: str
    target: str
    clip_set: str
    hold_s: float
    clips: list[ClipResult] = field(default_factory=list)

    @property
    def summary(self) -> dict[str, Any]:
        """``summarise`` over all clips."""
        return summarise(self.clips, "all")

    def format(self) -> str:
        """Per-clip table and the group means."""
        lines = [
            f"tracking ({self.target}) policy {self.policy} [{self.fingerprint}]",
            f"clips {self.clip_set}: {len(self.clips)} clips, each from its first frame to its last, then "
            f"{self.hold_s:g} s holding it",
            "{:<26}{:>7}{:>11}{:>9}{:>8}{:>11}{:>6}{:>7}{:>8}{:>9}".format(
                "clip",
                "steps",
                "joint rad",
                "body cm",
                "tip cm",
                "success %",
                "lost",
                "fault",
                "cap %",
                "chatter",
            ),
        ]
        row = "{:<26}{:>7}{:>11.4f}{:>9.2f}{:>8.2f}{:>11.1f}{:>6}{:>7}"
        for r in self.clips:
            q = r.quality
            cap = f"{100 * q['cap_ticks'] / max(q['ticks'], 1):>8.2f}" if q else f"{'':>8}"
            chatter = q.get("chatter_mrad") if q else None
            lines.append(
                row.format(*clip_columns(r), "yes" if r.faulted else "")
                + cap
                + (f"{'':>9}" if chatter is None else f"{chatter:>9.2f}")
            )
        for g in groups(self.clips):
            lines.append(row.format(*group_columns(g)))
        s = self.summary
        if s["faults"]:
            lines.append(
                f"{s['faults']} clip(s) ended by a fault (damped): their means cover the steps before it"
            )
        lines.append(
            f"mean joint error {s['joint_error_rad']:.4f} rad, tracked-body position error "
            f"{s['body_pos_error_cm']:.2f} cm, fingertip error {s['fingertip_error_cm']:.2f} cm "
            f"(per-step success: <= {SUCCESS_JOINT_RAD} rad and <= {100 * SUCCESS_FINGERTIP_M:g} cm)"
        )
        if any(r.quality for r in self.clips):
            lines += [quality_summary_line(self.gate_report()["quality"]), *self.gate_lines()]
        return "\n".join(lines)

    def gate_report(self) -> dict[str, Any]:
        """Frame-weighted tracking errors and the clips' safety and smoothness (the ship gate's input)."""
        records = [EpisodeQuality.from_dict(r.quality) for r in self.clips if r.quality]
        s = self.summary
        return {
            "task": "track",
            "clip_set": self.clip_set,
            "target": self.target,
            "quality": summarise_quality(records),
            "episodes": [r.to_dict() for r in records],
            "joint_error_rad": s["joint_error_rad"],
            "fingertip_error_cm": s["fingertip_error_cm"],
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "policy": self.policy,
            "obs_fingerprint": self.fingerprint,
            "target": self.target,
            "clip_set": self.clip_set,
            "hold_s": self.hold_s,
            "groups": groups(self.clips),
            "clips": [asdict(r) for r in self.clips],
            "gate_report": self.gate_report(),
        }


def eval_clips(spec: str, mode: str = "arms") -> tuple[str, list[Clip]]:
    """The clips ``--clips spec`` names: a clip set (``heldout``, ...) or comma-separated ``--motion`` specs.

    Returns:
        ``(clip set id, clips)``.
    """
    if spec in CLIP_SETS:
        chosen = clip_set(spec, mode=mode)
        return chosen.id, list(chosen.clips)
    clips = [load_motion(s.strip(), mode) for s in spec.split(",") if s.strip()]
    if not clips:
        raise ValueError(f"no clips in {spec!r}; give a clip set {sorted(CLIP_SETS)} or motion names / paths")
    return clip_set_id("custom", clips), clips


def evaluate_track(
    policy: Policy,
    clips: Sequence[Clip],
    *,
    runner: EpisodeRunner,
    hold_s: float = DEFAULT_HOLD_S,
    target: Any = None,
    clip_set: str = "",
    label: str = "",
    on_clip: Callable[[ClipResult], None] | None = None,
) -> TrackEvalResult:
    """Run every clip on ``target`` (default: ``runner.target()``, the C MuJoCo sim target).

    Args:
        policy: a tracking policy.
        clips: the motions.
        runner: runs each clip through the deploy code path (``deploy.episodes.SimEpisodes``; its safety
            config holds the supervisor's thresholds, the ramp always 0).
        hold_s: s of tracking the held last frame after each clip.
        target: a synchronous target with ``reset(q, dq)`` (``SimTarget``; the emulated bus starts at rest).
        clip_set: the clips' set id (for the report).
        label: the target's name in the report (default: its class name).
        on_clip: called with each clip's result as it finishes (progress).
    """
    sim = target or runner.target()
    dt = policy.policy_dt
    kin = Kinematics(policy.robot.mode)
    results = []
    for index, clip in enumerate(clips, 1):
        ref = reference_for(policy, clip, tail_s=hold_s, kinematics=kin)
        table, last = ref.table, ref.last
        n_ticks = last + ref.tail_ticks
        sums = dict.fromkeys(METRICS, 0.0)
        steps = [0]

        def meter(
            k: int,
            t: float,
            rt: Any,
            table: ReferenceTable = table,
            last: int = last,
            sums: dict[str, float] = sums,
            steps: list[int] = steps,
        ) -> None:
            if rt.safety.fault_count:
                return
            for key, v in step_errors(kin, true_q(sim), table, min(k + 1, last)).items():
                sums[key] += v
            steps[0] += 1

        dq0 = np.gradient(table.joint_pos[: min(last + 1, 3)].astype(np.float64), dt, axis=0)[0]
        sim.reset(table.joint_pos[0].astype(np.float64), dq0)  # type: ignore[attr-defined]
        res = runner.run(sim, ref, n_ticks * dt, kinematics=kin, on_tick=meter)
        quality = {**res.quality["episode"], "name": clip.name}
        result = ClipResult(clip.name, steps[0], sums, res.fault_count > 0, res.end_reason, quality=quality)
        results.append(result)
        fault = ", faulted" if result.faulted else ""
        figure = (
            f"{clip.name}, joint error {result.mean('joint_error'):.4f} rad, fingertip "
            f"{100 * result.mean('fingertip_error'):.2f} cm{fault}"
        )
        report_progress(runner, "clip", index, len(clips), figure)
        if on_clip is not None:
            on_clip(result)
    return TrackEvalResult(
        policy=str(policy.path),
        fingerprint=policy.obs_manager.fingerprint,
        target=label or (runner.target_label if target is None else type(target).__name__),
        clip_set=clip_set or clip_set_id("custom", list(clips)),
        hold_s=hold_s,
        clips=results,
    )
