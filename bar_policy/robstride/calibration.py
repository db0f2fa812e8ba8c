"""Joint calibration: the maths (pure) and the JSON file format.

Convention (lite-model.md section 2, Humanoid Control's calibration how-to)::

    joint = direction * (raw - homing_offset)        raw = direction * joint + homing_offset
    joint velocity / torque = direction * raw velocity / torque (no offset)

``homing_offset`` is per robot. It comes from a hand sweep of every joint to both mechanical stops while
the motors are disabled: with ``s = direction * raw`` (the "direction frame"), ``s_min``/``s_max`` the swept
extremes and ``lower``/``upper`` the URDF limits::

    homing_offset = direction * ((s_min - lower) + (s_max - upper)) / 2

i.e. the mean of the two extremes' offsets from the URDF limits, multiplied by direction. A joint whose
sweep is shorter than ``sweep_threshold`` keeps its prior offset (re-calibrate one joint at a time).

File format (JSON)::

    {"robot": "lite_dummy",
     "joints": {"left_shoulder_pitch": {"id": 11, "direction": -1, "homing_offset": 0.2817}, ...}}

A bare ``{"<joint>": {...}}`` mapping (without the ``joints`` key) is accepted too.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bar_policy._files import InputError, loads_json, shorten, write_atomic
from bar_policy.robot.constants import RobotSpec
from bar_policy.robstride.errors import InitializationError

__all__ = [
    "Calibration",
    "CalibrationError",
    "JointCalibration",
    "SweepRecorder",
    "SweepResult",
    "homing_offset",
]


class CalibrationError(InitializationError, InputError):
    """A calibration file is missing or malformed (an ``InitializationError`` and an ``_files.InputError``).

    ``Calibration.load`` / ``from_json`` raise only this for any malformed text (not UTF-8, invalid or too
    deeply nested JSON, wrong keys or types), with echoed values cut to ``_files.ECHO_LIMIT`` characters.
    """


def homing_offset(raw_min: float, raw_max: float, lower: float, upper: float, direction: int) -> float:
    """Homing offset of one joint from its swept raw extremes (motor frame) and URDF limits (rad).

    ``raw_min``/``raw_max`` are the extremes of the raw motor position; they are mapped to the direction
    frame first (for ``direction = -1`` the raw minimum is the joint's upper stop).
    """
    if direction not in (-1, 1):
        raise ValueError(f"direction must be +1 or -1, got {direction!r}")
    s_min, s_max = sorted((direction * raw_min, direction * raw_max))
    return direction * 0.5 * ((s_min - lower) + (s_max - upper))


@dataclass(frozen=True, kw_only=True)
class JointCalibration:
    """Calibration of one joint."""

    name: str
    """Joint name."""
    can_id: int
    """CAN id (must match the robot data)."""
    direction: int
    """+1 or -1 (must match the robot data)."""
    homing_offset: float
    """Raw motor position at joint zero, rad."""

    def __post_init__(self) -> None:
        if self.direction not in (-1, 1):
            raise ValueError(f"{self.name}: direction must be +1 or -1, got {self.direction!r}")
        if not math.isfinite(self.homing_offset):
            raise ValueError(f"{self.name}: homing_offset must be finite, got {self.homing_offset!r}")


@dataclass(frozen=True, kw_only=True)
class Calibration:
    """Per-robot calibration of every joint."""

    robot: str = "lite_dummy"
    """Robot name."""
    joints: Mapping[str, JointCalibration] = field(default_factory=dict)
    """Joint name -> calibration."""

    @classmethod
    def zeros(cls, robot: RobotSpec) -> Calibration:
        """Zero offsets with the robot data's ids and directions (motors zeroed at the joint zero)."""
        return cls(
            robot=robot.robot,
            joints={
                j.name: JointCalibration(
                    name=j.name, can_id=j.can_id, direction=j.direction, homing_offset=0.0
                )
                for j in robot.joints
            },
        )

    def offsets(self, robot: RobotSpec) -> np.ndarray:
        """Homing offsets in the robot's canonical order, rad, shape (num_joints,).

        Raises:
            InitializationError: a joint is missing, or its id or direction disagrees with the robot data.
        """
        missing = [n for n in robot.joint_names if n not in self.joints]
        if missing:
            raise InitializationError(
                f"calibration lacks joints {missing}; it has {sorted(self.joints)}. Run `bar-bus calibrate`."
            )
        for j in robot.joints:
            c = self.joints[j.name]
            if c.can_id != j.can_id or c.direction != j.direction:
                raise InitializationError(
                    f"calibration of {j.name} has id {c.can_id}, direction {c.direction}; the robot data has "
                    f"id {j.can_id}, direction {j.direction}. Recalibrate or fix the file."
                )
        return np.array([self.joints[n].homing_offset for n in robot.joint_names])

    def to_json(self) -> str:
        """The file text."""
        return json.dumps(
            {
                "robot": self.robot,
                "joints": {
                    n: {"id": c.can_id, "direction": c.direction, "homing_offset": c.homing_offset}
                    for n, c in self.joints.items()
                },
            },
            indent=2,
        )

    @classmethod
    def from_json(cls, text: str | bytes) -> Calibration:
        """Parse the file text (str or UTF-8 bytes); raises ``CalibrationError`` naming what is wrong.

        Values are taken exactly as written, never rounded: ``id`` an integer 0..127 (JSON ``11``, not
        ``11.5`` or ``"11"``), ``direction`` the integer 1 or -1 (``-1.9`` is refused, not truncated to
        -1), ``homing_offset`` a finite number of radians. The message names the joint and the key.
        """
        data = loads_json(text, "calibration file", CalibrationError)
        raw = data.get("joints", data) if isinstance(data, dict) else None
        if not isinstance(raw, dict):
            raise CalibrationError(f"invalid calibration file: the top level must be an object; {_SHAPE}")
        joints = {}
        for name, v in raw.items():
            if name == "robot":
                continue
            joints[str(name)] = _joint_from_json(str(name), v)
        robot = data.get("robot", "lite_dummy")
        if not isinstance(robot, str):
            raise CalibrationError(
                f"invalid calibration file: 'robot' = {shorten(repr(robot))} is not a string"
            )
        return cls(robot=robot, joints=joints)

    def save(self, path: str | Path) -> None:
        """Write the JSON file atomically (a temporary file, then a rename: never half a file)."""
        write_atomic(Path(path), (self.to_json() + "\n").encode())

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a JSON file; ``CalibrationError`` (an ``InitializationError``) when missing or malformed."""
        try:
            text = Path(path).read_bytes()
        except OSError as exc:
            raise CalibrationError(f"cannot read calibration file {path}: {exc}") from exc
        try:
            return cls.from_json(text)
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {exc}") from None


_SHAPE = 'expected {"joints": {"<joint>": {"id": int, "direction": 1 or -1, "homing_offset": float}}}'
"""The file's shape, as refusals state it."""


def _joint_from_json(name: str, v: object) -> JointCalibration:
    """One joint's entry, every value checked exactly (``CalibrationError`` naming the joint and key)."""
    where = f"invalid calibration file: joint {shorten(name)!r}"
    if not isinstance(v, dict):
        raise CalibrationError(f"{where}: must be an object; {_SHAPE}")
    keys = ("id", "direction", "homing_offset")
    missing = [k for k in keys if k not in v]
    if missing:
        raise CalibrationError(f"{where}: lacks {missing}; {_SHAPE}")
    can_id, direction, offset = (v[k] for k in keys)
    if isinstance(can_id, bool) or not isinstance(can_id, int) or not 0 <= can_id <= 127:
        raise CalibrationError(f"{where}: 'id' = {shorten(repr(can_id))} is not a CAN id (an integer 0..127)")
    if isinstance(direction, bool) or not isinstance(direction, int) or direction not in (-1, 1):
        shown = shorten(repr(direction))
        raise CalibrationError(f"{where}: 'direction' = {shown} must be 1 or -1 (an integer)")
    if isinstance(offset, bool) or not isinstance(offset, int | float) or not math.isfinite(offset):
        raise CalibrationError(
            f"{where}: 'homing_offset' = {shorten(repr(offset))} must be a finite number of radians"
        )
    return JointCalibration(name=name, can_id=can_id, direction=direction, homing_offset=float(offset))


@dataclass(frozen=True, kw_only=True)
class SweepResult:
    """Outcome of a calibration sweep."""

    calibration: Calibration
    """The new calibration (un-swept joints keep their prior offsets)."""
    swept: tuple[str, ...]
    """Joints whose offsets were recomputed."""
    kept: tuple[str, ...]
    """Joints whose sweep was below the threshold; prior offsets kept."""
    warnings: tuple[str, ...]
    """Suspicious sweeps (range larger than the URDF range, likely wrong direction)."""


class SweepRecorder:
    """Tracks the raw extremes of every joint while a person sweeps them by hand."""

    def __init__(self, robot: RobotSpec) -> None:
        self.robot = robot
        n = robot.num_joints
        self.raw_min = np.full(n, np.inf)
        """Smallest raw position seen per joint, rad."""
        self.raw_max = np.full(n, -np.inf)
        """Largest raw position seen per joint, rad."""
        self.samples = 0
        """Number of updates."""

    def update(self, raw: np.ndarray) -> None:
        """Add one reading of raw motor positions (canonical order, rad); NaN entries are skipped."""
        raw = np.asarray(raw, dtype=np.float64)
        ok = np.isfinite(raw)
        self.raw_min[ok] = np.minimum(self.raw_min[ok], raw[ok])
        self.raw_max[ok] = np.maximum(self.raw_max[ok], raw[ok])
        self.samples += 1

    @property
    def sweep(self) -> np.ndarray:
        """Swept range per joint, rad (0 where nothing was seen)."""
        span = self.raw_max - self.raw_min
        return np.where(np.isfinite(span), span, 0.0)

    def result(self, prior: Calibration | None = None, sweep_threshold: float = 0.5) -> SweepResult:
        """Compute offsets; joints swept less than ``sweep_threshold`` rad keep the prior offset (or 0)."""
        prior = prior or Calibration.zeros(self.robot)
        joints: dict[str, JointCalibration] = {}
        swept, kept, warnings = [], [], []
        for i, j in enumerate(self.robot.joints):
            if self.sweep[i] < sweep_threshold:
                old = prior.joints.get(j.name)
                offset = old.homing_offset if old is not None else 0.0
                kept.append(j.name)
            else:
                offset = homing_offset(self.raw_min[i], self.raw_max[i], j.lower, j.upper, j.direction)
                swept.append(j.name)
                urdf = j.upper - j.lower
                if self.sweep[i] > urdf + 0.3:
                    warnings.append(
                        f"{j.name}: swept {self.sweep[i]:.3f} rad but the URDF range is {urdf:.3f} rad "
                        "(wrong joint moved, or a 2*pi wrap?)"
                    )
            joints[j.name] = JointCalibration(
                name=j.name, can_id=j.can_id, direction=j.direction, homing_offset=float(offset)
            )
        return SweepResult(
            calibration=Calibration(robot=self.robot.robot, joints=joints),
            swept=tuple(swept),
            kept=tuple(kept),
            warnings=tuple(warnings),
        )
