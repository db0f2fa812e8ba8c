"""What ``python train/ppo.py`` spends from the process start to the end of its env build.

Runs the command's start (interpreter, CLI imports and parsing, ``run``'s imports phase, the model build,
the env construction) in ``--runs`` fresh interpreters, each stopped where the run directory would be
opened, and prints:

- the median seconds (min-max) of each start-up row (``bar_policy.training.startup.breakdown``);
- when the autotune-seed thread started and finished the device backend (``local_platform``), in seconds
  from the process start: the model build waits for it;
- one more run under ``python -X importtime``: the top-level packages by import seconds, and through which
  module each came in;
- per heavy package, how many of its loaded modules had no cached bytecode (``.pyc``): those are compiled
  from source at every import (a read-only or ``--no-compile`` install);
- the training-side packages the start loaded that it should not (torch, onnx, TensorBoard, ...);
- with ``--profile``, one more run's env build (``envs.load``) under cProfile.

Examples::

    python bench/startup_probe.py                       # 7 runs of the default command (LiteReach, brax, gpu)
    python bench/startup_probe.py --runs 9 --profile -- --preset tiny
    python bench/startup_probe.py -- --no-autotune-seed   # the backend starts in the model build instead
    PYTHONPATH=/other/tree python bench/startup_probe.py    # the same for another checkout
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import os
import pstats
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from typing import Any

NOT_BEFORE_TRAINING = ("torch", "rsl_rl", "tensordict", "onnx", "onnxruntime", "tensorboardX", "tensorboard")
NOT_BEFORE_TRAINING += ("matplotlib", "mcap", "boto3")
PYC_PACKAGES = ("jax", "jaxlib", "mujoco", "trimesh", "scipy", "networkx", "flax", "optax", "brax")
PYC_PACKAGES += ("bar_policy",)


def child(train_args: list[str], profile: bool) -> None:
    """One start, stopped before the run directory; prints one JSON line (``profile``: the env build's)."""
    os.environ.setdefault("MUJOCO_GL", "disable")  # as train/ppo.py does, before MuJoCo is imported
    from bar_policy.training.startup.breakdown import process_uptime

    started_at = time.monotonic() - process_uptime()
    from bar_policy.training.cli import parse_config

    cfg = parse_config(train_args)
    from bar_policy.training import run as run_mod
    from bar_policy.training.startup import autotune as autotune_seed

    backend: dict[str, float] = {}
    platform = autotune_seed.local_platform

    def timed_platform() -> tuple[str, str, str]:
        backend["start_s"] = time.monotonic() - started_at
        try:
            return platform()
        finally:
            backend["end_s"] = time.monotonic() - started_at

    autotune_seed.local_platform = timed_platform
    timers: list[Any] = []

    class StopError(Exception):
        pass

    def stop(cfg: Any, env: Any, start: Any, is_main: bool) -> None:  # run_dir.open_run's signature
        timers.append(start.timer)
        raise StopError

    run_mod.open_run = stop
    prof = cProfile.Profile()
    if profile:  # the env build: envs.load, model build included
        from bar_policy import envs

        load = envs.load
        envs.load = lambda *args, **kwargs: prof.runcall(load, *args, **kwargs)
    with contextlib.suppress(StopError):
        run_mod.run(cfg, started_at=started_at)
    text = io.StringIO()
    if profile:
        pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(25)
    rows = {k: v for k, v in timers[0].phases.items() if v > 0}
    rows["total (process start to env built)"] = timers[0].elapsed()
    pyc: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for name, mod in list(sys.modules.items()):
        top = name.partition(".")[0]
        cached = getattr(mod, "__cached__", None)
        if top in PYC_PACKAGES and cached:
            pyc[top][0] += 1
            pyc[top][1] += not os.path.exists(cached)
    loaded = sorted(m for m in NOT_BEFORE_TRAINING if m in sys.modules)
    print(
        json.dumps(
            {"rows": rows, "backend": backend, "pyc": pyc, "loaded": loaded, "profile": text.getvalue()}
        )
    )
    sys.stdout.flush()
    os._exit(0)  # the seed thread and jax's atexit hooks are not waited for


def _spawn(train_args: list[str], importtime: bool = False, profile: bool = False) -> tuple[dict, str]:
    flags = ["-X", "importtime"] if importtime else []
    mode = "--child-profile" if profile else "--child"
    cmd = [sys.executable, *flags, __file__, mode, "--", *train_args]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if out.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed ({out.returncode}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1]), out.stderr


def packages(importtime_log: str) -> list[tuple[float, str, str]]:
    """``(seconds, package, first module <- its importer)`` per top-level package, largest first.

    A package's seconds are the cumulative times of its modules imported from outside it (so a package
    pulled in by another counts once, under its own name).
    """
    rows = []
    for line in importtime_log.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            rows.append((int(m[2]), len(m[3]) // 2, m[4]))
    totals: dict[str, float] = defaultdict(float)
    via: dict[str, tuple[int, str]] = {}
    for i, (cum_us, depth, name) in enumerate(rows):  # children come before their parent
        parent = next((r[2] for r in rows[i + 1 :] if r[1] == depth - 1), "-")
        top = name.partition(".")[0]
        if parent.partition(".")[0] != top:
            totals[top] += cum_us / 1e6
            if cum_us > via.get(top, (-1, ""))[0]:
                via[top] = (cum_us, f"{name} <- {parent}")
    return sorted(((s, k, via[k][1]) for k, s in totals.items()), reverse=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=7)
    p.add_argument("--profile", action="store_true", help="also print cProfile of one env build")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--child-profile", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("train_args", nargs="*", help="flags for train/ppo.py (after --)")
    a = p.parse_args()
    if a.child or a.child_profile:
        child(a.train_args, profile=a.child_profile)
    with tempfile.TemporaryDirectory() as tmp:
        args = ["--runs-dir", f"{tmp}/runs", "--compile-cache-dir", f"{tmp}/cache", *a.train_args]
        _spawn(args)  # fills the compile cache: every timed run is a warm start
        got = [_spawn(args)[0] for _ in range(a.runs)]
        traced, log = _spawn(args, importtime=True)
        profiled = _spawn(args, profile=True)[0] if a.profile else None
    table: dict[str, list[float]] = defaultdict(list)
    for g in got:
        backend = {f"backend {k} (seed thread)": v for k, v in g["backend"].items()}
        for k, v in {**g["rows"], **backend}.items():
            table[k].append(v)
    print(f"{a.runs} warm starts of train/ppo.py {' '.join(a.train_args)} (seconds: median, min-max)")
    for k, v in table.items():
        print(f"  {k:<55} {statistics.median(v):7.3f}  ({min(v):.3f}-{max(v):.3f})")
    print("imports by top-level package (python -X importtime, one run; cumulative s):")
    for s, k, first in packages(log)[:14]:
        print(f"  {s:6.3f}  {k:<18} via {first}")
    missing = {k: f"{n} of {m}" for k, (m, n) in traced["pyc"].items() if n}
    print(f"modules imported without cached bytecode: {missing or 'none'}")
    print(f"loaded before training and not needed by it: {traced['loaded'] or 'none'}")
    if profiled:
        print("the env build (envs.load, model build included), cProfile by cumulative time:")
        print(profiled["profile"])


if __name__ == "__main__":
    main()
