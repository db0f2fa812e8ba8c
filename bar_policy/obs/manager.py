"""The frozen ObservationManager: one observation layout, shared by training (jax) and deployment (numpy).

A schema fixes the joint order, the action joints, the default pose and an ordered list of named terms
(size, scale, clip). ``ObservationManager.compute`` builds the observation from plain arrays with numpy or
jax from the same code. The schema exports as JSON with a short fingerprint (sha256 of the canonical JSON);
the JSON and fingerprint go into every exported ONNX file, and the deploy runtime refuses a policy whose
fingerprint differs from the running code's. Golden copies of the shipped layouts live in ``schemas/``; a
test fails when the code drifts from them, so a layout change has to be a deliberate new version.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field
from importlib import resources
from typing import Any

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy.obs.terms import LOOKAHEAD_RULES, TERM_CATALOG
from bar_policy.robot.constants import MODES, load_robot
from bar_policy.task_records import get_record, records, resolve

__all__ = ["SCHEMA_FORMAT", "SHIPPED_LAYOUTS", "ObsTerm", "ObservationManager", "ObservationSchema"]

SCHEMA_FORMAT = "bar_policy.obs/1"
"""Format tag of the schema JSON itself (not the layout version)."""


class _ShippedLayouts(Mapping[str, tuple[str, str]]):
    """Layout name -> (task, mode) of every registered task's golden layouts, read on first use."""

    def _load(self) -> dict[str, tuple[str, str]]:
        return {name: (r.name, mode) for r in records() for name, mode in r.shipped_layouts}

    def __getitem__(self, name: str) -> tuple[str, str]:
        return self._load()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())

    def __repr__(self) -> str:
        """``SHIPPED_LAYOUTS({'lite_reach_arms': ('reach', 'arms'), ...})``: what ``print`` shows."""
        return f"SHIPPED_LAYOUTS({self._load()!r})"


SHIPPED_LAYOUTS: Mapping[str, tuple[str, str]] = _ShippedLayouts()
"""Golden layouts committed under ``bar_policy/obs/schemas/``: name -> (task, mode), from the registered
task records (``TaskRecord.shipped_layouts``, ``bar_policy.task_records``)."""


@dataclass(frozen=True, kw_only=True)
class ObsTerm:
    """One named slice of the observation."""

    name: str
    """A name from ``TERM_CATALOG``."""
    size: int
    """Number of entries."""
    scale: float = 1.0
    """Multiplier applied after the offset (a term has one only when its catalog entry says so:
    ``TERM_CATALOG[name].offset_default_pose``, the schema's ``default_joint_pos`` subtracted first)."""
    clip: float = 100.0
    """Symmetric clip applied after scaling (> 0)."""


@dataclass(frozen=True, kw_only=True)
class ObservationSchema:
    """The complete, versioned observation contract."""

    name: str
    """Layout name, e.g. ``lite_reach_arms``."""
    version: int
    """Layout version; bump it for any deliberate change."""
    robot: str
    """Robot the joint names refer to."""
    mode: str
    """Joint set: ``arms`` or ``arms_neck``."""
    joint_names: tuple[str, ...]
    """Canonical joint order of ``joint_pos`` / ``joint_vel``."""
    action_joint_names: tuple[str, ...]
    """Joints the policy drives, in action order."""
    default_joint_pos: tuple[float, ...]
    """Pose subtracted from q in ``joint_pos``, rad, in ``joint_names`` order."""
    terms: tuple[ObsTerm, ...]
    """Terms in concatenation order."""
    body_names: tuple[str, ...] = ()
    """Tracked bodies of the lookahead terms, in term order (tracking layouts; omitted from the JSON when
    empty, so layouts without it hash as before)."""
    lookahead_steps: int = 0
    """Reference frames K of the lookahead terms (tracking layouts; omitted from the JSON when 0)."""
    format: str = field(default=SCHEMA_FORMAT)

    def __post_init__(self) -> None:
        _validate(self)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (lists, dicts, floats)."""
        d = asdict(self)
        d["joint_names"] = list(self.joint_names)
        d["action_joint_names"] = list(self.action_joint_names)
        d["default_joint_pos"] = [float(x) for x in self.default_joint_pos]
        d["terms"] = [asdict(t) for t in self.terms]
        if self.body_names:
            d["body_names"] = list(self.body_names)
        else:
            del d["body_names"]
        if not self.lookahead_steps:
            del d["lookahead_steps"]
        return d

    def to_json(self, indent: int | None = 2) -> str:
        """The schema as JSON text (keys sorted)."""
        return json.dumps(self.to_dict(), indent=indent, sort_keys=True)

    @property
    def fingerprint(self) -> str:
        """16 hex digits of sha256 over the canonical (sorted, compact) JSON."""
        canonical = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()[:16]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ObservationSchema:
        """Parse and validate; raises ``ValueError`` naming any problem."""
        if not isinstance(data, Mapping):
            raise ValueError(f"observation schema must be a JSON object, got {type(data).__name__}")
        required = (
            "name",
            "version",
            "robot",
            "mode",
            "joint_names",
            "action_joint_names",
            "default_joint_pos",
            "terms",
        )
        missing = [k for k in required if k not in data]
        if missing:
            raise ValueError(f"observation schema lacks keys {missing}")
        unknown_keys = sorted(set(data) - set(required) - {"format", "body_names", "lookahead_steps"})
        if unknown_keys:
            raise ValueError(f"observation schema has unknown keys {unknown_keys}")
        fmt = data.get("format", SCHEMA_FORMAT)
        if fmt != SCHEMA_FORMAT:
            raise ValueError(f"unsupported schema format {fmt!r}; this code reads {SCHEMA_FORMAT!r}")
        terms = []
        for t in data["terms"]:
            extra = sorted(set(t) - {"name", "size", "scale", "clip"})
            if extra or "name" not in t or "size" not in t:
                raise ValueError(f"malformed term {t!r}: needs name and size, may have scale and clip")
            terms.append(
                ObsTerm(
                    name=str(t["name"]),
                    size=int(t["size"]),
                    scale=float(t.get("scale", 1.0)),
                    clip=float(t.get("clip", 100.0)),
                )
            )
        return cls(
            name=str(data["name"]),
            version=int(data["version"]),
            robot=str(data["robot"]),
            mode=str(data["mode"]),
            joint_names=tuple(data["joint_names"]),
            action_joint_names=tuple(data["action_joint_names"]),
            default_joint_pos=tuple(float(x) for x in data["default_joint_pos"]),
            terms=tuple(terms),
            body_names=tuple(str(b) for b in data.get("body_names", ())),
            lookahead_steps=int(data.get("lookahead_steps", 0)),
            format=fmt,
        )

    @classmethod
    def from_json(cls, text: str) -> ObservationSchema:
        """Parse schema JSON text; malformed JSON is a ``ValueError`` too."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"observation schema is not valid JSON: {e}") from None
        return cls.from_dict(data)


def _validate(s: ObservationSchema) -> None:
    if s.mode not in MODES:
        raise ValueError(f"unknown mode {s.mode!r}; valid modes: {list(MODES)}")
    robot = load_robot(s.mode)
    if s.robot != robot.robot:
        raise ValueError(f"schema is for robot {s.robot!r}, this code knows {robot.robot!r}")
    for label, names in (("joint_names", s.joint_names), ("action_joint_names", s.action_joint_names)):
        dup = sorted({n for n in names if list(names).count(n) > 1})
        if dup:
            raise ValueError(f"duplicate joints in {label}: {dup}")
        unknown = [n for n in names if n not in robot.joint_names]
        if unknown:
            raise ValueError(
                f"unknown joints in {label}: {unknown}; mode {s.mode!r} has {list(robot.joint_names)}"
            )
    missing = [n for n in robot.joint_names if n not in s.joint_names]
    if missing:
        raise ValueError(f"joint_names misses joints of mode {s.mode!r}: {missing}")
    if tuple(s.joint_names) != robot.joint_names:
        raise ValueError(
            f"joint_names order {list(s.joint_names)} differs from the canonical order "
            f"{list(robot.joint_names)}"
        )
    if len(s.default_joint_pos) != len(s.joint_names):
        raise ValueError(
            f"default_joint_pos has {len(s.default_joint_pos)} entries, expected {len(s.joint_names)}"
        )
    if not all(math.isfinite(x) for x in s.default_joint_pos):
        raise ValueError("default_joint_pos has non-finite entries")
    if not s.terms:
        raise ValueError("schema has no terms")
    if len(set(s.body_names)) != len(s.body_names) or not all(isinstance(b, str) and b for b in s.body_names):
        raise ValueError(f"body_names must be distinct non-empty names, got {list(s.body_names)}")
    if not (isinstance(s.lookahead_steps, int) and s.lookahead_steps >= 0):
        raise ValueError(f"lookahead_steps must be an integer >= 0, got {s.lookahead_steps!r}")
    rules = {TERM_CATALOG[t.name].size for t in s.terms if t.name in TERM_CATALOG}
    uses_lookahead = any(r in LOOKAHEAD_RULES for r in rules)
    if uses_lookahead != (s.lookahead_steps > 0):
        raise ValueError(
            f"lookahead_steps = {s.lookahead_steps}: it must be >= 1 exactly when a term has a lookahead "
            f"size ({list(LOOKAHEAD_RULES)})"
        )
    uses_bodies = bool(rules & {"lookahead_body_pos", "lookahead_body_ori"})
    if uses_bodies != bool(s.body_names):
        raise ValueError(f"body_names {list(s.body_names)} must be given exactly when a body term is used")
    k, b = s.lookahead_steps, len(s.body_names)
    seen: set[str] = set()
    for t in s.terms:
        kind = TERM_CATALOG.get(t.name)
        if kind is None:
            raise ValueError(f"unknown observation term {t.name!r}; known terms: {sorted(TERM_CATALOG)}")
        if t.name in seen:
            raise ValueError(f"duplicate observation term {t.name!r}")
        seen.add(t.name)
        expected = {
            "joints": len(s.joint_names),
            "actions": len(s.action_joint_names),
            "lookahead_joints": k * len(s.joint_names),
            "lookahead_body_pos": k * b * 3,
            "lookahead_body_ori": k * b * 6,
        }.get(kind.size, kind.size)  # type: ignore[arg-type]
        if t.size != expected:
            raise ValueError(f"term {t.name!r} has size {t.size}, expected {expected}")
        if not (math.isfinite(t.scale) and math.isfinite(t.clip) and t.clip > 0):
            raise ValueError(f"term {t.name!r}: scale must be finite and clip finite and > 0")


class ObservationManager:
    """Builds observations from named input arrays according to a frozen ``ObservationSchema``.

    Usage (identical in the MJX env and the deploy runtime)::

        om = ObservationManager.for_task("reach", mode="arms")
        obs = om.compute({"joint_pos": q, "joint_vel": dq, "actions": last_action,
                          "fingertip_pos_left": pl, "fingertip_pos_right": pr,
                          "target_pos_left": tl, "target_pos_right": tr})

    Inputs may be numpy or jax arrays with any leading batch shape ``(..., size)``; the output has shape
    ``(..., om.size)`` and the inputs' array type.
    """

    def __init__(self, schema: ObservationSchema) -> None:
        self.schema = schema
        self._default = np.asarray(schema.default_joint_pos, dtype=np.float32)
        slices = {}
        self._terms = {t.name: t for t in schema.terms}
        start = 0
        for t in schema.terms:
            slices[t.name] = slice(start, start + t.size)
            start += t.size
        self._slices = slices
        self._size = start

    # -- construction ------------------------------------------------------------------------------
    @classmethod
    def for_task(cls, task: str = "reach", mode: str = "arms") -> ObservationManager:
        """The current layout of a task for a joint set (the task's ``TaskRecord.layout`` builder).

        Raises:
            ValueError: an unknown task (the message lists the tasks) or mode.
        """
        return cls(resolve(get_record(task).layout)(mode))

    @classmethod
    def from_json(cls, text: str) -> ObservationManager:
        """Load a schema from JSON text; validates it.

        ``text`` is what ``to_json`` writes: an ONNX file carries it in its ``bar.obs_schema`` metadata key
        (``PolicyMetadata.obs_schema``; read it with ``onnx.load(path).metadata_props`` or
        ``deploy.policy.load_policy(path).obs_manager``).
        """
        return cls(ObservationSchema.from_json(text))

    @classmethod
    def golden(cls, name: str) -> ObservationManager:
        """Load a committed golden layout by name (see ``SHIPPED_LAYOUTS``)."""
        if name not in SHIPPED_LAYOUTS:
            raise ValueError(f"unknown layout {name!r}; shipped layouts: {sorted(SHIPPED_LAYOUTS)}")
        text = resources.files("bar_policy.obs").joinpath("schemas", f"{name}.json").read_text()
        return cls.from_json(text)

    # -- description -------------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Total observation size."""
        return self._size

    @property
    def term_names(self) -> tuple[str, ...]:
        """Term names in concatenation order."""
        return tuple(t.name for t in self.schema.terms)

    @property
    def command_names(self) -> tuple[str, ...]:
        """Terms whose input comes from the task's command source."""
        return tuple(t for t in self.term_names if TERM_CATALOG[t].category == "command")

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Canonical joint order."""
        return self.schema.joint_names

    @property
    def fingerprint(self) -> str:
        """Schema fingerprint (16 hex digits)."""
        return self.schema.fingerprint

    def term_slice(self, name: str) -> slice:
        """Where a term sits in the observation vector."""
        self.term(name)
        return self._slices[name]

    def term(self, name: str) -> ObsTerm:
        """A term of the layout by name: its ``size``, ``scale`` and ``clip`` (``ObsTerm``).

        A term has no offset of its own: the one ``compute`` subtracts is the schema's ``default_joint_pos``,
        for the terms whose catalog entry asks for it (``TERM_CATALOG[name].offset_default_pose``).
        """
        if name not in self._terms:
            raise ValueError(f"no term {name!r} in layout {self.schema.name}; terms: {list(self._terms)}")
        return self._terms[name]

    def to_json(self) -> str:
        """Schema JSON."""
        return self.schema.to_json()

    # -- computation -------------------------------------------------------------------------------
    def compute(self, inputs: Mapping[str, Array]) -> Array:
        """Concatenate ``clip((input - offset) * scale, -clip, clip)`` over the terms.

        ``offset`` is the schema's ``default_joint_pos`` for a term whose catalog entry has
        ``offset_default_pose`` (``joint_pos``), else 0.

        Args:
            inputs: one array per term name, shape ``(..., term.size)``; extra keys are ignored.

        Returns:
            Observation, shape ``(..., self.size)``, float32 for numpy inputs.

        Raises:
            ValueError: a term's input is missing or its last dimension is not the term size.
        """
        missing = [t.name for t in self.schema.terms if t.name not in inputs]
        if missing:
            raise ValueError(f"observation inputs missing for terms {missing}")
        xp = array_namespace(*(inputs[t.name] for t in self.schema.terms))
        parts = []
        for t in self.schema.terms:
            x = xp.asarray(inputs[t.name], dtype=xp.float32)
            if x.shape[-1:] != (t.size,):
                raise ValueError(f"input {t.name!r} has shape {tuple(x.shape)}, last dim must be {t.size}")
            if TERM_CATALOG[t.name].offset_default_pose:
                x = x - self._default
            parts.append(xp.clip(x * t.scale, -t.clip, t.clip))
        shape = np.broadcast_shapes(*(p.shape[:-1] for p in parts))
        parts = [xp.broadcast_to(p, (*shape, p.shape[-1])) for p in parts]
        return xp.concatenate(parts, axis=-1)

    def split(self, obs: Array) -> dict[str, Array]:
        """Inverse view: the observation cut back into its (scaled, clipped) terms."""
        return {name: obs[..., s] for name, s in self._slices.items()}

    def __repr__(self) -> str:
        s = self.schema
        return f"ObservationManager({s.name} v{s.version}, size={self.size}, {self.fingerprint})"


def shipped_managers() -> dict[str, ObservationManager]:
    """The code's current layout for each shipped name (compare with the golden files)."""
    return {name: ObservationManager.for_task(task, mode) for name, (task, mode) in SHIPPED_LAYOUTS.items()}
