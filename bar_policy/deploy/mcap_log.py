"""The run log as MCAP: JSON messages with one JSON Schema per topic (Foxglove, ``mcap`` CLI, rosbag2 tools).

Layout of ``run.mcap`` (written by ``McapRunWriter``, read back by ``read_mcap_log``):

- metadata record ``bar_deploy.run`` (at the start): ``{"json": <run metadata JSON>}``;
- metadata record ``bar_deploy.fields``: ``{"json": {field: [shape, dtype]}}``, the per-tick fields and the
  NPZ array each one becomes;
- one message per control tick on each of the per-tick topics (``TICK_TOPICS``), every message carrying
  ``tick`` (int) and ``t`` (target clock, s):

  ========================  ==========================================================================
  ``/joint_state``          ``q`` (rad), ``dq`` (rad/s), ``tau`` (N*m): the measured state
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
  summary, counts, the stop path's outcome).

Message ``log_time`` is the run's wall-clock start (unix ns) plus the target time ``t``, so a sim run replays
at sim speed; ``publish_time`` is the wall clock when the tick started. Non-finite numbers are written as
JSON ``null`` (JSON has no NaN; the sign of an infinity is lost) and read back as NaN.

Durability: chunks (zstd) are closed by ``flush()``; the log writer calls it every ``flush_interval`` s of
wall time and then ``os.fsync``. A file that ends without a footer (SIGKILL, power loss) is read up to its
last complete chunk by ``read_mcap_log``; ``mcap_recover.recover_mcap`` (``bar-deploy log recover RUN``)
rewrites it as a complete, indexed MCAP (what the ``mcap`` library's indexed reader and Foxglove's seeking
need), keeping the original as ``run.mcap.cut``.

Metadata records hold strict JSON: every NaN or infinity is ``null`` (``_files.strict_json``), so any JSON
parser reads them.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from bar_policy._files import strict_json

__all__ = [
    "FIELD_ROUTES",
    "MCAP_FILE",
    "OPTIONAL_TICK_TOPICS",
    "TICK_TOPICS",
    "TRANSITION_TOPIC",
    "McapLog",
    "McapRunWriter",
    "read_mcap_log",
]

MCAP_FILE = "run.mcap"
"""File name of the MCAP log inside a run directory."""

TICK_TOPICS = ("/joint_state", "/mit_command", "/policy", "/commands", "/safety", "/timing")
"""Topics with one message per control tick, in the order they are written."""
OPTIONAL_TICK_TOPICS = ("/reference",)
"""Per-tick topics written only when some field routes there (a tracking run's reference)."""
TRANSITION_TOPIC = "/safety/transition"
"""Topic of mode changes."""
COMMANDS_TOPIC = "/commands"

FIELD_ROUTES: dict[str, tuple[str, str]] = {
    "q": ("/joint_state", "q"),
    "dq": ("/joint_state", "dq"),
    "tau": ("/joint_state", "tau"),
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
    "/joint_state": "bar_deploy.JointState",
    "/mit_command": "bar_deploy.MitCommand",
    "/policy": "bar_deploy.Policy",
    "/commands": "bar_deploy.Commands",
    "/safety": "bar_deploy.Safety",
    "/timing": "bar_deploy.Timing",
    "/reference": "bar_deploy.Reference",
    TRANSITION_TOPIC: "bar_deploy.Transition",
}
_DESCRIPTIONS = {
    "/joint_state": "Measured joint state, canonical joint order (rad, rad/s, N*m).",
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


class McapRunWriter:
    """Writes one run as MCAP (JSON messages, JSON Schema per topic) to an open binary stream."""

    def __init__(
        self,
        stream: IO[bytes],
        fields: Fields,
        meta: Mapping[str, Any],
        *,
        start_unix_ns: int,
        labels: Mapping[str, Mapping[int, str]] | None = None,
        library: str = "bar_policy",
    ) -> None:
        """Start the file: header, schemas, channels, the run and field metadata.

        Args:
            stream: binary output (kept open; the caller flushes, fsyncs and closes it).
            fields: the per-tick fields (``log.log_fields``).
            meta: run metadata (JSON-serialisable).
            start_unix_ns: wall clock of the run start, ns since the epoch (the log_time origin).
            labels: per integer field, value -> name, written beside it as ``<key>_name`` (the mode).
            library: writer identification in the MCAP header.
        """
        from mcap.writer import CompressionType, Writer

        self.fields = dict(fields)
        self.labels = {k: dict(v) for k, v in (labels or {}).items()}
        self.start_unix_ns = int(start_unix_ns)
        self._routes = _routes(self.fields)
        self._w = Writer(stream, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=library)
        self._channels: dict[str, int] = {}
        joint_names = meta.get("joint_names")
        self._topics = tuple(self._routes)  # TICK_TOPICS, plus the optional ones that have fields
        for topic in (*self._topics, TRANSITION_TOPIC):
            schema = (
                _TRANSITION_SCHEMA
                if topic == TRANSITION_TOPIC
                else _tick_schema(topic, self._routes[topic], self.fields, self.labels)
            )
            sid = self._w.register_schema(
                name=_SCHEMA_NAMES[topic], encoding="jsonschema", data=json.dumps(schema).encode()
            )
            chan_meta = {}
            if joint_names and topic in ("/joint_state", "/mit_command"):
                chan_meta["joint_names"] = ",".join(joint_names)
            self._channels[topic] = self._w.register_channel(
                topic=topic, message_encoding="json", schema_id=sid, metadata=chan_meta
            )
        spec = {k: [list(shape), np.dtype(dt).str] for k, (shape, dt) in self.fields.items()}
        self._w.add_metadata("bar_deploy.run", {"json": strict_json(meta, sort_keys=True)})
        self._w.add_metadata("bar_deploy.fields", {"json": strict_json(spec, sort_keys=True)})
        self._seq = 0

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
            self._w.add_message(
                self._channels[topic],
                log_time=log_ns,
                publish_time=pub_ns,
                data=json.dumps(msg, separators=(",", ":")).encode(),
                sequence=self._seq,
            )
        self._seq += 1

    def write_transition(self, transition: Mapping[str, Any], wall_ns: int) -> None:
        """One ``/safety/transition`` message (``Transition.to_dict()``)."""
        log_ns, pub_ns = self._times(float(transition["t"]), wall_ns)
        self._w.add_message(
            self._channels[TRANSITION_TOPIC],
            log_time=log_ns,
            publish_time=pub_ns,
            data=strict_json(dict(transition)).encode(),
            sequence=self._seq,
        )

    def flush(self) -> None:
        """Close the chunk in progress and write it (the caller fsyncs)."""
        self._w.flush()

    def finish(self, end_meta: Mapping[str, Any]) -> None:
        """Write the ``bar_deploy.end`` metadata, the summary and the footer."""
        self._w.add_metadata("bar_deploy.end", {"json": strict_json(end_meta, sort_keys=True)})
        self._w.finish()


# ---------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------
@dataclass
class McapLog:
    """What ``read_mcap_log`` recovered."""

    arrays: dict[str, np.ndarray]
    """Per-tick arrays (first axis = tick), as ``load_log`` returns them."""
    meta: dict[str, Any]
    """Run metadata, updated with ``bar_deploy.end`` when the run closed."""
    transitions: list[dict[str, Any]] = field(default_factory=list)
    """Mode changes from ``/safety/transition``."""
    complete: bool = False
    """True when the run closed: the file has its footer and the ``bar_deploy.end`` record. False for a
    truncated file, and for one that ``mcap_recover.recover_mcap`` rewrote (a footer, but no end record:
    never closed)."""
    error: str = ""
    """Why reading stopped early (empty for a complete file)."""
    publish_unix: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Wall clock when each tick started (the ``/timing`` messages' publish time), s since the epoch."""


def _decode_column(values: list[Any], shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    fill: Any = np.nan if dtype.kind == "f" else 0
    out = np.full((len(values), *shape), fill, dtype=dtype)
    for i, v in enumerate(values):
        if v is None:
            continue
        if shape:
            arr = np.array([np.nan if x is None else x for x in v], dtype=np.float64)
            if arr.shape != shape:
                continue
            out[i] = arr
        else:
            out[i] = v
    return out


def read_mcap_log(path: str | Path) -> McapLog:
    """Read a run's MCAP log, complete or truncated (no footer, a cut chunk: read up to the last good chunk).

    Raises:
        ValueError: the file is not an MCAP log written by ``McapRunWriter`` (bad magic, no field record).
    """
    from mcap.exceptions import EndOfFile, InvalidMagic, McapError
    from mcap.records import Channel, Footer, Message, Metadata
    from mcap.stream_reader import CRCValidationError, StreamReader

    path = Path(path)
    channels: dict[int, str] = {}
    meta: dict[str, Any] = {}
    end_meta: dict[str, Any] | None = None
    spec: dict[str, Any] | None = None
    all_topics = (*TICK_TOPICS, *OPTIONAL_TICK_TOPICS)
    per_topic: dict[str, dict[int, dict[str, Any]]] = {topic: {} for topic in all_topics}
    transitions: list[dict[str, Any]] = []
    published: dict[int, int] = {}
    complete = False
    error = ""
    with path.open("rb") as f:
        reader = StreamReader(f, validate_crcs=True)
        try:
            for rec in reader.records:
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    topic = channels.get(rec.channel_id)
                    if topic is None:
                        continue
                    msg = json.loads(rec.data)
                    if topic == TRANSITION_TOPIC:
                        transitions.append(msg)
                    elif topic in per_topic:
                        per_topic[topic][int(msg["tick"])] = msg
                        if topic == "/timing":
                            published[int(msg["tick"])] = rec.publish_time
                elif isinstance(rec, Metadata):
                    body = json.loads(rec.metadata.get("json", "{}"))
                    if rec.name == "bar_deploy.run":
                        meta = body
                    elif rec.name == "bar_deploy.fields":
                        spec = body
                    elif rec.name == "bar_deploy.end":
                        end_meta = body
                elif isinstance(rec, Footer):
                    complete = end_meta is not None  # a recovered file has a footer but no end record
        except InvalidMagic as e:
            if not channels and spec is None:
                raise ValueError(f"{path} is not an MCAP file: {e}") from None
            complete = False  # the end magic is missing
        except (EndOfFile, McapError, CRCValidationError, struct.error, zlib.error, ValueError) as e:
            error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        except Exception as e:  # a chunk cut by a crash fails inside the decompressor with its own type
            error = f"{type(e).__name__}: {e}"
    if spec is None:
        raise ValueError(
            f"{path} is not a bar-deploy MCAP log (no bar_deploy.fields record; {error or 'ok'})"
        )
    fields = {k: (tuple(shape), np.dtype(dt)) for k, (shape, dt) in spec.items()}
    routes = _routes(fields)
    ticks = sorted(set().union(*(set(m) for m in per_topic.values())))
    arrays: dict[str, np.ndarray] = {}
    any_topic = {k: next((per_topic[tp][k] for tp in all_topics if k in per_topic[tp]), {}) for k in ticks}
    if "t" in fields:
        arrays["t"] = _decode_column([any_topic[k].get("t") for k in ticks], *fields["t"])
    for topic in routes:
        msgs = per_topic[topic]
        for key, name in routes[topic]:
            values = [msgs[k].get(key) if k in msgs else None for k in ticks]
            arrays[name] = _decode_column(values, *fields[name])
    if end_meta is not None:
        meta = meta | end_meta
    publish = np.array([published.get(k, 0) / 1e9 if k in published else np.nan for k in ticks])
    return McapLog(
        arrays=arrays,
        meta=meta,
        transitions=transitions,
        complete=complete,
        error=error,
        publish_unix=publish,
    )
