"""File helpers shared by the exporter, the checkpoint writer and the caches; the error type of bad input."""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import tempfile
import zipfile
import zlib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

PACKAGE_ROOT = Path(__file__).resolve().parent
"""The ``bar_policy/`` directory (what ``package_hash`` reads)."""


@functools.cache
def package_hash() -> str:
    """SHA-256 of every file under ``bar_policy/`` (paths and contents; ``__pycache__`` left out).

    The content the caches key on (``training.startup.executable_key``, ``_array_cache``): any edit to the
    package's code, model files or shipped data changes it. Computed once per process (8 ms here).
    """
    h = hashlib.sha256()
    for p in sorted(PACKAGE_ROOT.rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc":
            h.update(p.relative_to(PACKAGE_ROOT).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and ``os.replace``.

    Readers never see half a file, and a failure leaves no partial file behind.
    """
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def fsync_dir(path: Path) -> None:
    """Make a directory's new or renamed entries durable (a no-op where a directory cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# ---------------------------------------------------------------------------------------------------
# Malformed input: one error type, short messages, bounded JSON
# ---------------------------------------------------------------------------------------------------
ECHO_LIMIT = 200
"""Characters of an input value that an error message echoes (``shorten``)."""

MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays / objects that ``loads_json`` accepts (project files nest a few levels)."""


class InputError(ValueError):
    """Malformed input: a file or a message that a loader cannot read.

    Policy metadata, motion clips, commands files, calibration files, run logs, CAN frames: every loader
    raises this type (through its own subclass: ``MetadataError``, ``PolicyLoadError``, ``ClipError``,
    ``CommandError``, ...) for any malformed input, and nothing else; the CLIs print it as one line and
    exit with status 2.
    """


def shorten(value: object, limit: int = ECHO_LIMIT) -> str:
    """``str(value)`` cut to ``limit`` characters plus ``... (N chars)`` when longer (for error messages)."""
    text = value if isinstance(value, str) else str(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} chars)"


NPZ_LOAD_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    ValueError,
    EOFError,
    zipfile.BadZipFile,
    zlib.error,
    KeyError,
    AttributeError,
    TypeError,
)
"""What ``np.load(path, allow_pickle=False)`` and reading its members raise for a file that is not a usable
NPZ: AttributeError / TypeError for a bare ``.npy`` array (no ``files``, no context manager); the others for
an empty, truncated or corrupt archive. Catch these and report them with :func:`npz_problem`."""


def npz_problem(path: str | Path, error: BaseException) -> str:
    """What is wrong with a file that ``np.load(path, allow_pickle=False)`` refused, for a user.

    numpy reads any file that is neither a zip archive nor a ``.npy`` array as a pickle and, with pickles
    refused, says "contains pickled (object) data ... load it unsafely": for a corrupt or random file that
    is misleading advice. A file without the zip header is named as such (with its first bytes); any other
    failure keeps numpy's or zipfile's own words.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(6)
    except OSError as e:
        return f"cannot read it: {e.strerror or e}"
    if head.startswith(b"\x93NUMPY"):
        return "a single .npy array, not an NPZ archive of named arrays"
    if not head.startswith(b"PK"):
        shown = head[:4].hex(" ") or "nothing"
        return f"not an NPZ archive: it does not start with a zip header (50 4b), but with {shown}"
    return shorten(error)


def json_depth(value: object) -> int:
    """Nesting depth of a parsed JSON value (a scalar is 0, ``[]`` 1), without recursion."""
    deepest = 0
    stack: list[tuple[object, int]] = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children: Iterable[object] = item.values()
        elif isinstance(item, list | tuple):
            children = item
        else:
            continue
        depth += 1
        deepest = max(deepest, depth)
        stack.extend((c, depth) for c in children)
    return deepest


def loads_json(
    text: str | bytes,
    what: str,
    error: type[InputError] = InputError,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """``json.loads(text)``, raising ``error`` (naming ``what``) for any malformed text.

    Refused: invalid JSON, text that is not UTF-8, and nesting deeper than ``max_depth`` (which would
    otherwise end in a ``RecursionError`` here or in whatever walks the value later).
    """
    try:
        value = json.loads(text)
    except RecursionError:
        raise error(f"{what} is nested too deeply (more than {max_depth} levels)") from None
    except (ValueError, TypeError) as e:  # JSONDecodeError, UnicodeDecodeError, huge integers
        raise error(f"{what} is not valid JSON: {shorten(e)}") from None
    if json_depth(value) > max_depth:
        raise error(f"{what} is nested too deeply (more than {max_depth} levels)")
    return value


def finite_json(value: object) -> Any:
    """``value`` made valid for ``json.dumps(..., allow_nan=False)``: every NaN or infinity becomes None.

    Walks mappings (keys made strings), lists and tuples; numpy scalars and arrays become Python numbers
    and lists first (``tolist``). Anything else is returned as is (``default=str`` writes it).
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, Mapping):
        return {str(k): finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(v) for v in value]
    tolist = getattr(value, "tolist", None)
    if callable(tolist):  # numpy scalar or array
        return finite_json(tolist())
    return value


def strict_json(value: object, **kwargs: Any) -> str:
    """``value`` as strict JSON: NaN and infinities become ``null`` (``finite_json``), never ``NaN``.

    ``allow_nan=False`` makes any non-finite float that slipped through an error instead of invalid JSON;
    ``default=str`` writes what JSON has no type for. ``kwargs`` go to ``json.dumps`` (``indent``, ...).
    """
    return json.dumps(finite_json(value), default=str, allow_nan=False, **kwargs)
