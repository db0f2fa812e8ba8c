"""The runtime's episode runner for a task's evaluation (``tasks.episodes.EpisodeRunner``).

``bar-deploy eval`` (and ``train/ship.py``) builds one for the loaded policy and hands it to the task's
``DeployTask.evaluate``, so the task runs its episodes through the deploy code path (``Runtime``: the
observation manager, the action clip, the safety supervisor, the target's MIT law) without importing the
runtime: every episode starts in POLICY with no ramp, a fault damps nothing, no signal handlers.

``BusEpisodes`` runs the same episodes on the real target over the emulated Robstride bus in lockstep
(``targets.emulated.EmulatedBusTarget``: the CAN code path, the 16-bit feedback, the firmware's law;
``bar-deploy eval --target bus``), the perturbed robot being the emulator's. A runner
is a context manager: leaving it closes the targets it made (the emulator's thread and its buses).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from bar_policy.deploy.run_config import RunResult, RuntimeConfig
from bar_policy.deploy.runtime import Runtime
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.safety_config import Mode

if TYPE_CHECKING:
    from bar_policy.deploy.policy import OnnxPolicy
    from bar_policy.deploy.targets.base import Target
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget
    from bar_policy.deploy.targets.sim import SimTarget
    from bar_policy.robot.kinematics import Kinematics
    from bar_policy.robot.params import RobotParams
    from bar_policy.robot.perturb_spec import Perturbation
    from bar_policy.robot.scene import SceneEdit
    from bar_policy.tasks.episodes import TickHook
    from bar_policy.tasks.interfaces import CommandSource

__all__ = ["RUNNERS", "BusEpisodes", "SimEpisodes"]


class SimEpisodes:
    """Episodes of ``policy`` on the C MuJoCo sim target (or a target the caller passes to ``run``)."""

    policy_mode = Mode.POLICY
    target_label = "C MuJoCo sim target"
    """What the evaluations' reports call the target."""

    def __init__(
        self,
        policy: OnnxPolicy,
        safety: SafetyConfig | None = None,
        *,
        perturbation: Perturbation | None = None,
        robot_params: RobotParams | None = None,
        say: Callable[[str], None] | None = None,
        hand_load: str | None = None,
        load_inertia: bool | None = None,
    ) -> None:
        """``safety``: the supervisor's thresholds (default ``SafetyConfig()``; the ramp is always 0).

        ``perturbation``: the sim target's robot differs from the model so (``--perturb``; None: nominal).
        ``robot_params``: the model is that identified robot (``--robot-params``; a perturbation applies on
        top of it; None: the description's robot).
        ``say``: where the progress lines go (``progress``; ``bar-deploy eval`` passes ``print``, ``--quiet``
        None: no lines).
        ``hand_load``: the runs' hand-load compensation (``RuntimeConfig.hand_load``; None: the task's).
        ``load_inertia``: the runs' load-inertia feed-forward (``RuntimeConfig.load_inertia``; None: the
        task's).
        """
        self.policy = policy
        self.hand_load = hand_load
        self.load_inertia = load_inertia
        self.safety = dataclasses.replace(safety or SafetyConfig(), ramp_time=0.0)
        self.perturbation = perturbation
        self.robot_params = robot_params
        self.say = say
        self.started = time.monotonic()
        from bar_policy.deploy.targets.sim import note_physics_dt

        note_physics_dt(policy.metadata.physics_dt)  # once per evaluation, not per episode

    def __enter__(self) -> SimEpisodes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the targets this runner made (the sim target holds nothing to close)."""

    def progress(self, kind: str, index: int, total: int, figure: str) -> None:
        """One progress line: ``eval episode 3/100: <figure> (12.3 s)``, the time since the runner was made.

        Called by the task's evaluation after each episode, clip or song (``tasks.episodes.report_progress``).
        """
        if self.say is not None:
            self.say(f"eval {kind} {index}/{total}: {figure} ({time.monotonic() - self.started:.1f} s)")

    def target(self, *, initial_pose: str | None = None, scene: SceneEdit | None = None) -> SimTarget:
        """A sim target integrating the law's damping as the policy was trained (``training_damping``).

        Of the identified robot when the runner has robot parameters, perturbed when it has a perturbation
        (``targets.perturbed.sim_target``).
        """
        from bar_policy.deploy.targets.perturbed import sim_target
        from bar_policy.deploy.targets.sim import SimConfig, training_damping

        damping = training_damping(self.policy.metadata.randomization)
        pose = {} if initial_pose is None else {"initial_pose": initial_pose}
        config = SimConfig(damping=damping, **pose)
        return sim_target(
            self.policy.robot.mode,
            config,
            scene=scene,
            perturbation=self.perturbation,
            robot_params=self.robot_params,
        )

    def run(
        self,
        target: Target,
        commands: CommandSource,
        duration: float,
        *,
        kinematics: Kinematics | None = None,
        on_tick: TickHook | None = None,
    ) -> RunResult:
        """One episode of ``duration`` s on ``target`` (already reset), the policy from the first tick."""
        cfg = RuntimeConfig(
            control_dt=self.policy.policy_dt,
            duration=duration,
            start_mode="policy",
            damping_after_fault=0.0,
            handle_signals=False,
            safety=self.safety,
            hand_load=self.hand_load,
            load_inertia=self.load_inertia,
        )
        return Runtime(self.policy, target, commands, cfg, kinematics=kinematics, on_tick=on_tick).run()


class BusEpisodes(SimEpisodes):
    """Episodes of ``policy`` on the real target over the emulated bus in lockstep (module docstring)."""

    target_label = "emulated CAN bus (lockstep)"

    def __init__(self, policy: OnnxPolicy, *args: Any, **kwargs: Any) -> None:
        """As ``SimEpisodes``; ``perturbation`` and ``robot_params`` make the emulator's robot."""
        super().__init__(policy, *args, **kwargs)
        self._made: list[EmulatedBusTarget] = []

    def target(self, *, initial_pose: str | None = None, scene: SceneEdit | None = None) -> EmulatedBusTarget:
        """A fresh emulated bus in ``scene`` (None: the robot alone; the piano's keyboard).

        ``initial_pose`` is unused: every evaluation resets the target to its episode's pose, where the
        emulator starts at rest (``EmulatedBusTarget.reset``).
        """
        from bar_policy.deploy.targets.emulated import EmulatedBusTarget

        target = EmulatedBusTarget(
            self.policy.robot.mode,
            self.policy.policy_dt,
            scene=scene,
            perturbation=self.perturbation,
            robot_params=self.robot_params,
        )
        self._made.append(target)
        return target

    def close(self) -> None:
        """Close every emulated bus this runner made (safe to call twice)."""
        while self._made:
            self._made.pop().close()


RUNNERS: dict[str, type[SimEpisodes]] = {"sim": SimEpisodes, "bus": BusEpisodes}
"""The episode runner of each evaluation target (``bar-deploy eval --target``, ``train/ship.py
--robustness-targets``)."""
