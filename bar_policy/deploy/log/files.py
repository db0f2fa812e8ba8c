"""The run log's per-tick fields, its errors and the durable file helpers (``run_log``'s lower layer).

``log_fields`` gives the per-tick arrays (``run_log`` documents each); ``_write_durable`` writes a file
through ``<path>.partial`` with fsyncs; ``_json_text`` / ``_json_bytes`` give strict JSON of the run
metadata; ``check_log_dir`` checks a log directory before anything moves.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from bar_policy._files import InputError, fsync_dir, strict_json

__all__ = [
    "CAN_LOG_FILE",
    "FLUSH_INTERVAL",
    "NOT_CLOSED",
    "LogDirError",
    "LogReadError",
    "check_log_dir",
    "log_fields",
]

FLUSH_INTERVAL = 0.5
"""Wall time between durable flushes of ``run.mcap``, s (the log loses at most this much on a crash)."""
CAN_LOG_FILE = "run.blf"
"""File name of the raw CAN traffic in a run directory (targets with ``record_can``: the real one)."""
NOT_CLOSED = "not closed: the process ended without closing the log (killed or power loss)"
"""``end_reason`` that ``load_log`` reports for a run recovered from ``run.mcap``."""


class LogDirError(ValueError):
    """The log directory cannot be created or written."""


class LogReadError(InputError):
    """A run log that ``load_log`` cannot read: not a log written by ``bar-deploy``, truncated or corrupt."""


def log_fields(
    n_joints: int,
    n_actions: int,
    obs_size: int,
    commands: Mapping[str, tuple[tuple[int, ...], type]] | Sequence[str] = (),
) -> dict[str, tuple[tuple[int, ...], type]]:
    """The per-tick fields of a run log: name -> (per-tick shape, dtype).

    Args:
        n_joints: joints of the robot state.
        n_actions: action entries.
        obs_size: observation entries.
        commands: the command source's fields (``CommandSource.log_fields``: name -> (shape, dtype)), or
            command names, each a (3,) float64 vector (the reach targets).
    """
    n = (n_joints,)
    fields: dict[str, tuple[tuple[int, ...], type]] = {
        "t": ((), np.float64),
        "wall": ((), np.float64),
        "mode": ((), np.int8),
        "q": (n, np.float64),
        "dq": (n, np.float64),
        "tau": (n, np.float64),
        "temperature": (n, np.float64),
        "obs": ((obs_size,), np.float32),
        "action": ((n_actions,), np.float32),
        "q_cmd": (n, np.float64),
        "dq_cmd": (n, np.float64),
        "kp": (n, np.float64),
        "kd": (n, np.float64),
        "tau_ff": (n, np.float64),
        "tau_cmd": (n, np.float64),
        "n_clipped": ((), np.int16),
        "n_action_clipped": ((), np.int16),
        "compute": ((), np.float64),
        "infer": ((), np.float64),
        "jitter": ((), np.float64),
        "overrun": ((), np.bool_),
    }
    if isinstance(commands, Mapping):
        clash = sorted(set(commands) & set(fields))
        if clash:
            raise ValueError(f"command source log fields {clash} collide with the run log's own fields")
        fields.update({k: (tuple(shape), dt) for k, (shape, dt) in commands.items()})
    else:
        fields.update({name: ((3,), np.float64) for name in commands})
    return fields


# ---------------------------------------------------------------------------------------------------
# Durable file helpers
# ---------------------------------------------------------------------------------------------------
def _write_durable(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write through ``<path>.partial``, fsync, rename over ``path``, fsync the directory."""
    tmp = path.with_name(path.name + ".partial")
    try:
        with tmp.open("wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def _json_text(meta: Mapping[str, Any], **kwargs: Any) -> str:
    """Strict JSON of the run metadata, keys sorted (``_files.strict_json``: NaN, infinities -> ``null``)."""
    return strict_json(meta, sort_keys=True, **kwargs)


def _json_bytes(meta: Mapping[str, Any]) -> bytes:
    """``run.json``'s bytes: strict JSON (``_json_text``; non-finite floats written as ``null``), indented."""
    return _json_text(meta, indent=2).encode()


def check_log_dir(root: str | Path) -> Path:
    """Create ``root`` if needed and check that a file can be written in it.

    Raises:
        LogDirError: naming the directory and the operating system's reason.
    """
    root = Path(root)
    try:
        root.mkdir(parents=True, exist_ok=True)
        probe = root / f".bar-deploy-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        reason = e.strerror or str(e)
        raise LogDirError(
            f"cannot write run logs under {str(root)!r}: {reason} (give a writable --log DIR, or --no-log)"
        ) from None
    return root


def _concat_chunks(
    files: list[Path], fields: Mapping[str, tuple[tuple[int, ...], type]] | None
) -> dict[str, np.ndarray]:
    parts: dict[str, list[np.ndarray]] = {}
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            for k in z.files:
                parts.setdefault(k, []).append(z[k])
    if parts:
        return {k: np.concatenate(v) for k, v in parts.items()}
    if fields is None:
        return {}
    return {k: np.zeros((0, *shape), dtype=dt) for k, (shape, dt) in fields.items()}
