"""Command line of ``bar-train`` (and ``python train/ppo.py``, the same flags): tyro over ``TrainConfig``.

Examples::

    bar-train                                             # gpu preset, brax backend
    bar-train --preset tiny --ppo.num-timesteps 4096
    bar-train --backend rsl-rl                            # rsl-rl: the gpu-rsl preset unless --preset
    bar-train --backend rsl-rl --ppo.num-envs 2048
    bar-train --env.episode-length-s 4.0 --env.reward.scales.reach-fine 2.0    # the env's typed settings
    bar-train --env-overrides episode_length_s=4.0 reward.scales.reach_fine=2.0  # the same, as a shorthand
    bar-train --resume runs/LiteReach-brax-20260101-120000 --ppo.num-timesteps 80000000
    bar-train --env LiteReach                             # --env is short for --env-name
    bar-train --no-compile-cache                          # compile everything afresh
    bar-train --preset reach-robust --robot-params p.json # the identified robot (bar-bus identify --out)
    bar-train --help                                      # every option once, grouped, with units

tyro parses every flag, ``--preset`` included. Because a preset supplies the defaults of every other flag
(and ``--help`` shows them), its value is looked up in the arguments first (``preset_of``) and handed to
tyro as the default instance; tyro then parses the whole line, ``--preset`` validated with its choices.
The env is looked up the same way (``env_of``): its config dataclass is the ``--env.*`` group
(``training.env_flags``), defaults the env's config with the preset's items. ``--env-overrides`` items, the
shorthand, are checked against that config before training starts (an unknown path is refused naming the
valid ones and the closest), with the one override syntax of ``bar_policy.overrides``. Every error is one
line, ``bar-train: error: ...``, exit status 2.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import replace

from bar_policy.overrides import changed_overrides, merge_overrides
from bar_policy.tasks.registry import TASKS
from bar_policy.training.config import PRESETS, TrainConfig, preset
from bar_policy.training.env_flags import PROG, command_for, fail, parse_command, train_config_of
from bar_policy.training.writers import check_logger

__all__ = [
    "BACKEND_PRESETS",
    "check_env_overrides",
    "env_of",
    "main",
    "parse_config",
    "preset_of",
    "robot_params_of",
]


BACKEND_PRESETS: dict[str, str] = {"rsl-rl": "gpu-rsl"}
"""The preset a backend runs when no ``--preset`` is given (else ``gpu``): ``--backend rsl-rl`` alone runs
``gpu-rsl``, the gpu preset's env at rsl-rl's fast sizes with a fixed rate (``tasks/reach/preset.py``)."""


def preset_of(argv: Sequence[str]) -> str:
    """The ``--preset`` value in ``argv`` (the last one wins, as in tyro).

    Without one: the ``--backend``'s own (``BACKEND_PRESETS``), else ``gpu``. An unknown name is left for
    tyro to refuse with the valid choices (``gpu`` meanwhile).
    """
    name = backend = None
    for i, a in enumerate(argv):
        if a == "--":
            break
        for flag in ("--preset", "--backend"):
            value = None
            if a == flag and i + 1 < len(argv):
                value = argv[i + 1]
            elif a.startswith(flag + "="):
                value = a.split("=", 1)[1]
            if value is not None and flag == "--preset":
                name = value
            elif value is not None:
                backend = value
    if name is None:
        name = BACKEND_PRESETS.get(backend or "", "gpu")
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
                fail("--robot-params needs a FILE")
            found = argv[i + 1]
            next(it, None)
        elif a.startswith("--robot-params="):
            found = a.split("=", 1)[1]
        else:
            out.append(a)
    return out, found


def env_of(argv: Sequence[str], default: str) -> str:
    """The ``--env`` (``--env-name``) value in ``argv`` (the last one wins); ``default`` if absent or unknown.

    ``--env.<field>`` flags are the env's settings, not its name. An unknown name is left for tyro to refuse
    with the valid choices.
    """
    name = default
    for i, a in enumerate(argv):
        if a == "--":
            break
        if a in ("--env", "--env-name") and i + 1 < len(argv):
            name = argv[i + 1]
        elif a.startswith(("--env=", "--env-name=")):
            name = a.split("=", 1)[1]
    return name if name in {e.name for r in TASKS for e in r.envs} else default


def parse_config(argv: Sequence[str] | None = None) -> TrainConfig:
    """Parse a command line into a ``TrainConfig`` (tyro; defaults from the named preset and env).

    The env's settings are typed flags (``--env.reward.scales.action-rate -0.1``, ``training.env_flags``)
    whose defaults are the env's config with the preset's own items; the ones a command line changes join
    the run's ``env_overrides`` after the preset's and ``--env-overrides``' items (so a flag wins).
    Exits with status 2 and a one-line message (``bar-train: error: ...``) on a bad flag, value or override.
    ``--robot-params FILE`` is short for the item ``robot_params=FILE``.
    """
    args, params_file = robot_params_of(list(sys.argv[1:] if argv is None else argv))
    name = preset_of(args)
    base = preset(name)
    env_name = env_of(args, base.env_name)
    preset_items, dropped = _preset_items(name, base.env_overrides, env_name)
    description = (
        __doc__.split("\n\n")[0]
        + f"\n\nDefaults shown: the {name} preset's. The --env.* settings are {env_name}'s (--env picks "
        + "another env's); --env-overrides path=value items are a shorthand for them. "
        + "--robot-params FILE: train on the identified robot (robot_params=FILE; docs/sysid.md)."
    )
    command, default = command_for(base, env_name, preset_items)
    parsed = parse_command(command, default, args, description=description, prog=PROG)
    if dropped:
        print(
            f"{PROG}: note: preset {name}'s env settings {list(base.env_overrides)} are the {dropped} "
            f"task's; not applied to {parsed.env_name}",
            file=sys.stderr,
        )
    cfg = train_config_of(parsed)
    # Equal to the preset's items: tyro's default, so nothing was given on the command line.
    given = () if cfg.env_overrides == base.env_overrides else cfg.env_overrides
    flags = changed_overrides(parsed.env, default.env)
    try:
        cfg = replace(cfg, env_overrides=merge_overrides(merge_overrides(preset_items, given), flags))
        if params_file is not None:
            cfg = replace(
                cfg, env_overrides=merge_overrides(cfg.env_overrides, (f"robot_params={params_file}",))
            )
        check_env_overrides(cfg)
    except ValueError as e:
        fail(f"--env-overrides: {e}")
    try:
        check_logger(cfg.logger)  # wandb is optional: refused here, before anything compiles
    except ValueError as e:
        fail(str(e))
    return cfg


def _preset_items(name: str, items: tuple[str, ...], env_name: str) -> tuple[tuple[str, ...], str]:
    """The preset's env items that apply to ``env_name``, and the preset's task name when they do not.

    A preset's items are its task's settings (the reach gpu preset's ``sim_dt=0.004``): with an env of
    another task (``--env LitePiano``) they are left out (``parse_config`` prints a note).
    """
    if not items:
        return (), ""
    own = next(r for r in TASKS if name in dict(r.presets))
    return ((), own.name) if env_name not in {e.name for e in own.envs} else (items, "")


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

    from bar_policy.training.startup.breakdown import process_uptime

    started_at = time.monotonic() - process_uptime()
    try:
        cfg = parse_config(argv)
    except BrokenPipeError:  # ``--help`` into a reader that stopped reading (``| head``): no traceback
        return _reader_gone()
    from bar_policy.training.run import run

    summary = run(cfg, started_at=started_at)
    return 0 if summary.env_steps > 0 else 1


def _reader_gone() -> int:
    """Status 1 after stdout's reader closed the pipe; stdout then points at /dev/null.

    The interpreter's flush at exit then raises nothing more (Python's advice for SIGPIPE, ``signal`` docs).
    """
    import os
    import sys

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return 1
