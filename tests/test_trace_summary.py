"""``bench/trace_summary.device_summary`` on a hand-made Perfetto trace: busy time, gaps, per-op tables."""

from __future__ import annotations

import gzip
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from trace_summary import device_summary, ops_tables


def _kernel(ts: float, dur: float, module: str, op: str) -> dict:
    return {
        "ph": "X",
        "pid": 7,
        "tid": 1,
        "ts": ts,
        "dur": dur,
        "name": f"k_{op}",
        "args": {"hlo_module": module, "hlo_op": op},
    }


@pytest.fixture()
def trace(tmp_path: Path) -> Path:
    """Four kernels on /device:GPU:0 (times in us, as the profiler writes them) and one host event."""
    events = [
        {"ph": "M", "name": "process_name", "pid": 7, "args": {"name": "/device:GPU:0"}},
        {"ph": "M", "name": "process_name", "pid": 1, "args": {"name": "/host:CPU"}},
        _kernel(0, 1000, "jit_update", "dot.1"),
        _kernel(500, 1000, "jit_update", "dot.1"),  # overlaps the first by 500 us
        _kernel(2000, 400, "jit_update", "fusion.3"),
        _kernel(12400, 200, "jit_rollout", "fusion.9"),  # 10 ms after the last one ends
        # two kernels a CUDA graph replays: the event names the graph as its instruction
        {**_kernel(12600, 100, "jit_rollout", "command_buffer_4"), "name": "loop_add_fusion"},
        {**_kernel(12700, 100, "jit_rollout", "command_buffer_4"), "name": "loop_add_fusion"},
        {"ph": "X", "pid": 1, "tid": 1, "ts": 0, "dur": 50000, "name": "host work", "args": {}},
    ]
    folder = tmp_path / "plugins" / "profile" / "run"
    folder.mkdir(parents=True)
    with gzip.open(folder / "perfetto_trace.json.gz", "wt") as f:
        json.dump({"traceEvents": events}, f)
    return tmp_path


def test_busy_window_and_gaps(trace: Path) -> None:
    s = device_summary(trace)
    # window: 0 to 12.8 ms; busy: [0, 1.5) + [2.0, 2.4) + [12.4, 12.8) = 1.5 + 0.4 + 0.4 = 2.3 ms
    assert s["window_ms"] == pytest.approx(12.8)
    assert s["busy_ms"] == pytest.approx(2.3)
    # gaps: 2.4 -> 12.4 ms (update to rollout) and 1.5 -> 2.0 ms (update to update), longest first
    assert s["gaps"] == [[10.0, "jit_update", "jit_rollout"], [0.5, "jit_update", "jit_update"]]
    # kernel time per module sums durations, the overlap counted twice: 1.0 + 1.0 + 0.4 = 2.4 ms
    assert s["modules"] == {"jit_update": [2.4, 3], "jit_rollout": [0.4, 3]}
    assert "ops" not in s


def test_ops_table(trace: Path) -> None:
    ops = device_summary(trace, ops=1)["ops"]
    # only the top instruction per module: dot.1 (2.0 ms in 2 kernels) over fusion.3 (0.4 ms)
    # (the rollout's tie, 0.2 ms each, goes to the first seen)
    assert ops == {"jit_update": [["dot.1", 2.0, 2]], "jit_rollout": [["fusion.9", 0.2, 1]]}
    five = device_summary(trace, ops=5)["ops"]
    assert five["jit_update"][1] == ["fusion.3", 0.4, 1]
    # a graph's kernels are told apart by their own name
    assert five["jit_rollout"][1] == ["command_buffer_4 / loop_add_fusion", 0.2, 2]


def test_ops_tables(trace: Path) -> None:
    lines = ops_tables(device_summary(trace, ops=1), "kernel")
    # one table per module; us each = 1e3 * ms / kernels: 2.0 ms / 2 -> 1000.0 us, 0.2 ms / 1 -> 200.0 us
    assert lines[:4] == [
        "",
        "| jit_update: kernel | kernel ms | kernels | us each |",
        "|---|---:|---:|---:|",
        "| dot.1 | 2.00 | 2 | 1000.0 |",
    ]
    assert lines[-1] == "| fusion.9 | 0.20 | 1 | 200.0 |"
    assert ops_tables(device_summary(trace)) == []  # no ops asked for: no tables
