"""A full or read-only log disk: the run still stops, run.json says why logging stopped, what was written
before stays readable, and closing the log raises nothing.

The failures are injected, not made by filling a real disk: ``FakeDisk`` wraps every file opened for
writing under the test's directory through ``Path.open`` (how the run log opens its files). Once ``full``,
a write that needs new space raises ``OSError(ENOSPC)`` (overwriting a file's existing bytes does not, as on
a real file system); once ``read_only``, creating a file raises ``PermissionError(EACCES)`` (what a
directory without write permission gives; the files already open or existing stay writable).
"""

from __future__ import annotations

import errno
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from fault_targets import SteppedMock

from bar_policy.deploy.log.files import log_fields
from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.log.run_log import RUN_JSON_RESERVE, RunLog
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands

_REAL_OPEN = Path.open


class _Guarded:
    """A file opened for writing: its writes go through the ``FakeDisk`` rules."""

    def __init__(self, f, disk: FakeDisk) -> None:
        self._f = f
        self._disk = disk
        self._size = os.fstat(f.fileno()).st_size  # bytes it holds on disk: overwriting them needs no space

    def write(self, data) -> int:
        end = self._f.tell() + len(data)
        if self._disk.full and end > self._size:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = self._f.write(data)
        self._size = max(self._size, end)
        return n

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._f.close()

    def __getattr__(self, name):
        return getattr(self._f, name)


class FakeDisk:
    def __init__(self, root: Path) -> None:
        self.root = root
        self.full = False
        self.read_only = False

    def open(self, path: Path, mode: str = "r", *args, **kwargs):
        mine = self.root in Path(path).parents
        creates = any(c in mode for c in "wxa") and not Path(path).exists()
        if mine and self.read_only and creates:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        f = _REAL_OPEN(path, mode, *args, **kwargs)
        if mine and any(c in mode for c in "wxa+"):
            return _Guarded(f, self)
        return f


@pytest.fixture
def disk(tmp_path, monkeypatch) -> FakeDisk:
    d = FakeDisk(tmp_path)
    monkeypatch.setattr(Path, "open", lambda self, *a, **k: d.open(self, *a, **k))
    return d


def _wait(cond, timeout: float = 60.0, log: RunLog | None = None) -> None:
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout:
            state = "" if log is None else f"{log.durable_ticks=}, {log._spilled=}, {sorted(log._held)=}"
            raise AssertionError(f"the log's writer thread did not catch up: {state}")
        time.sleep(0.005)


def _fill(log: RunLog, ticks: range) -> None:
    for k in ticks:
        log.append({"t": k * 0.02, "q": [float(k)]})


def _settle(log: RunLog) -> None:
    """Every tick so far written to run.mcap and flushed to disk after that, every spill written."""
    _wait(lambda: log.durable_ticks == log.ticks, log=log)
    _wait(lambda: len(log._spilled) == log.ticks // log.chunk_ticks, log=log)


def test_full_disk_mid_run(disk, tmp_path):
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {"x": 1}, chunk_ticks=100, flush_interval=0.02)
    _fill(log, range(300))  # chunks 0..2 spilled, run.mcap flushed
    _settle(log)
    disk.full = True
    _fill(log, range(300, 440))  # chunk 3 (300..399) cannot be spilled: held in memory
    out = log.close(end_reason="duration reached")  # raises nothing
    assert not out.exists() and not (log.path / "log.npz.partial").exists()
    record = json.loads((log.path / "run.json").read_text())
    assert record["status"] == "closed" and record["end_reason"] == "duration reached"
    assert record["ticks"] == 440 and record["log_npz"] == "not written"
    why = record["log_incomplete"]
    assert why.startswith("logging failed (") and "No space left on device" in why and "no log.npz" in why
    assert log.incomplete == why
    # What was written before the disk filled: the MCAP's closed chunks, ticks 0..299 exactly.
    arrays, meta = load_log(log.path)
    assert arrays["q"][:, 0].tolist() == list(range(300))
    assert meta["status"] == "closed" and meta["recovered_from"] == MCAP_FILE and meta["x"] == 1
    # The spill chunks written before stay too (removed only once log.npz is on disk).
    assert sorted(p.name for p in (log.path / "chunks").iterdir()) == [
        "chunk_000000.npz",
        "chunk_000001.npz",
        "chunk_000002.npz",
    ]


def test_full_disk_then_space_again_keeps_every_tick(disk, tmp_path):
    """Spills that failed are held in memory: if log.npz can be written at close, it has every tick."""
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {}, chunk_ticks=100, flush_interval=0.02)
    _fill(log, range(200))
    _settle(log)
    disk.full = True
    _fill(log, range(200, 450))  # chunks 2, 3 fail
    _wait(lambda: log._written == 450 and len(log._held) == 2, log=log)
    disk.full = False
    log.close(end_reason="duration reached")
    arrays, meta = load_log(log.path / "log.npz")
    assert arrays["q"][:, 0].tolist() == list(range(450))  # 0..199 read back, 200..399 held, 400..449 last
    assert meta["log_ticks_dropped"] == 0 and meta["log_write_error_count"] >= 2
    assert meta["log_incomplete"].startswith("logging failed (") and "No space left" in meta["log_incomplete"]
    assert any(e.startswith("spill chunk_000002.npz: OSError") for e in meta["log_write_errors"])
    assert json.loads((log.path / "run.json").read_text())["log_incomplete"] == meta["log_incomplete"]


def test_read_only_directory_mid_run(disk, tmp_path):
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {}, chunk_ticks=100, flush_interval=0.02)
    _fill(log, range(150))
    _settle(log)
    disk.read_only = True  # no new file: the spill, log.npz.partial, run.json.partial are refused
    _fill(log, range(150, 260))
    log.close(end_reason="SIGINT received")
    record = json.loads((log.path / "run.json").read_text())  # rewritten in place
    assert record["status"] == "closed" and record["end_reason"] == "SIGINT received"
    assert "Permission denied" in record["log_incomplete"] and "no log.npz" in record["log_incomplete"]
    # run.mcap was open before: it is complete, every tick in it.
    rec = read_mcap_log(log.path / MCAP_FILE)
    assert rec.complete and rec.arrays["q"][:, 0].tolist() == list(range(260))
    arrays, meta = load_log(log.path)
    assert arrays["q"][:, 0].tolist() == list(range(260)) and meta["status"] == "closed"


def test_unreadable_spill_is_dropped_and_counted(tmp_path):
    """The case that raised EOFError at close: a spill chunk left empty by the disk. Dropped and counted."""
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {}, chunk_ticks=100, flush_interval=0.02)
    _fill(log, range(250))
    _wait(lambda: len(log._spilled) == 2)
    (log.path / "chunks" / "chunk_000001.npz").write_bytes(b"")  # ticks 100..199 lost under the log
    log.close(end_reason="duration reached")
    arrays, meta = load_log(log.path / "log.npz")
    assert arrays["q"][:, 0].tolist() == [*range(100), *range(200, 250)]
    assert meta["log_ticks_dropped"] == 100
    assert meta["log_incomplete"].startswith("logging failed (read back chunk_000001.npz: EOFError")
    assert "100 of 250 ticks dropped" in meta["log_incomplete"]


def test_run_json_past_its_reserve_keeps_the_essentials(disk, tmp_path):
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {}, flush_interval=0.02)
    assert (log.path / "run.json").stat().st_size == RUN_JSON_RESERVE
    _fill(log, range(10))
    _settle(log)
    disk.full = True
    log.close(end_reason="duration reached", transitions=[{"reason": "x" * 100}] * 1000)  # ~110 kB of JSON
    record = json.loads((log.path / "run.json").read_text())
    assert (
        record["status"] == "closed" and record["end_reason"] == "duration reached" and record["ticks"] == 10
    )
    assert "No space left on device" in record["log_incomplete"] and "65536 B reserved" in record["cut"]


def test_the_run_still_stops_on_a_full_disk(disk, tmp_path, zero_policy):
    """A run whose disk fills at tick 10 ends as asked, safe stop and all, and says what was lost."""
    target = SteppedMock()

    def fill_at_10(k, t, rt) -> None:
        if k == 10:
            _settle(rt._runlog)  # ticks 0..9 on disk first
            disk.full = True

    cfg = RuntimeConfig(duration=1.0, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    cmds = SampledCommands(zero_policy.obs_manager.command_names, seed=0)
    rt = Runtime(zero_policy, target, cmds, cfg, log_dir=tmp_path / "runs", on_tick=fill_at_10)
    res = rt.run()
    assert res.end_reason.startswith("duration reached") and res.fault_count == 0
    assert "stop" in res.safe_stop
    (run,) = (tmp_path / "runs").iterdir()
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "closed" and "No space left on device" in record["log_incomplete"]
    arrays, _ = load_log(run)
    assert arrays["t"].shape[0] >= 10  # ticks 0..9 at least, from run.mcap
    # t = k * 0.02 s from the stepped clock (one product, exact to 1 ulp): 1e-9 s is ample
    np.testing.assert_allclose(arrays["t"][:10], np.arange(10) * 0.02, atol=1e-9)
