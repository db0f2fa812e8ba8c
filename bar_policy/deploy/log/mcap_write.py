"""The run log as MCAP: JSON messages with one JSON Schema per topic (Foxglove, ``mcap`` CLI, rosbag2 tools).

Layout of ``run.mcap`` (written by ``McapRunWriter``, read back by ``read_mcap_log``):

- metadata record ``bar_deploy.run`` (at the start): ``{"json": <run metadata JSON>}``;
- metadata record ``bar_deploy.fields``: ``{"json": {field: [shape, dtype]}}``, the per-tick fields and the
  NPZ array each one becomes;
- one message per control tick on each of the per-tick topics (``TICK_TOPICS``), every message carrying
  ``tick`` (int) and ``t`` (target clock, s):

  ========================  ==========================================================================
  ``/joint_state_json``     ``q`` (rad), ``dq`` (rad/s), ``tau`` (N*m): the measured state
  ``/mit_command``          ``q``, ``dq``, ``kp``, ``kd``, ``tau_ff``: the MIT command written;
                            ``tau_cmd``: the host's capped MIT torque of that command at the state
  ``/policy``               ``obs`` (the observation), ``action`` (raw policy output; null entries when
                            the policy did not run that tick)
  ``/commands``             one 3-vector per command term (``target_pos_left`` ...); every per-tick field
                            that no other topic takes lands here
  ``/reference``            tracking runs only (the topic exists when the log has its fields): ``q``
                            (rad), the motion reference the robot should be at that tick, and ``frame``,
                            its frame index in the clip
  ``/safety``               ``mode`` (int), ``mode_name``, ``n_clipped``, ``n_action_clipped``
  ``/timing``               ``wall`` (s since the loop started), ``compute``, ``infer``, ``jitter`` (s),
                            ``overrun`` (bool)
  ========================  ==========================================================================

- ``/safety/transition`` (one message per mode change): ``t``, ``tick``, ``from``, ``to``, ``reason``;
- metadata record ``bar_deploy.end`` (only when the run closed): the final metadata (end reason, timing
  summary, counts, the stop path's outcome);
- the same values again in well-known schemas that Foxglove and ROS 2 tools read without set-up
  (``channels`` lists them): ``/joint_states``, ``/joint_commands`` and ``/reference/joint_states`` as
  ROS 2 ``sensor_msgs/msg/JointState`` (CDR), the robot's body transforms ``/tf`` (and the reference's
  ghost, ``/reference/tf``) as ``foxglove.FrameTransforms``, its geometry ``/robot/scene`` (and
  ``/reference/scene``) as ``foxglove.SceneUpdate``, and the run's log lines ``/log`` as ``foxglove.Log``;
- attachment ``robot.xml``: the robot's MJCF (when the writer was given it).

Message ``log_time`` is the run's wall-clock start (unix ns) plus the target time ``t``, so a sim run replays
at sim speed; ``publish_time`` is the wall clock when the tick started. Non-finite numbers are written as
JSON ``null`` (JSON has no NaN; the sign of an infinity is lost) and read back as NaN.

Durability: chunks (zstd) are closed by ``flush()``; the log writer calls it every ``flush_interval`` s of
wall time and then ``os.fsync``. A file that ends without a footer (SIGKILL, power loss) is read up to its
last complete chunk by ``read_mcap_log``; ``recover.recover_mcap`` (``bar-deploy log recover RUN``)
rewrites it as a complete, indexed MCAP (what the ``mcap`` library's indexed reader and Foxglove's seeking
need), keeping the original as ``run.mcap.cut``.

Metadata records hold strict JSON: every NaN or infinity is ``null`` (``_files.strict_json``), so any JSON
parser reads them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import IO, Any

import numpy as np

from bar_policy._files import strict_json
from bar_policy.deploy.log.channels import WellKnownChannels, encode_log
from bar_policy.deploy.log.foxglove_scene import RobotScene
from bar_policy.deploy.log.live import LiveServer
from bar_policy.deploy.log.mcap_schema import (
    _SCHEMA_NAMES,
    _TRANSITION_SCHEMA,
    JOINT_STATE_TOPIC,
    TRANSITION_TOPIC,
    Fields,
    _finite_or_none,
    _routes,
    _tick_schema,
    _value,
)

__all__ = ["MODEL_ATTACHMENT", "McapRunWriter"]


MODEL_ATTACHMENT = "robot.xml"
"""Name of the attachment that holds the robot's MJCF."""


class McapRunWriter:
    """Writes one run as MCAP (the JSON topics, and the well-known ones of ``channels``) to a stream."""

    def __init__(
        self,
        stream: IO[bytes],
        fields: Fields,
        meta: Mapping[str, Any],
        *,
        start_unix_ns: int,
        labels: Mapping[str, Mapping[int, str]] | None = None,
        library: str = "bar_policy",
        scene: RobotScene | None = None,
        model_xml: str | None = None,
        live: LiveServer | None = None,
    ) -> None:
        """Start the file: header, schemas, channels, the run and field metadata, the robot model.

        Args:
            stream: binary output (kept open; the caller flushes, fsyncs and closes it).
            fields: the per-tick fields (``log.log_fields``).
            meta: run metadata (JSON-serialisable); its ``joint_names`` name the joint states.
            start_unix_ns: wall clock of the run start, ns since the epoch (the log_time origin).
            labels: per integer field, value -> name, written beside it as ``<key>_name`` (the mode).
            library: writer identification in the MCAP header.
            scene: the robot's model for ``/tf`` and ``/robot/scene`` (and the reference's ghost); None
                writes no transforms and no scene.
            model_xml: the robot's MJCF, attached to the file as ``robot.xml``.
            live: a live server that gets every channel and message too (``bar-deploy --live``).
        """
        from mcap.writer import CompressionType, Writer

        self.fields = dict(fields)
        self.labels = {k: dict(v) for k, v in (labels or {}).items()}
        self.start_unix_ns = int(start_unix_ns)
        self._routes = _routes(self.fields)
        self._w = Writer(stream, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=library)
        self._live = live
        self._schemas: dict[tuple[str, str], int] = {}
        self._topic_of: dict[int, str] = {}
        self._channels: dict[str, int] = {}
        joint_names = meta.get("joint_names")
        self._topics = tuple(self._routes)  # TICK_TOPICS, plus the optional ones that have fields
        for topic in (*self._topics, TRANSITION_TOPIC):
            schema = (
                _TRANSITION_SCHEMA
                if topic == TRANSITION_TOPIC
                else _tick_schema(topic, self._routes[topic], self.fields, self.labels)
            )
            chan_meta = {}
            if joint_names and topic in (JOINT_STATE_TOPIC, "/mit_command"):
                chan_meta["joint_names"] = ",".join(joint_names)
            record = (_SCHEMA_NAMES[topic], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self.register(topic, record, "json", chan_meta)
        self.well_known = WellKnownChannels(self.register, self.fields, joint_names or (), scene)
        spec = {k: [list(shape), np.dtype(dt).str] for k, (shape, dt) in self.fields.items()}
        self._w.add_metadata("bar_deploy.run", {"json": strict_json(meta, sort_keys=True)})
        self._w.add_metadata("bar_deploy.fields", {"json": strict_json(spec, sort_keys=True)})
        if model_xml is not None:
            self._w.add_attachment(
                create_time=self.start_unix_ns,
                log_time=self.start_unix_ns,
                name=MODEL_ATTACHMENT,
                media_type="application/xml",
                data=model_xml.encode(),
            )
        self._seq = 0

    def register(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        metadata: Mapping[str, str] | None = None,
    ) -> int:
        """Add a channel (and its schema, once per name and encoding), in the file and on the live server.

        Args:
            topic: the channel's topic.
            schema: (name, encoding, data) of its schema record.
            message_encoding: ``json``, ``cdr``, ``protobuf``.
            metadata: the channel's metadata.

        Returns:
            The channel id for ``add``.
        """
        name, encoding, data = schema
        sid = self._schemas.get((name, encoding))
        if sid is None:
            sid = self._schemas[(name, encoding)] = self._w.register_schema(
                name=name, encoding=encoding, data=data
            )
        meta = dict(metadata or {})
        cid = self._w.register_channel(
            topic=topic, message_encoding=message_encoding, schema_id=sid, metadata=meta
        )
        self._topic_of[cid] = topic
        if self._live is not None:
            self._live.add_channel(topic, schema, message_encoding, meta)
        return cid

    def add(self, channel: int, data: bytes, log_ns: int, pub_ns: int) -> None:
        """One message on a registered channel: to the file, and to the live server when there is one."""
        self._w.add_message(channel, log_time=log_ns, publish_time=pub_ns, data=data, sequence=self._seq)
        if self._live is not None:
            self._live.publish(self._topic_of[channel], data, log_ns)

    def _times(self, t: float, wall_ns: int) -> tuple[int, int]:
        log_ns = self.start_unix_ns + (round(t * 1e9) if math.isfinite(t) else 0)
        return max(log_ns, 0), wall_ns

    def write_tick(self, tick: int, row: Mapping[str, np.ndarray | np.generic], wall_ns: int) -> None:
        """One message per tick topic for one row of the log (field -> value)."""
        t = float(row["t"])
        log_ns, pub_ns = self._times(t, wall_ns)
        head = {"tick": int(tick), "t": _finite_or_none(t)}
        for topic in self._topics:
            msg = dict(head)
            for key, name in self._routes[topic]:
                value = _value(row[name])
                msg[key] = value
                if name in self.labels:
                    msg[f"{key}_name"] = self.labels[name].get(value, str(value))
            self.add(self._channels[topic], json.dumps(msg, separators=(",", ":")).encode(), log_ns, pub_ns)
        for channel, data in self.well_known.tick(row, t, log_ns):
            self.add(channel, data, log_ns, pub_ns)
        self._seq += 1

    def write_transition(self, transition: Mapping[str, Any], wall_ns: int) -> None:
        """One ``/safety/transition`` message (``Transition.to_dict()``)."""
        log_ns, pub_ns = self._times(float(transition["t"]), wall_ns)
        self.add(self._channels[TRANSITION_TOPIC], strict_json(dict(transition)).encode(), log_ns, pub_ns)

    def write_log(
        self, t: float, levelno: int, message: str, name: str, file: str, line: int, *, wall_ns: int
    ) -> None:
        """One ``/log`` message (``foxglove.Log``) at target time ``t`` (s).

        The arguments are a ``logging`` record's level, text, logger name, source file and line.
        """
        log_ns, pub_ns = self._times(t, wall_ns)
        data = encode_log(log_ns, levelno, message, name, file, line)
        self.add(self.well_known.log_channel, data, log_ns, pub_ns)

    def flush(self) -> None:
        """Close the chunk in progress and write it (the caller fsyncs)."""
        self._w.flush()

    def finish(self, end_meta: Mapping[str, Any]) -> None:
        """Write the ``bar_deploy.end`` metadata, the summary and the footer."""
        self._w.add_metadata("bar_deploy.end", {"json": strict_json(end_meta, sort_keys=True)})
        self._w.finish()
