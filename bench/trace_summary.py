"""Where a profiled stretch of a process spent its time: the top events of a ``jax.profiler`` trace.

``profiled(log_dir)`` wraps a stretch in ``jax.profiler.trace(..., create_perfetto_trace=True)``;
``top_events(log_dir)`` reads the Perfetto JSON it wrote and sums each event name's duration (inclusive
of nested events, over every thread), largest first. XLA names its compile passes, the GPU compiler's
stages and a load's steps in such events, so a compile or a load gets a breakdown without TensorBoard.
Used by ``program_split.py --profile``.
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
def profiled(log_dir: str | Path) -> Iterator[None]:
    """The stretch inside, traced by ``jax.profiler`` into ``log_dir`` (with a Perfetto JSON)."""
    import jax

    with jax.profiler.trace(str(log_dir), create_perfetto_trace=True):
        yield


def top_events(log_dir: str | Path, n: int = 40) -> list[dict[str, Any]]:
    """``[{"name", "ms", "count", "threads"}]``: the ``n`` event names with the most summed duration.

    ``ms`` sums complete events (``ph == "X"``) of that name over all threads, nested ones included, so a
    parent and its children both appear; ``threads`` is how many threads had one. Python frames (the
    tracer's ``$file:line function`` events) are left out: the C++ events are what this is for. Empty
    when no trace.
    """
    files = sorted(Path(log_dir).rglob("perfetto_trace.json.gz"))
    if not files:
        return []
    with gzip.open(files[-1], "rt") as f:
        events = json.load(f).get("traceEvents", [])
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
