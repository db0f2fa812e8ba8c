"""Robstride private CAN protocol, host side: MIT encoding and reply decoding. Pure: no I/O, no python-can.

Reference: ``shared/reference/robstride-protocol.md`` (section numbers below are that file's).

- 29-bit extended id: ``(type << 24) | (area2 << 8) | dest`` (section 1.2). Host -> motor frames carry the
  host id in area2 bits 15..8 and the motor id in bits 7..0; replies carry the motor id in bits 15..8.
- MIT / operation control (type 1, section 2): torque u16 in id bits 23..8; position, velocity, Kp, Kd
  big-endian u16 in the payload. Encoded with the official truncating ``float_to_uint``
  (``bar_policy.robot.mit.encode_u16``) and the manual ranges of ``ROBSTRIDE_MODELS`` (P_max = 4*pi).
  Out-of-range fields are clamped *and reported* (the encoders return which fields were clamped, the bus
  counts them in a ``ClampCounter``); non-finite fields raise ``CommandError``.
- Feedback (type 2, section 3): mode bits 23..22, fault bits 21..16, motor id 15..8; position, velocity,
  torque big-endian u16, temperature big-endian u16 in 0.1 degC.
- Enable 3, stop 4 (byte0 = 1 clears faults), set zero 6, get id 0, parameter read 17 / write 18 (LE index
  and value), fault frame 21 (LE fault and warning words), active report 24 (tolerated, ignored).

Decoders raise only ``FrameError`` on frames they cannot interpret, whatever the input. Ids, simple host
frames, parameters and fault names live in ``framing``; the motor side (frames a motor sends, decoding of
host requests: what firmware does, used by the emulator) lives in ``motor_side``. Both are re-exported
here, so ``protocol`` stays the one import for the whole codec.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from bar_policy.robot.actuators import P_MAX, ROBSTRIDE_MODELS
from bar_policy.robot.mit import U16_MAX, WireRanges, encode_u16, wire_ranges
from bar_policy.robstride.errors import CommandError, FrameError
from bar_policy.robstride.framing import (
    CAN_TIMEOUT_MAX,
    CAN_TIMEOUT_MIN,
    CAN_TIMEOUT_TICK,
    DEFAULT_CAN_TIMEOUT,
    DEVICE_ID_REPLY_DEST,
    FAULT_BITS,
    FAULT_WORD_BITS,
    HOST_ID,
    MIT_FIELDS,
    MODE_NAMES,
    PARAM_CAN_TIMEOUT,
    PARAM_LIMIT_CURRENT,
    PARAM_LIMIT_TORQUE,
    PARAMS,
    CommType,
    Frame,
    MitSetpoint,
    ParamSpec,
    can_timeout_ticks,
    check_can_timeout,
    check_frame,
    check_motor_id,
    decode_param_value,
    enable_frame,
    encode_param_value,
    fault_names,
    fault_word_names,
    get_id_frame,
    pack_id,
    param_dtype,
    read_param_frame,
    set_zero_frame,
    stop_frame,
    unpack_id,
    write_param_frame,
)
from bar_policy.robstride.motor_side import (
    MitRequest,
    Request,
    SimpleRequest,
    _u16,  # noqa: F401 - re-exported for tests/robstride/test_protocol.py (bit-identical to encode_u16)
    decode_request,
    device_id_reply_frame,
    fault_frame,
    feedback_frame,
    param_reply_frame,
)

__all__ = [
    # re-exported from ``framing`` and ``motor_side``
    "CAN_TIMEOUT_MAX",
    "CAN_TIMEOUT_MIN",
    "CAN_TIMEOUT_TICK",
    "DEFAULT_CAN_TIMEOUT",
    "DEVICE_ID_REPLY_DEST",
    "FAULT_BITS",
    "FAULT_WORD_BITS",
    "HOST_ID",
    "MIT_FIELDS",
    "MODE_NAMES",
    "PARAMS",
    "PARAM_CAN_TIMEOUT",
    "PARAM_LIMIT_CURRENT",
    "PARAM_LIMIT_TORQUE",
    "ActiveReport",
    "ClampCounter",
    "CommType",
    "CommandError",
    "DeviceIdReply",
    "FaultReport",
    "Feedback",
    "Frame",
    "FrameError",
    "MitRequest",
    "MitSetpoint",
    "ParamReply",
    "ParamSpec",
    "Reply",
    "Request",
    "SimpleRequest",
    "can_timeout_ticks",
    "check_can_timeout",
    "check_frame",
    "decode_param_value",
    "decode_reply",
    "decode_request",
    "device_id_reply_frame",
    "enable_frame",
    "encode_mit",
    "encode_mit_batch",
    "encode_param_value",
    "fault_frame",
    "fault_names",
    "fault_word_names",
    "feedback_frame",
    "field_bounds",
    "get_id_frame",
    "pack_id",
    "param_reply_frame",
    "read_param_frame",
    "set_zero_frame",
    "stop_frame",
    "unpack_id",
    "wire_ranges",
    "write_param_frame",
]


# ---------------------------------------------------------------------------------------------------
# MIT (type 1)
# ---------------------------------------------------------------------------------------------------
@dataclass
class ClampCounter:
    """Counts deliberately clamped MIT fields, per field and per CAN id (never a silent clamp)."""

    by_field: dict[str, int] = field(default_factory=lambda: dict.fromkeys(MIT_FIELDS, 0))
    """Field name -> number of clamped values."""
    by_id: dict[int, int] = field(default_factory=dict)
    """CAN id -> number of clamped values."""

    @property
    def total(self) -> int:
        """Total clamped values."""
        return sum(self.by_field.values())

    def add(self, can_id: int, fields: Sequence[str]) -> None:
        """Record the clamped ``fields`` of one frame for ``can_id``."""
        for name in fields:
            self.by_field[name] += 1
        if fields:
            self.by_id[can_id] = self.by_id.get(can_id, 0) + len(fields)


def field_bounds(ranges: WireRanges) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds, shape (5, n), in ``MIT_FIELDS`` order."""
    zero = np.zeros_like(ranges.kp_max)
    lo = np.stack([-ranges.p_max, -ranges.v_max, zero, zero, -ranges.t_max])
    hi = np.stack([ranges.p_max, ranges.v_max, ranges.kp_max, ranges.kd_max, ranges.t_max])
    return lo, hi


_PACK_MIT = struct.Struct(">HHHH").pack


def encode_mit_batch(
    can_ids: Sequence[int],
    ranges: WireRanges,
    values: np.ndarray,
    *,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[list[Frame], np.ndarray]:
    """Encode n MIT frames at once.

    Args:
        can_ids: motor ids, length n.
        ranges: per-motor wire ranges (``wire_ranges(models)``), each shape (n,).
        values: shape (5, n): q (rad), dq (rad/s), kp, kd, tau (N*m) in ``MIT_FIELDS`` order, motor frame.
        bounds: ``field_bounds(ranges)``, precomputed by callers on a hot path.

    Returns:
        The frames, and a bool mask of shape (5, n) of the fields that were clamped to their range.

    Raises:
        CommandError: a field is NaN or infinite (naming the field and id), or shapes and ids are invalid.
    """
    values = np.asarray(values, dtype=np.float64)
    n = len(can_ids)
    if values.shape != (5, n):
        raise CommandError(f"MIT values must have shape (5, {n}), got {values.shape}")
    if not np.isfinite(values).all():
        f, j = np.argwhere(~np.isfinite(values))[0]
        raise CommandError(
            f"non-finite MIT {MIT_FIELDS[f]}={float(values[f, j])} for CAN id {can_ids[j]}; nothing was sent"
        )
    for can_id in can_ids:
        check_motor_id(can_id)
    lo, hi = bounds if bounds is not None else field_bounds(ranges)
    clamped = (values < lo) | (values > hi)
    uq, udq, ukp, ukd, utau = encode_u16(values, lo, hi).astype(np.int64).tolist()
    new = tuple.__new__
    frames = [
        new(Frame, ((0x01 << 24) | (utau[j] << 8) | can_id, _PACK_MIT(uq[j], udq[j], ukp[j], ukd[j])))
        for j, can_id in enumerate(can_ids)
    ]
    return frames, clamped


def encode_mit(can_id: int, model: str, cmd: MitSetpoint) -> tuple[Frame, tuple[str, ...]]:
    """Encode one MIT frame for a motor of ``model``; returns the frame and the names of clamped fields."""
    values = np.array([[cmd.q], [cmd.dq], [cmd.kp], [cmd.kd], [cmd.tau]])
    frames, clamped = encode_mit_batch([can_id], wire_ranges([model]), values)
    return frames[0], tuple(MIT_FIELDS[f] for f in range(5) if clamped[f, 0])


# ---------------------------------------------------------------------------------------------------
# Decoded replies
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True, slots=True)
class Feedback:
    """A decoded type-2 frame, in the motor's own frame."""

    motor_id: int
    """Sender CAN id (bits 15..8)."""
    host_id: int
    """Bits 7..0."""
    mode: int
    """Mode state, bits 23..22: 0 reset, 1 calibration, 2 run."""
    faults: int
    """Fault flags, bits 21..16 as a 6-bit number (``FAULT_BITS``)."""
    position: float
    """Position, rad (+-4*pi, model independent)."""
    velocity: float
    """Velocity, rad/s; NaN when the sender's model is unknown."""
    torque: float
    """Torque, N*m; NaN when the sender's model is unknown."""
    temperature: float
    """Temperature, degC."""
    model: str | None
    """Model used to scale velocity and torque."""


@dataclass(frozen=True, kw_only=True, slots=True)
class ParamReply:
    """A decoded type-17 reply."""

    motor_id: int
    """Sender CAN id."""
    index: int
    """Parameter index."""
    status: int
    """0 = success, non-zero = failure (unknown index)."""
    raw: bytes
    """The 4 value bytes (LE)."""

    def value(self, dtype: str | None = None) -> float | int:
        """The value as ``dtype`` (default: the table's type for known indexes)."""
        return decode_param_value(self.raw, param_dtype(self.index, dtype))


@dataclass(frozen=True, kw_only=True, slots=True)
class DeviceIdReply:
    """A decoded type-0 reply."""

    motor_id: int
    """Sender CAN id."""
    uid: bytes
    """64-bit MCU unique id."""


@dataclass(frozen=True, kw_only=True, slots=True)
class FaultReport:
    """A decoded type-21 fault frame."""

    motor_id: int
    """Sender CAN id."""
    fault_word: int
    """Fault bits (``FAULT_WORD_BITS``)."""
    warning_word: int
    """Warning bits (bit 0: overtemperature warning)."""


@dataclass(frozen=True, kw_only=True, slots=True)
class ActiveReport:
    """A type-24 (0x18) active report: tolerated and ignored (payload layout uncertain, section 1.3)."""

    motor_id: int
    """Sender CAN id (bits 15..8)."""


_UNPACK_FB = struct.Struct(">HHHH").unpack
_P_SCALE = 2 * P_MAX / U16_MAX
# model -> (velocity LSB, V_max, torque LSB, T_max): the official uint_to_float, u * (hi - lo) / 65535 + lo
_FB_SCALE = {
    m: (2 * s.v_max / U16_MAX, s.v_max, 2 * s.t_max / U16_MAX, s.t_max) for m, s in ROBSTRIDE_MODELS.items()
}

Reply = Feedback | ParamReply | DeviceIdReply | FaultReport | ActiveReport
"""Anything ``decode_reply`` returns."""


def decode_reply(
    arbitration_id: int,
    data: bytes,
    *,
    is_extended_id: bool = True,
    models: Mapping[int, str] | None = None,
) -> Reply:
    """Decode a motor -> host frame.

    Args:
        arbitration_id: the 29-bit id.
        data: the payload (8 bytes).
        is_extended_id: False for 11-bit frames (rejected).
        models: CAN id -> model, used to scale type-2 velocity and torque.

    Raises:
        FrameError: the frame is not a motor -> host private-protocol frame this driver understands.
    """
    arbitration_id, payload = check_frame(arbitration_id, data, is_extended_id)
    comm, area2, dest = unpack_id(arbitration_id)
    motor_id = area2 & 0xFF
    if comm == CommType.FEEDBACK:
        p, v, t, temp = _UNPACK_FB(payload)
        model = models.get(motor_id) if models else None
        scale = _FB_SCALE.get(model) if model is not None else None
        return Feedback(
            motor_id=motor_id,
            host_id=dest,
            mode=(area2 >> 14) & 0x3,
            faults=(area2 >> 8) & 0x3F,
            position=p * _P_SCALE - P_MAX,
            velocity=v * scale[0] - scale[1] if scale else math.nan,
            torque=t * scale[2] - scale[3] if scale else math.nan,
            temperature=temp / 10.0,
            model=model if scale else None,
        )
    if comm == CommType.PARAM_READ:
        index = struct.unpack_from("<H", payload, 0)[0]
        return ParamReply(motor_id=motor_id, index=index, status=area2 >> 8, raw=payload[4:8])
    if comm == CommType.GET_ID:
        if dest != DEVICE_ID_REPLY_DEST:
            raise FrameError(f"type-0 frame {arbitration_id:#010x} is a request, not a reply (dest != 0xFE)")
        return DeviceIdReply(motor_id=motor_id, uid=payload)
    if comm == CommType.FAULT:
        fw, ww = struct.unpack("<II", payload)
        return FaultReport(motor_id=motor_id, fault_word=fw, warning_word=ww)
    if comm == CommType.ACTIVE_REPORT:
        return ActiveReport(motor_id=motor_id)
    raise FrameError(f"id {arbitration_id:#010x}: communication type {comm} is not a motor reply")
