"""Bimanual reach: each fingertip of the Lite to its own target.

The folder holds the whole task; this ``__init__`` stays light (numpy only: deploy imports it with jax
blocked) and re-exports the shared definitions:

==================  =========================================================================================
``shared.py``       the target distribution, the success radius, the command transition (numpy and jax)
``terms.py``        the observation terms it adds (the fingertip targets)
``layout.py``       its observation layout ``lite_reach_<mode>``
``env.py``          ``LiteReach`` (MJX): rewards, metrics, episode, ``ReachEnvConfig``        jax
``preset.py``       the training presets ``gpu``, ``rsl`` (rsl-rl at the field's values), ``gpu-rsl``
                    (``--backend rsl-rl``'s default), ``cpu``, ``tiny``, ``reach-robust``
``commands.py``     deploy command sources (``--commands sampled|file:|stream:``)         numpy
``transition.py``   the deploy side of the command transition (``TransitionCommands``)
``evaluate.py``     ``bar-deploy eval``: segment success rate on the C MuJoCo sim target
``deploy.py``       the ``reach`` deploy task (options, command source, evaluation)
==================  =========================================================================================
"""

from bar_policy.task_records import EnvEntry, TaskRecord
from bar_policy.tasks.reach.shared import (
    SUCCESS_RADIUS,
    ReachTargetConfig,
    min_jerk,
    sample_targets,
    transition_point,
)

__all__ = [
    "RECORD",
    "SUCCESS_RADIUS",
    "ReachTargetConfig",
    "min_jerk",
    "sample_targets",
    "transition_point",
]

_HERE = "bar_policy.tasks.reach"

RECORD = TaskRecord(
    name="reach",
    summary="fingertip targets",
    envs=(
        EnvEntry(name="LiteReach", env=f"{_HERE}.env:LiteReach", config=f"{_HERE}.env:default_config"),
        EnvEntry(name="LiteReachNeck", env=f"{_HERE}.env:LiteReach", config=f"{_HERE}.env:neck_config"),
    ),
    layout=f"{_HERE}.layout:schema",
    terms=f"{_HERE}.terms:TERMS",
    shipped_layouts=(("lite_reach_arms", "arms"), ("lite_reach_arms_neck", "arms_neck")),
    command_terms=("target_pos_left", "target_pos_right"),
    implied_by=("target_pos_left", "target_pos_right", "fingertip_pos_left", "fingertip_pos_right"),
    hc_only=True,
    metadata_keys=("command_transition_s",),
    metric="segment success rate (both fingertips within 3 cm at a segment's end)",
    presets=(
        *((p, f"{_HERE}.preset:{p.upper()}") for p in ("gpu", "rsl", "cpu", "tiny")),
        ("gpu-rsl", f"{_HERE}.preset:GPU_RSL"),
        ("reach-robust", f"{_HERE}.preset:REACH_ROBUST"),
    ),
    gate=f"{_HERE}.gate:GATE",
    deploy=f"{_HERE}.deploy",
)
"""The reach task's registration (``bar_policy.tasks.registry``)."""
