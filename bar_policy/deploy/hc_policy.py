"""HC-only policy files (the 13 Humanoid Control keys, no ``bar.*`` key): joint set, schema and gains.

mjlab and Humanoid Control write only the HC keys. ``complete_hc`` derives what ``bar`` files state
explicitly:

- the joint set (``mode``): the mode whose canonical joints ``joint_names`` lists, in canonical order;
- the observation schema, from ``observation_names`` with HC's built-in meaning (``joint_pos = (q -
  default) * 1``, ``joint_vel`` raw, ``actions`` = the previous action, every scale 1, no clip), whatever
  the ``task_type``; every term must be one the runtime can feed (``supported_terms``);
- the deploy task, from the terms (``deploy.task_registry.implied_task``): reach when it reads reach
  targets or fingertips, ``state`` when it reads the robot state only. HC's ``task_type`` is a free label.

Reference-tracking terms (``motion_*``) are not fed to HC-only files: HC's anchor frame and lookahead
convention for them are not verified against ours (``docs/tracking.md``); export trackers with bar_policy.
``check_hc_gains`` requires the file's gains to be inside each motor's MIT wire range (never clamped).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from bar_policy.deploy.contract import diff_joints, refuse
from bar_policy.deploy.inputs import RUNTIME_INPUTS
from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.deploy.task_registry import HC_TASKS, TASK_COMMAND_TERMS
from bar_policy.obs.manager import ObservationSchema, ObsTerm
from bar_policy.obs.terms import TERM_CATALOG
from bar_policy.robot.constants import MODES, RobotSpec, load_robot
from bar_policy.robot.mit import wire_ranges

__all__ = ["HC_TERM_CLIP", "check_hc_gains", "complete_hc", "supported_terms"]

HC_TERM_CLIP = 1e6
"""Clip of every term of an HC-only file's schema: effectively none, as Humanoid Control does not clip."""


def supported_terms() -> tuple[str, ...]:
    """Observation terms an HC-only file may use, in catalogue order.

    Read from ``TERM_CATALOG`` each call: a state or action term when the runtime computes it
    (``RUNTIME_INPUTS``), a command term when a task that HC-only files may have (``HC_TASKS``) feeds it.
    IMU terms, for one, are not fed, and neither are the tracking reference terms (module docstring).
    """
    commands = {n for task in HC_TASKS for n in TASK_COMMAND_TERMS[task]}
    return tuple(n for n in TERM_CATALOG if n in RUNTIME_INPUTS or n in commands)


def _hc_mode(path: Path, meta: PolicyMetadata) -> str:
    """The joint set whose canonical joints an HC-only file's ``joint_names`` lists."""
    for mode in MODES:
        robot = load_robot(mode)
        if set(meta.joint_names) == set(robot.joint_names) and len(meta.joint_names) == robot.num_joints:
            msg = diff_joints("metadata key 'joint_names'", meta.joint_names, robot.joint_names)
            if msg:
                raise refuse(path, msg)
            return mode
    sets = "; ".join(f"{m}: {list(load_robot(m).joint_names)}" for m in MODES)
    raise refuse(
        path,
        f"metadata key 'joint_names' lists {len(meta.joint_names)} joints {list(meta.joint_names)}, which is "
        f"not the joint set of any mode ({sets})",
    )


def complete_hc(path: Path, meta: PolicyMetadata) -> PolicyMetadata:
    """An HC-only file's joint set and observation schema, built from its HC keys (refusing unknown terms)."""
    mode = _hc_mode(path, meta)
    robot = load_robot(mode)
    supported = supported_terms()
    for key, names in (("observation_names", meta.observation_names), ("command_names", meta.command_names)):
        unknown = [n for n in names if n not in supported]
        if unknown:
            raise refuse(
                path,
                f"metadata key {key!r} uses terms {unknown} that this runtime cannot feed; "
                f"supported terms: {list(supported)}",
            )
    if not meta.observation_names:
        raise refuse(path, "metadata key 'observation_names' is empty")
    obs_commands = tuple(n for n in meta.observation_names if TERM_CATALOG[n].category == "command")
    if set(meta.command_names) != set(obs_commands):
        raise refuse(
            path,
            f"metadata key 'command_names' {list(meta.command_names)} differs from the command terms of "
            f"'observation_names' {list(obs_commands)}",
        )
    sizes = {"joints": len(meta.joint_names), "actions": len(meta.action_joint_names)}
    terms = tuple(
        ObsTerm(name=n, size=sizes.get(TERM_CATALOG[n].size, TERM_CATALOG[n].size), clip=HC_TERM_CLIP)  # type: ignore[arg-type]
        for n in meta.observation_names
    )
    try:
        schema = ObservationSchema(
            name=f"hc_{meta.task or 'policy'}_{mode}",
            version=0,
            robot=robot.robot,
            mode=mode,
            joint_names=meta.joint_names,
            action_joint_names=meta.action_joint_names,
            default_joint_pos=meta.default_joint_pos,
            terms=terms,
        )
    except ValueError as e:
        raise refuse(path, f"the HC keys do not make a valid observation schema: {e}") from None
    return dataclasses.replace(
        meta,
        robot=robot.robot,
        mode=mode,
        command_names=obs_commands,
        obs_schema=schema.to_json(indent=None),
        obs_fingerprint=schema.fingerprint,
    )


def check_hc_gains(path: Path, meta: PolicyMetadata, robot: RobotSpec) -> None:
    """An HC-only file's gains must be finite, >= 0 and within each motor's MIT wire range (never clamped)."""
    ranges = wire_ranges(robot.models)
    for key, values, top in (
        ("joint_stiffness", meta.joint_stiffness, ranges.kp_max),
        ("joint_damping", meta.joint_damping, ranges.kd_max),
    ):
        bad = [
            f"{robot.joint_names[i]}: {v:g} not in [0, {top[i]:g}]"
            for i, v in enumerate(values)
            if not (math.isfinite(v) and 0.0 <= v <= top[i])
        ]
        if bad:
            raise refuse(path, f"metadata key {key!r} is outside the motors' MIT range: {', '.join(bad)}")
