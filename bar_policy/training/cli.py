"""Command line of ``python train/ppo.py``: tyro over ``TrainConfig``; ``--preset`` picks the defaults.

Examples::

    python train/ppo.py                                   # gpu preset, brax backend
    python train/ppo.py --preset tiny --ppo.num-timesteps 4096
    python train/ppo.py --backend rsl-rl --ppo.num-envs 2048
    python train/ppo.py --env-overrides episode_length_s=4.0 reward.scales.reach_fine=2.0
    python train/ppo.py --resume runs/LiteReach-brax-20260101-120000 --ppo.num-timesteps 80000000
    python train/ppo.py --help                            # every option, with units
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from bar_policy.training.config import PRESETS, TrainConfig, preset

__all__ = ["main", "parse_config"]


def parse_config(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse the command line into a ``TrainConfig`` (``--preset`` first picks the defaults)."""
    import tyro

    argv = list(sys.argv[1:] if argv is None else argv)
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default="gpu", choices=sorted(PRESETS))
    known, rest = pre.parse_known_args(argv)
    default = preset(known.preset)
    description = (
        __doc__.split("\n\n")[0]
        + f"\n\n--preset {{{','.join(sorted(PRESETS))}}} picks the defaults shown below "
        + f"(now: {known.preset})."
    )
    return tyro.cli(TrainConfig, default=default, args=rest, description=description)


def _enable_compile_cache() -> None:
    """Persistent XLA compile cache in ``~/.cache/bar_policy/jax`` unless JAX_COMPILATION_CACHE_DIR is set.

    A rerun on the same machine then skips the env's compile (minutes on a CPU, ~1 min on a GPU).
    """
    import os
    from pathlib import Path

    import jax

    if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        jax.config.update("jax_compilation_cache_dir", str(Path.home() / ".cache" / "bar_policy" / "jax"))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, train, evaluate, export; prints progress and a final summary table."""
    cfg = parse_config(argv)
    _enable_compile_cache()
    from bar_policy.training.run import run

    summary = run(cfg)
    return 0 if summary.env_steps > 0 else 1
