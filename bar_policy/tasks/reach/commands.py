"""Reach command sources: where the reach task's command terms (the fingertip targets) come from at run time.

A source is called once per control tick with the run time ``t`` (s since the start) and returns one array
per command name (``target_pos_left``, ``target_pos_right``: shape (3,), chest frame, m). Nothing is
hard-coded in the runtime; the CLI picks a source with ``--commands``:

- ``sampled`` / ``sampled:PERIOD``: targets drawn like training's (``sample_targets`` on uniform variates),
  resampled every ``PERIOD`` s (default ``DEFAULT_RESAMPLE_PERIOD``), seeded.
- ``file:PATH``: a timed sequence, held from each entry's time to the next (zero-order hold; before the first
  entry the first is used, after the last the last is held). Formats:
  JSON ``[{"t": 0.0, "target_pos_left": [x, y, z], "target_pos_right": [x, y, z]}, ...]`` (or
  ``{"commands": [...]}``); CSV with a header ``t,<name>_x,<name>_y,<name>_z,...``; NPZ with ``t`` (K,) and
  one (K, 3) array per command name.
- ``stream:stdin`` / ``stream:udp:PORT``: JSON lines ``{"target_pos_left": [...], "target_pos_right": [...]}``
  (either key alone updates that target) from stdin, or UDP datagrams on 127.0.0.1:PORT (loopback only).
  Until the first message the targets are the ``initial`` values (the fingertips at the default pose); a bad
  line is logged and counted, and the previous targets stay.

Targets outside the training workspace are not clipped: each is counted and logged (first time per source).
Every source is a ``tasks.interfaces.CommandSource`` of task ``reach``; the run log records its targets each
tick.
"""

from __future__ import annotations

import abc
import csv
import logging
import math
import queue
import socket
import sys
import threading
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

from bar_policy._files import InputError, loads_json, shorten
from bar_policy.tasks.interfaces import CommandSource
from bar_policy.tasks.reach.shared import ReachTargetConfig, sample_targets

__all__ = [
    "COMMAND_SIZES",
    "DEFAULT_RESAMPLE_PERIOD",
    "CommandError",
    "CommandSource",
    "FileCommands",
    "ReachSource",
    "SampledCommands",
    "StreamCommands",
    "make_command_source",
]

log = logging.getLogger(__name__)

DEFAULT_RESAMPLE_PERIOD = 2.5
"""Resampling period of ``sampled`` targets, s (the env's ``ReachEnvConfig.resample_period_s``)."""

COMMAND_SIZES: dict[str, int] = {"target_pos_left": 3, "target_pos_right": 3}
"""Command terms a source can feed, with their sizes."""

_SPECS = "sampled, sampled:PERIOD, file:PATH, stream:stdin, stream:udp:PORT"


class CommandError(InputError):
    """A command source is misconfigured or its input is malformed.

    ``FileCommands`` raises only this for a malformed file (empty, truncated, not UTF-8, invalid or too
    deeply nested JSON, wrong keys, types or shapes), naming the file; echoed values are cut to
    ``_files.ECHO_LIMIT`` characters.
    """


def _check_names(names: tuple[str, ...]) -> None:
    unknown = [n for n in names if n not in COMMAND_SIZES]
    if unknown:
        raise CommandError(f"no command source can feed terms {unknown}; known: {sorted(COMMAND_SIZES)}")


def _vector(name: str, value: Any, where: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise CommandError(
            f"{where}: {name} must be a list of {COMMAND_SIZES[name]} numbers, got {shorten(repr(value))}"
        ) from None
    if v.shape != (COMMAND_SIZES[name],):
        raise CommandError(f"{where}: {name} must have {COMMAND_SIZES[name]} numbers, got shape {v.shape}")
    if not np.isfinite(v).all():
        raise CommandError(f"{where}: {name} has non-finite values {v.tolist()}")
    return v


class ReachSource(CommandSource):
    """Feeds the reach targets (a subset of ``COMMAND_SIZES``), one dict per control tick."""

    task = "reach"

    def __init__(self, names: tuple[str, ...], workspace: ReachTargetConfig | None = None) -> None:
        _check_names(tuple(names))
        self.names = tuple(names)
        self.workspace = workspace or ReachTargetConfig()
        self.outside_count = 0
        """Targets seen outside the training workspace (not clipped)."""
        self._warned_outside = False
        self._last: dict[str, np.ndarray] = {}
        lo, hi = self.workspace.low, self.workspace.high
        mirror = np.array([1.0, -1.0, 1.0])
        right = (np.minimum(lo * mirror, hi * mirror) - 1e-9, np.maximum(lo * mirror, hi * mirror) + 1e-9)
        self._boxes = {n: (lo - 1e-9, hi + 1e-9) if n == "target_pos_left" else right for n in self.names}

    @abc.abstractmethod
    def _values(self, t: float) -> dict[str, np.ndarray]:
        """The commands at run time ``t``."""

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The commands at run time ``t`` (s): one array per name, shape (3,), chest frame, m."""
        values = self._values(t)
        self._check_workspace(values)
        self._last = values
        return values

    @property
    def log_fields(self) -> dict[str, tuple[tuple[int, ...], type]]:
        """Every target, each tick: name -> ((3,), float64)."""
        return {n: ((COMMAND_SIZES[n],), np.float64) for n in self.names}

    def record(self) -> dict[str, np.ndarray]:
        """The targets of the last call."""
        return dict(self._last)

    def _check_workspace(self, values: Mapping[str, np.ndarray]) -> None:
        for name, v in values.items():
            lo, hi = self._boxes[name]
            if (v < lo).any() or (v > hi).any():
                self.outside_count += 1
                if not self._warned_outside:
                    self._warned_outside = True
                    log.warning(
                        "%s %s is outside the training workspace [%s, %s]; used as is (further ones counted)",
                        name,
                        np.round(v, 4).tolist(),
                        np.round(lo, 3).tolist(),
                        np.round(hi, 3).tolist(),
                    )


class SampledCommands(ReachSource):
    """Targets drawn like training's, resampled every ``period`` s, from a seeded generator."""

    def __init__(
        self,
        names: tuple[str, ...],
        *,
        seed: int = 0,
        period: float = DEFAULT_RESAMPLE_PERIOD,
        workspace: ReachTargetConfig | None = None,
    ) -> None:
        super().__init__(names, workspace)
        if not (math.isfinite(period) and period > 0):
            raise CommandError(f"resample period must be > 0 s, got {period}")
        self.seed = seed
        self.period = period
        self._rng = np.random.default_rng(seed)
        self._index = -1
        self._current: dict[str, np.ndarray] = {}

    def _values(self, t: float) -> dict[str, np.ndarray]:
        k = max(math.floor(t / self.period + 1e-9), 0)
        while self._index < k:  # draw every period in order, so the sequence depends on the seed only
            left, right = sample_targets(self._rng.random(6), self.workspace)
            self._current = {"target_pos_left": left, "target_pos_right": right}
            self._index += 1
        return {n: self._current[n].copy() for n in self.names}

    def describe(self) -> str:
        """One line for logs."""
        return f"sampled(seed={self.seed}, period={self.period:g} s)"


class FileCommands(ReachSource):
    """A timed sequence from a JSON, CSV or NPZ file (zero-order hold)."""

    def __init__(
        self, names: tuple[str, ...], path: str | Path, workspace: ReachTargetConfig | None = None
    ) -> None:
        super().__init__(names, workspace)
        self.path = Path(path)
        if not self.path.is_file():
            raise CommandError(f"command file {str(self.path)!r} does not exist")
        suffix = self.path.suffix.lower()
        readers = {".json": self._read_json, ".csv": self._read_csv, ".npz": self._read_npz}
        if suffix not in readers:
            raise CommandError(
                f"command file {str(self.path)!r}: unsupported type {suffix!r}; use {sorted(readers)}"
            )
        t, values = readers[suffix]()
        if t.ndim != 1 or t.size == 0:
            raise CommandError(f"command file {str(self.path)!r} has no entries")
        if not np.isfinite(t).all() or np.any(np.diff(t) <= 0):
            raise CommandError(
                f"command file {str(self.path)!r}: times must be finite and strictly increasing"
            )
        self.t = t
        self.values = values

    def _where(self, k: int | str) -> str:
        return f"command file {str(self.path)!r} entry {k}"

    def _read_json(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        try:
            text = self.path.read_bytes()
        except OSError as e:
            raise CommandError(f"command file {str(self.path)!r} cannot be read: {e.strerror or e}") from None
        data = loads_json(text, f"command file {str(self.path)!r}", CommandError)
        if isinstance(data, dict):
            data = data.get("commands")
        if not isinstance(data, list):
            raise CommandError(
                f"command file {str(self.path)!r}: expected a list of entries (or {{'commands': [...]}})"
            )
        t = []
        cols: dict[str, list[np.ndarray]] = {n: [] for n in self.names}
        for k, entry in enumerate(data):
            if not isinstance(entry, dict) or "t" not in entry:
                raise CommandError(f"{self._where(k)}: must be an object with 't' and {list(self.names)}")
            missing = [n for n in self.names if n not in entry]
            if missing:
                raise CommandError(f"{self._where(k)}: missing {missing}")
            try:
                t.append(float(entry["t"]))
            except (TypeError, ValueError, OverflowError):
                raise CommandError(
                    f"{self._where(k)}: t must be a number, got {shorten(repr(entry['t']))}"
                ) from None
            for n in self.names:
                cols[n].append(_vector(n, entry[n], self._where(k)))
        return np.array(t), {n: np.array(v).reshape(-1, COMMAND_SIZES[n]) for n, v in cols.items()}

    def _read_csv(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        try:
            with self.path.open(newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as e:
            raise CommandError(
                f"command file {str(self.path)!r} is not a readable CSV: {shorten(e)}"
            ) from None
        if not rows:
            raise CommandError(f"command file {str(self.path)!r} has no rows")
        want = ["t"] + [f"{n}_{a}" for n in self.names for a in "xyz"]
        missing = [c for c in want if c not in rows[0]]
        if missing:
            raise CommandError(
                f"command file {str(self.path)!r}: missing columns {missing}; header needs {want}"
            )
        t = []
        cols: dict[str, list[np.ndarray]] = {n: [] for n in self.names}
        for k, row in enumerate(rows):
            try:
                t.append(float(row["t"]))
                for n in self.names:
                    cols[n].append(_vector(n, [float(row[f"{n}_{a}"]) for a in "xyz"], self._where(k)))
            except (TypeError, ValueError) as e:
                if isinstance(e, CommandError):
                    raise
                raise CommandError(f"{self._where(k)}: not a number ({shorten(e)})") from None
        return np.array(t), {n: np.array(v) for n, v in cols.items()}

    def _read_npz(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        if self.path.stat().st_size == 0:
            raise CommandError(f"command file {str(self.path)!r} is not a readable NPZ: the file is empty")
        try:
            with np.load(self.path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError, AttributeError) as e:
            # AttributeError: a bare .npy array (no ``files``); the rest: empty, truncated or corrupt archives
            raise CommandError(
                f"command file {str(self.path)!r} is not a readable NPZ: {shorten(e)}"
            ) from None
        missing = [k for k in ("t", *self.names) if k not in arrays]
        if missing:
            raise CommandError(
                f"command file {str(self.path)!r}: missing arrays {missing}; has {shorten(sorted(arrays))}"
            )
        for k in ("t", *self.names):
            if arrays[k].dtype.kind not in "fiu":  # complex, bool or text: not times or targets
                raise CommandError(
                    f"command file {str(self.path)!r}: {k} must hold real numbers, got dtype "
                    f"{arrays[k].dtype}"
                )
        try:
            t = np.asarray(arrays["t"], dtype=np.float64).reshape(-1)
            raw = {n: np.asarray(arrays[n], dtype=np.float64) for n in self.names}
        except (TypeError, ValueError, OverflowError) as e:
            raise CommandError(
                f"command file {str(self.path)!r}: arrays must be numbers ({shorten(e)})"
            ) from None
        values = {}
        for n in self.names:
            v = raw[n]
            if v.shape != (t.size, COMMAND_SIZES[n]):
                raise CommandError(
                    f"command file {str(self.path)!r}: {n} has shape {v.shape}, expected ({t.size}, 3)"
                )
            if not np.isfinite(v).all():
                raise CommandError(f"command file {str(self.path)!r}: {n} has non-finite values")
            values[n] = v
        return t, values

    def _values(self, t: float) -> dict[str, np.ndarray]:
        k = max(int(np.searchsorted(self.t, t + 1e-9, side="right")) - 1, 0)
        return {n: self.values[n][k].copy() for n in self.names}

    def describe(self) -> str:
        """One line for logs."""
        return f"file({self.path}, {self.t.size} entries, {self.t[0]:g}..{self.t[-1]:g} s)"


class StreamCommands(ReachSource):
    """Live targets from JSON lines on stdin or UDP datagrams on 127.0.0.1 (a background reader thread)."""

    def __init__(
        self,
        names: tuple[str, ...],
        initial: Mapping[str, np.ndarray],
        *,
        stdin: IO[str] | None = None,
        udp_port: int | None = None,
        workspace: ReachTargetConfig | None = None,
    ) -> None:
        super().__init__(names, workspace)
        if (stdin is None) == (udp_port is None):
            raise CommandError("a stream source reads either stdin or a UDP port")
        self._current = {n: _vector(n, initial[n], "initial command") for n in self.names}
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.bad_messages = 0
        """Messages rejected (malformed JSON, wrong keys or sizes, non-finite)."""
        self.messages = 0
        """Messages accepted."""
        self._stop = threading.Event()
        self._sock: socket.socket | None = None
        if udp_port is not None:
            if not 0 <= udp_port < 65536:
                raise CommandError(f"UDP port must be in 0..65535 (0: any free port), got {udp_port}")
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind(("127.0.0.1", udp_port))  # loopback only, never another address
            except OSError as e:
                sock.close()
                raise CommandError(f"cannot bind UDP 127.0.0.1:{udp_port}: {e.strerror or e}") from None
            sock.settimeout(0.1)
            self._sock = sock
            self.port = sock.getsockname()[1]
            target = self._read_udp
        else:
            self._stdin = stdin
            target = self._read_stdin
        self._thread = threading.Thread(target=target, name="bar-deploy-commands", daemon=True)
        self._thread.start()

    def _read_stdin(self) -> None:
        assert self._stdin is not None
        for line in self._stdin:
            if self._stop.is_set():
                break
            if line.strip():
                self._queue.put(line)

    def _read_udp(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            for line in data.decode("utf-8", errors="replace").splitlines():
                if line.strip():
                    self._queue.put(line)

    def _apply(self, line: str) -> None:
        try:
            msg = loads_json(line, "message", CommandError)
            if not isinstance(msg, dict):
                raise CommandError(f"expected a JSON object, got {type(msg).__name__}")
            unknown = sorted(set(msg) - set(self.names) - {"t"})
            known = [n for n in self.names if n in msg]
            if unknown or not known:
                raise CommandError(f"keys must be among {list(self.names)}; got {shorten(sorted(msg))}")
            update = {n: _vector(n, msg[n], "stream message") for n in known}
        except CommandError as e:
            self.bad_messages += 1
            log.warning(
                "ignored command message %r: %s (%d bad so far)", line.strip()[:200], e, self.bad_messages
            )
            return
        self._current.update(update)
        self.messages += 1

    def _values(self, t: float) -> dict[str, np.ndarray]:
        while True:
            try:
                line = self._queue.get_nowait()
            except queue.Empty:
                break
            self._apply(line)
        return {n: v.copy() for n, v in self._current.items()}

    def describe(self) -> str:
        """One line for logs."""
        return f"stream(udp 127.0.0.1:{self.port})" if self._sock else "stream(stdin)"

    def close(self) -> None:
        """Stop the reader thread and close the socket."""
        self._stop.set()
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def make_command_source(
    spec: str,
    names: tuple[str, ...],
    *,
    seed: int = 0,
    initial: Mapping[str, np.ndarray] | None = None,
    workspace: ReachTargetConfig | None = None,
) -> ReachSource:
    """Build a source from a CLI spec.

    Specs: ``sampled[:PERIOD]``, ``file:PATH``, ``stream:stdin``, ``stream:udp:PORT``.

    Args:
        spec: the spec string.
        names: command term names of the policy's layout.
        seed: seed of ``sampled``.
        initial: targets before the first stream message (required for ``stream``).
        workspace: training target workspace (for ``sampled`` and the outside-workspace count).

    Raises:
        CommandError: naming the valid specs.
    """
    kind, _, rest = spec.partition(":")
    if kind == "sampled":
        if not rest:
            return SampledCommands(names, seed=seed, workspace=workspace)
        try:
            period = float(rest)
        except ValueError:
            raise CommandError(f"sampled:PERIOD needs a period in s, got {rest!r}") from None
        return SampledCommands(names, seed=seed, period=period, workspace=workspace)
    if kind == "file" and rest:
        return FileCommands(names, rest, workspace=workspace)
    if kind == "stream" and rest:
        if initial is None:
            raise CommandError("stream commands need initial targets")
        if rest == "stdin":
            return StreamCommands(names, initial, stdin=sys.stdin, workspace=workspace)
        sub, _, port = rest.partition(":")
        if sub == "udp":
            try:
                p = int(port)
            except ValueError:
                raise CommandError(f"stream:udp:PORT needs an integer port, got {port!r}") from None
            return StreamCommands(names, initial, udp_port=p, workspace=workspace)
    raise CommandError(f"unknown command source {spec!r}; valid: {_SPECS}")
