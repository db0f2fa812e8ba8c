"""Robstride private CAN framing: ids, communication types, simple host frames, parameters, fault names.

Also what both sides of the wire share: ``MitSetpoint`` (one MIT command in SI units) and ``check_frame``
(an 8-byte extended frame, else ``FrameError``). Pure: no I/O, no python-can. The host side (MIT encoder,
reply decoder) is ``protocol``, which re-exports everything here; the motor side (frames a motor sends,
request decoder) is ``motor_side``. Reference: ``shared/reference/robstride-protocol.md`` sections 1, 5 and 6.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum

from bar_policy.robstride.errors import CommandError, FrameError

__all__ = [
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
    "CommType",
    "Frame",
    "MitSetpoint",
    "ParamSpec",
    "can_timeout_ticks",
    "check_can_timeout",
    "check_frame",
    "check_motor_id",
    "decode_param_value",
    "enable_frame",
    "encode_param_value",
    "fault_names",
    "fault_word_names",
    "get_id_frame",
    "pack_id",
    "param_dtype",
    "read_param_frame",
    "set_zero_frame",
    "stop_frame",
    "unpack_id",
    "write_param_frame",
]

HOST_ID = 0xFD
"""Host id this driver puts in area2 bits 15..8 (what the vendor tools use, section 1.1)."""
DEVICE_ID_REPLY_DEST = 0xFE
"""Bits 7..0 of a type-0 (device id) reply."""
_MAX_ID = 0x7F


class CommType(IntEnum):
    """Communication types (id bits 28..24) used here (section 1.3)."""

    GET_ID = 0
    MIT = 1
    FEEDBACK = 2
    ENABLE = 3
    STOP = 4
    SET_ZERO = 6
    SET_ID = 7
    PARAM_READ = 17
    PARAM_WRITE = 18
    FAULT = 21
    SAVE = 22
    BAUD = 23
    ACTIVE_REPORT = 24
    PROTOCOL = 25


MODE_NAMES: dict[int, str] = {0: "reset", 1: "calibration", 2: "run", 3: "unknown(3)"}
"""Type-2 mode state (bits 23..22) -> name; run = enabled and following commands."""

FAULT_BITS: dict[int, str] = {
    0: "undervoltage",
    1: "overcurrent",
    2: "overtemperature",
    3: "magnetic encoder fault",
    4: "stall/overload",
    5: "uncalibrated",
}
"""Type-2 fault flags: bit k of the 6-bit field = id bit 16 + k (section 6.1)."""

FAULT_WORD_BITS: dict[int, str] = {
    0: "motor overtemperature",
    1: "driver chip fault",
    2: "undervoltage",
    3: "overvoltage",
    4: "B-phase overcurrent",
    5: "C-phase overcurrent",
    7: "encoder not calibrated",
    8: "hardware identification fault",
    9: "position initialisation fault",
    14: "stall/I2t overload",
    16: "A-phase overcurrent",
}
"""Type-21 fault word (and parameter 0x3022) bits (section 6.2)."""

MIT_FIELDS: tuple[str, ...] = ("q", "dq", "kp", "kd", "tau")
"""Names of the five MIT fields, in the order clamp masks use."""


@dataclass(frozen=True, kw_only=True, slots=True)
class MitSetpoint:
    """One motor's MIT command in the motor's own frame (raw, before direction/offset)."""

    q: float
    """Target position, rad."""
    dq: float
    """Target velocity, rad/s."""
    kp: float
    """Stiffness, N*m/rad."""
    kd: float
    """Damping, N*m*s/rad."""
    tau: float
    """Feed-forward torque, N*m."""


# ---------------------------------------------------------------------------------------------------
# Ids and frames
# ---------------------------------------------------------------------------------------------------
class Frame(tuple):
    """An extended CAN data frame: ``(arbitration_id, data)``; data is 8 bytes for every frame built here."""

    __slots__ = ()

    def __new__(cls, arbitration_id: int, data: bytes) -> Frame:
        """Build a frame; ``arbitration_id`` must fit 29 bits."""
        if not 0 <= arbitration_id < (1 << 29):
            raise FrameError(f"arbitration id {arbitration_id:#x} does not fit 29 bits")
        return super().__new__(cls, (arbitration_id, bytes(data)))

    @property
    def arbitration_id(self) -> int:
        """29-bit extended id."""
        return self[0]

    @property
    def data(self) -> bytes:
        """Payload bytes."""
        return self[1]

    def __repr__(self) -> str:
        return f"Frame({self[0]:#010x}, {self[1].hex(' ')})"


def pack_id(comm_type: int, area2: int, dest: int) -> int:
    """``(type << 24) | (area2 << 8) | dest``; type 0..31, area2 0..0xFFFF, dest 0..0xFF."""
    if not (0 <= comm_type < 32 and 0 <= area2 <= 0xFFFF and 0 <= dest <= 0xFF):
        raise FrameError(f"id fields out of range: type={comm_type}, area2={area2:#x}, dest={dest:#x}")
    return (comm_type << 24) | (area2 << 8) | dest


def unpack_id(arbitration_id: int) -> tuple[int, int, int]:
    """Split a 29-bit id into ``(type, area2, dest)``."""
    return (arbitration_id >> 24) & 0x1F, (arbitration_id >> 8) & 0xFFFF, arbitration_id & 0xFF


def check_motor_id(can_id: int) -> None:
    """Raise ``CommandError`` unless ``can_id`` is a valid motor id (0..127)."""
    if not 0 <= can_id <= _MAX_ID:
        raise CommandError(f"CAN id must be in 0..127, got {can_id}")


def check_frame(arbitration_id: object, data: object, is_extended_id: bool) -> tuple[int, bytes]:
    """Validate a received frame of either direction; returns ``(id, payload)``, else ``FrameError``.

    Valid: an extended (29-bit) id and exactly 8 payload bytes (every private-protocol frame has 8).
    """
    if not is_extended_id:
        raise FrameError(f"standard (11-bit) frame id {arbitration_id!r}: not a private-protocol frame")
    if not isinstance(arbitration_id, int) or not 0 <= arbitration_id < (1 << 29):
        raise FrameError(f"arbitration id {arbitration_id!r} is not a 29-bit integer")
    try:
        payload = bytes(data)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise FrameError(f"payload {data!r} is not bytes") from exc
    if len(payload) != 8:
        raise FrameError(f"id {arbitration_id:#010x}: payload has {len(payload)} bytes, expected 8")
    return arbitration_id, payload


def _simple(comm_type: CommType, can_id: int, host_id: int, data: bytes = bytes(8)) -> Frame:
    check_motor_id(can_id)
    return Frame(pack_id(comm_type, host_id, can_id), data)


def get_id_frame(can_id: int, host_id: int = HOST_ID) -> Frame:
    """Type 0: ask ``can_id`` for its device id (answered by a type-0 frame with the 64-bit MCU id)."""
    return _simple(CommType.GET_ID, can_id, host_id)


def enable_frame(can_id: int, host_id: int = HOST_ID) -> Frame:
    """Type 3: enable (run). Answered by a type-2 frame."""
    return _simple(CommType.ENABLE, can_id, host_id)


def stop_frame(can_id: int, *, clear_faults: bool = False, host_id: int = HOST_ID) -> Frame:
    """Type 4: stop (disable); byte0 = 1 also clears latched faults. Answered by a type-2 frame."""
    return _simple(CommType.STOP, can_id, host_id, bytes([1 if clear_faults else 0]) + bytes(7))


def set_zero_frame(can_id: int, host_id: int = HOST_ID) -> Frame:
    """Type 6: make the present position the mechanical zero (byte0 = 1). Answered by a type-2 frame."""
    return _simple(CommType.SET_ZERO, can_id, host_id, b"\x01" + bytes(7))


# ---------------------------------------------------------------------------------------------------
# Parameters (types 17 and 18, section 5)
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class ParamSpec:
    """One readable/writable parameter."""

    index: int
    """Parameter index (0x70xx runtime table, 0x30xx diagnostics)."""
    name: str
    """Manual name."""
    dtype: str
    """Wire type: ``f32``, ``u8``, ``u16``, ``u32`` or ``i16`` (little-endian in bytes 4..7)."""
    unit: str = ""
    """Unit of the value."""


PARAMS: dict[int, ParamSpec] = {
    p.index: p
    for p in (
        ParamSpec(index=0x7005, name="run_mode", dtype="u8"),
        ParamSpec(index=0x7006, name="iq_ref", dtype="f32", unit="A"),
        ParamSpec(index=0x700A, name="spd_ref", dtype="f32", unit="rad/s"),
        ParamSpec(index=0x700B, name="limit_torque", dtype="f32", unit="N*m"),
        ParamSpec(index=0x7010, name="cur_kp", dtype="f32"),
        ParamSpec(index=0x7011, name="cur_ki", dtype="f32"),
        ParamSpec(index=0x7014, name="cur_filt_gain", dtype="f32"),
        ParamSpec(index=0x7016, name="loc_ref", dtype="f32", unit="rad"),
        ParamSpec(index=0x7017, name="limit_spd", dtype="f32", unit="rad/s"),
        ParamSpec(index=0x7018, name="limit_cur", dtype="f32", unit="A"),
        ParamSpec(index=0x7019, name="mechPos", dtype="f32", unit="rad"),
        ParamSpec(index=0x701A, name="iqf", dtype="f32", unit="A"),
        ParamSpec(index=0x701B, name="mechVel", dtype="f32", unit="rad/s"),
        ParamSpec(index=0x701C, name="VBUS", dtype="f32", unit="V"),
        ParamSpec(index=0x701E, name="loc_kp", dtype="f32"),
        ParamSpec(index=0x701F, name="spd_kp", dtype="f32"),
        ParamSpec(index=0x7020, name="spd_ki", dtype="f32"),
        ParamSpec(index=0x7021, name="spd_filt_gain", dtype="f32"),
        ParamSpec(index=0x7022, name="acc_rad", dtype="f32", unit="rad/s^2"),
        ParamSpec(index=0x7024, name="vel_max", dtype="f32", unit="rad/s"),
        ParamSpec(index=0x7025, name="acc_set", dtype="f32", unit="rad/s^2"),
        ParamSpec(index=0x7026, name="EPScan_time", dtype="u16"),
        ParamSpec(index=0x7028, name="canTimeout", dtype="u32", unit="50 us ticks"),
        ParamSpec(index=0x7029, name="zero_sta", dtype="u8"),
        ParamSpec(index=0x3022, name="faultSta", dtype="u32"),
    )
}
"""Known parameters by index (section 5.2). Other indexes need an explicit dtype."""

PARAM_LIMIT_TORQUE = 0x700B
"""Torque cap parameter, N*m (written at activation)."""
PARAM_LIMIT_CURRENT = 0x7018
"""Current cap parameter, A (written at activation)."""
PARAM_CAN_TIMEOUT = 0x7028
"""CAN watchdog ``canTimeout``, u32 in ``CAN_TIMEOUT_TICK`` ticks, 0 = off (written at activation)."""

CAN_TIMEOUT_TICK = 50e-6
"""One ``canTimeout`` tick, s: the manual's "20000 = 1 s" (section 5.2). kscalelabs labels the 0x200C twin in
microseconds instead (section 5.3, a conflict); ``bar-bus watchdog`` measures which one a motor uses."""
DEFAULT_CAN_TIMEOUT = 0.2
"""Default watchdog, s (4000 ticks, what s2015-turtle writes): a motor that hears nothing for 0.2 s disables
itself (reset mode), so a dead host leaves no motor on its last command for longer than that."""
CAN_TIMEOUT_MIN = 0.01
"""Shortest accepted watchdog, s: below 10 ms one late tick of a 50-100 Hz loop would disable the motors."""
CAN_TIMEOUT_MAX = 10.0
"""Longest accepted watchdog, s: a longer one protects nothing (the u32 field would allow 59 hours)."""


def check_can_timeout(seconds: float, what: str = "can_timeout") -> float:
    """Return ``seconds`` as a float if it is 0 (leave the motors' setting) or within the accepted range.

    Raises:
        ValueError: naming ``what``, the value and the valid choices (NaN, negative, out of range).
    """
    value = float(seconds)
    if value == 0.0 or CAN_TIMEOUT_MIN <= value <= CAN_TIMEOUT_MAX:
        return value
    raise ValueError(
        f"{what} must be 0 (leave the motors' watchdog setting) or "
        f"{CAN_TIMEOUT_MIN:g}..{CAN_TIMEOUT_MAX:g} s, got {seconds!r}"
    )


def can_timeout_ticks(seconds: float) -> int:
    """``canTimeout`` register value for a watchdog of ``seconds`` (nearest tick; 0 stays 0)."""
    return round(check_can_timeout(seconds) / CAN_TIMEOUT_TICK)


_DTYPES: dict[str, str] = {"f32": "<f", "u8": "<B", "u16": "<H", "u32": "<I", "i16": "<h"}


def param_dtype(index: int, dtype: str | None) -> str:
    """The wire type of a parameter: ``dtype`` if given, else the known table's."""
    if dtype is None:
        if index not in PARAMS:
            raise CommandError(
                f"parameter {index:#06x} is not in the known table; pass dtype, one of {sorted(_DTYPES)}"
            )
        dtype = PARAMS[index].dtype
    if dtype not in _DTYPES:
        raise CommandError(f"unknown parameter dtype {dtype!r}; valid: {sorted(_DTYPES)}")
    return dtype


def encode_param_value(value: float | int, dtype: str) -> bytes:
    """Value bytes 4..7 of a parameter frame (little-endian, zero padded)."""
    if dtype == "f32":
        if not math.isfinite(float(value)):
            raise CommandError(f"parameter value must be finite, got {value!r}")
        raw = struct.pack("<f", float(value))
    else:
        if float(value) != int(value):
            raise CommandError(f"{dtype} parameter value must be an integer, got {value!r}")
        try:
            raw = struct.pack(_DTYPES[dtype], int(value))
        except struct.error as exc:
            raise CommandError(f"value {value!r} does not fit {dtype}") from exc
    return raw.ljust(4, b"\x00")


def decode_param_value(raw: bytes, dtype: str) -> float | int:
    """Inverse of ``encode_param_value`` on the 4 value bytes."""
    fmt = _DTYPES[dtype]
    value = struct.unpack_from(fmt, raw, 0)[0]
    return float(value) if dtype == "f32" else int(value)


def read_param_frame(can_id: int, index: int, host_id: int = HOST_ID) -> Frame:
    """Type 17: read one parameter. Bytes 0..1 = index (LE), rest zero."""
    if not 0 <= index <= 0xFFFF:
        raise CommandError(f"parameter index must fit 16 bits, got {index:#x}")
    return _simple(CommType.PARAM_READ, can_id, host_id, struct.pack("<H", index) + bytes(6))


def write_param_frame(
    can_id: int, index: int, value: float | int, *, dtype: str | None = None, host_id: int = HOST_ID
) -> Frame:
    """Type 18: write one parameter (volatile). Bytes 0..1 index LE, 2..3 zero, 4..7 value LE."""
    if not 0 <= index <= 0xFFFF:
        raise CommandError(f"parameter index must fit 16 bits, got {index:#x}")
    data = struct.pack("<H", index) + bytes(2) + encode_param_value(value, param_dtype(index, dtype))
    return _simple(CommType.PARAM_WRITE, can_id, host_id, data)


# ---------------------------------------------------------------------------------------------------
# Names
# ---------------------------------------------------------------------------------------------------
def fault_names(bits: int) -> tuple[str, ...]:
    """Names of the set type-2 fault flags."""
    return tuple(name for k, name in FAULT_BITS.items() if bits >> k & 1)


def fault_word_names(word: int) -> tuple[str, ...]:
    """Names of the set type-21 fault-word bits (unknown bits as ``bit N``)."""
    return tuple(FAULT_WORD_BITS.get(k, f"bit {k}") for k in range(32) if word >> k & 1)
