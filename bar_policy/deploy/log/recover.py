"""Recovery of a run's MCAP log cut by a crash (SIGKILL, power loss): ``bar-deploy log recover RUN``.

``read_mcap_log`` reads a cut file up to its last complete record, but the ``mcap`` library's indexed reader
(and Foxglove's seeking) need the summary and footer a cut file lacks. ``recover_mcap`` reads the file
record by record up to the first incomplete or corrupt one and rewrites everything it read (schemas,
channels, messages, metadata, attachments; ``bar_deploy.*`` metadata as strict JSON) as a complete, indexed
MCAP: to a temporary file beside it, verified with the indexed reader, fsync-ed, then moved over the
original, which is kept as ``run.mcap.cut`` (a hard link, else a copy). A complete file is left alone.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from bar_policy._files import fsync_dir, shorten, strict_json
from bar_policy.deploy.log.files import LogReadError
from bar_policy.deploy.log.mcap_schema import MCAP_FILE

__all__ = ["CUT_SUFFIX", "RecoverReport", "recover_mcap"]

CUT_SUFFIX = ".cut"
"""``recover_mcap`` keeps the original file beside the rewritten one as ``<name>.cut``."""
_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length


@dataclass
class RecoverReport:
    """What ``recover_mcap`` did to one MCAP file."""

    path: Path
    """The MCAP file (rewritten in place unless ``complete``)."""
    complete: bool
    """The file already had its summary and footer: nothing was changed."""
    messages: int = 0
    """Messages in the file (recovered ones, or those of the complete file)."""
    per_topic: dict[str, int] = field(default_factory=dict)
    """Topic -> messages, in the order the channels were written."""
    metadata: int = 0
    """Metadata records kept."""
    attachments: int = 0
    """Attachments kept."""
    bytes_dropped: int = 0
    """Bytes at the end of the cut file that held no complete record (a chunk cut mid-write, ...)."""
    stopped_at: str = ""
    """Why reading stopped before the end of the file (empty when it reached it)."""
    truncated: bool = True
    """Reading stopped at a record the end of the file cuts (a crash), not at a corrupt one."""
    original: Path | None = None
    """Where the cut file's bytes were kept (``<name>.cut``); None when nothing was changed."""

    def line(self) -> str:
        """The one line ``bar-deploy log recover`` prints."""
        topics = ", ".join(f"{t} {n}" for t, n in self.per_topic.items()) or "none"
        if self.complete:
            return (
                f"{self.path}: already complete (summary and footer present), nothing changed: "
                f"{self.messages} messages ({topics})"
            )
        kept = ((self.metadata, "metadata"), (self.attachments, "attachments"))
        extra = "".join(f", {n} {what}" for n, what in kept if n)
        why = "" if self.truncated else f" ({self.stopped_at})"
        return (
            f"{self.path}: recovered {self.messages} messages ({topics}){extra}; dropped "
            f"{self.bytes_dropped} bytes at the tail (an incomplete record){why}; original kept as "
            f"{self.original}"
        )


@dataclass
class _Salvage:
    """The records of a cut MCAP file that could be read, in file order."""

    header: Any = None
    records: list[Any] = field(default_factory=list)
    """Schema, Channel, Message, Metadata and Attachment records of the data section."""
    end: int = 0
    """Offset just past the last record read whole."""
    footer: bool = False
    """The footer and the closing magic were read: the file is complete."""
    error: str = ""
    truncated: bool = True
    """False when reading stopped at a record that is whole but corrupt."""


def _read_record(opcode: int, body: bytes) -> list[Any]:
    """The records of one top-level record worth keeping (a chunk's inner ones); [] for the others."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Attachment, Channel, Chunk, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import breakup_chunk

    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        return breakup_chunk(Chunk.read(stream), validate_crc=True)
    if opcode == Opcode.MESSAGE:
        return [Message.read(stream, len(body))]
    readers = {
        Opcode.HEADER: Header,
        Opcode.SCHEMA: Schema,
        Opcode.CHANNEL: Channel,
        Opcode.METADATA: Metadata,
        Opcode.ATTACHMENT: Attachment,
        Opcode.FOOTER: Footer,
    }
    cls = readers.get(opcode)
    return [] if cls is None else [cls.read(stream)]


def _salvage(f: IO[bytes], size: int) -> _Salvage:
    """Read ``f`` record by record up to the first one that is incomplete or corrupt."""
    from mcap.opcode import Opcode
    from mcap.records import Header

    out = _Salvage()
    if f.read(len(_MAGIC)) != _MAGIC:
        raise ValueError("not an MCAP file (no MCAP magic at the start)")
    pos = len(_MAGIC)
    out.end = pos
    in_data = True  # past DATA_END come the summary's repeated schemas and channels: not kept twice
    while pos < size:
        head = f.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            out.error = f"record at byte {pos}: its opcode and length are cut"
            break
        opcode, length = _RECORD_HEAD.unpack(head)
        if length > size - pos - _RECORD_HEAD.size:
            out.error = f"record 0x{opcode:02x} at byte {pos}: {length} bytes announced, the file ends first"
            break
        body = f.read(length)
        try:
            records = _read_record(opcode, body)
        except Exception as e:  # corrupt content fails in struct, zstd, CRC checks, with their own types
            out.error = f"record 0x{opcode:02x} at byte {pos}: {type(e).__name__}: {shorten(e, 200)}"
            out.truncated = False
            break
        pos += _RECORD_HEAD.size + length
        if opcode == Opcode.HEADER:
            out.header = records[0]
        elif opcode == Opcode.DATA_END:
            in_data = False
        elif opcode == Opcode.FOOTER:
            out.end = pos
            out.footer = f.read(len(_MAGIC)) == _MAGIC and pos + len(_MAGIC) == size
            if not out.footer:
                out.error = f"footer at byte {pos - _RECORD_HEAD.size - length}: no closing magic after it"
                out.truncated = pos + len(_MAGIC) > size
            break
        elif in_data:
            out.records.extend(r for r in records if not isinstance(r, Header))
        out.end = pos
    return out


def _strict_metadata(name: str, data: Mapping[str, str]) -> dict[str, str]:
    """A metadata record's map; a ``bar_deploy.*`` JSON value with NaN or infinity is rewritten strictly."""
    data = dict(data)
    if name.startswith("bar_deploy.") and "json" in data:

        def refuse(constant: str) -> None:
            raise ValueError(constant)

        try:
            json.loads(data["json"], parse_constant=refuse)
        except ValueError:
            with contextlib.suppress(ValueError):  # not JSON at all: kept as it was
                data["json"] = strict_json(json.loads(data["json"]), sort_keys=True)
    return data


def _write_salvage(stream: IO[bytes], s: _Salvage) -> tuple[dict[str, int], int, int]:
    """Write the salvaged records as a complete MCAP; returns (topic -> messages, metadata, attachments)."""
    from mcap.records import Attachment, Channel, Message, Metadata, Schema
    from mcap.writer import CompressionType, Writer

    w = Writer(stream, compression=CompressionType.ZSTD)
    w.start(profile=s.header.profile, library=s.header.library)
    schemas: dict[int, int] = {0: 0}
    channels: dict[int, int] = {}
    topics: dict[int, str] = {}
    per_topic: dict[str, int] = {}
    n_meta = n_att = 0
    for rec in s.records:
        if isinstance(rec, Schema):
            if rec.id not in schemas:
                schemas[rec.id] = w.register_schema(name=rec.name, encoding=rec.encoding, data=rec.data)
        elif isinstance(rec, Channel):
            if rec.id not in channels and rec.schema_id in schemas:
                channels[rec.id] = w.register_channel(
                    topic=rec.topic,
                    message_encoding=rec.message_encoding,
                    schema_id=schemas[rec.schema_id],
                    metadata=dict(rec.metadata),
                )
                topics[rec.id] = rec.topic
                per_topic.setdefault(rec.topic, 0)
        elif isinstance(rec, Message):
            if rec.channel_id in channels:  # a message before its channel cannot be decoded: not kept
                w.add_message(
                    channels[rec.channel_id],
                    log_time=rec.log_time,
                    data=rec.data,
                    publish_time=rec.publish_time,
                    sequence=rec.sequence,
                )
                per_topic[topics[rec.channel_id]] += 1
        elif isinstance(rec, Metadata):
            w.add_metadata(rec.name, _strict_metadata(rec.name, rec.metadata))
            n_meta += 1
        elif isinstance(rec, Attachment):
            w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
            n_att += 1
    w.finish()
    return per_topic, n_meta, n_att


def _keep_original(path: Path) -> Path:
    """Link (or copy) ``path`` to ``<name>.cut`` (``.cut.1``, ... when taken); returns that path."""
    import shutil

    for i in range(1000):
        dest = path.with_name(f"{path.name}{CUT_SUFFIX}" + (f".{i}" if i else ""))
        if dest.exists():
            continue
        try:
            os.link(path, dest)  # the same bytes, never a moment without them
        except FileExistsError:
            continue
        except OSError:  # no hard links on this file system
            shutil.copy2(path, dest)
            with dest.open("rb") as g:
                os.fsync(g.fileno())
        return dest
    raise FileExistsError(f"{path}{CUT_SUFFIX} and its numbered variants all exist")


def recover_mcap(path: str | Path) -> RecoverReport:
    """Rewrite an MCAP file cut by a crash (no summary, no footer) as a complete, indexed one.

    Every record that can be read (schemas, channels, messages, metadata, attachments), up to the first
    incomplete or corrupt one, is written to a temporary file in the same directory, which is checked with
    the ``mcap`` indexed reader, ``fsync``-ed and renamed over ``path``. The original bytes stay beside it
    as ``<name>.cut`` (a hard link made before the rename). A complete file is left as it is.

    Args:
        path: an MCAP file, or a run directory (its ``run.mcap``).

    Raises:
        FileNotFoundError: nothing at ``path``.
        LogReadError: (``bar_policy.deploy.log.run_log``; an ``InputError``) not an MCAP file, or not even its
            header can be read.
        OSError: the directory cannot be written.
    """
    path = Path(path)
    if path.is_dir():
        path = path / MCAP_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no MCAP file at {path}")
    size = path.stat().st_size
    try:
        with path.open("rb") as f:
            s = _salvage(f, size)
    except ValueError as e:
        raise LogReadError(f"{path}: {shorten(e, 300)}") from None
    if s.header is None:
        raise LogReadError(f"{path}: not a readable MCAP file: no complete header ({s.error or 'empty'})")
    if s.footer:
        per_topic = _summary_counts(path)
        if per_topic is not None:
            return RecoverReport(path, True, sum(per_topic.values()), per_topic)
    tmp = path.with_name(f".{path.name}.recover-{os.getpid()}.tmp")
    try:
        with tmp.open("wb") as out:
            per_topic, n_meta, n_att = _write_salvage(out, s)
            out.flush()
            os.fsync(out.fileno())
        check = _summary_counts(tmp)
        if check != per_topic:
            raise RuntimeError(f"the rewritten file does not read back ({check} != {per_topic})")
        original = _keep_original(path)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    fsync_dir(path.parent)
    return RecoverReport(
        path=path,
        complete=False,
        messages=sum(per_topic.values()),
        per_topic=per_topic,
        metadata=n_meta,
        attachments=n_att,
        bytes_dropped=size - s.end,
        stopped_at=s.error,
        truncated=s.truncated,
        original=original,
    )


def _summary_counts(path: Path) -> dict[str, int] | None:
    """Topic -> messages from the file's summary (``make_reader``), None when it has none or is unreadable."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # the indexed reader fails in many ways on a damaged file
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = summary.statistics.channel_message_counts
    return {ch.topic: counts.get(cid, 0) for cid, ch in sorted(summary.channels.items())}
