"""Repeated log warnings counted into one line each (``bar-deploy eval``).

An evaluation runs many episodes through the same supervisor code, so one cause repeats: the safety
supervisor's ``q_cmd of %s clipped to its limit`` came 64 times in a 62 s evaluation. ``WarningTally``, a
``logging.Filter`` on the root logger's handlers, holds every WARNING-or-worse record back and counts it by
its kind (logger name and message template); ``lines()`` then gives one line per kind with the first
message and the count, and ``to_dict()`` the same for the result file. Nothing is dropped: every record
is counted, and every kind printed once.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

__all__ = ["WarningTally"]


@dataclass
class _Kind:
    level: str
    logger: str
    first: str
    """The first record's message, formatted."""
    count: int = 0


class WarningTally(logging.Filter):
    """Counts WARNING-or-worse records by (logger, template) and holds them back; lower levels pass."""

    def __init__(self) -> None:
        super().__init__()
        self.kinds: dict[tuple[str, str], _Kind] = {}
        self._handlers: list[logging.Handler] = []
        self._last: logging.LogRecord | None = None

    def filter(self, record: logging.LogRecord) -> bool:
        """False (held back, counted) for a WARNING or worse; True for the rest.

        A record reaches each handler in turn: it is counted at the first (the same object again is not).
        """
        if record.levelno < logging.WARNING:
            return True
        if record is self._last:
            return False
        self._last = record
        key = (record.name, str(record.msg))
        kind = self.kinds.get(key)
        if kind is None:
            kind = self.kinds[key] = _Kind(record.levelname, record.name, record.getMessage())
        kind.count += 1
        return False

    def __enter__(self) -> WarningTally:
        """Install on the root logger's handlers (else on the last-resort one, which prints when none is)."""
        self._handlers = list(logging.getLogger().handlers) or [h for h in (logging.lastResort,) if h]
        for h in self._handlers:
            h.addFilter(self)
        return self

    def __exit__(self, *exc: object) -> None:
        for h in self._handlers:
            h.removeFilter(self)
        self._handlers = []

    @property
    def total(self) -> int:
        """Warnings counted, all kinds."""
        return sum(k.count for k in self.kinds.values())

    def lines(self) -> list[str]:
        """One line per kind, first seen first: ``WARNING <logger>: <first message> [x64]``."""
        return [f"{k.level} {k.logger}: {k.first} [x{k.count}]" for k in self.kinds.values()]

    def to_dict(self) -> list[dict[str, Any]]:
        """``[{"level", "logger", "template", "first", "count"}, ...]`` for the result file."""
        return [
            {"level": k.level, "logger": k.logger, "template": template, "first": k.first, "count": k.count}
            for (_, template), k in self.kinds.items()
        ]
