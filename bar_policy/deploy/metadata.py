"""The deployment contract stored inside every exported ONNX file (``metadata_props``).

Two families of keys are written:

- ``bar.*`` keys, JSON-valued: everything ``bar-deploy`` checks before it runs a policy (observation schema
  and fingerprint, joint order, gains, default pose, action scale and semantics, rates, training
  randomisation ranges, code version).
- The 13 keys that Berkeley Humanoids' Humanoid Control runner requires (task_type, joint_names, ...), in
  the comma-separated form that mjlab's exporter writes, so our files also load there.

numpy-free and jax-free: the exporter (training side) and the runtime (robot side) both import it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "ACTION_SEMANTICS",
    "BAR_KEYS",
    "HC_KEYS",
    "METADATA_VERSION",
    "MetadataError",
    "PolicyMetadata",
]

METADATA_VERSION = 1
"""Version of the ``bar.*`` key set."""

ACTION_SEMANTICS = ("delta_from_default",)
"""Supported action meanings: ``q_cmd = default_joint_pos + action_scale * action`` (clipped to limits)."""

HC_KEYS = (
    "task_type", "joint_names", "action_joint_names", "joint_stiffness", "joint_damping",
    "default_joint_pos", "observation_names", "command_names", "action_scale", "policy_dt",
    "body_names", "dataset_repo_id", "lookahead_steps",
)  # fmt: skip
"""Keys the Humanoid Control ONNX runner refuses to run without (lite-model.md 2.1)."""

BAR_KEYS = (
    "bar.metadata_version", "bar.task", "bar.robot", "bar.mode", "bar.joint_names",
    "bar.action_joint_names", "bar.joint_stiffness", "bar.joint_damping", "bar.default_joint_pos",
    "bar.action_scale", "bar.action_semantics", "bar.policy_dt", "bar.physics_dt", "bar.obs_schema",
    "bar.obs_fingerprint", "bar.command_names", "bar.randomization", "bar.code_version",
    "bar.training",
)  # fmt: skip


class MetadataError(ValueError):
    """A policy file's metadata is missing, malformed or inconsistent."""


@dataclass(frozen=True, kw_only=True)
class PolicyMetadata:
    """Everything a runtime needs to run a policy file, and to refuse the wrong one."""

    task: str
    """Task name, e.g. ``reach``."""
    robot: str
    """Robot name (``lite_dummy``)."""
    mode: str
    """Joint set, ``arms`` or ``arms_neck``."""
    joint_names: tuple[str, ...]
    """Canonical joint order of the robot state the policy sees."""
    action_joint_names: tuple[str, ...]
    """Joints the policy drives, in action order."""
    joint_stiffness: tuple[float, ...]
    """Kp per joint (joint_names order), N*m/rad."""
    joint_damping: tuple[float, ...]
    """Kd per joint, N*m*s/rad."""
    default_joint_pos: tuple[float, ...]
    """Default pose per joint, rad."""
    action_scale: tuple[float, ...]
    """Per action joint, rad per unit action."""
    action_semantics: str
    """One of ``ACTION_SEMANTICS``."""
    policy_dt: float
    """Policy period, s."""
    physics_dt: float
    """Physics step the policy was trained with, s."""
    obs_schema: str
    """Observation schema JSON (``ObservationSchema.to_json``)."""
    obs_fingerprint: str
    """Fingerprint of ``obs_schema``."""
    command_names: tuple[str, ...]
    """Observation terms fed by the command source."""
    randomization: Mapping[str, Any] = field(default_factory=dict)
    """Domain-randomisation ranges used in training (for envelope checks and the record)."""
    code_version: str = "unknown"
    """bar_policy version and git commit that exported the file."""
    training: Mapping[str, Any] = field(default_factory=dict)
    """Free-form training record (backend, steps, evaluation)."""
    body_names: tuple[str, ...] = ()
    """Tracked bodies of a reference-tracking task (Humanoid Control ``body_names``); empty otherwise."""
    lookahead_steps: int = 0
    """Reference frames ahead that the observation holds (Humanoid Control ``lookahead_steps``)."""
    dataset_repo_id: str = ""
    """Id of the reference data the policy was trained on (Humanoid Control ``dataset_repo_id``)."""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for name in ("joint_stiffness", "joint_damping", "default_joint_pos"):
            if len(getattr(self, name)) != n:
                raise MetadataError(f"{name} has {len(getattr(self, name))} entries, expected {n}")
        if len(self.action_scale) != len(self.action_joint_names):
            raise MetadataError(
                f"action_scale has {len(self.action_scale)} entries, expected "
                f"{len(self.action_joint_names)} (one per action joint)"
            )
        if self.action_semantics not in ACTION_SEMANTICS:
            raise MetadataError(
                f"unknown action_semantics {self.action_semantics!r}; supported: {list(ACTION_SEMANTICS)}"
            )
        if not (math.isfinite(self.policy_dt) and self.policy_dt > 0):
            raise MetadataError(f"policy_dt must be a positive number of seconds, got {self.policy_dt}")
        values = (*self.joint_stiffness, *self.joint_damping, *self.default_joint_pos, *self.action_scale)
        if not all(math.isfinite(v) for v in values):
            raise MetadataError("gains, default pose and action scale must be finite")
        if isinstance(self.lookahead_steps, bool) or not (
            isinstance(self.lookahead_steps, int) and self.lookahead_steps >= 0
        ):
            raise MetadataError(f"lookahead_steps must be an integer >= 0, got {self.lookahead_steps!r}")
        if any("," in n for n in self.body_names) or "," in self.dataset_repo_id:
            raise MetadataError("body_names and dataset_repo_id must not contain commas (HC's CSV form)")

    # -- writing ---------------------------------------------------------------------------------------
    def to_props(self) -> dict[str, str]:
        """All metadata keys (``bar.*`` JSON plus the Humanoid Control keys) as strings."""
        schema = json.loads(self.obs_schema)
        obs_names = [t["name"] for t in schema["terms"]]
        bar = {
            "bar.metadata_version": METADATA_VERSION,
            "bar.task": self.task,
            "bar.robot": self.robot,
            "bar.mode": self.mode,
            "bar.joint_names": list(self.joint_names),
            "bar.action_joint_names": list(self.action_joint_names),
            "bar.joint_stiffness": list(self.joint_stiffness),
            "bar.joint_damping": list(self.joint_damping),
            "bar.default_joint_pos": list(self.default_joint_pos),
            "bar.action_scale": list(self.action_scale),
            "bar.action_semantics": self.action_semantics,
            "bar.policy_dt": self.policy_dt,
            "bar.physics_dt": self.physics_dt,
            "bar.obs_schema": schema,
            "bar.obs_fingerprint": self.obs_fingerprint,
            "bar.command_names": list(self.command_names),
            "bar.randomization": dict(self.randomization),
            "bar.code_version": self.code_version,
            "bar.training": dict(self.training),
        }
        props = {k: json.dumps(v, sort_keys=True) for k, v in bar.items()}

        def csv(values: Any) -> str:
            return ",".join(f"{v:.6g}" if isinstance(v, float) else str(v) for v in values)

        props.update(
            {
                "task_type": self.task,
                "joint_names": csv(self.joint_names),
                "action_joint_names": csv(self.action_joint_names),
                "joint_stiffness": csv(self.joint_stiffness),
                "joint_damping": csv(self.joint_damping),
                "default_joint_pos": csv(self.default_joint_pos),
                "observation_names": csv(obs_names),
                "command_names": csv(self.command_names),
                "action_scale": csv(self.action_scale),
                "policy_dt": f"{self.policy_dt:.6g}",
                "body_names": csv(self.body_names),
                "dataset_repo_id": self.dataset_repo_id,
                "lookahead_steps": str(self.lookahead_steps),
            }
        )
        return props

    # -- reading ---------------------------------------------------------------------------------------
    @classmethod
    def from_props(cls, props: Mapping[str, str]) -> PolicyMetadata:
        """Parse ``metadata_props``; raises ``MetadataError`` naming missing or malformed keys."""
        missing = [k for k in (*BAR_KEYS, *HC_KEYS) if k not in props]
        if missing:
            raise MetadataError(
                f"policy metadata lacks keys {missing}; export the policy with bar_policy "
                "(train/ppo.py writes every key)"
            )
        parsed: dict[str, Any] = {}
        for k in BAR_KEYS:
            try:
                parsed[k] = json.loads(props[k])
            except json.JSONDecodeError as e:
                raise MetadataError(f"metadata key {k!r} is not valid JSON: {e}") from None
        version = parsed["bar.metadata_version"]
        if version != METADATA_VERSION:
            raise MetadataError(
                f"metadata version {version!r} is not supported; this runtime reads {METADATA_VERSION}"
            )

        def floats(key: str) -> tuple[float, ...]:
            v = parsed[key]
            if not isinstance(v, list) or not all(isinstance(x, int | float) for x in v):
                raise MetadataError(f"metadata key {key!r} must be a list of numbers")
            return tuple(float(x) for x in v)

        def names(key: str) -> tuple[str, ...]:
            v = parsed[key]
            if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
                raise MetadataError(f"metadata key {key!r} must be a list of strings")
            return tuple(v)

        schema = parsed["bar.obs_schema"]
        if not isinstance(schema, dict):
            raise MetadataError("metadata key 'bar.obs_schema' must be a JSON object")
        return cls(
            task=str(parsed["bar.task"]),
            robot=str(parsed["bar.robot"]),
            mode=str(parsed["bar.mode"]),
            joint_names=names("bar.joint_names"),
            action_joint_names=names("bar.action_joint_names"),
            joint_stiffness=floats("bar.joint_stiffness"),
            joint_damping=floats("bar.joint_damping"),
            default_joint_pos=floats("bar.default_joint_pos"),
            action_scale=floats("bar.action_scale"),
            action_semantics=str(parsed["bar.action_semantics"]),
            policy_dt=float(parsed["bar.policy_dt"]),
            physics_dt=float(parsed["bar.physics_dt"]),
            obs_schema=json.dumps(schema, sort_keys=True),
            obs_fingerprint=str(parsed["bar.obs_fingerprint"]),
            command_names=names("bar.command_names"),
            randomization=parsed["bar.randomization"],
            code_version=str(parsed["bar.code_version"]),
            training=parsed["bar.training"],
            body_names=tuple(n for n in props["body_names"].split(",") if n),
            lookahead_steps=_int_prop(props, "lookahead_steps"),
            dataset_repo_id=props["dataset_repo_id"],
        )


def _int_prop(props: Mapping[str, str], key: str) -> int:
    """A non-negative integer HC key (``lookahead_steps``); refuses anything else naming the key."""
    text = props[key].strip()
    if not text.isdigit():
        raise MetadataError(f"metadata key {key!r} must be a non-negative integer, got {props[key]!r}")
    return int(text)
