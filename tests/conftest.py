"""Suite-wide settings: CPU jax with a persistent compile cache (JIT compiles dominate CPU test time), and
the two tiers of the suite (``tiers.py``).

SIGINT: a suite started in the background by a shell without job control (``nohup pytest &``) inherits
SIGINT ignored, and so would every child it starts, whose Python then installs no KeyboardInterrupt
handler: the tests that interrupt a child's start-up with SIGINT would see it ignored. Python's own handler
here makes the children start with the default disposition, as from a terminal (a handler, unlike an
ignore, is reset at exec).
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

pytest_plugins = ["tiers", "pytester"]  # tiers.py: the default run leaves the slow tests out

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# XLA's CPU compiler as the tiny preset's ``QUICK_COMPILE`` sets it for its programs, here for every program:
# - without its new fusion emitters: a LiteReach step compiles in about 60 % of the CPU time (22 against
#   45 s unbatched, 41 against 67 s for 64 envs, jaxlib 0.10.2, 2-core CPU) and runs as fast;
# - LLVM at -O1: 15 % less CPU time on two env test files, cold (94 against 110 s).
# The float32 results differ in rounding only (3.6e-7 rad after 51 steps), inside every tolerance here, which
# are written for other machines' code (``-m numerics`` under ``--xla_cpu_max_isa=AVX2``). Appended: a
# caller's flags stay.
SUITE_XLA_FLAGS = "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=1"
if SUITE_XLA_FLAGS not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SUITE_XLA_FLAGS}".strip()
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "bar_policy" / "jax"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_xdist_auto_num_workers(config: object) -> int:
    """``-n auto`` (``pyproject.toml``'s ``addopts``): one worker per core this process may use, at most 4.

    On 2 cores two workers cut the default tier from 11m27s to 7m31s (docs/testing.md): XLA compiles one
    program on one thread. More than 4 would repeat the session fixtures' compiles for little gain, and
    each worker holds its own compiled programs in memory. ``-n 0`` runs in this process.
    """
    return max(1, min(len(os.sched_getaffinity(0)), 4))
