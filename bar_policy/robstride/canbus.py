"""Opening python-can buses, with one-line errors that say what is wrong and how to fix it.

``open_can_bus(interface, channel)`` wraps ``can.Bus``; every failure becomes ``BusOpenError`` with one line:

- errno 97 (EAFNOSUPPORT) creating the socket: this kernel has no SocketCAN (not Linux, a container or WSL
  without the CAN modules). Load the modules or run on the robot computer; ``virtual`` runs the emulator.
- errno 19 (ENODEV) binding: no interface of that name (adapter unplugged, or named differently).
- the interface exists but is down (its ``IFF_UP`` flag in ``/sys/class/net/<channel>/flags`` is clear;
  the kernel would only refuse the first frame, with errno 100, ENETDOWN).

Each message ends with the command that brings the interface up at the Lite's 1 Mbit/s. ``down_hint`` gives
the same advice for errors on a bus that was already open (``RobstrideBus`` uses it for ENETDOWN on send).
"""

from __future__ import annotations

import errno
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can

from bar_policy.robstride.errors import BusOpenError

__all__ = ["BITRATE", "bring_up_command", "down_hint", "open_can_bus", "open_can_buses"]

BITRATE = 1_000_000
"""The Robstride default bit rate, bit/s (reference section 1.1)."""
_IFF_UP = 0x1


def bring_up_command(channel: str) -> str:
    """The shell command that configures and starts ``channel`` at 1 Mbit/s."""
    return f"sudo ip link set {channel} up type can bitrate {BITRATE}"


def down_hint(error_code: int | None, channel: str) -> str | None:
    """Advice for an errno seen on an open SocketCAN bus (interface down or gone); None for other errors."""
    if error_code == errno.ENETDOWN:
        return f"CAN interface {channel} is down; bring it up with `{bring_up_command(channel)}`"
    if error_code in (errno.ENODEV, errno.ENXIO):
        return (
            f"CAN interface {channel} disappeared (adapter unplugged?); check `ip -br link show type can`, "
            f"then `{bring_up_command(channel)}`"
        )
    return None


def _interface_is_down(channel: str, sys_net: Path) -> bool:
    """True when sysfs says ``channel`` exists and is administratively down (unknown: False)."""
    try:
        flags = int((sys_net / channel / "flags").read_text().strip(), 0)
    except (OSError, ValueError):
        return False
    return not flags & _IFF_UP


def open_can_bus(
    interface: str, channel: str, *, sys_net: str | Path = "/sys/class/net", **kwargs: Any
) -> can.BusABC:
    """``can.Bus(interface=interface, channel=channel, **kwargs)``, or ``BusOpenError`` with a one-line fix.

    Args:
        interface: python-can interface (``socketcan``, ``virtual``, ...).
        channel: the channel (``can0``).
        sys_net: where the kernel lists network interfaces (tests point it elsewhere).
        kwargs: passed to ``can.Bus``.
    """
    try:
        bus = can.Bus(interface=interface, channel=channel, **kwargs)
    except (OSError, can.CanError, ImportError, ValueError) as exc:
        code = getattr(exc, "errno", None) or getattr(exc, "error_code", None)
        up = bring_up_command(channel)
        if code == errno.EAFNOSUPPORT:
            msg = (
                f"cannot open {interface} channel {channel}: SocketCAN is not available on this machine "
                "(the kernel has no CAN support: not Linux, or a container/VM without the can modules); "
                f"on the robot computer run `sudo modprobe can_raw` and `{up}`, or use the virtual "
                "interface for the emulator"
            )
        elif code == errno.ENODEV:
            msg = (
                f"cannot open {interface} channel {channel}: no CAN interface named {channel} "
                f"(adapter unplugged or named differently: `ip -br link show type can`); then `{up}`"
            )
        else:
            detail = " ".join(str(exc).split())
            msg = f"cannot open {interface} channel {channel}: {type(exc).__name__}: {detail}"
        raise BusOpenError(msg, interface=interface, channel=channel) from exc
    if interface == "socketcan" and _interface_is_down(channel, Path(sys_net)):
        bus.shutdown()
        raise BusOpenError(
            f"cannot use {interface} channel {channel}: the interface is down; bring it up with "
            f"`{bring_up_command(channel)}`",
            interface=interface,
            channel=channel,
        )
    return bus


def open_can_buses(interface: str, channels: Mapping[str, str], **kwargs: Any) -> dict[str, can.BusABC]:
    """``open_can_bus`` per robot interface -> channel; on a failure the ones already open are closed."""
    buses: dict[str, can.BusABC] = {}
    try:
        for name, channel in channels.items():
            buses[name] = open_can_bus(interface, channel, **kwargs)
    except BaseException:
        for bus in buses.values():
            bus.shutdown()
        raise
    return buses
