"""Reading a run log back: ``load_log`` (``log.npz``, else ``run.mcap``, else the NPZ chunks of older runs).

``run_log`` documents the run directory and the per-tick arrays; ``mcap_write`` the MCAP schema.
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from bar_policy._files import loads_json, npz_problem, shorten
from bar_policy.deploy.log.files import NOT_CLOSED, LogReadError, _concat_chunks
from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE

__all__ = ["load_log"]


# ---------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any]:
    """``run.json`` as a dict; ``{}`` when it is missing, malformed or not an object (it only informs)."""
    try:
        value = loads_json(path.read_bytes(), str(path), LogReadError)
    except (OSError, LogReadError):
        return {}
    return value if isinstance(value, dict) else {}


def _load_mcap(path: Path, run_json: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    try:
        rec = read_mcap_log(path)
    except LogReadError:
        raise
    except (ValueError, TypeError, KeyError, RecursionError, EOFError) as e:
        raise LogReadError(
            f"{path} is not a run log (MCAP written by bar-deploy): {shorten(e, 500)}"
        ) from None
    meta = run_json | rec.meta
    if not rec.complete and run_json.get("status") == "closed":
        # The run closed, but run.mcap could not be finished (a full disk): run.json has the end.
        meta = rec.meta | run_json
        meta["recovered_from"] = path.name
        if rec.error:
            meta["recovery_stopped_at"] = rec.error
    elif not rec.complete:
        meta["status"] = "running"
        meta["end_reason"] = NOT_CLOSED
        meta["recovered_from"] = path.name
        if rec.error:
            meta["recovery_stopped_at"] = rec.error
        meta.setdefault("transitions", rec.transitions)
    meta["ticks"] = int(rec.arrays["t"].shape[0]) if "t" in rec.arrays else 0
    return rec.arrays, meta


def load_log(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a run log: a run directory, its ``log.npz`` or its ``run.mcap``.

    A directory is read from ``log.npz`` when the run closed, else from ``run.mcap`` (complete or cut off by
    a crash: everything up to the last durable flush), else from NPZ chunks (logs of older versions). A run
    recovered without ``close()`` has ``meta["status"] == "running"`` and ``meta["end_reason"]`` saying so.

    Returns:
        ``(arrays, meta)``: per-tick arrays (first axis = tick) and the run metadata.

    Raises:
        FileNotFoundError: nothing at ``path``.
        LogReadError: (an ``_files.InputError``, a ``ValueError``) the file is not a run log, or a corrupt
            one: the only error for malformed content, whatever the bytes.
    """
    path = Path(path)
    if path.is_dir():
        run_json = _read_json(path / "run.json")
        if (path / "log.npz").is_file():
            path = path / "log.npz"
        elif (path / MCAP_FILE).is_file():
            try:
                return _load_mcap(path / MCAP_FILE, run_json)
            except ValueError as e:
                chunks = sorted((path / "chunks").glob("chunk_*.npz"))
                if not chunks:
                    raise LogReadError(
                        f"run {path} has no log.npz and its {MCAP_FILE} is unreadable: {shorten(e, 500)}"
                    ) from None
                return _read_chunks(path, chunks), run_json
        else:
            chunks = sorted((path / "chunks").glob("chunk_*.npz"))
            if not chunks:
                raise FileNotFoundError(f"{path} has neither log.npz, {MCAP_FILE} nor chunks/chunk_*.npz")
            return _read_chunks(path, chunks), run_json
    if not path.is_file():
        raise FileNotFoundError(
            f"no run log at {path} (give a run directory, its log.npz or its {MCAP_FILE})"
        )
    if path.suffix == ".mcap":
        return _load_mcap(path, _read_json(path.parent / "run.json"))
    try:
        if path.stat().st_size == 0:
            raise ValueError("the file is empty")
        z = np.load(path, allow_pickle=False)
        if not hasattr(z, "files"):
            raise ValueError("a single array, not an NPZ archive")
        with z:
            arrays = {k: z[k] for k in z.files if k != "meta_json"}
            meta = (
                loads_json(str(z["meta_json"]), "meta_json", LogReadError) if "meta_json" in z.files else {}
            )
        if not isinstance(meta, dict):
            raise ValueError(f"meta_json is a JSON {type(meta).__name__}, not an object")
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise LogReadError(
            f"{path} is not a run log (NPZ written by bar-deploy): {shorten(npz_problem(path, e), 500)}"
        ) from None
    return arrays, meta


def _read_chunks(run: Path, chunks: list[Path]) -> dict[str, np.ndarray]:
    """The NPZ chunks of a run that never closed, concatenated; ``LogReadError`` when one is corrupt."""
    try:
        return _concat_chunks(chunks, None)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise LogReadError(f"run {run}: its NPZ chunks are unreadable: {shorten(e, 500)}") from None
