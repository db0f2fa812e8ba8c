"""Reading a run's MCAP log back, complete or truncated by a crash: ``read_mcap_log`` -> ``McapLog``."""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.deploy.log.mcap_schema import (
    LEGACY_TOPICS,
    OPTIONAL_TICK_TOPICS,
    TICK_TOPICS,
    TRANSITION_TOPIC,
    _routes,
)

__all__ = ["McapLog", "read_mcap_log"]


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
    truncated file, and for one that ``recover.recover_mcap`` rewrote (a footer, but no end record:
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

    A log written before a topic's rename (``mcap_schema.LEGACY_TOPICS``: ``/joint_state``, now
    ``/joint_state_json``) reads the same.

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
                    channels[rec.id] = LEGACY_TOPICS.get(rec.topic, rec.topic)  # an older log's names
                elif isinstance(rec, Message):
                    topic = channels.get(rec.channel_id)
                    if topic == TRANSITION_TOPIC:
                        transitions.append(json.loads(rec.data))
                    elif topic in per_topic:  # the JSON topics (the well-known ones repeat their values)
                        msg = json.loads(rec.data)
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
