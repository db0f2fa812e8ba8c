"""The real target: the Lite's Robstride actuators in MIT mode over CAN (python-can), one bus per arm.

``RealTarget`` (``targets.real_target``) is asynchronous (wall clock): ``advance`` only returns, the runtime
keeps the rate; ``start()`` runs the safety sequence of ``RobstrideGroup.activate`` (the CAN watchdog
included), and any driver error inside a read or write sends damping then stop frames on every bus, then
raises (``TargetError``). ``real_target`` documents each step.

CLI glue for ``bar-deploy --target real`` (``targets.real_cli``): ``add_arguments(parser)`` and
``make_target(args, mode)``. With ``--can-interface virtual`` an in-process emulator (``RobstrideEmulator``)
answers on the same channels. Opening a channel that cannot be used raises ``BusOpenError`` with a one-line
fix (``canbus``).

This module re-exports both, so ``bar-deploy`` imports one module for the real target.
"""

from __future__ import annotations

from bar_policy.deploy.targets.real_cli import (  # noqa: F401 (re-exported: callers import them from here)
    VIRTUAL_REPLY_TIMEOUT,
    _make_target,
    add_arguments,
    installed_stop_request,
    make_target,
)
from bar_policy.deploy.targets.real_target import RealTarget

__all__ = ["RealTarget", "add_arguments", "make_target"]
