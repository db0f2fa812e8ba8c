"""The deployment contract stored inside every exported ONNX file (``metadata_props``).

Two families of keys are written:

- ``bar.*`` keys, JSON-valued: everything ``bar-deploy`` checks before it runs a policy (observation schema
  and fingerprint, joint order, gains, default pose, action scale and semantics, rates, training
  randomisation ranges, code version). Optional keys (``OPTIONAL_BAR_KEYS``): ``bar.action_filter``,
  ``bar.command_transition``, ``bar.robot_params``, ``bar.song_lead_steps``, ``bar.gains``
  (``metadata_fields`` parses them), and ``bar.provenance``: the git commit and dirty flag, the library
  versions and the training command (``bar_policy.provenance``), which informs and is never checked (older
  files load without it, a malformed one with the problem in its place, ``provenance.read_record``).
- The 13 keys that Berkeley Humanoids' Humanoid Control runner requires (task_type, joint_names, ...), in
  the comma-separated form that mjlab's exporter writes, so our files also load there.

Two dialects are read (``PolicyMetadata.dialect``):

- ``bar``: the ``bar.*`` keys and the 13 HC keys. The keys that both carry must agree, or the file is
  refused with a message naming both keys: joint names, action joints, stiffness, damping, default pose,
  action scale, policy dt, observation and command names (numbers to 1e-5 relative, as the HC form is
  written with 6 significant digits). Otherwise a runtime reading one dialect and a runtime reading the
  other would drive different joints or gains from the same file.
- ``hc``: only the 13 HC keys, as mjlab / Humanoid Control write them (no ``bar.*`` key at all). The
  schema comes from ``observation_names`` and the gains from ``joint_stiffness`` / ``joint_damping``;
  ``deploy.policy`` completes the joint set (``mode``) and the observation schema, and refuses terms the
  runtime cannot feed.

numpy-free and jax-free: the exporter (training side) and the runtime (robot side) both import it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bar_policy._files import loads_json, shorten
from bar_policy.deploy.metadata_fields import (
    MetadataError,
    action_filter_key,
    check_agreement,
    command_transition_key,
    csv_float,
    csv_floats,
    csv_names,
    gains_key,
    int_prop,
    provenance_key,
    robot_params_key,
    song_lead_key,
)
from bar_policy.robot.gains import GAINS

__all__ = [
    "ACTION_SEMANTICS",
    "BAR_KEYS",
    "DIALECTS",
    "HC_KEYS",
    "METADATA_VERSION",
    "OPTIONAL_BAR_KEYS",
    "MetadataError",
    "PolicyMetadata",
]

METADATA_VERSION = 1
"""Version of the ``bar.*`` key set."""

ACTION_SEMANTICS = ("delta_from_default",)
"""Supported action meanings: ``q_cmd = default_joint_pos + action_scale * action`` (clipped to limits)."""

HC_KEYS = (
    "task_type",
    "joint_names",
    "action_joint_names",
    "joint_stiffness",
    "joint_damping",
    "default_joint_pos",
    "observation_names",
    "command_names",
    "action_scale",
    "policy_dt",
    "body_names",
    "dataset_repo_id",
    "lookahead_steps",
)
"""Keys the Humanoid Control ONNX runner refuses to run without (lite-model.md 2.1)."""

BAR_KEYS = (
    "bar.metadata_version",
    "bar.task",
    "bar.robot",
    "bar.mode",
    "bar.joint_names",
    "bar.action_joint_names",
    "bar.joint_stiffness",
    "bar.joint_damping",
    "bar.default_joint_pos",
    "bar.action_scale",
    "bar.action_semantics",
    "bar.policy_dt",
    "bar.physics_dt",
    "bar.obs_schema",
    "bar.obs_fingerprint",
    "bar.command_names",
    "bar.randomization",
    "bar.code_version",
    "bar.training",
)
"""Keys every ``bar`` file carries (``from_props`` refuses a file that lacks one)."""

OPTIONAL_BAR_KEYS = (
    "bar.action_filter",
    "bar.command_transition",
    "bar.provenance",
    "bar.robot_params",
    "bar.song_lead_steps",
    "bar.gains",
)
"""``bar.*`` keys a file may lack (older files): read when present, never required. ``bar.action_filter``
and ``bar.command_transition`` are validated when present; ``bar.provenance`` informs only and is never
checked; ``bar.robot_params`` (the robot-parameters file a policy trained on: ``{"sha256", "summary"}``,
``robot.params.params_record``) must be an object with a hex ``sha256``; absent: the nominal model;
``bar.song_lead_steps`` (the piano's goal keys' lead) an integer >= 0; absent: 0; ``bar.gains`` (the gain
profile, ``robot.gains``) one of its names; absent: ``robot``."""

DIALECTS = ("bar", "hc")
"""Metadata dialects: ``bar`` (``bar.*`` keys plus the HC keys, checked to agree), ``hc`` (HC keys only)."""


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
    physics_dt: float | None
    """Physics step the policy was trained with, s (None: not recorded, an HC-only file)."""
    obs_schema: str
    """Observation schema JSON (``ObservationSchema.to_json``); empty for a parsed HC-only file until
    ``deploy.policy`` builds it from ``observation_names``."""
    obs_fingerprint: str
    """Fingerprint of ``obs_schema`` (empty with it)."""
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
    observation_names: tuple[str, ...] = ()
    """HC ``observation_names`` of an HC-only file (a ``bar`` file's terms are in ``obs_schema``)."""
    dialect: str = "bar"
    """Which keys the file carried: ``bar`` or ``hc`` (``DIALECTS``)."""
    action_filter_hz: float | None = None
    """Cutoff of the first-order low-pass between the policy's output and the command, Hz
    (``bar_policy.robot.action_filter``; optional key ``bar.action_filter``); None: no filter."""
    command_transition_s: float = 0.0
    """Duration of the minimum-jerk move of the commanded target to each new command, s
    (``bar_policy.tasks.reach.transition_point``; optional key ``bar.command_transition``); 0: a step."""
    song_lead_steps: int = 0
    """Control steps the piano's goal keys lead the song (``tasks.piano.bank.PlaybackConfig.lead_steps``;
    optional key ``bar.song_lead_steps``); 0: frame 0 is the step's own goal (files before the key)."""
    gains: str = "robot"
    """The gain profile the file trained on (``robot.gains.GAINS``; optional key ``bar.gains``, written when
    not ``robot``): the runtime checks the file's Kp / Kd against that profile of the robot data."""
    provenance: Mapping[str, Any] = field(default_factory=dict)
    """``bar.provenance``: git commit and dirty flag, library versions, training command
    (``bar_policy.provenance.collect``); empty when the file has none."""
    robot_params: Mapping[str, Any] = field(default_factory=dict)
    """``bar.robot_params``: the robot-parameters file the policy trained on (``sha256`` of its canonical
    JSON and a ``summary`` of its values, ``robot.params.params_record``); empty: the nominal model."""

    def __post_init__(self) -> None:
        if self.dialect not in DIALECTS:
            raise MetadataError(
                f"unknown metadata dialect {shorten(repr(self.dialect))}; valid: {list(DIALECTS)}"
            )
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
                f"unknown action_semantics {shorten(repr(self.action_semantics))}; supported: "
                f"{list(ACTION_SEMANTICS)}"
            )
        if not (math.isfinite(self.policy_dt) and self.policy_dt > 0):
            raise MetadataError(f"policy_dt must be a positive number of seconds, got {self.policy_dt}")
        values = (*self.joint_stiffness, *self.joint_damping, *self.default_joint_pos, *self.action_scale)
        if not all(math.isfinite(v) for v in values):
            raise MetadataError("gains, default pose and action scale must be finite")
        if isinstance(self.lookahead_steps, bool) or not (
            isinstance(self.lookahead_steps, int) and self.lookahead_steps >= 0
        ):
            raise MetadataError(
                f"lookahead_steps must be an integer >= 0, got {shorten(repr(self.lookahead_steps))}"
            )
        f = self.action_filter_hz
        if f is not None and not (isinstance(f, int | float) and 0 < f < 0.5 / self.policy_dt):
            raise MetadataError(
                f"action filter cutoff must be a number of Hz in (0, {0.5 / self.policy_dt:g}) (below "
                f"Nyquist), got {shorten(repr(f))}"
            )
        c = self.command_transition_s
        if isinstance(c, bool) or not (isinstance(c, int | float) and math.isfinite(c) and c >= 0):
            raise MetadataError(f"command transition must be a number of s >= 0, got {shorten(repr(c))}")
        d = self.song_lead_steps
        if isinstance(d, bool) or not (isinstance(d, int) and d >= 0):
            raise MetadataError(f"song lead must be an integer >= 0 (control steps), got {shorten(repr(d))}")
        if self.gains not in GAINS:
            raise MetadataError(f"gain profile must be one of {list(GAINS)}, got {shorten(repr(self.gains))}")
        if any("," in n for n in self.body_names) or "," in self.dataset_repo_id:
            raise MetadataError("body_names and dataset_repo_id must not contain commas (HC's CSV form)")

    # -- writing ---------------------------------------------------------------------------------------
    def to_props(self) -> dict[str, str]:
        """All metadata keys (``bar.*`` JSON plus the Humanoid Control keys) as strings."""
        if not self.obs_schema:
            raise MetadataError("metadata without an observation schema cannot be written")
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
            **({"bar.action_filter": {"cutoff_hz": self.action_filter_hz}} if self.action_filter_hz else {}),
        }
        if self.command_transition_s > 0:
            bar["bar.command_transition"] = {"duration_s": self.command_transition_s, "profile": "min_jerk"}
        if self.song_lead_steps > 0:
            bar["bar.song_lead_steps"] = self.song_lead_steps
        if self.gains != "robot":
            bar["bar.gains"] = self.gains
        if self.provenance:
            bar["bar.provenance"] = dict(self.provenance)
        if self.robot_params:
            bar["bar.robot_params"] = dict(self.robot_params)
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
        """Parse ``metadata_props`` in either dialect; raises ``MetadataError`` naming the offending keys."""
        if not any(k in props for k in BAR_KEYS):
            return cls._from_hc(props)
        missing = [k for k in (*BAR_KEYS, *HC_KEYS) if k not in props]
        if missing:
            raise MetadataError(
                f"policy metadata lacks keys {missing}; export the policy with bar_policy "
                "(train/ppo.py writes every key)"
            )
        meta = cls._from_bar(props)
        check_agreement(meta, props)
        return meta

    @classmethod
    def _from_bar(cls, props: Mapping[str, str]) -> PolicyMetadata:
        parsed: dict[str, Any] = {
            k: loads_json(props[k], f"metadata key {k!r}", MetadataError) for k in BAR_KEYS
        }
        version = parsed["bar.metadata_version"]
        if version != METADATA_VERSION or isinstance(version, bool):
            raise MetadataError(
                f"metadata version {shorten(repr(version))} is not supported; this runtime reads "
                f"{METADATA_VERSION}"
            )

        def floats(key: str) -> tuple[float, ...]:
            v = parsed[key]
            if not isinstance(v, list) or not all(isinstance(x, int | float) for x in v):
                raise MetadataError(f"metadata key {key!r} must be a list of numbers")
            try:
                return tuple(float(x) for x in v)
            except OverflowError:
                raise MetadataError(f"metadata key {key!r} holds a number out of range") from None

        def names(key: str) -> tuple[str, ...]:
            v = parsed[key]
            if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
                raise MetadataError(f"metadata key {key!r} must be a list of strings")
            return tuple(v)

        def number(key: str, optional: bool = False) -> float | None:
            v = parsed[key]
            if v is None and optional:
                return None
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise MetadataError(f"metadata key {key!r} must be a number, got {shorten(repr(v))}")
            try:
                return float(v)
            except OverflowError:
                raise MetadataError(f"metadata key {key!r} is out of range: {shorten(repr(v))}") from None

        def obj(key: str) -> dict[str, Any]:
            v = parsed[key]
            if not isinstance(v, dict):
                raise MetadataError(f"metadata key {key!r} must be a JSON object, got {type(v).__name__}")
            return v

        schema = obj("bar.obs_schema")
        policy_dt = number("bar.policy_dt") or 0.0  # never None (not optional); 0 is refused below
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
            policy_dt=policy_dt,
            physics_dt=number("bar.physics_dt", optional=True),
            obs_schema=json.dumps(schema, sort_keys=True),
            obs_fingerprint=str(parsed["bar.obs_fingerprint"]),
            command_names=names("bar.command_names"),
            randomization=obj("bar.randomization"),
            code_version=str(parsed["bar.code_version"]),
            training=obj("bar.training"),
            body_names=csv_names(props, "body_names"),
            lookahead_steps=int_prop(props, "lookahead_steps"),
            dataset_repo_id=props["dataset_repo_id"],
            action_filter_hz=action_filter_key(props),
            command_transition_s=command_transition_key(props),
            song_lead_steps=song_lead_key(props),
            gains=gains_key(props),
            provenance=provenance_key(props.get("bar.provenance")),
            robot_params=robot_params_key(props),
        )

    @classmethod
    def _from_hc(cls, props: Mapping[str, str]) -> PolicyMetadata:
        """An HC-only file: every setting from the 13 comma-separated keys (mode and schema left empty)."""
        missing = [k for k in HC_KEYS if k not in props]
        if missing:
            raise MetadataError(
                f"policy metadata has no bar.* keys and lacks the Humanoid Control keys {missing}; a file "
                f"needs all 13 HC keys {list(HC_KEYS)} (as mjlab writes them), or the bar.* keys as well "
                "(export with bar_policy)"
            )
        joints = csv_names(props, "joint_names")
        if not joints:
            raise MetadataError("metadata key 'joint_names' is empty")
        return cls(
            task=props["task_type"].strip(),
            robot="",
            mode="",
            joint_names=joints,
            action_joint_names=csv_names(props, "action_joint_names"),
            joint_stiffness=csv_floats(props, "joint_stiffness"),
            joint_damping=csv_floats(props, "joint_damping"),
            default_joint_pos=csv_floats(props, "default_joint_pos"),
            action_scale=csv_floats(props, "action_scale"),
            action_semantics="delta_from_default",
            policy_dt=csv_float(props, "policy_dt"),
            physics_dt=None,
            obs_schema="",
            obs_fingerprint="",
            command_names=csv_names(props, "command_names"),
            body_names=csv_names(props, "body_names"),
            lookahead_steps=int_prop(props, "lookahead_steps"),
            dataset_repo_id=props["dataset_repo_id"].strip(),
            observation_names=csv_names(props, "observation_names"),
            dialect="hc",
        )
