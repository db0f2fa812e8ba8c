"""The robustness randomisation as env overrides, and the ``<task>-robust`` training presets built from it.

``ROBUST_ENV_OVERRIDES`` turns on the randomisation that covers the deploy side's perturbation suite
(``bar_policy.robot.perturb_suite``; docs/robust_training.md): every field it sets
is a ``RobotEnvConfig`` field whose default leaves today's presets as they were. A task's preset module
adds ``robust(PRESET, "<task>-robust")``; any other run gets the same with
``--env-overrides`` and these items. Plain data: this module imports nothing (the task records are read
with jax blocked).
"""

from __future__ import annotations

from typing import Any

__all__ = ["ROBUST_ENV_OVERRIDES", "robust"]

ROBUST_ENV_OVERRIDES: tuple[str, ...] = (
    "randomization.link_mass_scale=(0.8, 1.2)",  # x, every body's mass and inertia, per env slot
    "randomization.frictionloss=(0.05, 1.35)",  # N*m: the default 0.05-0.35 plus up to +1.0
    "randomization.damping=(0.0, 1.0)",  # N*m*s/rad added to each joint's passive damping
    "randomization.armature_scale=(0.8, 1.2)",  # x, on the description-identified armature draw
    "randomization.payload_kg=(0.0, 0.6)",  # kg at each hand, drawn per hand and env slot
    "randomization.payload_at=either",  # fingertip or palm, per hand and env slot
    "actuator.strength=(0.8, 1.0)",  # x on each joint's torque and its cap, per episode
    "actuator.latency_steps=(0, 2)",  # action latency, control steps (the default's range)
    "actuator.obs_latency_steps=(0, 1)",  # observation latency, control steps
    "actuator.encoder_offset=0.01",  # rad, U(-x, x) per joint and episode (the default's)
    "randomization.nominal_share=0.2",  # a fifth of the slots drawn as the nominal robot (the gate's)
    "evaluate_nominal=true",  # the trainer's evaluations on the nominal robot, as the ship gate's sim
)
"""``dotted.path=value`` items on a ``RobotEnvConfig`` (``bar_policy.overrides``) that cover the suite's
rows: mass x0.8/x1.2, payload 0.5 kg at fingertip or palm, friction +1.0 N*m, damping +1.0 N*m*s/rad,
strength x0.8, action delay 2 ticks, observation delay 1 tick, offset 0.01 rad; and keep the nominal robot
inside the training distribution and measured by the evaluations (docs/robust_training.md, "The MJX-vs-C gap
of the first robust reach file")."""


def robust(preset: dict[str, Any], name: str, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """``preset`` renamed ``name``: its own env overrides, ``ROBUST_ENV_OVERRIDES``, then ``extra``.

    ``extra``: the task's own items for the robust case (reward weights, observation terms).
    """
    return {
        **preset,
        "preset": name,
        "env_overrides": (*preset.get("env_overrides", ()), *ROBUST_ENV_OVERRIDES, *extra),
    }
