"""``bar-deploy plot`` and ``bar-deploy log``: the tools that read run logs (no policy, no target)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from bar_policy._files import shorten
from bar_policy.tasks.cli_types import Parser as _Parser
from bar_policy.tasks.cli_types import one_line

__all__ = ["MAX_ERROR_CHARS", "fail", "log_command", "plot_command"]

MAX_ERROR_CHARS = 1000
"""Longest error line printed (the file and the problem come first; longer lines end in ``... (N chars)``)."""


def fail(msg: object, status: int = 2) -> int:
    """Print ``bar-deploy: error: <one line>`` to stderr; return ``status``."""
    print(f"bar-deploy: error: {shorten(one_line(msg), MAX_ERROR_CHARS)}", file=sys.stderr)
    return status


def plot_command(argv: Sequence[str]) -> int:
    """``bar-deploy plot LOG [--out DIR]``."""
    p = _Parser(prog="bar-deploy plot", description="Write PNG plots of a run log.")
    p.add_argument("log", type=Path, help="run directory, its log.npz or its run.mcap")
    p.add_argument("--out", type=Path, help="output directory (default: the run directory)")
    args = p.parse_args(argv)
    from bar_policy.deploy.log.plot import plot_log

    try:
        files = plot_log(args.log, args.out)
    except (FileNotFoundError, ValueError) as e:
        return fail(e)
    except OSError as e:
        return fail(f"cannot write the plots: {e.strerror or e}: {e.filename or args.out}")
    for f in files:
        print(f)
    return 0


def log_command(argv: Sequence[str]) -> int:
    """``bar-deploy log recover RUN_DIR``."""
    p = _Parser(prog="bar-deploy log", description="Tools for run logs.")
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION", parser_class=_Parser)
    r = sub.add_parser(
        "recover",
        help="rewrite a run.mcap cut by a crash as a complete, indexed MCAP",
        description="Rewrite a run.mcap cut by a crash (SIGKILL, power loss: no summary, no footer) as a "
        "complete, indexed MCAP with every message that can be read. The original is kept beside it as "
        "run.mcap.cut; a complete file is left as it is.",
    )
    r.add_argument("run", type=Path, metavar="RUN_DIR", help="run directory, or its run.mcap")
    args = p.parse_args(argv)
    from bar_policy.deploy.log.recover import recover_mcap

    try:
        report = recover_mcap(args.run)
    except (FileNotFoundError, ValueError) as e:  # LogReadError is a ValueError
        return fail(e)
    except OSError as e:
        return fail(f"cannot rewrite {args.run}: {e.strerror or e}: {e.filename or args.run}")
    print(report.line())
    return 0
