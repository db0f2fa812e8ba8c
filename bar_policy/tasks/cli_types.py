"""``bar-deploy``'s argument types and parser: finite numbers with a stated range, one-line errors.

Shared by ``deploy.cli`` and the tasks' deploy options (``bar_policy.tasks.<task>.deploy``), so it lives
below both.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from typing import NoReturn

__all__ = [
    "Parser",
    "asks_help",
    "count0",
    "count1",
    "duration",
    "number",
    "one_line",
    "priority",
    "seconds",
    "seconds0",
]


def one_line(msg: object) -> str:
    """A message on one line (multi-line driver messages joined with '; ')."""
    return "; ".join(part.strip() for part in str(msg).splitlines() if part.strip())


def asks_help(argv: Sequence[str]) -> bool:
    """``-h`` / ``--help`` in ``argv`` (before a ``--``)."""
    args = list(argv)
    return any(a in ("-h", "--help") for a in args[: args.index("--") if "--" in args else len(args)])


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``PROG: error: MESSAGE (see PROG --help)``, exit status 2."""

    def error(self, message: str) -> NoReturn:
        """Exit with status 2 and the message on one line."""
        self.exit(2, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def number(kind: str, test: Callable[[float], bool], cast: type = float) -> Callable[[str], float]:
    """An argparse type: a finite number of ``cast`` that passes ``test``; the error says ``kind``."""

    def parse(text: str) -> float:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        if not (math.isfinite(value) and test(value)):
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}")
        return value

    parse.__name__ = kind  # argparse names the type in some messages
    return parse


seconds = number("a time > 0 s", lambda v: v > 0)
seconds0 = number("a time >= 0 s", lambda v: v >= 0)
count0 = number("an integer >= 0", lambda v: v >= 0, int)
count1 = number("an integer >= 1", lambda v: v >= 1, int)
priority = number("an integer in 1..99", lambda v: 1 <= v <= 99, int)
port = number("a TCP port in 0..65535", lambda v: 0 <= v <= 65535, int)


def duration(text: str) -> float:
    """``--duration``: seconds > 0, or ``inf`` (until stopped or the commands end) as ``math.inf``."""
    if text.strip().lower() in ("inf", "infinity", "forever"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(
            f"expected a time > 0 s, or 'inf' to run until stopped; got {text!r}"
        )
    return value
