"""The catalogue of observation terms: every name an observation schema may use, with its size rule.

A term reads one named input array and contributes ``clip((input - offset) * scale)`` to the observation.
Sizes are fixed by the term (3 for a position) or by the joint set (``"joints"``: one per joint,
``"actions"``: one per action joint), or, for the reference terms of the tracking task, by the schema's
``lookahead_steps`` K and ``body_names`` (B bodies): ``"lookahead_joints"`` = K * joints,
``"lookahead_body_pos"`` = K * B * 3, ``"lookahead_body_ori"`` = K * B * 6. Adding a term is an API
change: schemas that use it get a new version, existing golden schemas stay valid.

The robot's own terms (``ROBOT_TERMS``: joint state, the last action, the fingertips that the runtime
computes, the IMU) are defined here; a task adds its own (its commands) in its folder and names them in its
record (``TaskRecord.terms``, e.g. ``bar_policy/tasks/track/terms.py``). ``TERM_CATALOG`` is both, read
from the registered task records (``bar_policy.task_records``) on first use.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Literal

from bar_policy.task_records import records, resolve

__all__ = ["LOOKAHEAD_RULES", "ROBOT_TERMS", "TERM_CATALOG", "TermKind"]

SizeRule = int | Literal["joints", "actions", "lookahead_joints", "lookahead_body_pos", "lookahead_body_ori"]

LOOKAHEAD_RULES = ("lookahead_joints", "lookahead_body_pos", "lookahead_body_ori")
"""Size rules that need the schema's ``lookahead_steps`` (and ``body_names`` for the body terms)."""


@dataclass(frozen=True, kw_only=True)
class TermKind:
    """What a term name means."""

    size: SizeRule
    """Fixed size, ``"joints"`` / ``"actions"`` for one entry per (action) joint, or a lookahead rule."""
    category: Literal["state", "command", "action", "imu"]
    """Where the input comes from at deploy time: robot state, the command source, the policy, the IMU."""
    offset_default_pose: bool = False
    """True when the default joint pose is subtracted before scaling (``joint_pos``)."""
    unit: str = ""
    """Unit of the raw input."""
    doc: str = ""


ROBOT_TERMS: dict[str, TermKind] = {
    "joint_pos": TermKind(
        size="joints",
        category="state",
        offset_default_pose=True,
        unit="rad",
        doc="q - default_joint_pos, canonical joint order",
    ),
    "joint_vel": TermKind(size="joints", category="state", unit="rad/s", doc="dq, canonical order"),
    "actions": TermKind(size="actions", category="action", doc="previous policy output (raw action)"),
    "fingertip_pos_left": TermKind(
        size=3, category="state", unit="m", doc="left finger2_tip site, chest frame (forward kinematics)"
    ),
    "fingertip_pos_right": TermKind(
        size=3, category="state", unit="m", doc="right finger2_tip site in the chest frame"
    ),
    "joint_error_ema": TermKind(
        size="joints",
        category="state",
        unit="rad",
        doc="moving average of q_cmd (last step) - q, tau 0.5 s (robot.error_ema); opt-in layouts only",
    ),
    "projected_gravity": TermKind(size=3, category="imu", unit="1", doc="gravity direction, IMU frame"),
    "imu_quaternion": TermKind(size=4, category="imu", unit="1", doc="orientation (w, x, y, z)"),
    "imu_angular_velocity": TermKind(size=3, category="imu", unit="rad/s", doc="gyroscope"),
    "imu_linear_acceleration": TermKind(size=3, category="imu", unit="m/s^2", doc="accelerometer"),
}
"""The robot's terms: what the runtime computes from the robot's state (or the policy's last action)."""


class _Catalog(Mapping[str, TermKind]):
    """``ROBOT_TERMS`` plus every registered task's terms, read from the task records on first use.

    Lazy because a task's terms module imports ``TermKind`` from here.
    """

    def __init__(self) -> None:
        self._terms: dict[str, TermKind] | None = None

    def _load(self) -> dict[str, TermKind]:
        if self._terms is None:
            terms = dict(ROBOT_TERMS)
            for record in records():
                for name, kind in (resolve(record.terms) if record.terms else {}).items():
                    if name in terms and terms[name] != kind:
                        raise ValueError(f"task {record.name!r} redefines the observation term {name!r}")
                    terms[name] = kind
            self._terms = terms
        return self._terms

    def __getitem__(self, name: str) -> TermKind:
        return self._load()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())


TERM_CATALOG: Mapping[str, TermKind] = _Catalog()
"""Every term name a schema may use: ``ROBOT_TERMS``, then each registered task's (registry order)."""
