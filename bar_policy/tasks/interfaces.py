"""What a deploy task gives the runtime and the CLI: a command source, its options, its evaluation.

``CommandSource`` is everything the loop knows of a task. Each tick the runtime calls ``source(t)`` for the
observation's command terms (``names``), logs ``source.record()`` (fields ``source.log_fields``), and
follows the source's schedule:

- ``hold_pose``: the pose the start-up HOLD ramp goes to before the policy (None: the policy's hold pose);
- ``begin(t)``: called on the tick POLICY starts (the source's phase 0, e.g. a motion clip's first frame);
- ``finished(t)``: a reason once the commands are over (a motion clip's last frame); the runtime then
  enters HOLD at ``end_pose`` (gains kept) and ends the run as completed after ``RuntimeConfig.end_hold``;
- ``after_policy_tick()``: called after each tick that ended in POLICY (a task's scored ticks: the piano's
  song window, counted alike by ``bar-deploy eval`` and the run's figure).

A source feeds the terms of exactly one task (``task``); a policy of another task refuses it (the
runtime's message names both tasks). ``DeployTask`` is one task's entry for ``bar-deploy``: its
``run`` / ``eval`` options, the command source built from them, its evaluation with its own metric
(run by the ``tasks.episodes.EpisodeRunner`` the runtime hands in), and the figure a ``bar-deploy`` run
ends with (``run_figure``: a ``RunFigure`` fed every tick, whose ``line()`` follows the ``end:`` line).

These are the interfaces a task's deploy part implements (``bar_policy/tasks/<task>/deploy.py``), so they
live here, below the runtime that calls them (``deploy.runtime``, ``deploy.cli``), not inside it.
"""

from __future__ import annotations

import abc
import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.robot.scene import SceneEdit
    from bar_policy.tasks.episodes import EpisodeRunner, Policy

__all__ = ["CommandSource", "DeployTask", "EvalReport", "OptionError", "RunFigure"]

LogFields = dict[str, tuple[tuple[int, ...], type]]


class OptionError(ValueError):
    """A ``bar-deploy`` option that does not fit the policy's task (or is malformed)."""


class CommandSource(abc.ABC):
    """Feeds one task's command terms, one dict per control tick, and states the task's schedule."""

    task: ClassVar[str] = ""
    """The deploy task whose command terms this source feeds."""

    names: tuple[str, ...] = ()
    """Command terms fed to the observation, in the layout's order."""
    hand_load: ClassVar[str] = "off"
    """The task's hand-load compensation when the run does not choose one (``RuntimeConfig.hand_load``):
    ``estimate``, ``tare`` (needs ``still_s`` > 0) or ``off`` (``deploy.hand_load``)."""
    load_inertia: ClassVar[bool] = False
    """The task's load-inertia feed-forward when the run does not choose (``RuntimeConfig.load_inertia``;
    ``deploy.load_inertia``): the fit's masses' inertia, from a reference arm in ``reference_scene``."""
    outside_count: int = 0
    """Commands seen outside the training distribution (counted and logged, never clipped)."""

    @abc.abstractmethod
    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The command terms at run time ``t`` (s): one float array per name."""

    # -- logging -------------------------------------------------------------------------------------
    @property
    def log_fields(self) -> LogFields:
        """Per-tick values the run log records: name -> (shape, dtype). Default: nothing beyond the obs."""
        return {}

    def record(self) -> dict[str, Any]:
        """The ``log_fields`` values of the last call."""
        return {}

    def metadata(self) -> dict[str, Any]:
        """JSON description for the run log (the clip, the file, the seed)."""
        return {"task": self.task, "describe": self.describe()}

    # -- schedule ------------------------------------------------------------------------------------
    @property
    def hold_pose(self) -> np.ndarray | None:
        """Where the start-up HOLD ramp goes (rad, canonical order); None: the policy's hold pose."""
        return None

    @property
    def end_pose(self) -> np.ndarray | None:
        """Where HOLD goes once ``finished`` (rad); None: the pose the robot is in."""
        return None

    @property
    def still_s(self) -> float:
        """How long from POLICY's first tick the commands hold the arms still and off any contact, s.

        The hand-load ``tare`` fits the loads then (0: never still; ``tare`` is refused).
        """
        return 0.0

    @property
    def reference_scene(self) -> SceneEdit | None:
        """What the task adds to the robot's scene, for the load-inertia reference arm (None: nothing).

        The piano's keyboard: its keys stop the reference's fingertip where they stop the robot's.
        """
        return None

    def begin(self, t: float) -> None:  # noqa: B027 - optional hook
        """POLICY starts at run time ``t`` (s): the commands' phase 0."""

    # -- the robot's side ------------------------------------------------------------------------------
    def attach(self, target: Any) -> None:  # noqa: B027 - optional hook
        """The runtime's target, given once before the first tick (a source that reads the sim's scene)."""

    def observe(self, q: np.ndarray, dq: np.ndarray) -> None:  # noqa: B027 - optional hook
        """The measured joint state (rad, rad/s, canonical order), each tick before ``__call__``."""

    def target_q(self) -> np.ndarray | None:
        """Joint positions the last call's command targets, rad (canonical order); None: no reference.

        Chatter is measured on ``q_cmd`` minus it (tracking), or on ``q_cmd`` itself when it is None.
        """
        return None

    def finished(self, t: float) -> str | None:
        """Why the commands are over at run time ``t`` (a completed run), or None while they last."""
        return None

    def after_policy_tick(self) -> None:  # noqa: B027 - optional hook
        """The tick of the last call ended in POLICY: a tick the task may score (the piano's song ticks).

        The runtime calls it after the tick's log record and transitions, on exactly the ticks
        ``bar-deploy eval``'s per-tick hook sees in POLICY.
        """

    # -- misc ----------------------------------------------------------------------------------------
    def describe(self) -> str:
        """One line for logs."""
        return type(self).__name__

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release threads and sockets."""


class EvalReport(abc.ABC):
    """A task's evaluation result: printed by ``bar-deploy eval`` and written with ``--json``."""

    @abc.abstractmethod
    def format(self) -> str:
        """Summary lines."""

    @abc.abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """JSON form (with ``gate_report()`` under ``"gate_report"``)."""

    @abc.abstractmethod
    def gate_report(self) -> dict[str, Any]:
        """The held-out report the ship gate reads (``bar_policy.quality.gate``).

        ``{"task", "quality", "episodes", <the task's accuracy figures>}``.
        """

    def gate_lines(self) -> list[str]:
        """The gate's thresholds, then PASS or one line per miss."""
        import bar_policy.tasks.registry  # noqa: F401 - registers every task's gate
        from bar_policy.quality import check, thresholds_text

        rep = self.gate_report()
        misses = check(rep["task"], rep)
        verdict = ["gate: PASS"] if not misses else [f"gate: MISS {m}" for m in misses]
        return [thresholds_text(rep["task"]), *verdict]


class RunFigure(abc.ABC):
    """A task's figure of one ``bar-deploy`` run (reach: success rate and final distance; track: errors).

    The CLI gets one from the task (``DeployTask.run_figure``, the task found through the registry by the
    policy's ``bar.task``), hands ``tick`` to the runtime (called after every tick with the tick index,
    the run time in s and the runtime: ``safety.mode``, ``last_state.q``, ``last_commands``) and prints
    ``final_line()`` after the ``end:`` line. Only the ticks the policy drove count (``policy_ticks``).
    A task implements ``on_tick``, ``line`` and ``to_dict``; ``tick`` keeps a failing figure from ending a
    run on the robot (the error is logged once, the figure stops, ``final_line`` says so).
    """

    error: str = ""
    """Why the figure stopped (``tick`` caught an exception), empty while it runs."""

    def tick(self, k: int, t: float, rt: Any) -> None:
        """``on_tick``, guarded: an exception is logged once and stops the figure, never the run."""
        if self.error:
            return
        try:
            self.on_tick(k, t, rt)
        except Exception as e:  # a bug in a figure must not stop the robot
            self.error = f"stopped at tick {k}: {type(e).__name__}: {e}"
            logging.getLogger(__name__).warning("the run's task figure %s", self.error, exc_info=True)

    def final_line(self) -> str:
        """``line()``, or the task's name and why its figure stopped."""
        return f"{type(self).__name__}: no figure ({self.error})" if self.error else self.line()

    @staticmethod
    def policy_ticking(rt: Any) -> bool:
        """Whether the runtime's tick was a POLICY one (the mode's name: the task does not import it)."""
        mode = getattr(getattr(rt, "safety", None), "mode", None)
        return getattr(mode, "name", "") == "POLICY" and getattr(rt, "last_state", None) is not None

    @abc.abstractmethod
    def on_tick(self, k: int, t: float, rt: Any) -> None:
        """Take in one tick (the runtime's ``on_tick`` hook)."""

    @abc.abstractmethod
    def line(self) -> str:
        """One line, ``<task>: <figure>`` (``<task>: no policy ticks`` when the policy never drove)."""

    @abc.abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """The figure's numbers (SI units: m, rad), for a result file."""


class DeployTask(abc.ABC):
    """One task's entry in ``bar-deploy``: options, command source, evaluation."""

    name: ClassVar[str]
    """Task name (``bar.task``)."""
    summary: ClassVar[str]
    """What its policies do, a few words (messages)."""
    usage: ClassVar[str]
    """How to give its commands on the command line (messages)."""
    run_options: ClassVar[tuple[tuple[str, str], ...]] = ()
    """``bar-deploy run`` options of this task: (option string, argparse dest)."""
    eval_options: ClassVar[tuple[tuple[str, str], ...]] = ()
    """``bar-deploy eval`` options of this task: (option string, argparse dest)."""
    default_duration: ClassVar[float | None] = 10.0
    """Run length when ``--duration`` is not given, s (None: until the commands end or a stop)."""
    example_run: ClassVar[tuple[str, ...]] = ()
    """``bar-deploy run`` options of a short demonstration run (the shipped files' mock-target test runs each
    shipped file with its task's)."""
    seed_help: ClassVar[str] = ""
    """What ``bar-deploy --seed`` seeds in this task (empty: nothing); the CLI's help joins them."""

    def add_run_arguments(self, parser: argparse.ArgumentParser) -> None:  # noqa: B027 - optional
        """Add the run options (every default None: ``check_options`` tells given from not given)."""

    def add_eval_arguments(self, parser: argparse.ArgumentParser) -> None:  # noqa: B027 - optional
        """Add the eval options (defaults None, as above)."""

    def scene(self, policy: Policy) -> SceneEdit | None:
        """What the task adds to the sim target's scene (``robot.scene.SceneEdit``); None: the robot alone."""
        return None

    @abc.abstractmethod
    def command_source(
        self, policy: Policy, args: argparse.Namespace, kinematics: Kinematics | None = None
    ) -> CommandSource:
        """The command source the run options ask for.

        Raises:
            OptionError: a malformed option (the message names it and the valid choices).
        """

    def plot(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], out: Path) -> list[Path]:
        """The task's own PNGs of a run log (``bar-deploy plot``) written under ``out``; default none."""
        return []

    def run_figure(
        self, policy: Policy, commands: CommandSource, kinematics: Kinematics | None = None
    ) -> RunFigure | None:
        """The figure a ``bar-deploy`` run of this task ends with (fed every tick); None: the task has none.

        ``commands`` is the run's source (``command_source``'s), ``kinematics`` the robot's forward
        kinematics when the CLI built it (None: build one if needed).
        """
        return None

    def evaluate(self, policy: Policy, args: argparse.Namespace, runner: EpisodeRunner) -> EvalReport:
        """Sim2sim evaluation with this task's metric, its episodes run by ``runner``.

        ``bar-deploy eval`` hands in the runtime's runner (``deploy.episodes.SimEpisodes``: the C MuJoCo sim
        target, the deploy code path), so the task never imports the runtime.
        """
        raise OptionError(
            f"{policy.path} is a {self.name!r} policy ({self.summary}): there is no task metric to evaluate; "
            "bar-deploy eval evaluates reach and track policies"
        )

    def check_options(
        self,
        policy_path: object,
        args: argparse.Namespace,
        others: tuple[DeployTask, ...],
        which: str = "run",
    ) -> None:
        """Refuse options of other tasks given for a policy of this task (the message says so).

        Args:
            policy_path: the policy file (for the message).
            args: the parsed options.
            others: the other tasks.
            which: ``run`` or ``eval`` (whose options to check).
        """
        for other in others:
            options = other.run_options if which == "run" else other.eval_options
            mine = {dest for _, dest in (self.run_options if which == "run" else self.eval_options)}
            for flag, dest in options:
                value = getattr(args, dest, None)
                if value is None or dest in mine:
                    continue
                shown = f"{flag} {value}" if not isinstance(value, bool) else flag
                hint = self.usage if which == "run" else self.eval_usage
                raise OptionError(
                    f"{shown} is for {other.name!r} policies ({other.summary}), but {policy_path} is a "
                    f"{self.name!r} policy ({self.summary}); {hint}"
                )

    @property
    def eval_usage(self) -> str:
        """How to evaluate this task's policies (messages)."""
        if not self.eval_options:
            return "its policies have no evaluation"
        return "its evaluation options: " + ", ".join(flag for flag, _ in self.eval_options)
