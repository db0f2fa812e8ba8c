"""Bimanual reach on the robot: ``--commands`` picks the fingertip targets; eval scores target segments.

The command sources are ``commands.py`` (``sampled`` / ``sampled:PERIOD`` like training, ``file:PATH``,
``stream:stdin`` / ``stream:udp:PORT``), unchanged; the fingertip observation terms are state terms that the
runtime computes (``deploy.inputs``). The evaluation is ``tasks.reach.evaluate`` (segment success rate).
HC-only files whose terms are reach's (targets or fingertips) run here too.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from bar_policy.tasks.cli_types import count1, number, seconds, seconds0
from bar_policy.tasks.interfaces import DeployTask, EvalReport, OptionError
from bar_policy.tasks.reach.commands import CommandError, ReachSource, make_command_source
from bar_policy.tasks.reach.run_figure import ReachRunFigure
from bar_policy.tasks.reach.transition import TransitionCommands, with_transition

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.tasks.episodes import EpisodeRunner, Policy

__all__ = ["SEED_HELP", "TASK", "ReachTask"]

_SPECS = "sampled | sampled:PERIOD | file:PATH | stream:stdin | stream:udp:PORT"

SEED_HELP = (
    "seed of the sampled fingertip targets (reach; --commands sampled[:PERIOD]): bar-deploy --seed N draws "
    "the targets that episode 0 of bar-deploy eval --seed N draws"
)
"""``--seed`` means one thing in ``bar-deploy`` and ``bar-deploy eval``: the seed of the target sampler."""


class ReachTask(DeployTask):
    """``reach``: ``--commands SPEC``; eval: segment success rate over seeded episodes."""

    name = "reach"
    summary = "fingertip targets"
    usage = f"give --commands {_SPECS} (default sampled)"
    run_options = (("--commands", "commands"),)
    example_run = ("--commands", "sampled")
    eval_options = (
        ("--episodes", "episodes"),
        ("--seed", "eval_seed"),
        ("--episode-length", "episode_length"),
        ("--resample-period", "resample_period"),
        ("--init-noise", "init_noise"),
    )
    default_duration = 10.0
    seed_help = SEED_HELP

    def add_run_arguments(self, parser: argparse.ArgumentParser) -> None:
        """``--commands``."""
        g = parser.add_argument_group("reach policies (fingertip targets)")
        g.add_argument("--commands", metavar="SPEC", help=f"command source: {_SPECS} (default sampled)")

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:
        """The episode protocol's options (``evaluate.EvalConfig``)."""
        g = parser.add_argument_group("reach policies (segment success rate)")
        g.add_argument("--episodes", type=count1, help="number of episodes (default 100)")
        g.add_argument(
            "--seed",
            dest="eval_seed",
            type=int,
            metavar="N",
            help="seed of the sampled fingertip targets (and initial noise) of episode 0; episode e: N + e. "
            "Episode 0's targets are those of bar-deploy --seed N (default 0)",
        )
        g.add_argument("--episode-length", type=seconds, help="episode length in s (env: 5)")
        g.add_argument(
            "--resample-period", type=seconds0, help="target resampling period in s (env: 2.5; 0: none)"
        )
        g.add_argument(
            "--init-noise",
            type=number("an angle >= 0 rad", lambda v: v >= 0),
            help="initial joint noise half-width, rad (default 0)",
        )

    def command_source(
        self, policy: Policy, args: argparse.Namespace, kinematics: Kinematics | None = None
    ) -> ReachSource | TransitionCommands:
        """The source ``--commands`` names (default ``sampled``, seeded by ``--seed``).

        Streams start at the fingertips of the default pose. A file trained with a command transition
        (``bar.command_transition``) gets its source wrapped in ``TransitionCommands``, starting there too.
        """
        from bar_policy.robot.kinematics import Kinematics

        kin = kinematics or Kinematics(policy.robot.mode)
        left, right = kin.fingertips(policy.default_joint_pos)
        spec = getattr(args, "commands", None) or "sampled"
        initial = {"target_pos_left": left, "target_pos_right": right}
        try:
            source = make_command_source(
                spec, policy.obs_manager.command_names, seed=getattr(args, "seed", 0) or 0, initial=initial
            )
        except CommandError as e:
            raise OptionError(str(e)) from None
        return with_transition(source, policy, initial)

    def run_figure(
        self, policy: Policy, commands: object, kinematics: Kinematics | None = None
    ) -> ReachRunFigure:
        """Segment-end success rate and final fingertip distances of the run (``run_figure``)."""
        from bar_policy.robot.kinematics import Kinematics

        kin = kinematics if kinematics is not None else Kinematics(policy.robot.mode)
        return ReachRunFigure(kin, policy.policy_dt)

    def evaluate(self, policy: Policy, args: argparse.Namespace, runner: EpisodeRunner) -> EvalReport:
        """Segment success rate on the C MuJoCo sim target (``evaluate.evaluate``)."""
        from bar_policy.tasks.reach.evaluate import EvalConfig, evaluate

        def given(name: str, default: float) -> float:
            value = getattr(args, name, None)
            return default if value is None else value

        period = given("resample_period", 2.5)
        cfg = EvalConfig(
            episodes=int(given("episodes", 100)),
            seed=int(given("eval_seed", 0)),
            episode_length=given("episode_length", 5.0),
            resample_period=period if period > 0 else None,
            init_noise=given("init_noise", 0.0),
        )
        return evaluate(policy, cfg, runner=runner)


TASK = ReachTask()
"""The ``reach`` deploy task."""
