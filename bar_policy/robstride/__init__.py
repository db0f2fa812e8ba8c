"""Robstride actuators over python-can: protocol codec, bus layer, safety sequence, emulator and tools.

Layers (style.md item 15): ``framing`` + ``protocol`` (pure bytes <-> messages, host side) +
``motor_side`` (pure, what a motor sends and decodes), ``canbus`` (opening python-can buses,
``BusOpenError`` with a one-line fix), ``bus`` (one CAN interface, injected ``can.BusABC``; its values in
``bus_types``, its scan and parameter exchanges in ``bus_params``) with ``activation`` (its activation-time
checks and cap writes) and ``startup`` (``StartupControl``: stop checks, retries), ``group`` (both arms as
one flat joint list, the safety sequence; its rounds and damping-then-stop in ``rounds``), ``watchdog``
(the motors' CAN watchdog canTimeout), ``temperature`` (per-model over-temperature thresholds),
``calibration`` (homing offsets), ``emulator`` (MuJoCo-backed motors on a bus; imported on demand; its
physics in ``emulator_physics``) with ``firmware`` (one emulated motor's state and answers), ``cli_args``
and ``tools`` (``bar-bus``). Imports point one way (``tests/robstride/test_layering.py``) and never into
``bar_policy.deploy``, whose ``targets.real.RealTarget`` is the deploy target built on this package.
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
