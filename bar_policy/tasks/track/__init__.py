"""Motion tracking: follow a reference clip with lookahead.

The folder holds the whole task; this ``__init__`` stays light (numpy and C MuJoCo only: deploy imports it
with jax blocked) and re-exports the shared definitions:

==================  =========================================================================================
``shared.py``       the reference table with lookahead, the tracked bodies, the action box (numpy and jax)
``terms.py``        the observation terms it adds (the reference with lookahead)
``layout.py``       its observation layout ``lite_track_<mode>``
``config.py``       ``TrackEnvConfig`` (rewards, clips, termination, adaptive start sampling)
``env.py``          ``LiteTrack`` (MJX): rewards, termination, metrics                      jax
``preset.py``       the training presets ``track``, ``track-rsl`` (the tracker on rsl-rl, robot grade),
                    ``track-robust``
``reference.py``    the deploy command source (``MotionReference``, ``--motion``)          numpy
``evaluate.py``     ``bar-deploy eval``: joint, body and fingertip errors on held-out clips
``deploy.py``       the ``track`` deploy task (options, command source, evaluation)
==================  =========================================================================================
"""

from bar_policy.task_records import EnvEntry, TaskRecord
from bar_policy.tasks.track.shared import (
    ACTION_MARGIN,
    COMMAND_TERMS,
    LOST_DISTANCE,
    SUCCESS_FINGERTIP_M,
    SUCCESS_JOINT_RAD,
    TRACK_BODY_NAMES,
    TRACK_LOOKAHEAD_STEPS,
    ReferenceTable,
    lookahead_frames,
    reference_inputs,
    track_action_scale,
    track_default_pose,
)

__all__ = [
    "ACTION_MARGIN",
    "COMMAND_TERMS",
    "LOST_DISTANCE",
    "RECORD",
    "SUCCESS_FINGERTIP_M",
    "SUCCESS_JOINT_RAD",
    "TRACK_BODY_NAMES",
    "TRACK_LOOKAHEAD_STEPS",
    "ReferenceTable",
    "lookahead_frames",
    "reference_inputs",
    "track_action_scale",
    "track_default_pose",
]

_HERE = "bar_policy.tasks.track"

RECORD = TaskRecord(
    name="track",
    summary="motion tracking",
    envs=(
        EnvEntry(
            name="LiteTrack",
            env=f"{_HERE}.env:LiteTrack",
            config=f"{_HERE}.config:default_config",
            action_prior="reference",
        ),
    ),
    layout=f"{_HERE}.layout:schema",
    terms=f"{_HERE}.terms:TERMS",
    shipped_layouts=(("lite_track_arms", "arms"),),
    command_terms=COMMAND_TERMS,
    implied_by=COMMAND_TERMS,
    hc_only=False,
    metadata_keys=("body_names", "lookahead_steps", "dataset_repo_id"),
    metric="joint, tracked-body and fingertip errors on held-out clips",
    presets=(
        ("track", f"{_HERE}.preset:TRACK"),
        ("track-rsl", f"{_HERE}.preset:TRACK_RSL"),
        ("track-robust", f"{_HERE}.preset:TRACK_ROBUST"),
    ),
    gate=f"{_HERE}.gate:GATE",
    deploy=f"{_HERE}.deploy",
)
"""The track task's registration (``bar_policy.tasks.registry``)."""
