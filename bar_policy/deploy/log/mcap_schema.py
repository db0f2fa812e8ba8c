"""The MCAP run log's topics and JSON Schemas, and the JSON form of a tick's values (``mcap_write``).

``FIELD_ROUTES`` maps each per-tick field to its topic and key; ``_tick_schema`` / ``_TRANSITION_SCHEMA``
give each topic's JSON Schema; ``_value`` writes a numpy value as plain JSON (non-finite -> null).
``mcap_write`` documents the file's layout.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

__all__ = [
    "COMMANDS_TOPIC",
    "FIELD_ROUTES",
    "JOINT_STATE_TOPIC",
    "LEGACY_TOPICS",
    "MCAP_FILE",
    "OPTIONAL_TICK_TOPICS",
    "TICK_TOPICS",
    "TRANSITION_TOPIC",
    "Fields",
]

MCAP_FILE = "run.mcap"
"""File name of the MCAP log inside a run directory."""

JOINT_STATE_TOPIC = "/joint_state_json"
"""Topic of the measured joint state as JSON. Named apart from ROS 2's ``/joint_states`` (the same values as
``sensor_msgs/msg/JointState``, ``log_channels``): logs written before the rename call it ``/joint_state``."""
LEGACY_TOPICS = {"/joint_state": JOINT_STATE_TOPIC}
"""Old topic name -> current one: the reader (``mcap_read``) accepts logs that use the old names."""

TICK_TOPICS = (JOINT_STATE_TOPIC, "/mit_command", "/policy", "/commands", "/safety", "/timing")
"""Topics with one message per control tick, in the order they are written."""
OPTIONAL_TICK_TOPICS = ("/reference",)
"""Per-tick topics written only when some field routes there (a tracking run's reference)."""
TRANSITION_TOPIC = "/safety/transition"
"""Topic of mode changes."""
COMMANDS_TOPIC = "/commands"

FIELD_ROUTES: dict[str, tuple[str, str]] = {
    "q": (JOINT_STATE_TOPIC, "q"),
    "dq": (JOINT_STATE_TOPIC, "dq"),
    "tau": (JOINT_STATE_TOPIC, "tau"),
    "q_cmd": ("/mit_command", "q"),
    "dq_cmd": ("/mit_command", "dq"),
    "kp": ("/mit_command", "kp"),
    "kd": ("/mit_command", "kd"),
    "tau_ff": ("/mit_command", "tau_ff"),
    "tau_cmd": ("/mit_command", "tau_cmd"),
    "obs": ("/policy", "obs"),
    "action": ("/policy", "action"),
    "mode": ("/safety", "mode"),
    "n_clipped": ("/safety", "n_clipped"),
    "n_action_clipped": ("/safety", "n_action_clipped"),
    "wall": ("/timing", "wall"),
    "compute": ("/timing", "compute"),
    "infer": ("/timing", "infer"),
    "jitter": ("/timing", "jitter"),
    "overrun": ("/timing", "overrun"),
    "ref_q": ("/reference", "q"),
    "ref_frame": ("/reference", "frame"),
}
"""Per-tick field -> (topic, JSON key). ``t`` is in every message; other fields go to ``/commands``."""

_SCHEMA_NAMES = {
    JOINT_STATE_TOPIC: "bar_deploy.JointState",
    "/mit_command": "bar_deploy.MitCommand",
    "/policy": "bar_deploy.Policy",
    "/commands": "bar_deploy.Commands",
    "/safety": "bar_deploy.Safety",
    "/timing": "bar_deploy.Timing",
    "/reference": "bar_deploy.Reference",
    TRANSITION_TOPIC: "bar_deploy.Transition",
}
_DESCRIPTIONS = {
    JOINT_STATE_TOPIC: "Measured joint state, canonical joint order (rad, rad/s, N*m).",
    "/mit_command": "MIT command written to the joints; tau_cmd is the host's capped MIT torque of it (N*m).",
    "/policy": "Observation fed to the policy and its raw action (null where the policy did not run).",
    "/commands": "Command terms fed to the observation (chest frame, m).",
    "/safety": "Controller mode of the tick and clip counts.",
    "/timing": "Loop timing of the tick (s).",
    "/reference": "Motion reference the robot should be at this tick: joint positions (rad), clip frame.",
    TRANSITION_TOPIC: "A controller mode change and its reason.",
}

Fields = Mapping[str, tuple[tuple[int, ...], Any]]


def _json_type(dtype: Any) -> str | list[str]:
    kind = np.dtype(dtype).kind
    if kind == "b":
        return "boolean"
    if kind in "iu":
        return "integer"
    return ["number", "null"]


def _property(shape: tuple[int, ...], dtype: Any) -> dict[str, Any]:
    item: dict[str, Any] = {"type": _json_type(dtype)}
    if not shape:
        return item
    if len(shape) != 1:
        raise ValueError(f"MCAP log fields must be scalars or vectors, got shape {shape}")
    return {"type": "array", "items": item, "minItems": shape[0], "maxItems": shape[0]}


def _routes(fields: Fields) -> dict[str, list[tuple[str, str]]]:
    """Topic -> [(JSON key, field)] for the per-tick fields (``t`` excluded: it is in every message).

    Every ``TICK_TOPICS`` topic is present; an ``OPTIONAL_TICK_TOPICS`` topic only when a field routes there.
    """
    out: dict[str, list[tuple[str, str]]] = {topic: [] for topic in (*TICK_TOPICS, *OPTIONAL_TICK_TOPICS)}
    for name in fields:
        if name == "t":
            continue
        topic, key = FIELD_ROUTES.get(name, (COMMANDS_TOPIC, name))
        out[topic].append((key, name))
    return {topic: keys for topic, keys in out.items() if keys or topic in TICK_TOPICS}


def _tick_schema(topic: str, keys: list[tuple[str, str]], fields: Fields, labels: Iterable[str]) -> dict:
    props: dict[str, Any] = {
        "tick": {"type": "integer", "description": "control tick"},
        "t": {"type": ["number", "null"], "description": "target clock, s"},
    }
    for key, name in keys:
        props[key] = _property(*fields[name])
        if name in labels:
            props[f"{key}_name"] = {"type": "string"}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": _SCHEMA_NAMES[topic],
        "description": _DESCRIPTIONS[topic],
        "type": "object",
        "properties": props,
        "required": ["tick", "t", *(k for k, _ in keys)],
    }


_TRANSITION_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": _SCHEMA_NAMES[TRANSITION_TOPIC],
    "description": _DESCRIPTIONS[TRANSITION_TOPIC],
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "target clock, s"},
        "tick": {"type": "integer"},
        "from": {"type": "string"},
        "to": {"type": "string"},
        "reason": {"type": "string"},
    },
    "required": ["t", "tick", "from", "to", "reason"],
}


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _value(v: np.ndarray | np.generic) -> Any:
    """A numpy scalar or vector as plain JSON values (non-finite -> None)."""
    if np.ndim(v) == 0:
        x = v.item()
        return _finite_or_none(x) if isinstance(x, float) else x
    if v.dtype.kind == "f" and not np.isfinite(v).all():
        return [_finite_or_none(x) for x in v.tolist()]
    return v.tolist()
