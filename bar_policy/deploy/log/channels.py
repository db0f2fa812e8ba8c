"""The run log's channels in well-known schemas: ROS 2 joint states, Foxglove transforms, scene and log lines.

``McapRunWriter`` writes these beside its own JSON topics (``mcap_schema``), from the same per-tick values:

==========================  ==============================  ============================================
topic                       schema (encoding)               content
==========================  ==============================  ============================================
``/joint_states``           ``sensor_msgs/msg/JointState``  measured ``q`` (position, rad), ``dq``
                            (``ros2msg``, CDR)              (velocity, rad/s), ``tau`` (effort, N*m)
``/joint_commands``         ``sensor_msgs/msg/JointState``  the MIT command: ``q_cmd``, ``dq_cmd`` and
                                                            ``tau_cmd`` (host's capped MIT torque, N*m)
``/reference/joint_states`` ``sensor_msgs/msg/JointState``  tracking runs: ``ref_q`` (position only)
``/tf``                     ``foxglove.FrameTransforms``    every body's pose from the measured ``q``
``/reference/tf``           ``foxglove.FrameTransforms``    the reference's, frames ``ref/<body>``
``/robot/scene``            ``foxglove.SceneUpdate``        the MJCF's geoms, one entity per body
``/reference/scene``        ``foxglove.SceneUpdate``        the same in ``ref/`` frames, translucent
``/log``                    ``foxglove.Log``                the run's log lines (``bar_policy`` loggers)
==========================  ==============================  ============================================

Joint states name every joint (``name``, the log's joint order) and carry the logged float64 values bit
for bit, ``header.stamp`` = the message's log time. A tick whose joint vector has a NaN gets no
transforms (Foxglove keeps the last pose). The scenes are written at the start and again every
``SCENE_PERIOD`` s of target time, so Foxglove finds them after a seek and a live viewer that connects
later gets them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from bar_policy.deploy.log.foxglove_scene import GHOST_COLOR, GHOST_PREFIX, RobotScene, foxglove_schema
from bar_policy.deploy.log.ros2_schema import JOINT_STATE_SCHEMA, JOINT_STATE_TYPE, encode_joint_state

__all__ = [
    "JOINT_COMMANDS_TOPIC",
    "JOINT_STATES_TOPIC",
    "LOG_TOPIC",
    "REF_JOINT_STATES_TOPIC",
    "REF_SCENE_TOPIC",
    "REF_TF_TOPIC",
    "SCENE_PERIOD",
    "SCENE_TOPIC",
    "TF_TOPIC",
    "WELL_KNOWN_TOPICS",
    "WellKnownChannels",
    "encode_log",
]

JOINT_STATES_TOPIC = "/joint_states"
JOINT_COMMANDS_TOPIC = "/joint_commands"
REF_JOINT_STATES_TOPIC = "/reference/joint_states"
TF_TOPIC = "/tf"
REF_TF_TOPIC = "/reference/tf"
SCENE_TOPIC = "/robot/scene"
REF_SCENE_TOPIC = "/reference/scene"
LOG_TOPIC = "/log"
WELL_KNOWN_TOPICS = (
    JOINT_STATES_TOPIC,
    JOINT_COMMANDS_TOPIC,
    REF_JOINT_STATES_TOPIC,
    TF_TOPIC,
    REF_TF_TOPIC,
    SCENE_TOPIC,
    REF_SCENE_TOPIC,
    LOG_TOPIC,
)
"""Every topic ``WellKnownChannels`` may write (the reference's only on tracking runs)."""
SCENE_PERIOD = 1.0
"""Target time between two writes of the scenes, s."""

_JOINT_TOPICS = {
    JOINT_STATES_TOPIC: ("q", "dq", "tau"),
    JOINT_COMMANDS_TOPIC: ("q_cmd", "dq_cmd", "tau_cmd"),
    REF_JOINT_STATES_TOPIC: ("ref_q", None, None),
}
"""Topic -> the fields that become position, velocity, effort (None: left empty)."""

Schema = tuple[str, str, bytes]
"""An MCAP schema: (name, encoding, data)."""
Register = Callable[[str, Schema, str], int]
"""``register(topic, schema, message_encoding) -> channel id`` (the writer's)."""
Message = tuple[int, bytes]
"""(channel id, message data)."""


def _log_level(levelno: int) -> Any:
    from foxglove.messages import LogLevel

    if levelno >= logging.CRITICAL:
        return LogLevel.Fatal
    if levelno >= logging.ERROR:
        return LogLevel.Error
    if levelno >= logging.WARNING:
        return LogLevel.Warning
    if levelno >= logging.INFO:
        return LogLevel.Info
    return LogLevel.Debug


def encode_log(stamp_ns: int, levelno: int, message: str, name: str, file: str, line: int) -> bytes:
    """One ``foxglove.Log`` as protobuf bytes (``levelno``: a ``logging`` level; ``stamp_ns``: epoch ns)."""
    from foxglove.messages import Log, Timestamp

    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Log(
        timestamp=Timestamp(sec, nsec),
        level=_log_level(levelno),
        message=message,
        name=name,
        file=file,
        line=int(line),
    ).encode()


class WellKnownChannels:
    """Registers the well-known channels of one run and encodes their messages."""

    def __init__(
        self,
        register: Register,
        fields: Mapping[str, Any],
        joint_names: Sequence[str],
        scene: RobotScene | None = None,
    ) -> None:
        """Register the channels that the log's fields fill.

        Args:
            register: the writer's channel registration (schema records are shared by name).
            fields: the log's per-tick fields (name -> (shape, dtype)).
            joint_names: the log's joint order, shape (n,): the ``name`` of every joint state.
            scene: the robot's model for the transforms and scenes; None writes joint states only.
        """
        self.joint_names = tuple(joint_names)
        n = len(self.joint_names)
        joint_schema = (JOINT_STATE_TYPE, "ros2msg", JOINT_STATE_SCHEMA.encode())
        self._joints: dict[int, tuple[str | None, ...]] = {}
        for topic, names in _JOINT_TOPICS.items():
            given = [k for k in names if k is not None]
            if n and all(k in fields and tuple(fields[k][0]) == (n,) for k in given):
                self._joints[register(topic, joint_schema, "cdr")] = names
        self.has_reference = any(names[0] == "ref_q" for names in self._joints.values())
        self.scene = scene
        self._tf: dict[int, tuple[str, str]] = {}
        self._scenes: list[tuple[int, str, tuple[float, ...] | None]] = []
        if scene is not None:
            tf_schema, scene_schema = foxglove_schema("FrameTransforms"), foxglove_schema("SceneUpdate")
            self._tf[register(TF_TOPIC, tf_schema, "protobuf")] = ("q", "")
            self._scenes.append((register(SCENE_TOPIC, scene_schema, "protobuf"), "", None))
            if self.has_reference:
                self._tf[register(REF_TF_TOPIC, tf_schema, "protobuf")] = ("ref_q", GHOST_PREFIX)
                ghost = (register(REF_SCENE_TOPIC, scene_schema, "protobuf"), GHOST_PREFIX, GHOST_COLOR)
                self._scenes.append(ghost)
        self.log_channel = register(LOG_TOPIC, foxglove_schema("Log"), "protobuf")
        self._next_scene_t = 0.0

    def scenes(self, stamp_ns: int) -> list[Message]:
        """The scene messages (robot, and the ghost on tracking runs), stamped ``stamp_ns``."""
        if self.scene is None:
            return []
        return [(cid, self.scene.scene(stamp_ns, prefix, color)) for cid, prefix, color in self._scenes]

    def tick(self, row: Mapping[str, np.ndarray | np.generic], t: float, stamp_ns: int) -> list[Message]:
        """The messages of one tick: joint states, transforms, and the scenes when they are due.

        Args:
            row: the tick's values (field -> value; joint vectors (n,) float64 in the log's joint order).
            t: target time of the tick, s (schedules the scenes).
            stamp_ns: the message's log time, ns since the epoch (``header.stamp``, transform stamps).
        """
        out: list[Message] = []
        for cid, names in self._joints.items():
            values = [() if k is None else row[k] for k in names]
            out.append((cid, encode_joint_state(stamp_ns, self.joint_names, *values)))
        if self.scene is None:
            return out
        for cid, (key, prefix) in self._tf.items():
            q = np.asarray(row[key], dtype=np.float64)
            if np.isfinite(q).all():
                out.append((cid, self.scene.transforms(q, stamp_ns, prefix)))
        if np.isfinite(t) and t >= self._next_scene_t:
            out += self.scenes(stamp_ns)
            self._next_scene_t = t + SCENE_PERIOD
        return out
