"""One log per run: a streaming MCAP file that survives a crash, and one NPZ of every tick at the end.

A run directory ``<dir>/<YYYYmmdd-HHMMSS>-<target>/`` holds:

- ``run.mcap``: every tick as JSON messages on named topics (``mcap_write``: the schema), written by a
  background thread as the ticks arrive. Every ``flush_interval`` s of wall time (0.5 s) the chunk in
  progress is closed, written and ``fsync``-ed, so a SIGKILL or a power loss loses at most the last
  ``flush_interval`` s plus the writer's backlog (counted: ``log_max_backlog_ticks``). Foxglove and the
  ``mcap`` CLI open it; ``read_mcap_log`` reads it back even without its footer. Beside the JSON topics it
  holds the same values in well-known schemas (``channels``): ROS 2 joint states, the robot drawn in
  Foxglove's 3D panel (transforms and the MJCF's geometry, the tracking reference as a ghost), the run's
  log lines as ``foxglove.Log``; with ``live``, every message also goes to the live server.
- ``run.blf`` (real target): the raw CAN traffic of every bus (``robstride.can_record``).
- ``log.npz``: all ticks as arrays, written (atomically, fsync-ed) by ``close()``, plus ``meta_json`` (a 0-d
  string: run metadata, mode transitions, timing summary, end reason, the stop path's outcome). The runtime
  calls ``close()`` in ``finally``, so it is written when the run ends on a signal or an exception too.
- ``run.json``: the metadata for humans, ``status: running`` until ``close()`` rewrites it with
  ``status: closed`` (both writes atomic and fsync-ed). It is strict JSON: every NaN or infinity in the
  metadata (a timing statistic of a run with no tick, say) is written as ``null``
  (``_files.strict_json``); so is ``meta_json`` in ``log.npz``.
- ``chunks/``: while the run lasts, the NPZ spill of every ``chunk_ticks`` ticks (memory stays bounded);
  removed once ``log.npz`` is on disk.

Per-tick arrays (first axis = tick): ``t`` (target clock, s), ``wall`` (s since start), ``mode`` (int8,
``safety.Mode``), ``q``/``dq``/``tau`` (measured, (T, n)), ``temperature`` (motor temperature, degC, (T, n);
NaN on targets that report none), ``obs`` (T, obs_size) float32, ``action``
(T, n_actions) float32 (NaN where the policy did not run), ``q_cmd``/``dq_cmd``/``kp``/``kd``/``tau_ff``
(T, n), ``tau_cmd`` (host's MIT torque for the command at the measured state, capped, (T, n)),
``n_clipped`` (joints whose q_cmd was clipped to a limit that tick), ``n_action_clipped`` (action
entries clipped to the action bound), ``compute`` / ``infer`` / ``jitter`` (s), ``overrun`` (bool),
and the command source's fields (``CommandSource.log_fields``): for reach one (T, 3) array per target
(``target_pos_left`` / ``target_pos_right``, chest frame, m); for tracking the reference the robot should
be at that tick, ``ref_q`` (T, n) rad, and ``ref_frame`` (T,) int32, its frame index in the clip (0 during
the start-up HOLD, which ramps to the first frame; the last frame once the clip is over). ``load_log``
reads ``log.npz``, or, for a run that never closed (killed, power loss), ``run.mcap`` (and NPZ chunks of
older runs).
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import shutil
import threading
import time
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from bar_policy._files import fsync_dir
from bar_policy.deploy.log.files import (
    FLUSH_INTERVAL,
    LogDirError,
    _concat_chunks,
    _json_bytes,
    _json_text,
    _write_durable,
)
from bar_policy.deploy.log.mcap_schema import MCAP_FILE
from bar_policy.deploy.log.mcap_write import McapRunWriter

if TYPE_CHECKING:
    from bar_policy.deploy.log.foxglove_scene import RobotScene
    from bar_policy.deploy.log.live import LiveServer

__all__ = ["RunLog"]

log = logging.getLogger(__name__)

HELD_TICKS = 30_000
"""Most ticks of spill chunks kept in memory when they cannot be written (disk full, read-only), 10 min
at 50 Hz (45 MB for a reach policy on the arms: 1486 B a tick): ``log.npz`` gets them if it can be written
at close. Ticks past it are dropped and counted (``log_ticks_dropped``)."""

RUN_JSON_RESERVE = 64 * 1024
"""Bytes the ``running`` version of ``run.json`` takes on disk (the JSON, then spaces): room that closing
the log can rewrite in place when the disk is full or the directory read-only, so ``run.json`` never stays
``running`` after a close. A closing record longer than this is cut to its essentials."""


def _save_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``arrays`` as an NPZ at ``path``; a partial file is removed when writing fails."""
    try:
        with path.open("wb") as f:
            np.savez(f, **arrays)
    except BaseException:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        raise


def _rewrite_in_place(path: Path, data: bytes) -> None:
    """Overwrite the existing file ``path`` with ``data``, then ``fsync``.

    No new file: a read-only directory allows it, and a full disk too while ``data`` fits the file's blocks.
    """
    with path.open("r+b") as f:
        f.write(data)
        f.truncate()
        f.flush()
        os.fsync(f.fileno())


# ---------------------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------------------
class _LogLines(logging.Handler):
    """Hands the records of a logger (INFO and above) to a ``RunLog`` for ``/log``."""

    def __init__(self, runlog: RunLog) -> None:
        super().__init__(level=logging.INFO)
        self.runlog = runlog

    def emit(self, record: logging.LogRecord) -> None:
        """Queue the record's level, text and origin for the writer thread."""
        try:
            self.runlog.log_line(record)
        except Exception:  # a record whose message cannot be formatted: logging's own report
            self.handleError(record)


class RunLog:
    """Per-tick recorder: a durable streaming ``run.mcap``, an NPZ spill, and ``log.npz`` at close."""

    def __init__(
        self,
        root: str | Path,
        fields: Mapping[str, tuple[tuple[int, ...], type]],
        meta: Mapping[str, Any],
        *,
        name: str = "run",
        chunk_ticks: int = 1000,
        flush_interval: float = FLUSH_INTERVAL,
        labels: Mapping[str, Mapping[int, str]] | None = None,
        scene: RobotScene | None = None,
        model_xml: str | None = None,
        live: LiveServer | None = None,
        log_lines: str | None = "bar_policy",
    ) -> None:
        """Create the run directory and start the writer thread.

        Args:
            root: parent directory of run directories.
            fields: per-tick fields (``log_fields``).
            meta: JSON-serialisable run metadata.
            name: suffix of the run directory (the target name).
            chunk_ticks: ticks per NPZ spill chunk (bounds the memory of a long run).
            flush_interval: wall time between durable flushes of ``run.mcap``, s (> 0).
            labels: names of integer field values for the MCAP messages (``{"mode": {1: "DAMPING"}}``).
            scene: the robot's model for the transforms and the scene in ``run.mcap`` (``foxglove_scene``).
            model_xml: the robot's MJCF, attached to ``run.mcap``.
            live: a live server that gets every channel of ``run.mcap`` too (``bar-deploy --live``).
            log_lines: the logger whose records (INFO and above) are written to ``/log`` while the log is
                open; None writes none.

        Raises:
            LogDirError: the run directory or its files cannot be created.
        """
        if chunk_ticks < 1:
            raise ValueError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
        if not flush_interval > 0:
            raise ValueError(f"flush_interval must be > 0 s, got {flush_interval}")
        self.fields = dict(fields)
        self.chunk_ticks = chunk_ticks
        self.flush_interval = float(flush_interval)
        start_ns = time.time_ns()
        self.meta: dict[str, Any] = {"started_unix": start_ns / 1e9} | dict(meta)
        self.path = self._make_dir(Path(root), name)
        self.ticks = 0
        self._n = 0
        self._chunk = 0
        self._buf = self._new_buffer()
        self._spilled: dict[int, Path] = {}
        """Chunk index -> its NPZ, written (by the writer thread)."""
        self._held: dict[int, dict[str, np.ndarray]] = {}
        """Chunk index -> its arrays, kept in memory because the spill failed (at most ``HELD_TICKS``)."""
        self._held_ticks = 0
        self.dropped_ticks = 0
        """Ticks lost: spills that failed once ``HELD_TICKS`` were held, or a spill unreadable at close."""
        self._write_errors: list[str] = []
        self.incomplete: str | None = None
        """Why the log is incomplete (set by ``close``; None: complete), as ``run.json`` says."""
        self.flushes = 0
        self.durable_ticks = 0
        """Ticks in ``run.mcap`` as of its last durable flush (what a crash now would keep)."""
        """Durable flushes of ``run.mcap`` so far."""
        self.max_backlog = 0
        """Most ticks ever waiting for the writer thread (what a crash could lose beyond a flush period)."""
        self._written = 0
        self.closed = False
        try:
            running = _json_bytes(self.meta | {"status": "running"})
            reserve = b" " * max(RUN_JSON_RESERVE - len(running) - 1, 0) + b"\n"  # room to close in place
            _write_durable(self.path / "run.json", lambda f: f.write(running + reserve))
            self._mcap_file = (self.path / MCAP_FILE).open("wb")
            self._mcap = McapRunWriter(
                self._mcap_file,
                self.fields,
                self.meta,
                start_unix_ns=start_ns,
                labels=labels,
                scene=scene,
                model_xml=model_xml,
                live=live,
            )
            self._mcap.flush()
            self._mcap_file.flush()
            os.fsync(self._mcap_file.fileno())
            fsync_dir(self.path)
        except OSError as e:
            raise LogDirError(f"cannot write the run log in {str(self.path)!r}: {e.strerror or e}") from None
        self._queue: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        self._last_t = 0.0
        self._writer = threading.Thread(target=self._write_loop, name="bar-deploy-log", daemon=True)
        self._writer.start()
        self._lines = _LogLines(self)
        self._lines_logger = None if log_lines is None else logging.getLogger(log_lines)
        if self._lines_logger is not None:
            self._lines_logger.addHandler(self._lines)

    @staticmethod
    def _make_dir(root: Path, name: str) -> Path:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        try:
            root.mkdir(parents=True, exist_ok=True)
            k = 0
            while True:
                path = root / (f"{stamp}-{name}" if k == 0 else f"{stamp}-{name}-{k}")
                try:
                    (path / "chunks").mkdir(parents=True, exist_ok=False)
                    break
                except FileExistsError:
                    k += 1
        except OSError as e:
            raise LogDirError(
                f"cannot create a run directory under {str(root)!r}: {e.strerror or e} "
                "(give a writable --log DIR, or --no-log)"
            ) from None
        fsync_dir(root)
        return path

    def _new_buffer(self) -> dict[str, np.ndarray]:
        def empty(shape: tuple[int, ...], dt: type) -> np.ndarray:
            fill = np.nan if np.issubdtype(dt, np.floating) else 0
            return np.full((self.chunk_ticks, *shape), fill, dtype=dt)

        return {k: empty(shape, dt) for k, (shape, dt) in self.fields.items()}

    # -- the loop's side (cheap: copy into the buffer, hand a reference to the writer) ----------------
    def append(self, record: Mapping[str, Any]) -> None:
        """Record one tick (name -> value); fields left out stay NaN (float fields) or 0."""
        if self.closed:
            raise RuntimeError("the run log is closed")
        i = self._n
        buf = self._buf
        for k, v in record.items():
            buf[k][i] = v
        self._last_t = float(buf["t"][i]) if "t" in buf else self._last_t
        # Rows are never written again once appended, so the writer thread may read them at leisure.
        self._queue.put(("tick", buf, i, self.ticks, time.time_ns()))
        self._n += 1
        self.ticks += 1
        if self._n == self.chunk_ticks:
            self._spill_chunk()

    def transition(self, transition: Mapping[str, Any]) -> None:
        """Record a mode change (``Transition.to_dict()``) on ``/safety/transition``."""
        if not self.closed:
            self._queue.put(("transition", dict(transition), time.time_ns()))

    def log_line(self, record: logging.LogRecord) -> None:
        """Record a log line on ``/log``, at the target time of the latest tick (any thread)."""
        if not self.closed:
            line = (record.levelno, record.getMessage(), record.name, record.pathname, record.lineno)
            self._queue.put(("line", line, self._last_t, time.time_ns()))

    def _spill_chunk(self) -> None:
        if self._n == 0:
            return
        arrays = {k: v[: self._n] for k, v in self._buf.items()}
        path = self.path / "chunks" / f"chunk_{self._chunk:06d}.npz"
        self._queue.put(("chunk", self._chunk, path, arrays))
        self._chunk += 1
        self._buf = self._new_buffer()
        self._n = 0

    # -- the writer thread -------------------------------------------------------------------------
    def _error(self, what: str, e: BaseException) -> None:
        msg = f"{what}: {type(e).__name__}: {e}"
        if not self._write_errors:
            log.error("run log: %s (further errors counted)", msg)
        self._write_errors.append(msg)

    def _hold(self, index: int, arrays: dict[str, np.ndarray]) -> None:
        """Keep a failed spill in memory for ``log.npz``; past ``HELD_TICKS``, drop it (counted)."""
        n = len(next(iter(arrays.values()))) if arrays else 0
        if self._held_ticks + n <= HELD_TICKS:
            self._held[index] = arrays
            self._held_ticks += n
        else:
            self.dropped_ticks += n

    def _kept_arrays(self) -> dict[str, np.ndarray]:
        """Every tick kept, in order: the spilled chunks read back and the held ones (writer thread joined).

        A spilled chunk that cannot be read back (the disk failed under it) is dropped and counted.
        """
        parts: list[dict[str, np.ndarray]] = []
        for index in sorted(self._spilled.keys() | self._held.keys()):
            if index in self._held:
                parts.append(self._held[index])
                continue
            path = self._spilled[index]
            try:
                with np.load(path, allow_pickle=False) as z:
                    parts.append({k: z[k] for k in z.files})
            except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
                self._error(f"read back {path.name}", e)
                self.dropped_ticks += self._chunk_len(index)
        if not parts:
            return _concat_chunks([], self.fields)
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def _chunk_len(self, index: int) -> int:
        """Ticks of chunk ``index``: ``chunk_ticks``, the last one (the close's spill) ``ticks`` mod it."""
        last = (self.ticks - 1) // self.chunk_ticks if self.ticks else 0
        return self.chunk_ticks if index < last else self.ticks - last * self.chunk_ticks

    def _durable_flush(self) -> None:
        written = self._written
        try:
            self._mcap.flush()
            self._mcap_file.flush()
            os.fsync(self._mcap_file.fileno())
            self.flushes += 1
            self.durable_ticks = written
        except (OSError, ValueError) as e:
            self._error("flush run.mcap", e)

    def _write_loop(self) -> None:
        dirty = False
        next_flush = time.monotonic() + self.flush_interval
        while True:
            try:
                item = self._queue.get(timeout=max(next_flush - time.monotonic(), 0.0))
            except queue.Empty:
                item = ("idle",)
            kind = item[0]
            if kind == "tick":
                _, buf, i, tick, wall_ns = item
                try:
                    self._mcap.write_tick(tick, {k: v[i] for k, v in buf.items()}, wall_ns)
                except Exception as e:
                    self._error(f"tick {tick} to run.mcap", e)
                self._written = tick + 1
                self.max_backlog = max(self.max_backlog, self.ticks - self._written)
                dirty = True
            elif kind == "transition":
                try:
                    self._mcap.write_transition(item[1], item[2])
                except Exception as e:
                    self._error("transition to run.mcap", e)
                dirty = True
            elif kind == "line":
                try:
                    self._mcap.write_log(item[2], *item[1], wall_ns=item[3])
                except Exception as e:
                    self._error("log line to run.mcap", e)
                dirty = True
            elif kind == "chunk":
                _, index, path, arrays = item
                try:
                    _save_npz(path, arrays)
                    self._spilled[index] = path
                except Exception as e:  # OSError: disk full, read-only; or numpy's zip writer failing on it
                    self._error(f"spill {path.name}", e)
                    self._hold(index, arrays)
            elif kind == "close":
                try:
                    self._mcap.finish(item[1])
                    self._mcap_file.flush()
                    os.fsync(self._mcap_file.fileno())
                except Exception as e:
                    self._error("finish run.mcap", e)
                with contextlib.suppress(OSError):
                    self._mcap_file.close()
                return
            if time.monotonic() >= next_flush:
                if dirty:
                    self._durable_flush()
                    dirty = False
                next_flush = time.monotonic() + self.flush_interval

    # -- closing -----------------------------------------------------------------------------------
    def close(self, **meta: Any) -> Path:
        """Finish ``run.mcap``, write ``log.npz`` and ``run.json`` (idempotent); returns the ``log.npz`` path.

        ``meta`` is merged into the run metadata (end reason, transitions, timing, counts).
        """
        out = self.path / "log.npz"
        if self.closed:
            return out
        if self._lines_logger is not None:
            self._lines_logger.removeHandler(self._lines)
        self.closed = True
        self._spill_chunk()
        self.meta.update(meta)
        self.meta["ticks"] = self.ticks
        self.meta["status"] = "closed"
        self.meta["log_flush_interval_s"] = self.flush_interval
        # The writer finishes the MCAP with the final metadata; the counters it adds are its own.
        end = dict(self.meta)
        self._queue.put(("close", end))
        self._writer.join()
        self.meta["log_flushes"] = self.flushes
        self.meta["log_max_backlog_ticks"] = self.max_backlog
        arrays = self._kept_arrays()
        self._note_errors()

        def write_npz(f: IO[bytes]) -> None:
            np.savez(f, meta_json=np.array(_json_text(self.meta)), **arrays)

        npz_written = True
        try:
            _write_durable(out, write_npz)
        except (OSError, ValueError) as e:  # a full disk, a read-only directory (numpy's writer: ValueError)
            npz_written = False
            self._error("write log.npz", e)
            self.meta["log_npz"] = "not written"
            self._note_errors()
        self._write_run_json()
        if npz_written:
            shutil.rmtree(self.path / "chunks", ignore_errors=True)
            log.info("run log written to %s (%d ticks)", out, self.ticks)
        if self.incomplete:
            log.error("run log incomplete: %s", self.incomplete)
        return out

    def _note_errors(self) -> None:
        """Put the write errors so far into the metadata, with ``log_incomplete`` saying what was lost."""
        if not self._write_errors:
            return
        self.meta["log_write_errors"] = self._write_errors[:20]
        self.meta["log_write_error_count"] = len(self._write_errors)
        self.meta["log_ticks_dropped"] = self.dropped_ticks
        lost = [f"{self.dropped_ticks} of {self.ticks} ticks dropped"] if self.dropped_ticks else []
        if self.meta.get("log_npz") == "not written":
            lost.append("no log.npz (run.mcap holds the ticks up to the failure)")
        self.incomplete = f"logging failed ({self._write_errors[0]})"
        if lost:
            self.incomplete += ": " + "; ".join(lost)
        self.meta["log_incomplete"] = self.incomplete

    def _write_run_json(self) -> None:
        """The closing ``run.json``: never left ``running`` while the file can be written at all.

        Atomically (a new file, renamed), else in place (a read-only directory, a full disk: the ``running``
        version reserved ``RUN_JSON_RESERVE`` bytes), else only its essentials in place.
        """
        path = self.path / "run.json"
        data = _json_bytes(self.meta)
        try:
            _write_durable(path, lambda f: f.write(data))
            return
        except OSError as e:
            self._error("write run.json", e)
            self._note_errors()
            data = _json_bytes(self.meta)
        keys = ("status", "end_reason", "ticks", "log_incomplete", "log_write_error_count")
        cut = {k: self.meta[k] for k in keys if k in self.meta}
        cut["cut"] = f"the full record exceeded the {RUN_JSON_RESERVE} B reserved"
        last: OSError | None = None
        for version in (data, _json_bytes(cut)):
            try:
                _rewrite_in_place(path, version)
                return
            except OSError as e:
                last = e
        log.error("run.json could not be updated (%s); it still says 'running'", last)
