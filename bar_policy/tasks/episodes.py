"""What a task's deploy part reads of a policy and of the runtime: protocols the deploy runtime implements.

The tasks sit below the deploy runtime (``bar_policy.deploy``) and never import it. ``Policy`` is what a
command source or an evaluation reads of a loaded policy file (``deploy.policy.OnnxPolicy`` is one).
``EpisodeRunner`` is what an evaluation needs to run episodes through the deploy code path;
``bar-deploy eval`` builds the runtime's (``deploy.episodes.SimEpisodes``: the C MuJoCo sim target with the
damping the policy was trained with, and ``Runtime`` with the policy from the first tick, no ramp) and hands
it to the task (``DeployTask.evaluate``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from bar_policy.obs.manager import ObservationManager
    from bar_policy.robot.constants import RobotSpec
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.robot.scene import SceneEdit

__all__ = ["EpisodeRunner", "Policy", "RunOutcome", "TickHook", "report_progress", "true_q"]


class Policy(Protocol):
    """A loaded policy file, as a task reads it."""

    path: Path
    """The file it was loaded from."""
    task: str
    """Its deploy task."""
    metadata: Any
    """The parsed metadata (``deploy.metadata.PolicyMetadata``: ``randomization``, the task's keys)."""
    robot: RobotSpec
    """The joint set it runs on."""
    obs_manager: ObservationManager
    """Its observation layout."""
    default_joint_pos: np.ndarray
    """Default pose, rad (canonical order)."""

    @property
    def policy_dt(self) -> float:
        """Control period, s."""
        ...


TickHook = Callable[[int, float, Any], None]
"""Called after each tick's physics with the tick index, the run time (s) and the runtime (its ``safety``:
``mode``, ``fault_count``; its ``last_commands``)."""


class RunOutcome(Protocol):
    """How one episode ended (``deploy.run_config.RunResult``)."""

    ticks: int
    fault_count: int
    end_reason: str
    quality: dict[str, Any]
    """``{"episode": EpisodeQuality.to_dict(), ...}``: the run's safety and smoothness."""


class EpisodeRunner(Protocol):
    """Runs a policy for one episode at a time through the deploy code path."""

    policy_mode: Any
    """The supervisor's mode while the policy drives (compare with the runtime's ``safety.mode``)."""
    target_label: str
    """What a report calls the runner's target (``C MuJoCo sim target``, ``emulated CAN bus (lockstep)``)."""

    def target(self, *, initial_pose: str | None = None, scene: SceneEdit | None = None) -> Any:
        """A fresh sim target (``reset(q[, dq])``, ``read_state()``).

        In ``scene`` (None: the robot alone), at ``initial_pose`` (None: the target's default).
        """
        ...

    def run(
        self,
        target: Any,
        commands: Any,
        duration: float,
        *,
        kinematics: Kinematics | None = None,
        on_tick: TickHook | None = None,
    ) -> RunOutcome:
        """One episode of ``duration`` s on ``target`` (already reset), the policy from the first tick.

        ``commands`` is the episode's ``tasks.interfaces.CommandSource``.
        """
        ...


def report_progress(runner: Any, kind: str, index: int, total: int, figure: str) -> None:
    """Tell ``runner`` that episode ``index`` of ``total`` (1-based) ended with ``figure`` (one line's worth).

    ``kind`` names the unit (``episode``, ``clip``, ``song``). A runner with a ``progress`` method (the
    runtime's ``SimEpisodes``: ``bar-deploy eval``'s progress line) receives it; others ignore it, so an
    evaluation works with any runner.
    """
    fn = getattr(runner, "progress", None)
    if fn is not None:
        fn(kind, index, total, figure)


def true_q(target: Any) -> np.ndarray:
    """The joint positions an evaluation scores, rad: the robot's true joints.

    A target of a perturbed robot (``deploy.targets.perturbed``: an encoder offset, an observation delay)
    has ``true_q()``: where the joints really are, which the runtime does not read. Any other target's
    reading is its truth: ``read_state().q``.
    """
    fn = getattr(target, "true_q", None)
    return np.asarray(fn() if fn is not None else target.read_state().q)
