"""Seconds to build LiteTrack and its evaluation env, array cache off vs warm (fresh interpreters).

Each run is a fresh ``python`` that imports ``bar_policy.envs`` and then times ``envs.load("LiteTrack")``
(the model build, the 64 training clips, the reference table) and ``env.evaluation_env()`` (the held-out
clips). ``off`` runs with ``BAR_POLICY_ARRAY_CACHE=0``; ``warm`` runs on a cache directory of its own that
one untimed run filled first. Prints the median (min-max) of each.

Examples::

    python bench/track_env_build.py --runs 7
    PYTHONPATH=/other/tree python bench/track_env_build.py --runs 7   # the same for another checkout
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

CHILD = """
import json, os, time
os.environ.setdefault("MUJOCO_GL", "disable")
from bar_policy import envs
t0 = time.perf_counter()
env = envs.load("LiteTrack")
t1 = time.perf_counter()
env.evaluation_env()
t2 = time.perf_counter()
print(envs.__file__)
print(json.dumps({"env": t1 - t0, "evaluation env": t2 - t1, "both": t2 - t0}))
"""


def _run(extra_env: dict[str, str], cwd: str) -> tuple[dict[str, float], str]:
    """One fresh interpreter in ``cwd`` (so ``PYTHONPATH`` picks the checkout): times, ``envs``'s file."""
    env = {**os.environ, "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu"), **extra_env}
    cmd = [sys.executable, "-c", CHILD]
    out = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, check=True)
    *_, where, times = out.stdout.strip().splitlines()
    return json.loads(times), where


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=7)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        cwd = cache  # an empty directory: no bar_policy/ beside the interpreter's start
        modes = {
            "off": {"BAR_POLICY_ARRAY_CACHE": "0"},
            "warm": {"BAR_POLICY_ARRAY_CACHE": "1", "BAR_POLICY_CACHE_DIR": cache},
        }
        where = _run(modes["warm"], cwd)[1]  # fills the cache
        print(f"bar_policy.envs from {where}")
        results: dict[str, list[dict[str, float]]] = {m: [] for m in modes}
        for _ in range(args.runs):  # interleaved, so drifting machine load hits both alike
            for m, extra in modes.items():
                results[m].append(_run(extra, cwd)[0])
    for m, runs in results.items():
        cols = []
        for k in runs[0]:
            xs = [r[k] for r in runs]
            cols.append(f"{k} {statistics.median(xs):.3f} s ({min(xs):.3f}-{max(xs):.3f})")
        print(f"{m:5s} ({len(runs)} runs): " + ", ".join(cols))


if __name__ == "__main__":
    main()
