"""argparse value types shared by ``bar-bus`` and the real target's ``bar-deploy`` options.

Each refuses a bad value with ``argparse.ArgumentTypeError`` naming the valid range, so argparse prints one
line (``argument --timeout: must be a number > 0 s, got '-1'``) and exits with status 2.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from bar_policy.deploy.robstride import protocol as proto

__all__ = ["can_timeout_arg", "float_list", "int_range", "non_negative", "positive"]


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def positive(unit: str) -> Callable[[str], float]:
    """A finite float > 0 (``unit`` names it in the error, e.g. ``s`` or ``Hz``)."""

    def parse(text: str) -> float:
        value = _number(text)
        if value <= 0:
            raise argparse.ArgumentTypeError(f"must be a number > 0{_unit(unit)}, got {text!r}")
        return value

    return parse


def non_negative(unit: str, hi: float | None = None) -> Callable[[str], float]:
    """A finite float in ``[0, hi]`` (no upper bound when ``hi`` is None)."""

    def parse(text: str) -> float:
        value = _number(text)
        if value < 0 or (hi is not None and value > hi):
            valid = f"0..{hi:g}" if hi is not None else ">= 0"
            raise argparse.ArgumentTypeError(f"must be a number {valid}{_unit(unit)}, got {text!r}")
        return value

    return parse


def int_range(lo: int, hi: int) -> Callable[[str], int]:
    """An integer in ``lo..hi`` (decimal or ``0x`` hex)."""

    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer in {lo}..{hi}, got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be an integer in {lo}..{hi}, got {text!r}")
        return value

    return parse


def can_timeout_arg(text: str) -> float:
    """The CAN watchdog in s: 0 (leave the motors' setting) or ``CAN_TIMEOUT_MIN..CAN_TIMEOUT_MAX``."""
    try:
        return proto.check_can_timeout(_number(text), "the CAN watchdog")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def float_list(item: Callable[[str], float]) -> Callable[[str], list[float]]:
    """A comma-separated, non-empty list of values parsed by ``item``."""

    def parse(text: str) -> list[float]:
        parts = [p.strip() for p in text.split(",") if p.strip()]
        if not parts:
            raise argparse.ArgumentTypeError(f"must be a comma-separated list of numbers, got {text!r}")
        return [item(p) for p in parts]

    return parse
