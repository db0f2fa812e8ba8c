"""The Lite robot as data: the one source of truth for joint order, CAN layout, limits and gains.

Everything per joint comes from ``lite_dummy.json`` beside this module (shaped like Lite-Description's
``cad/ros2_control.json``, plus URDF limits and MJCF joint properties). The canonical joint order is the
file's order: indices 0-13 are the arms (``mode="arms"``), 14-16 the neck (``mode="arms_neck"``). Once a
policy is trained against this order it is frozen: new joints are appended, never inserted.

numpy only: the deploy side imports this without jax.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from bar_policy.robot.actuators import RobstrideSpec, robstride_spec

__all__ = [
    "MODES",
    "POSE_NAMES",
    "JointSpec",
    "RobotSpec",
    "load_robot",
    "robot_from_ros2_control",
]

MODES: tuple[str, ...] = ("arms", "arms_neck")
"""Valid joint-set modes: 14 arm joints, or 17 with the neck."""

ROBOT_DATA_FILE = "lite_dummy.json"

# ---------------------------------------------------------------------------------------------------
# Sites, bodies and named poses (rad, canonical order, per arm: pitch, roll, yaw, elbow, w_yaw, w_roll,
# w_pitch). Sources: lite-model.md sections 1.2 and 4.6.
# ---------------------------------------------------------------------------------------------------
FINGERTIP_SITES: tuple[str, str] = ("left_finger2_tip", "right_finger2_tip")
"""MJCF site names of the two fingertips (left, right)."""

_ARM_POSES: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "zero": ((0.0,) * 7, (0.0,) * 7),
    "arms_hanging": (
        (0.0, -math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0),
        (0.0, math.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0),
    ),
    "piano_ready": (
        (0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3),
        (0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3),
    ),
}
POSE_NAMES: tuple[str, ...] = tuple(_ARM_POSES)
"""Named poses: ``zero`` (CAD zero, T-pose), ``arms_hanging``, ``piano_ready`` (the standby target)."""


@dataclass(frozen=True, kw_only=True)
class JointSpec:
    """One actuated joint of the Lite."""

    index: int
    """Canonical index (0-13 arms, 14-16 neck)."""
    name: str
    """Joint name, identical in the MJCF, the CAN layout and every policy file."""
    group: str
    """``left_arm``, ``right_arm`` or ``neck``."""
    can_id: int
    """Robstride CAN id (1..127)."""
    can_interface: str
    """SocketCAN interface the joint's bus is on (``can0`` left, ``can1`` right)."""
    model: str
    """Robstride model key (``rs-00`` .. ``rs-06``)."""
    direction: int
    """+1 or -1: joint = direction * (raw - homing_offset)."""
    lower: float
    """Lower position limit, rad."""
    upper: float
    """Upper position limit, rad."""
    torque_limit: float
    """Firmware torque cap written to parameter 0x700B, N*m (0 = skip the write)."""
    current_limit: float
    """Firmware current cap written to parameter 0x7018, A (0 = skip the write)."""
    kp: float
    """Default MIT stiffness, N*m/rad."""
    kd: float
    """Default MIT damping, N*m*s/rad."""
    armature: float
    """Reflected rotor inertia in the MJCF, kg*m^2."""
    frictionloss: float
    """Coulomb friction in the MJCF, N*m."""
    sim_effort: float
    """Actuator force range in the MJCF, N*m (upstream sim value; the hardware cap is torque_limit)."""

    def __post_init__(self) -> None:
        if self.direction not in (-1, 1):
            raise ValueError(f"{self.name}: direction must be +1 or -1, got {self.direction!r}")
        if not self.lower < self.upper:
            raise ValueError(f"{self.name}: lower limit {self.lower} must be below upper {self.upper}")
        if not 0 < self.can_id < 128:
            raise ValueError(f"{self.name}: CAN id must be in 1..127, got {self.can_id}")
        for field in ("torque_limit", "current_limit", "kp", "kd", "armature", "frictionloss"):
            if getattr(self, field) < 0:
                raise ValueError(f"{self.name}: {field} must be >= 0, got {getattr(self, field)}")
        spec = self.actuator  # validates the model name
        if self.torque_limit > spec.t_max:
            raise ValueError(
                f"{self.name}: torque_limit {self.torque_limit} N*m exceeds {self.model}'s range "
                f"+-{spec.t_max} N*m"
            )

    @property
    def actuator(self) -> RobstrideSpec:
        """The Robstride model spec of this joint."""
        return robstride_spec(self.model)

    @property
    def torque_cap(self) -> float:
        """Torque the MIT law is clipped to, N*m: the firmware cap, or the model's range when the cap is 0."""
        return self.torque_limit if self.torque_limit > 0 else self.actuator.t_max


@dataclass(frozen=True, kw_only=True)
class RobotSpec:
    """The joint set of one mode, in canonical order, with per-joint arrays for vectorised code.

    Every array has shape ``(num_joints,)`` and float64 dtype (int for ids and directions).
    """

    robot: str
    """Robot name (``lite_dummy``)."""
    mode: str
    """``arms`` (14 joints) or ``arms_neck`` (17)."""
    joints: tuple[JointSpec, ...]
    """Joint specs in canonical order."""

    def __post_init__(self) -> None:
        names = [j.name for j in self.joints]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"duplicate joint names in the robot data: {dup}")
        ids = [(j.can_interface, j.can_id) for j in self.joints]
        dup_ids = sorted({i for i in ids if ids.count(i) > 1})
        if dup_ids:
            raise ValueError(f"duplicate (interface, CAN id) pairs in the robot data: {dup_ids}")

    @property
    def num_joints(self) -> int:
        """Number of actuated joints (14 or 17)."""
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names in canonical order."""
        return tuple(j.name for j in self.joints)

    def _array(self, field: str, dtype: type = np.float64) -> np.ndarray:
        return np.array([getattr(j, field) for j in self.joints], dtype=dtype)

    @property
    def lower(self) -> np.ndarray:
        """Lower joint limits, rad. Shape (num_joints,)."""
        return self._array("lower")

    @property
    def upper(self) -> np.ndarray:
        """Upper joint limits, rad. Shape (num_joints,)."""
        return self._array("upper")

    @property
    def kp(self) -> np.ndarray:
        """Default Kp, N*m/rad. Shape (num_joints,)."""
        return self._array("kp")

    @property
    def kd(self) -> np.ndarray:
        """Default Kd, N*m*s/rad. Shape (num_joints,)."""
        return self._array("kd")

    @property
    def torque_cap(self) -> np.ndarray:
        """Torque the MIT law is clipped to (firmware cap), N*m. Shape (num_joints,)."""
        return np.array([j.torque_cap for j in self.joints])

    @property
    def armature(self) -> np.ndarray:
        """MJCF armature, kg*m^2. Shape (num_joints,)."""
        return self._array("armature")

    @property
    def frictionloss(self) -> np.ndarray:
        """MJCF frictionloss, N*m. Shape (num_joints,)."""
        return self._array("frictionloss")

    @property
    def sim_effort(self) -> np.ndarray:
        """MJCF actuator force range, N*m. Shape (num_joints,)."""
        return self._array("sim_effort")

    @property
    def direction(self) -> np.ndarray:
        """Encoder directions (+1/-1). Shape (num_joints,), int."""
        return self._array("direction", np.int64)

    @property
    def can_ids(self) -> np.ndarray:
        """CAN ids. Shape (num_joints,), int."""
        return self._array("can_id", np.int64)

    @property
    def models(self) -> tuple[str, ...]:
        """Robstride model of each joint."""
        return tuple(j.model for j in self.joints)

    def pose(self, name: str) -> np.ndarray:
        """A named pose as joint positions, rad. Shape (num_joints,); the neck is 0 in every pose.

        Raises ``ValueError`` naming the valid poses for an unknown name.
        """
        if name not in _ARM_POSES:
            raise ValueError(f"unknown pose {name!r}; valid poses: {list(POSE_NAMES)}")
        left, right = _ARM_POSES[name]
        q = np.zeros(self.num_joints)
        q[:14] = left + right
        return q

    def index(self, name: str) -> int:
        """Canonical index of a joint, or ``ValueError`` listing the joints."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise ValueError(f"unknown joint {name!r}; joints: {list(self.joint_names)}") from None


def robot_from_ros2_control(
    data: Mapping[str, Any],
    mode: str = "arms",
    joint_extras: Mapping[str, Mapping[str, Any]] | None = None,
) -> RobotSpec:
    """Build a ``RobotSpec`` from a ros2_control.json-style mapping.

    The mapping has ``groups`` (name, and ``can_interface`` or upstream's ``can_interface_arg`` naming an
    entry of ``args``), ``modes`` (mode -> group names) and ``joints`` (name, group, can_id, model,
    direction, torque_limit, current_limit; our packaged file also carries lower/upper, kp/kd, armature,
    frictionloss, sim_effort). Upstream's file keeps limits in the URDF and gains elsewhere: pass those as
    ``joint_extras`` (joint name -> missing fields). Joints keep the file's order within the mode's groups.
    """
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid modes: {list(MODES)}")
    modes = data.get("modes", {})
    if mode not in modes:
        raise ValueError(f"robot data has no mode {mode!r}; it defines: {sorted(modes)}")
    groups = {g["name"]: g for g in data["groups"]}
    wanted = list(modes[mode])
    unknown = [g for g in wanted if g not in groups]
    if unknown:
        raise ValueError(f"mode {mode!r} names unknown groups {unknown}; groups: {sorted(groups)}")
    required = (
        "name",
        "group",
        "can_id",
        "model",
        "direction",
        "lower",
        "upper",
        "torque_limit",
        "current_limit",
        "kp",
        "kd",
        "armature",
        "frictionloss",
        "sim_effort",
    )
    args = data.get("args", {})
    joints = []
    for raw in data["joints"]:
        if raw.get("group") not in wanted:
            continue
        raw = {**(joint_extras or {}).get(raw.get("name", ""), {}), **raw}
        group = groups[raw["group"]]
        iface = group.get("can_interface") or args.get(group.get("can_interface_arg", ""))
        if not iface:
            raise ValueError(f"group {group['name']!r} names no CAN interface")
        missing = [k for k in required if k not in raw]
        if missing:
            raise ValueError(f"joint {raw.get('name', '?')!r} lacks keys {missing}")
        joints.append(
            JointSpec(
                index=len(joints),
                name=str(raw["name"]),
                group=str(raw["group"]),
                can_id=int(raw["can_id"]),
                can_interface=str(iface),
                model=str(raw["model"]),
                direction=int(raw["direction"]),
                lower=float(raw["lower"]),
                upper=float(raw["upper"]),
                torque_limit=float(raw["torque_limit"]),
                current_limit=float(raw["current_limit"]),
                kp=float(raw["kp"]),
                kd=float(raw["kd"]),
                armature=float(raw["armature"]),
                frictionloss=float(raw["frictionloss"]),
                sim_effort=float(raw["sim_effort"]),
            )
        )
    return RobotSpec(robot=str(data.get("robot", "lite_dummy")), mode=mode, joints=tuple(joints))


@cache
def _robot_data() -> dict[str, Any]:
    text = resources.files("bar_policy.robot").joinpath(ROBOT_DATA_FILE).read_text()
    return json.loads(text)


@cache
def load_robot(mode: str = "arms") -> RobotSpec:
    """The Lite joint set for ``mode`` (``arms``: 14 joints, ``arms_neck``: 17), from the packaged data."""
    return robot_from_ros2_control(_robot_data(), mode)
