"""``file:PATH``: reach targets from a timed JSON, CSV or NPZ file (zero-order hold; ``commands.py``)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from bar_policy._files import NPZ_LOAD_ERRORS, loads_json, npz_problem, shorten
from bar_policy.tasks.reach.shared import ReachTargetConfig
from bar_policy.tasks.reach.sources import COMMAND_SIZES, CommandError, ReachSource, _vector

__all__ = ["FileCommands"]


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
        except NPZ_LOAD_ERRORS as e:
            raise CommandError(
                f"command file {str(self.path)!r} is not a readable NPZ: {npz_problem(self.path, e)}"
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
