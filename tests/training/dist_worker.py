"""One process of the 2-process ``jax.distributed`` test (started by ``test_distributed.py``).

Usage: ``python dist_worker.py PORT PROCESS_ID OUT_DIR [override ...] [--toy]``. Trains the tiny preset on
LiteReach (``--toy``: the stand-in env) through ``run`` (the command line's path) with the coordinator on
127.0.0.1:PORT, its start-up counted from the process start as ``bar-train`` counts it, then writes
``OUT_DIR/result_<id>.npz``: every parameter leaf of the final (normaliser, policy, value) params, the
normaliser's observation count, the step count, the devices it saw, and whether torch was imported.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from bar_policy.training.config import apply_overrides, preset
from bar_policy.training.run import run
from bar_policy.training.startup.breakdown import process_uptime


def _count(c: object) -> int:
    """brax's observation count (a ``UInt64`` of two uint32 words, or a plain integer)."""
    if hasattr(c, "hi"):
        return int(c.hi) * 2**32 + int(c.lo)
    return int(np.asarray(c))


def main() -> None:
    port, pid, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    overrides = [a for a in sys.argv[4:] if a != "--toy"]
    cfg = apply_overrides(
        preset("tiny"),
        [
            f"runs_dir={out}",
            "run_name=dist",
            f"distributed.coordinator_address=127.0.0.1:{port}",
            "distributed.num_processes=2",
            f"distributed.process_id={pid}",
            *overrides,
        ],
    )
    env = None
    if "--toy" in sys.argv:
        sys.path.insert(0, str(Path(__file__).parent))
        from toy_env import ToyReach

        env = ToyReach()
    summary = run(cfg, env=env, started_at=time.monotonic() - process_uptime())
    import jax

    leaves = jax.tree_util.tree_leaves(summary.params)
    np.savez(
        f"{out}/result_{pid}.npz",
        *[np.asarray(x) for x in leaves],
        env_steps=summary.env_steps,
        normalizer_count=_count(summary.params[0].count),
        global_devices=jax.device_count(),
        local_devices=jax.local_device_count(),
        torch_imported="torch" in sys.modules,
        success_rate=summary.final_eval.get("success_rate", -1.0),
    )


if __name__ == "__main__":
    main()
