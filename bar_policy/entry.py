"""The ``bar-deploy`` console entry point: the stop signals are handled before any heavy import.

The console script imports this module and calls ``deploy()``. Its first lines make SIGTERM and SIGHUP
raise a ``KeyboardInterrupt`` like SIGINT (``_early_stop.install``), then import ``bar_policy.deploy.cli``
(numpy, the tasks: tenths of a second) inside a ``try``: a signal during the imports ends with the one line
and the status ``early_interrupt`` gives, never a traceback. ``bar_policy.deploy.cli.main`` takes over
from there (its own ``try`` covers everything until ``StopSignals`` is installed).
"""

from __future__ import annotations

import sys

from bar_policy import _early_stop

__all__ = ["deploy"]


def _subcommand(argv: list[str]) -> str:
    return argv[0] if argv and argv[0] in ("run", "plot", "eval", "log") else "run"


def deploy(argv: list[str] | None = None) -> int:
    """``bar-deploy``: ``bar_policy.deploy.cli.main`` behind the early signal handling; the exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        _early_stop.install()
        from bar_policy.deploy.cli import main

        return main(args)
    except KeyboardInterrupt as e:  # a stop signal before main's own handling took over
        status, line = _early_stop.early_interrupt(_subcommand(args), _early_stop.signal_name_of(e))
        print(line, file=sys.stdout if status == 0 else sys.stderr, flush=True)
        return status


if __name__ == "__main__":
    raise SystemExit(deploy())
