"""Command line of ``bar-train`` (and ``python train/ppo.py``, the same flags): tyro over ``TrainConfig``.

Examples::

    bar-train                                             # gpu preset, brax backend
    bar-train --preset tiny --ppo.num-timesteps 4096
    bar-train --backend rsl-rl --ppo.num-envs 2048
    bar-train --env-overrides episode_length_s=4.0 reward.scales.reach_fine=2.0
    bar-train --resume runs/LiteReach-brax-20260101-120000 --ppo.num-timesteps 80000000
    bar-train --env LiteReach                             # --env is short for --env-name
    bar-train --no-compile-cache                          # compile everything afresh
    bar-train --preset reach-robust --robot-params p.json # the identified robot (bar-bus identify --out)
    bar-train --help                                      # every option once, grouped, with units

tyro parses every flag, ``--preset`` included. Because a preset supplies the defaults of every other flag
(and ``--help`` shows them), its value is looked up in the arguments first (``preset_of``) and handed to
tyro as the default instance; tyro then parses the whole line, ``--preset`` validated with its choices.
``--env-overrides`` items are checked against the chosen env's config before training starts (an unknown
path is refused naming the valid ones), with the one override syntax of ``bar_policy.overrides``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import replace

from bar_policy.overrides import merge_overrides
from bar_policy.tasks.registry import TASKS
from bar_policy.training.config import PRESETS, TrainConfig, preset

__all__ = ["check_env_overrides", "main", "parse_config", "preset_of", "robot_params_of"]

PROG = "bar-train"
"""Program name in messages (``python train/ppo.py`` runs the same parser)."""


def preset_of(argv: Sequence[str]) -> str:
    """The ``--preset`` value in ``argv`` (the last one wins, as in tyro); ``gpu`` when absent or unknown.

    An unknown name is left for tyro to refuse with the valid choices.
    """
    name = "gpu"
    for i, a in enumerate(argv):
        if a == "--":
            break
        if a == "--preset" and i + 1 < len(argv):
            name = argv[i + 1]
        elif a.startswith("--preset="):
            name = a.split("=", 1)[1]
    return name if name in PRESETS else "gpu"


def robot_params_of(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without ``--robot-params FILE`` (or ``--robot-params=FILE``), and that FILE (None: absent).

    ``--robot-params FILE`` is short for ``--env-overrides robot_params=FILE`` (``RobotEnvConfig.
    robot_params``: train on the identified robot, randomisation centred on its values); a bad file is
    refused like any env override (one line, exit 2).
    """
    out: list[str] = []
    found: str | None = None
    it = iter(range(len(argv)))
    for i in it:
        a = argv[i]
        if a == "--":
            out.extend(argv[i:])
            break
        if a == "--robot-params":
            if i + 1 >= len(argv):
                print(f"{PROG}: error: --robot-params needs a FILE", file=sys.stderr)
                raise SystemExit(2)
            found = argv[i + 1]
            next(it, None)
        elif a.startswith("--robot-params="):
            found = a.split("=", 1)[1]
        else:
            out.append(a)
    return out, found


def parse_config(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse a command line into a ``TrainConfig`` (tyro; defaults from the named preset).

    Exits with status 2 and a one-line message on a bad flag, value or env override.
    """
    import tyro

    args, params_file = robot_params_of(list(sys.argv[1:] if argv is None else argv))
    name = preset_of(args)
    description = (
        __doc__.split("\n\n")[0]
        + f"\n\nDefaults shown: the {name} preset's. Env and reward settings: dotted.path=value items "
        + "(docs/training.md lists them). --robot-params FILE: train on the identified robot "
        + "(robot_params=FILE; docs/sysid.md)."
    )
    base = preset(name)
    cfg = tyro.cli(TrainConfig, default=base, args=args, description=description, prog=PROG)
    try:
        cfg = replace(cfg, env_overrides=_on_preset(name, base.env_overrides, cfg))
        if params_file is not None:
            cfg = replace(
                cfg, env_overrides=merge_overrides(cfg.env_overrides, (f"robot_params={params_file}",))
            )
        check_env_overrides(cfg)
    except ValueError as e:
        print(f"{PROG}: error: --env-overrides: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    return cfg


def _on_preset(name: str, preset_items: tuple[str, ...], cfg: TrainConfig) -> tuple[str, ...]:
    """The run's env overrides: ``--env-overrides`` on top of the preset's own items.

    A path given on the command line replaces the preset's value for it; the preset's other items stay
    (``overrides.merge_overrides``). A preset's items are its task's settings (the reach gpu preset's
    ``sim_dt=0.004``): with an env of another task (``--env LitePiano``) they are left out, with a note.
    """
    if not preset_items:
        return cfg.env_overrides
    # Equal to the preset's items: tyro's default, so nothing was given on the command line.
    given = () if cfg.env_overrides == preset_items else cfg.env_overrides
    own = next(r for r in TASKS if name in dict(r.presets))
    if cfg.env_name in {e.name for e in own.envs}:
        return merge_overrides(preset_items, given)
    print(
        f"{PROG}: note: preset {name}'s env settings {list(preset_items)} are the {own.name} task's; "
        f"not applied to {cfg.env_name}",
        file=sys.stderr,
    )
    return given


def check_env_overrides(cfg: TrainConfig) -> None:
    """Apply ``cfg.env_overrides`` to ``cfg.env_name``'s default config; raises ``ValueError`` if one fails.

    Imports the env package (jax) only when there are overrides, so ``--help`` and plain runs stay quick.
    """
    if not cfg.env_overrides:
        return
    from bar_policy import envs

    envs.apply_overrides(envs.default_config(cfg.env_name), cfg.env_overrides)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bar-train``: parse, train, evaluate, export; prints progress and a summary table."""
    import time

    from bar_policy.training.startup.compiler import process_uptime

    started_at = time.monotonic() - process_uptime()
    cfg = parse_config(argv)
    from bar_policy.training.run import run

    summary = run(cfg, started_at=started_at)
    return 0 if summary.env_steps > 0 else 1
