"""The ``PolicyMetadata`` of a policy trained on an env: everything read from the env, nothing retyped."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.export.policy import code_version
from bar_policy.provenance import collect
from bar_policy.robot.mjcf import PHYSICS_DT

__all__ = ["policy_metadata", "randomization_record", "with_training"]

_RANDOMIZATION_FIELDS = ("actuator", "obs_noise", "randomization", "init_noise")
"""Env config fields that describe training randomisation (recorded in ``bar.randomization``)."""


def randomization_record(env_config: Any) -> dict[str, Any]:
    """The randomisation ranges of an env config as plain JSON (tuples become lists).

    Takes the config's ``actuator`` (latency, Kp/Kd scale, encoder offset, wire quantisation, torque
    saturation), ``obs_noise``, model-level ``randomization`` and ``init_noise`` when present.
    """
    out: dict[str, Any] = {}
    for name in _RANDOMIZATION_FIELDS:
        if hasattr(env_config, name):
            value = getattr(env_config, name)
            out[name] = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
    return _jsonable(out)


def _jsonable(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if hasattr(x, "item"):
        return x.item()
    return x


def policy_metadata(
    env: Any,
    *,
    task: str | None = None,
    training: Mapping[str, Any] | None = None,
    provenance: Mapping[str, Any] | None = None,
) -> PolicyMetadata:
    """Metadata for a policy trained on ``env`` (a ``bar_policy.envs`` env).

    Reads the joint order, action joints and observation schema from ``env.obs_manager``, Kp/Kd from
    ``env.kp``/``env.kd`` (N*m/rad, N*m*s/rad) and their profile's name from ``env.config.gains``, the default
    pose and per-joint action scale (rad) from ``env.default_pose``/``env.action_scale``, the policy period
    from ``env.dt`` (s), the physics step from ``env.config.sim_dt``, the randomisation ranges from
    ``env.config`` and the action filter's cutoff from ``env.action_filter_hz`` (Hz; None: no filter), and the
    robot-parameters file's hash and summary from ``env.robot_params`` (``bar.robot_params``; none for the
    nominal model).

    Args:
        env: the (unwrapped) training env.
        task: task name written to ``task_type`` / ``bar.task`` (default: ``env.task_name``, else reach).
        training: free-form training record (backend, steps, evaluation, config).
        provenance: the run's ``bar_policy.provenance.collect()`` record (commit, dirty flag, library
            versions, training command); None collects this process's now.
    """
    om = env.obs_manager
    schema = om.schema
    cfg = getattr(env, "config", None)
    extra = env.task_metadata() if hasattr(env, "task_metadata") else {}
    return PolicyMetadata(
        task=task or getattr(env, "task_name", "reach"),
        robot=schema.robot,
        mode=schema.mode,
        joint_names=tuple(schema.joint_names),
        action_joint_names=tuple(schema.action_joint_names),
        joint_stiffness=tuple(float(x) for x in env.kp),
        joint_damping=tuple(float(x) for x in env.kd),
        default_joint_pos=tuple(float(x) for x in env.default_pose),
        action_scale=tuple(float(x) for x in env.action_scale),
        action_semantics="delta_from_default",
        policy_dt=float(env.dt),
        physics_dt=float(getattr(cfg, "sim_dt", PHYSICS_DT)),
        obs_schema=om.to_json(),
        obs_fingerprint=om.fingerprint,
        command_names=tuple(om.command_names),
        randomization=randomization_record(cfg) if cfg is not None else {},
        code_version=code_version(),
        training=_jsonable(dict(training or {})),
        action_filter_hz=getattr(env, "action_filter_hz", None),
        body_names=tuple(extra.get("body_names", ())),
        lookahead_steps=int(extra.get("lookahead_steps", 0)),
        dataset_repo_id=str(extra.get("dataset_repo_id", "")),
        command_transition_s=float(extra.get("command_transition_s", 0.0)),
        song_lead_steps=int(extra.get("song_lead_steps", 0)),
        gains=str(getattr(cfg, "gains", "robot")),
        provenance=_jsonable(dict(provenance) if provenance is not None else collect()),
        robot_params=_params_record(getattr(env, "robot_params", None)),
    )


def with_training(metadata: PolicyMetadata, training: Mapping[str, Any]) -> PolicyMetadata:
    """``metadata`` with another training record (``bar.training``; e.g. the best iterate's), as JSON."""
    return dataclasses.replace(metadata, training=_jsonable(dict(training)))


def _params_record(params: Any) -> dict[str, Any]:
    """``bar.robot_params`` of an env built from a robot-parameters file (``robot.params``); {} without."""
    if params is None:
        return {}
    from bar_policy.robot.params import params_record

    return _jsonable(params_record(params))
