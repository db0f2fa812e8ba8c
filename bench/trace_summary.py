"""Where a profiled stretch of a process spent its time: the top events of a ``jax.profiler`` trace.

``profiled(log_dir)`` wraps a stretch in ``jax.profiler.trace(..., create_perfetto_trace=True)``;
``top_events(log_dir)`` reads the Perfetto JSON it wrote and sums each event name's duration (inclusive
of nested events, over every thread), largest first. XLA names its compile passes, the GPU compiler's
stages and a load's steps in such events, so a compile or a load gets a breakdown without TensorBoard.
Used by ``train_breakdown.py`` and ``update_scaling.py`` (``--profile``).
"""

from __future__ import annotations

import contextlib
import gzip
import json
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def profiled(log_dir: str | Path, python: bool = True) -> Iterator[None]:
    """The stretch inside, traced by ``jax.profiler`` into ``log_dir`` (with a Perfetto JSON).

    ``python=False`` leaves Python frames out (a device trace of many kernels otherwise hits the
    profiler's event cap, about a million).
    """
    import jax

    opts = jax.profiler.ProfileOptions()
    opts.python_tracer_level = 1 if python else 0
    with jax.profiler.trace(str(log_dir), create_perfetto_trace=True, profiler_options=opts):
        yield


def _trace_events(log_dir: str | Path) -> list[dict[str, Any]]:
    """The events of the last Perfetto JSON ``profiled`` wrote under ``log_dir`` ([] when there is none)."""
    files = sorted(Path(log_dir).rglob("perfetto_trace.json.gz"))
    if not files:
        return []
    with gzip.open(files[-1], "rt") as f:
        return json.load(f).get("traceEvents", [])


def top_events(log_dir: str | Path, n: int = 40) -> list[dict[str, Any]]:
    """``[{"name", "ms", "count", "threads"}]``: the ``n`` event names with the most summed duration.

    ``ms`` sums complete events (``ph == "X"``) of that name over all threads, nested ones included, so a
    parent and its children both appear; ``threads`` is how many threads had one. Python frames (the
    tracer's ``$file:line function`` events) are left out: the C++ events are what this is for. Empty
    when no trace.
    """
    events = _trace_events(log_dir)
    total: dict[str, float] = defaultdict(float)
    count: dict[str, int] = defaultdict(int)
    threads: dict[str, set] = defaultdict(set)
    for e in events:
        if e.get("ph") != "X" or "dur" not in e or str(e.get("name", "")).startswith("$"):
            continue
        name = str(e.get("name", "?"))[:90]
        total[name] += float(e["dur"]) / 1e3
        count[name] += 1
        threads[name].add((e.get("pid"), e.get("tid")))
    names = sorted(total, key=total.__getitem__, reverse=True)[:n]
    return [
        {"name": k, "ms": round(total[k], 1), "count": count[k], "threads": len(threads[k])} for k in names
    ]


def _op(e: dict) -> str:
    """The instruction a kernel event comes from: its ``hlo_op``, and for a kernel a command buffer (CUDA
    graph) replays, whose ``hlo_op`` names only the buffer, ``command_buffer_N / <kernel name>``."""
    op, name = str(e.get("args", {}).get("hlo_op") or ""), str(e.get("name", "?"))
    if not op:
        return name[:60]
    return f"{op} / {name[:60]}" if op.startswith("command_buffer") else op[:60]


def device_summary(log_dir: str | Path, gaps: int = 12, ops: int = 0) -> dict[str, Any]:
    """What the GPU did in a trace: kernel time per XLA module, busy and idle time, the longest idle gaps.

    Device events are those of processes whose name holds ``GPU`` (the profiler's ``/device:GPU:0``).
    ``modules``: ``{hlo_module: [ms, count]}``; ``window_ms``: first kernel start to last kernel end;
    ``busy_ms``: the union of kernel intervals (streams overlapping counted once); ``gaps``: the longest
    idle stretches as ``[ms, module before, module after]``. With ``ops`` > 0 also ``ops``:
    ``{hlo_module: [[op, ms, count], ...]}``, each module's ``ops`` instructions with the most kernel time
    (``_op``: inside a CUDA graph, the kernel's own name): which of a program's instructions its kernels
    come from, and how long each runs on average (``ms / count``). Empty dict when no trace or no device
    events.
    """
    events = _trace_events(log_dir)
    if not events:
        return {}
    names = {
        e.get("pid"): str(e.get("args", {}).get("name", ""))
        for e in events
        if e.get("ph") == "M" and e.get("name") == "process_name"
    }
    dev = [e for e in events if e.get("ph") == "X" and "dur" in e and "GPU" in names.get(e.get("pid"), "")]
    if not dev:
        return {"process_names": sorted(set(names.values()))[:20]}
    modules: dict[str, list[float]] = defaultdict(lambda: [0.0, 0])

    def module(e: dict) -> str:
        a = e.get("args", {})
        return str(a.get("hlo_module") or a.get("hlo_module_name") or a.get("module") or "?")[:60]

    per_op: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(lambda: [0.0, 0]))
    for e in dev:
        mod, ms = module(e), float(e["dur"]) / 1e3
        for row in (modules[mod], per_op[mod][_op(e)]):
            row[0] += ms
            row[1] += 1
    dev.sort(key=lambda e: float(e["ts"]))
    busy, found = 0.0, []
    end, last = float(dev[0]["ts"]), dev[0]
    for e in dev:
        ts, te = float(e["ts"]), float(e["ts"]) + float(e["dur"])
        if ts > end:
            found.append([round((ts - end) / 1e3, 2), module(last), module(e)])
        busy += max(0.0, te - max(ts, end))
        if te > end:
            end, last = te, e
    window = (end - float(dev[0]["ts"])) / 1e3
    out = {
        "modules": {k: [round(v[0], 1), v[1]] for k, v in sorted(modules.items(), key=lambda kv: -kv[1][0])},
        "window_ms": round(window, 1),
        "busy_ms": round(busy / 1e3, 1),
        "gaps": sorted(found, reverse=True)[:gaps],
        "arg_keys": sorted(dev[0].get("args", {}))[:12],
    }
    if ops > 0:
        out["ops"] = {
            mod: [[k, round(v[0], 3), v[1]] for k, v in sorted(table.items(), key=lambda kv: -kv[1][0])[:ops]]
            for mod, table in per_op.items()
        }
    return out


def ops_tables(summary: dict[str, Any], what: str = "instruction") -> list[str]:
    """``device_summary``'s ``ops`` as one Markdown table per module (``what`` heads the first column): each
    instruction's kernel time, kernel count and time per kernel. No lines when it has no ``ops``."""
    lines: list[str] = []
    for mod, table in summary.get("ops", {}).items():
        lines += ["", f"| {mod}: {what} | kernel ms | kernels | us each |", "|---|---:|---:|---:|"]
        lines += [f"| {op} | {ms:,.2f} | {n} | {1e3 * ms / n:.1f} |" for op, ms, n in table]
    return lines
