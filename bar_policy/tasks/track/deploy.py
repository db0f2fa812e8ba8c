"""Motion tracking on the robot: the ``track`` deploy task (``bar-deploy --motion NAME|PATH``).

Its command source, the clip's reference with lookahead, is ``tasks.track.reference`` (``MotionReference``,
re-exported here); its evaluation, tracking errors on held-out clips, is ``tasks.track.evaluate``
(imported when used: it loads the runtime).
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from bar_policy.motion.gestures import GESTURES
from bar_policy.tasks.cli_types import number, seconds0
from bar_policy.tasks.interfaces import DeployTask, EvalReport, OptionError
from bar_policy.tasks.track.reference import MotionReference, load_motion, reference_for
from bar_policy.tasks.track.run_figure import TrackRunFigure

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.tasks.episodes import EpisodeRunner, Policy

__all__ = ["TASK", "MotionReference", "TrackTask", "load_motion", "reference_for"]


class TrackTask(DeployTask):
    """``track``: ``--motion NAME|PATH``; eval: tracking errors on held-out clips."""

    name = "track"
    summary = "motion tracking"
    usage = (
        "give --motion NAME|PATH (a gesture: " + ", ".join(sorted(GESTURES)) + "; a clip set member "
        "random-s<seed>-<index>; or an .npz / .csv clip file)"
    )
    run_options = (("--motion", "motion"), ("--motion-rate", "motion_rate"))
    example_run = ("--motion", "wave")
    eval_options = (("--clips", "clips"), ("--hold-s", "hold_s"))
    default_duration = None

    def add_run_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--motion`` and ``--motion-rate``."""
        g = parser.add_argument_group("track policies (motion tracking)")
        gestures = ", ".join(sorted(GESTURES))
        g.add_argument(
            "--motion",
            metavar="NAME|PATH",
            help=f"motion to track: a gesture ({gestures}), a clip set member random-s<seed>-<index>, or an "
            ".npz / .csv clip; the run ends after the clip",
        )
        g.add_argument(
            "--motion-rate",
            type=number("a rate > 0 Hz", lambda v: v > 0),
            metavar="HZ",
            help="rate of a CSV clip without a 'time' column, Hz",
        )

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--clips`` and ``--hold-s``."""
        from bar_policy.tasks.track.evaluate import DEFAULT_HOLD_S

        g = parser.add_argument_group("track policies (tracking errors)")
        g.add_argument(
            "--clips",
            metavar="SET|NAMES",
            help="clip set (heldout, gestures, families, train) or comma-separated --motion specs (default "
            "heldout: random clips of seed 1 and the gestures; families: periodic, noisy, long holds, one "
            "arm still; none used in training)",
        )
        g.add_argument(
            "--hold-s",
            type=seconds0,
            metavar="S",
            help=f"s of tracking the held last frame after each clip (default {DEFAULT_HOLD_S})",
        )

    def command_source(
        self, policy: Policy, args: argparse.Namespace, kinematics: Kinematics | None = None
    ) -> MotionReference:
        """The reference of ``--motion`` for the policy."""
        spec = getattr(args, "motion", None)
        if spec is None:
            raise OptionError(f"{policy.path} is a 'track' policy ({self.summary}): {self.usage}")
        rate = getattr(args, "motion_rate", None)
        try:
            clip = load_motion(spec, policy.robot.mode, rate)
        except ValueError as e:  # ClipError is a ValueError
            msg = str(e).removeprefix(f"{spec}: ")  # the loader names the file first: once is enough
            raise OptionError(f"--motion {spec}: {msg}") from None
        return reference_for(policy, clip)

    def run_figure(
        self, policy: Policy, commands: object, kinematics: Kinematics | None = None
    ) -> TrackRunFigure | None:
        """Tracking errors of the run against its reference (``run_figure``); None for another source."""
        if not isinstance(commands, MotionReference):
            return None
        from bar_policy.robot.kinematics import Kinematics

        kin = kinematics if kinematics is not None else Kinematics(policy.robot.mode)
        return TrackRunFigure(commands, kin)

    def evaluate(self, policy: Policy, args: argparse.Namespace, runner: EpisodeRunner) -> EvalReport:
        """Tracking errors on the C MuJoCo sim target (``evaluate.evaluate_track``)."""
        from bar_policy.tasks.track.evaluate import DEFAULT_HOLD_S, eval_clips, evaluate_track

        hold = DEFAULT_HOLD_S if getattr(args, "hold_s", None) is None else args.hold_s
        if not (math.isfinite(hold) and hold >= 0):
            raise OptionError(f"--hold-s must be a time >= 0 s, got {hold}")
        try:
            set_id, clips = eval_clips(getattr(args, "clips", None) or "heldout", policy.robot.mode)
        except ValueError as e:
            raise OptionError(f"--clips: {e}") from None
        return evaluate_track(policy, clips, runner=runner, hold_s=hold, clip_set=set_id)


TASK = TrackTask()
"""The ``track`` deploy task."""
