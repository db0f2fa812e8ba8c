"""The motor side of the Robstride private CAN protocol: what firmware sends and what it receives.

Pure: no I/O, no python-can, no motor state (that is ``firmware``, the emulated motor). Used by the emulator;
the host side (MIT encoder, reply decoder) is ``protocol``, which re-exports these names. Kept apart so the
host's control path reads only what the host does, and the emulator's motor-side codec is one place.
Reference: ``shared/reference/robstride-protocol.md`` (section numbers are that file's).

- Frames a motor sends: type-2 feedback (section 3: mode bits 23..22, fault bits 21..16, motor id 15..8;
  position, velocity, torque big-endian u16 scaled to the model's ranges, temperature big-endian u16 in
  0.1 degC), type-17 parameter reply, type-0 device-id reply, type-21 fault report.
- Requests a motor decodes: type-1 MIT frames keep their raw u16 fields (``MitRequest``; the receiving
  motor scales them with its *own* model, as hardware would), anything else is a ``SimpleRequest``.
  ``decode_request`` raises only ``FrameError`` on frames it cannot interpret.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from bar_policy.robot.actuators import robstride_spec
from bar_policy.robot.mit import U16_MAX, decode_u16
from bar_policy.robstride.errors import FrameError
from bar_policy.robstride.framing import (
    DEVICE_ID_REPLY_DEST,
    HOST_ID,
    CommType,
    Frame,
    MitSetpoint,
    check_frame,
    check_motor_id,
    pack_id,
    unpack_id,
)

__all__ = [
    "MitRequest",
    "Request",
    "SimpleRequest",
    "decode_request",
    "device_id_reply_frame",
    "fault_frame",
    "feedback_frame",
    "param_reply_frame",
]


# ---------------------------------------------------------------------------------------------------
# Motor -> host frames (built by the emulator, decoded by ``protocol.decode_reply``)
# ---------------------------------------------------------------------------------------------------
def _u16(x: float, lo: float, hi: float) -> int:
    """Scalar ``encode_u16`` (same float operations, so bit-identical; tested), NaN -> 0."""
    if not math.isfinite(x):
        return 0 if math.isnan(x) or x < 0 else U16_MAX
    return int((min(max(x, lo), hi) - lo) * (U16_MAX / (hi - lo)))


def feedback_frame(
    motor_id: int,
    model: str,
    *,
    position: float,
    velocity: float,
    torque: float,
    temperature: float,
    mode: int = 2,
    faults: int = 0,
    host_id: int = HOST_ID,
) -> Frame:
    """Type 2 feedback as a motor sends it (values saturate at the model's ranges)."""
    spec = robstride_spec(model)
    check_motor_id(motor_id)
    area2 = ((mode & 0x3) << 14) | ((faults & 0x3F) << 8) | motor_id
    temp = max(0, min(U16_MAX, round(temperature * 10.0))) if math.isfinite(temperature) else 0
    data = struct.pack(
        ">HHHH",
        _u16(position, -spec.p_max, spec.p_max),
        _u16(velocity, -spec.v_max, spec.v_max),
        _u16(torque, -spec.t_max, spec.t_max),
        temp,
    )
    return Frame(pack_id(CommType.FEEDBACK, area2, host_id), data)


def param_reply_frame(
    motor_id: int, index: int, value: bytes, *, status: int = 0, host_id: int = HOST_ID
) -> Frame:
    """Type 17 reply: status in bits 23..16, index LE in bytes 0..1, value bytes 4..7."""
    area2 = ((status & 0xFF) << 8) | motor_id
    return Frame(
        pack_id(CommType.PARAM_READ, area2, host_id), struct.pack("<H", index) + bytes(2) + value[:4]
    )


def device_id_reply_frame(motor_id: int, uid: bytes) -> Frame:
    """Type 0 reply: motor id in bits 15..8, 0xFE in bits 7..0, 64-bit MCU id as payload."""
    return Frame(pack_id(CommType.GET_ID, motor_id, DEVICE_ID_REPLY_DEST), bytes(uid[:8]).ljust(8, b"\0"))


def fault_frame(motor_id: int, fault_word: int, warning_word: int = 0, *, host_id: int = HOST_ID) -> Frame:
    """Type 21 fault report: LE u32 fault word, LE u32 warning word."""
    return Frame(
        pack_id(CommType.FAULT, motor_id, host_id),
        struct.pack("<II", fault_word & 0xFFFFFFFF, warning_word & 0xFFFFFFFF),
    )


# ---------------------------------------------------------------------------------------------------
# Decoded requests (what a motor, i.e. the emulator, receives)
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class MitRequest:
    """A type-1 frame as received: raw 16-bit fields (scaling needs the receiving motor's model)."""

    motor_id: int
    """Addressed CAN id."""
    raw: tuple[int, int, int, int, int]
    """u16 of q, dq, kp, kd, tau (``MIT_FIELDS`` order)."""

    def setpoint(self, model: str) -> MitSetpoint:
        """The command as a motor of ``model`` decodes it (official ``uint_to_float``)."""
        s = robstride_spec(model)
        q, dq, kp, kd, tau = self.raw
        return MitSetpoint(
            q=float(decode_u16(q, -s.p_max, s.p_max)),
            dq=float(decode_u16(dq, -s.v_max, s.v_max)),
            kp=float(decode_u16(kp, 0.0, s.kp_max)),
            kd=float(decode_u16(kd, 0.0, s.kd_max)),
            tau=float(decode_u16(tau, -s.t_max, s.t_max)),
        )


@dataclass(frozen=True, kw_only=True, slots=True)
class SimpleRequest:
    """Any other host -> motor frame: type, addressed id, host id and payload."""

    comm_type: CommType
    """Communication type."""
    motor_id: int
    """Addressed CAN id (bits 7..0)."""
    host_id: int
    """Sender host id (bits 15..8)."""
    data: bytes
    """Payload."""

    @property
    def index(self) -> int:
        """Parameter index (types 17/18)."""
        return struct.unpack_from("<H", self.data, 0)[0]

    @property
    def value_bytes(self) -> bytes:
        """Parameter value bytes 4..7 (type 18)."""
        return self.data[4:8]


Request = MitRequest | SimpleRequest
"""Anything ``decode_request`` returns."""

_REQUEST_TYPES = frozenset(
    {
        CommType.GET_ID,
        CommType.ENABLE,
        CommType.STOP,
        CommType.SET_ZERO,
        CommType.SET_ID,
        CommType.PARAM_READ,
        CommType.PARAM_WRITE,
        CommType.SAVE,
        CommType.BAUD,
        CommType.ACTIVE_REPORT,
        CommType.PROTOCOL,
    }
)


def decode_request(arbitration_id: int, data: bytes, *, is_extended_id: bool = True) -> Request:
    """Decode a host -> motor frame; raises ``FrameError`` for anything else."""
    arbitration_id, payload = check_frame(arbitration_id, data, is_extended_id)
    comm, area2, dest = unpack_id(arbitration_id)
    if comm == CommType.MIT:
        q, dq, kp, kd = struct.unpack(">HHHH", payload)
        return MitRequest(motor_id=dest, raw=(q, dq, kp, kd, area2))
    if comm == CommType.GET_ID and dest == DEVICE_ID_REPLY_DEST:
        raise FrameError(f"type-0 frame {arbitration_id:#010x} is a device-id reply, not a request")
    if comm in _REQUEST_TYPES:
        return SimpleRequest(comm_type=CommType(comm), motor_id=dest, host_id=area2 & 0xFF, data=payload)
    raise FrameError(f"id {arbitration_id:#010x}: communication type {comm} is not a host request")
