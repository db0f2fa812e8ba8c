"""What ``bar-deploy`` does with a stop signal that arrives before its stop path is installed.

The stop path itself (SIGINT, SIGTERM and SIGHUP -> one flag: ``StopSignals``) is ``bar_policy.signals``,
shared with ``bar-bus``. Before ``StopSignals`` is installed (imports, argument parsing, loading the policy
and the commands) a signal is a ``KeyboardInterrupt`` (SIGINT by Python; SIGTERM and SIGHUP by the handlers
the console entry point ``bar_policy.entry`` installs before any heavy import), which ``main`` and the entry
point catch and end quietly, without a traceback: ``early_interrupt`` (defined in ``bar_policy._early_stop``,
standard library only, so the entry point can use it before numpy is imported).
"""

from __future__ import annotations

from bar_policy._early_stop import INTERRUPT_STATUS, EarlyStop, early_interrupt, signal_name_of

__all__ = ["INTERRUPT_STATUS", "EarlyStop", "early_interrupt", "signal_name_of"]
