"""The env's settings as typed ``bar-train`` flags, and the command line's one error style.

``bar-train``'s command is ``TrainConfig`` plus one group, ``env``: the chosen env's config dataclass
(``ReachEnvConfig``, ``TrackEnvConfig``, ...: frozen, nested, units in each field's docstring), so
``--help`` lists every env and reward setting (``--env.reward.scales.action-rate``, ``--env.sim-dt``) with
its unit and the default the run would use. The env is known before parsing (``cli.env_of``), as the preset
is, so the group is that env's; its defaults are the env's default config with the preset's own items.

The parsed ``env`` group is not kept as such: the settings it changes become ``path=value`` items of
``TrainConfig.env_overrides`` (``overrides.changed_overrides``), the form a run records, resumes and keys
its caches by, so a preset's resolved env config is the same as before these flags existed.

Every error of the command line is one line on stderr, ``bar-train: error: <what>``, with the valid
choices (and a "did you mean" for a mistyped option), exit status 2: tyro's boxed messages are
condensed to that line, and unknown options are refused here before tyro sees them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import io
import sys
from collections.abc import Sequence
from typing import Annotated, Any, NoReturn

from bar_policy.overrides import apply_overrides
from bar_policy.task_records import resolve
from bar_policy.tasks.registry import env_entries
from bar_policy.training.config import TrainConfig

__all__ = [
    "PROG",
    "command_for",
    "env_default",
    "fail",
    "option_names",
    "parse_command",
    "train_config_of",
]

PROG = "bar-train"
"""Program name in messages (``python train/ppo.py`` runs the same parser)."""

ENV_HELP = (
    "The env's settings (its config dataclass; units in each field's help). Defaults: the env's config "
    "with the preset's own env items. A changed one joins env_overrides as path=value."
)
"""Help of the ``--env.*`` group."""


def fail(message: str) -> NoReturn:
    """Print ``bar-train: error: <message>`` as one line on stderr and exit with status 2."""
    sys.stderr.write(f"{PROG}: error: {' '.join(message.split())}\n")
    raise SystemExit(2)


def env_default(env_name: str) -> Any:
    """The default (training) config of a registered env (imports the env's config module)."""
    from bar_policy import _mjx_quiet  # noqa: F401 - before the env module's mujoco.mjx: no Warp notice

    return resolve(env_entries()[env_name][1].config)()


def command_for(base: TrainConfig, env_name: str, preset_items: Sequence[str]) -> tuple[type, Any]:
    """The command's dataclass (``TrainConfig`` + ``env``) and its default instance for this preset and env.

    Args:
        base: the preset's config (every other flag's default).
        env_name: the env whose config the ``env`` group is.
        preset_items: the preset's env items that apply to this env (its ``env_overrides``, or none).
    """
    shown = apply_overrides(env_default(env_name), preset_items)
    env_type = Annotated[type(shown), _tyro().conf.arg(help=ENV_HELP)]
    # Named as its base: tyro's message for a failed check of the root names the class (TrainConfig).
    command = dataclasses.make_dataclass(
        "TrainConfig",
        [("env", env_type, dataclasses.field(default_factory=lambda: shown))],
        bases=(TrainConfig,),
        frozen=True,
        kw_only=True,
    )
    values = {f.name: getattr(base, f.name) for f in dataclasses.fields(TrainConfig)}
    return command, command(**values, env=shown)


def train_config_of(parsed: Any) -> TrainConfig:
    """The ``TrainConfig`` part of a parsed command (its ``env`` group left out)."""
    return TrainConfig(**{f.name: getattr(parsed, f.name) for f in dataclasses.fields(TrainConfig)})


def option_names(default: Any, prefix: str = "") -> list[str]:
    """Every option tyro makes of a dataclass tree: ``--ppo.num-envs``, ``--no-export-onnx`` for a boolean."""
    out = []
    for f in dataclasses.fields(default):
        value = getattr(default, f.name)
        flag = f.name.replace("_", "-")
        if dataclasses.is_dataclass(value):
            out += option_names(value, f"{prefix}{flag}.")
        else:
            out.append(f"--{prefix}{flag}")
            if isinstance(value, bool):
                out.append(f"--{prefix}no-{flag}")
    return out


def check_options(args: Sequence[str], valid: Sequence[str]) -> None:
    """Refuse (``fail``) the first option of ``args`` that the command does not have.

    The message names it, the closest valid option ("did you mean") and the valid options of its group
    (``--env.reward.scales.``'s fields for a mistyped reward scale).
    """
    known = set(valid)
    for a in args:
        if a == "--":
            return
        name = a.split("=", 1)[0]
        if not name.startswith("--") or name in known:
            continue
        group = name[: name.rfind(".") + 1] if "." in name else "--"
        siblings = [v for v in valid if v.startswith(group) and "." not in v[len(group) :]] or list(valid)
        close = difflib.get_close_matches(name, valid, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]}?" if close else ""
        shown = ", ".join(s for s in siblings if "no-" not in s.rsplit(".", 1)[-1][:3])
        where = f" under {group}" if group != "--" else ""
        fail(f"unknown option {name}{hint} valid options{where}: {shown}")


def parse_command(command: type, default: Any, args: Sequence[str], *, description: str, prog: str) -> Any:
    """Tyro's parse of ``args`` into ``command``; any error as one line (``fail``), ``--help`` as tyro's."""
    tyro = _tyro()
    check_options(args, [*option_names(default), "--env", "--help", "-h"])
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            parsed = tyro.cli(command, default=default, args=list(args), description=description, prog=prog)
    except SystemExit as e:
        if e.code in (0, None):
            sys.stderr.write(captured.getvalue())
            raise
        fail(condense(captured.getvalue()) or f"bad command line {' '.join(args)}")
    sys.stderr.write(captured.getvalue())  # anything else tyro said (a warning) is passed on
    return parsed


def condense(box: str) -> str:
    """Tyro's error as one line: its message lines, without its title, frame, rules and help pointers.

    Tyro draws a box on a terminal (``╭─ Value error ─╮``, ``│ ... │``) and a plain block elsewhere (the
    title, then rules of ``-``); the first line is the title (the kind of error) either way.
    """
    lines = [line.strip().strip("│╭╮╰╯─").strip() for line in box.splitlines()]
    lines = [x for x in lines if x and set(x) - set("-─")]  # no blanks, no rules
    kept = []
    for body in lines[1:]:  # lines[0]: the title
        if body.startswith(("Argument helptext", "For full helptext", "Perhaps you meant")):
            break
        kept.append(body)
    return " ".join(kept)


def _tyro() -> Any:
    import tyro

    return tyro
