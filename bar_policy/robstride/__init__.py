"""Robstride actuators over python-can: protocol codec, bus layer, safety sequence, emulator and tools.

Layers (style.md item 15): ``framing`` + ``protocol`` (pure bytes <-> messages, host side) +
``motor_side`` (pure, what a motor sends and decodes), ``canbus`` (opening python-can buses,
``BusOpenError`` with a one-line fix), ``bus`` (one CAN interface, injected ``can.BusABC``) with
``activation`` (its activation-time checks and cap writes; ``StartupControl``: stop checks, retries),
``group`` (both arms as one flat joint list, activation and damping-then-stop), ``watchdog`` (the motors'
CAN watchdog canTimeout), ``temperature`` (per-model over-temperature thresholds), ``calibration``
(homing offsets), ``emulator`` (MuJoCo-backed motors on a bus; imported on demand) with ``firmware`` (one
emulated motor's state and answers), ``tools`` (``bar-bus``). The deploy target is
``bar_policy.deploy.targets.real.RealTarget``.
"""

from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.bus_types import BusReading, MotorConfig
from bar_policy.robstride.calibration import Calibration, JointCalibration, homing_offset
from bar_policy.robstride.canbus import open_can_bus
from bar_policy.robstride.errors import (
    BusOpenError,
    CommandError,
    DisabledError,
    FaultError,
    FrameError,
    InitializationError,
    OperationError,
    RobstrideError,
    StopRequestedError,
    TimeoutError,
    UnexpectedDeviceError,
)
from bar_policy.robstride.group import RobstrideGroup

__all__ = [
    "BusOpenError",
    "BusReading",
    "Calibration",
    "CommandError",
    "DisabledError",
    "FaultError",
    "FrameError",
    "InitializationError",
    "JointCalibration",
    "MotorConfig",
    "OperationError",
    "RobstrideBus",
    "RobstrideError",
    "RobstrideGroup",
    "StopRequestedError",
    "TimeoutError",
    "UnexpectedDeviceError",
    "homing_offset",
    "open_can_bus",
]
