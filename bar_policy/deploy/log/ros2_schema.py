"""ROS 2 ``sensor_msgs/msg/JointState`` for the run log: its ``ros2msg`` schema text and its CDR bytes.

The MCAP run log writes the joint states in this well-known message so that ROS 2 tools read them without a
ROS install (``mcap_ros2.decoder``, rosbags, Foxglove, PlotJuggler): schema encoding ``ros2msg`` (the
concatenated message definitions, as rosbag2 writes them), message encoding ``cdr`` (little-endian XCDR1,
what ROS 2's default middleware puts on the wire). The encoder is a few lines of ``struct``/numpy, so the
robot computer needs no ROS 2 library; a test decodes its bytes with ``mcap_ros2``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

__all__ = ["JOINT_STATE_SCHEMA", "JOINT_STATE_TYPE", "encode_joint_state"]

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
"""The MCAP schema name of the joint-state channels (the ROS 2 type name)."""

JOINT_STATE_SCHEMA = """\
# This is a message that holds data to describe the state of a set of torque controlled joints.
std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
"""``ros2msg`` text of ``sensor_msgs/msg/JointState`` with its dependencies (rosbag2's concatenated form)."""

_CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: CDR, little endian, no options


class _Cdr:
    """Little-endian CDR body; alignment is relative to the end of the 4-byte encapsulation header."""

    def __init__(self) -> None:
        self.parts: list[bytes] = [_CDR_LE]
        self.n = 0  # bytes after the header

    def _align(self, size: int) -> None:
        pad = -self.n % size
        if pad:
            self.parts.append(b"\x00" * pad)
            self.n += pad

    def put(self, fmt: str, *values: int | float, size: int) -> None:
        self._align(size)
        data = struct.pack("<" + fmt, *values)
        self.parts.append(data)
        self.n += len(data)

    def string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.put("I", len(data), size=4)
        self.parts.append(data)
        self.n += len(data)

    def float64s(self, values: np.ndarray) -> None:
        self.put("I", len(values), size=4)
        if len(values):  # CDR aligns the elements, not the (empty) sequence
            self._align(8)
            data = np.ascontiguousarray(values, dtype="<f8").tobytes()
            self.parts.append(data)
            self.n += len(data)


def encode_joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: np.ndarray | Sequence[float] = (),
    velocity: np.ndarray | Sequence[float] = (),
    effort: np.ndarray | Sequence[float] = (),
    frame_id: str = "",
) -> bytes:
    """One ``sensor_msgs/msg/JointState`` as CDR bytes (the MCAP message data of a ``cdr`` channel).

    Args:
        stamp_ns: ``header.stamp``, ns since the epoch (split into ``sec`` and ``nanosec``; >= 0).
        names: joint names, shape (n,).
        position: rad, shape (n,) or empty (the message's convention for "not given").
        velocity: rad/s, shape (n,) or empty.
        effort: N*m, shape (n,) or empty.
        frame_id: ``header.frame_id`` (empty: joint states have no frame).

    The floats are written bit for bit (NaN stays NaN), so a decoder returns exactly the logged values.
    """
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    w = _Cdr()
    w.put("iI", sec, nanosec, size=4)
    w.string(frame_id)
    w.put("I", len(names), size=4)
    for name in names:
        w.string(name)
    for values in (position, velocity, effort):
        w.float64s(np.asarray(values, dtype=np.float64).reshape(-1))
    return b"".join(w.parts)
