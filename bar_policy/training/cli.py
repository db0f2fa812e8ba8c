"""Command line of ``python train/ppo.py``: tyro over ``TrainConfig``; ``--preset`` picks the defaults.

Examples::

    python train/ppo.py                                   # gpu preset, brax backend
    python train/ppo.py --preset tiny --ppo.num-timesteps 4096
    python train/ppo.py --backend rsl-rl --ppo.num-envs 2048
    python train/ppo.py --env-overrides episode_length_s=4.0 reward.scales.reach_fine=2.0
    python train/ppo.py --resume runs/LiteReach-brax-20260101-120000 --ppo.num-timesteps 80000000
    python train/ppo.py --env LiteReach                   # --env is short for --env-name
    python train/ppo.py --no-compile-cache                # compile everything afresh
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

    argv = _expand_aliases(list(sys.argv[1:] if argv is None else argv))
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default="gpu", choices=sorted(PRESETS))
    known, rest = pre.parse_known_args(argv)
    default = preset(known.preset)
    description = (
        __doc__.split("\n\n")[0]
        + f"\n\n--preset {{{','.join(sorted(PRESETS))}}} picks the defaults shown below "
        + f"(now: {known.preset}). --env NAME is short for --env-name NAME."
    )
    return tyro.cli(TrainConfig, default=default, args=rest, description=description)


_ALIASES = {"--env": "--env-name"}
"""Short flags -> the tyro flag they stand for."""


def _expand_aliases(argv: list[str]) -> list[str]:
    """``--env X`` / ``--env=X`` -> ``--env-name X`` (tyro makes one flag per field; these are short ones)."""
    out = []
    for a in argv:
        name, eq, value = a.partition("=")
        if name in _ALIASES:
            a = _ALIASES[name] + eq + value
        out.append(a)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: parse, train, evaluate, export; prints progress and a final summary table."""
    import time

    from bar_policy.training.startup import process_uptime

    started_at = time.monotonic() - process_uptime()
    cfg = parse_config(argv)
    from bar_policy.training.run import run

    summary = run(cfg, started_at=started_at)
    return 0 if summary.env_steps > 0 else 1
