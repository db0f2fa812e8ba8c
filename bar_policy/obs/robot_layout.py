"""The parts every task's layout shares: the robot's joint fields and its state terms.

A task's layout (``tasks/<task>/layout.py``) is ``robot_schema(name, version, mode, terms)`` with its own
terms around ``state_terms(n)``: measured q (offset by the default pose), dq (scaled by 0.1) and the last
action, every one clipped at 100.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from bar_policy.obs.manager import ObservationSchema, ObsTerm
from bar_policy.robot.constants import load_robot
from bar_policy.robot.error_ema import ERROR_EMA_SCALE

__all__ = ["CLIP", "ERROR_EMA_TERM", "robot_schema", "state_terms", "term", "with_error_ema"]

ERROR_EMA_TERM = "joint_error_ema"
"""The opt-in integral-like term (``robot.error_ema``)."""

CLIP = 100.0
"""Clip of every shipped layout's terms (after scaling)."""


def term(name: str, size: int, scale: float = 1.0) -> ObsTerm:
    """One term at the shipped layouts' clip."""
    return ObsTerm(name=name, size=size, scale=scale, clip=CLIP)


def state_terms(n: int) -> tuple[ObsTerm, ObsTerm, ObsTerm]:
    """``joint_pos``, ``joint_vel`` (x 0.1) and ``actions`` for ``n`` joints, in Humanoid Control's order."""
    return term("joint_pos", n), term("joint_vel", n, 0.1), term("actions", n)


def robot_schema(
    name: str,
    version: int,
    mode: str,
    terms: Sequence[ObsTerm],
    default_joint_pos: Sequence[float] | None = None,
    **extra: Any,
) -> ObservationSchema:
    """A layout over every joint of ``mode``, each acted on; default pose ``piano_ready`` unless given.

    ``extra``: the schema's other fields (``body_names``, ``lookahead_steps``).
    """
    robot = load_robot(mode)
    pose = robot.pose("piano_ready") if default_joint_pos is None else default_joint_pos
    return ObservationSchema(
        name=name,
        version=version,
        robot=robot.robot,
        mode=mode,
        joint_names=robot.joint_names,
        action_joint_names=robot.joint_names,
        default_joint_pos=tuple(float(x) for x in pose),
        terms=tuple(terms),
        **extra,
    )


def with_error_ema(schema: ObservationSchema) -> ObservationSchema:
    """``schema`` with ``joint_error_ema`` appended (one per joint, x ``ERROR_EMA_SCALE``), version + 1.

    The opt-in layout of a task (``RobotEnvConfig.joint_error_ema``; the robust presets): same name, the
    next version (``lite_reach_arms`` v2), a new fingerprint; the task's own layout is unchanged.
    """
    n = len(schema.joint_names)
    return replace(
        schema, version=schema.version + 1, terms=(*schema.terms, term(ERROR_EMA_TERM, n, ERROR_EMA_SCALE))
    )
