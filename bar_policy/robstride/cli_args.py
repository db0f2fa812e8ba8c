"""argparse value types and option names shared by ``bar-bus`` and the real target's ``bar-deploy`` options.

Each type refuses a bad value with ``argparse.ArgumentTypeError`` naming the valid range, so argparse prints
one line (``argument --reply-timeout: must be a number > 0 s, got '-1'``) and exits with status 2.

One name per concept in both tools (``HELP`` words the shared ones once): ``--can-interface`` (python-can's
driver), ``--channel`` (one bus) / ``--channels`` (the robot's buses), ``--calibration`` (the calibration
JSON, written by ``bar-bus calibrate``, read by ``bar-deploy --target real``), ``--reply-timeout``,
``--can-timeout``, ``--scan-to``. Old spellings stay as hidden ``deprecated_alias`` options that print a
one-line notice.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence

from bar_policy.robstride import protocol as proto

__all__ = [
    "CAN_INTERFACES",
    "HELP",
    "DeprecatedAlias",
    "can_timeout_arg",
    "deprecated_alias",
    "float_list",
    "int_range",
    "non_negative",
    "parse_channels",
    "positive",
]


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


# ---------------------------------------------------------------------------------------------------
# One name per concept across bar-bus and bar-deploy
# ---------------------------------------------------------------------------------------------------
CAN_INTERFACES = ("socketcan", "virtual")
"""python-can interfaces (drivers) the tools open: the robot's SocketCAN, or the in-process virtual bus."""

HELP = {
    "--can-interface": "python-can interface (driver): socketcan for the robot, virtual for the in-process "
    "emulator (default socketcan)",
    "--channel": "CAN channel of the one bus, e.g. can0 (default can0)",
    "--channels": "CAN channels of the robot's buses (can0: left arm and neck, can1: right arm): "
    "'can0,can1' in that order, or 'can0=vcan0,can1=vcan1' (default: the names themselves)",
    "--reply-timeout": "deadline for each motor's reply, s",
    "--scan-to": "highest CAN id scanned, 1..127",
}
"""Help of the options both tools share, worded once."""


class DeprecatedAlias(argparse.Action):
    """A hidden old spelling of an option: stores into the new option's ``dest`` and prints a notice.

    The notice is one line on stderr, ``PROG: note: --iface is deprecated; use --channel``, each time the
    old spelling is used. Type and choices are the new option's, so a bad value is refused the same way.
    """

    def __init__(self, option_strings: list[str], dest: str, new: str = "", **kwargs: object) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kwargs)  # type: ignore[arg-type]

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        """Store the value as the new option would, after the notice."""
        sys.stderr.write(f"{parser.prog}: note: {option_string} is deprecated; use {self.new}\n")
        setattr(namespace, self.dest, values)


def deprecated_alias(parser: argparse.ArgumentParser, old: str, new: argparse.Action) -> None:
    """Add ``old`` as a hidden, deprecated spelling of the option ``new`` (an action ``add_argument`` made).

    ``new`` must take one value (``nargs`` None); the alias takes the same type, choices and metavar.
    """
    parser.add_argument(
        old,
        action=DeprecatedAlias,
        new=new.option_strings[0],
        dest=new.dest,
        type=new.type,
        choices=new.choices,
        metavar=new.metavar,
        default=argparse.SUPPRESS,
        help=argparse.SUPPRESS,
    )


def parse_channels(spec: str | None, interfaces: Sequence[str]) -> dict[str, str]:
    """Robot interface -> channel from ``--channels`` (ordered list or ``iface=channel`` pairs)."""
    if not spec:
        return {i: i for i in interfaces}
    items = [s.strip() for s in spec.split(",") if s.strip()]
    if all("=" in s for s in items):
        mapping = dict(s.split("=", 1) for s in items)
    elif not any("=" in s for s in items) and len(items) == len(interfaces):
        mapping = dict(zip(interfaces, items, strict=True))
    else:
        raise ValueError(
            f"--channels {spec!r}: give {len(interfaces)} channels for {list(interfaces)} in order, "
            "or iface=channel pairs"
        )
    missing = [i for i in interfaces if i not in mapping]
    if missing:
        raise ValueError(f"--channels {spec!r} lacks interfaces {missing}")
    return mapping


def perturbation_arg(text: str) -> object:
    """``--emulate-perturb KEY=VALUE,...``: the emulator's robot (``robot.perturb_spec.Perturbation``).

    A bad spec is an ``ArgumentTypeError`` naming the key and what is valid (one line, exit 2).
    """
    from bar_policy.robot.perturb_spec import PerturbationError, parse_perturbation

    try:
        return parse_perturbation(text)
    except PerturbationError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def emulate_perturb_help() -> str:
    """Help of ``--emulate-perturb`` (both tools): what it does and the keys with their units."""
    from bar_policy.robot.perturb_spec import help_text

    return (
        "the in-process emulator's robot differs from the model so, hidden from the host (a robot the "
        f"software does not know). Keys: {help_text()}"
    )
