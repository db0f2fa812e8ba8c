"""The bus layer's values: ``MotorConfig``, ``BusReading`` and the deadlines.

``MotorConfig`` is one motor on a bus, with its joint mapping; ``BusReading`` the joint-frame state of one
round; ``DEFAULT_REPLY_TIMEOUT`` and ``DEFAULT_PARAM_TIMEOUT`` the deadlines of a round and of a parameter
exchange.

Deadline: the default 3 ms covers the worst-case wire time of one round on a 1 Mbit/s bus with 7 motors
(7 commands + 7 replies, 160 bits each with worst-case stuffing: 14 * 160 us = 2.24 ms) plus motor latency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bar_policy.robot.actuators import robstride_spec
from bar_policy.robstride import protocol as proto

__all__ = ["DEFAULT_PARAM_TIMEOUT", "DEFAULT_REPLY_TIMEOUT", "BusReading", "MotorConfig"]

DEFAULT_REPLY_TIMEOUT = 0.003
"""Reply deadline of one round, s (see the module docstring)."""
DEFAULT_PARAM_TIMEOUT = 0.05
"""Shortest deadline of a parameter exchange, s (lerobot waits 20 ms for reads; section 7)."""


@dataclass(frozen=True, kw_only=True)
class MotorConfig:
    """One motor on a bus, with its joint mapping."""

    name: str
    """Joint name."""
    can_id: int
    """CAN id, 1..127."""
    model: str
    """Robstride model key (``rs-00`` ..)."""
    direction: int = 1
    """+1 or -1: joint = direction * (raw - homing_offset)."""
    homing_offset: float = 0.0
    """Raw position at joint zero, rad (per robot, from the calibration file)."""
    torque_limit: float = 0.0
    """Torque cap written to 0x700B at activation, N*m; 0 skips the write."""
    current_limit: float = 0.0
    """Current cap written to 0x7018 at activation, A; 0 skips the write."""
    can_timeout: float = proto.DEFAULT_CAN_TIMEOUT
    """CAN watchdog written to canTimeout (0x7028) at activation, s: the motor disables itself when no frame
    reaches it for this long. 0 skips the write (the motor keeps its own setting). See ``watchdog``."""

    def __post_init__(self) -> None:
        robstride_spec(self.model)
        proto.check_can_timeout(self.can_timeout, f"{self.name}: can_timeout")
        if self.direction not in (-1, 1):
            raise ValueError(f"{self.name}: direction must be +1 or -1, got {self.direction!r}")
        if not 0 < self.can_id < 128:
            raise ValueError(f"{self.name}: CAN id must be in 1..127, got {self.can_id}")


@dataclass(frozen=True, kw_only=True)
class BusReading:
    """Joint-frame state of the motors of one bus. Arrays have shape (num_motors,); NaN where missing."""

    q: np.ndarray
    """Positions, rad."""
    dq: np.ndarray
    """Velocities, rad/s."""
    tau: np.ndarray
    """Torques, N*m."""
    temperature: np.ndarray
    """Temperatures, degC."""
    mode: np.ndarray
    """Mode state per motor (0 reset, 1 calibration, 2 run; -1 no reply)."""
    faults: np.ndarray
    """Type-2 fault bits per motor (0 = healthy)."""
    stamp: float
    """``time.monotonic()`` when the round completed, s."""
