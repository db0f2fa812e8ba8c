"""The emulated firmware of one Robstride motor: its state and its answer to one decoded request.

Pure state-machine code, no bus and no physics: ``RobstrideEmulator`` (``emulator.py``) owns the buses, the
MuJoCo model and the lockstep rounds, decodes each frame with the protocol layer, and calls these functions
with the motor's state and a reading of its joint. Answers, as the reference gives them:

- type 0 -> type-0 device-id reply with the motor's UID; type 3/4/6/18 -> type-2 feedback; type 17 -> type-17
  reply (status 1 and a zero value for an unknown index); other request types -> no reply.
- type 1 (MIT) -> the command is stored, decoded with the motor's *own* model ranges (a wrong-model motor
  misreads the host's frames as the hardware would); the emulator answers type-2 feedback, mode 2 (run) when
  enabled, 0 (reset) when not.
- Watchdog (``canTimeout``, 0x7028): an enabled motor that heard nothing for ``ticks * tick`` seconds goes to
  reset mode, exactly as after a stop frame: disabled, command cleared, zero torque, feedback mode 0.

Units: positions rad, velocities rad/s, torques N*m, temperatures degC, times s on the emulator's clock.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

from bar_policy.robot.actuators import P_MAX, robstride_spec
from bar_policy.robstride import framing, motor_side

__all__ = [
    "DEFAULT_LIMIT_CURRENT",
    "EmulatedMotor",
    "Injection",
    "JointReading",
    "apply_mit",
    "device_uid",
    "drop_reply",
    "feedback_frames",
    "handle_request",
    "power_on_params",
    "reset_mode",
    "trip_watchdog",
    "watchdog_expired",
    "watchdog_window",
]

DEFAULT_LIMIT_CURRENT = 23.0
"""Power-on limit_cur of an emulated motor, A (a placeholder: current is not modelled)."""
_ZERO_CMD = (0.0, 0.0, 0.0, 0.0, 0.0)
_JOINT_STATE_PARAMS = (0x7019, 0x701B)
"""mechPos and mechVel: read from the joint, not stored."""
_READ_ONLY_PARAMS = (0x7019, 0x701A, 0x701B, 0x701C, 0x3022)
"""Writes to these are ignored (the firmware computes or measures them)."""


@dataclass(kw_only=True)
class Injection:
    """Faults injected into one emulated motor (mutable; change through ``RobstrideEmulator.inject``)."""

    drop_replies: int = 0
    """Replies to drop from now on; -1 drops all."""
    drop_only: int | None = None
    """Communication type (``framing.CommType``) whose replies ``drop_replies`` drops; None: every reply."""
    temperature: float | None = None
    """Temperature this motor reports, degC; None: the emulator's ``temperature``."""
    fault_bits: int = 0
    """Type-2 fault flags (6 bits) reported in every feedback."""
    fault_word: int = 0
    """When non-zero, a type-21 fault frame with this word follows every feedback."""
    reply_as: int | None = None
    """Answer as this CAN id (a wrong id) instead of the own one."""
    active_reports: bool = False
    """Follow every feedback with a type-24 (0x18) active report frame."""


@dataclass(kw_only=True)
class EmulatedMotor:
    """The state of one emulated motor (mutable; the emulator's lock guards it)."""

    can_id: int
    model: str
    """Robstride model actually installed (``rs-02``, ...); scales its MIT frames and caps its torque."""
    interface: str
    """Robot CAN interface name (``can0``)."""
    name: str
    """Joint name, or ``extra<id>`` for an unknown device."""
    joint: int | None
    """Index in the robot's joint order; None for an extra device that is not attached to a joint."""
    direction: int = 1
    """Motor frame = direction * joint frame (+ offset for positions)."""
    offset: float = 0.0
    """True homing offset: raw position = direction * joint position + offset, rad."""
    enabled: bool = False
    cmd: tuple[float, float, float, float, float] = _ZERO_CMD
    """Latest MIT command as this motor decoded it: q rad, dq rad/s, kp N*m/rad, kd N*m*s/rad, tau N*m."""
    params: dict[int, float | int] = field(default_factory=dict)
    """Parameter table, index -> value (``power_on_params``)."""
    inj: Injection = field(default_factory=Injection)
    uid: bytes = b""
    """8-byte UID answered to a type-0 scan (``device_uid``)."""
    last_rx: float = 0.0
    """Arrival time of the last frame addressed to this motor, emulator clock, s."""
    watchdog_trips: list[tuple[float, float]] = field(default_factory=list)
    """(last frame, trip) times of every watchdog trip, emulator clock, s."""


@dataclass(frozen=True, kw_only=True, slots=True)
class JointReading:
    """What the motor's encoder and driver see of its joint now, joint frame (the emulator reads MuJoCo)."""

    q: float
    """Joint position, rad."""
    dq: float
    """Joint velocity, rad/s."""
    tau_raw: float
    """Torque the motor applied in the last physics step, motor frame, N*m."""


def power_on_params(model: str) -> dict[int, float | int]:
    """The parameter table of a freshly powered motor of ``model``.

    run_mode 0 (MIT), limit_torque the model's T_max N*m, limit_cur ``DEFAULT_LIMIT_CURRENT`` A, VBUS 48 V,
    iqf 0 A, EPScan_time 1, canTimeout 0 (watchdog off, the firmware default), zero_sta 0, faultSta 0.
    """
    return {
        0x7005: 0,
        0x700B: robstride_spec(model).t_max,
        0x7018: DEFAULT_LIMIT_CURRENT,
        0x701C: 48.0,
        0x701A: 0.0,
        0x7026: 1,
        0x7028: 0,
        0x7029: 0,
        0x3022: 0,
    }


def device_uid(interface: str, can_id: int) -> bytes:
    """A deterministic 8-byte UID (``RS`` tag + interface hash + id): the same on every run, for scans."""
    return struct.pack("<Q", 0x5253000000000000 | (zlib.crc32(interface.encode()) & 0xFFFF) << 8 | can_id)


def reset_mode(m: EmulatedMotor) -> None:
    """Reset mode (after a stop frame or a watchdog trip): disabled, command cleared, so zero torque."""
    m.enabled = False
    m.cmd = _ZERO_CMD


def apply_mit(m: EmulatedMotor, req: motor_side.MitRequest) -> None:
    """Store a type-1 command, decoded with the motor's own model ranges (stored even when disabled)."""
    s = req.setpoint(m.model)
    m.cmd = (s.q, s.dq, s.kp, s.kd, s.tau)


def _feedback(m: EmulatedMotor, joint: JointReading | None, temperature: float) -> framing.Frame:
    """The type-2 feedback frame; an extra device (``joint`` None) reports zeros."""
    if joint is None:
        pos = vel = tau = 0.0
    else:
        pos = m.direction * joint.q + m.offset
        pos = (pos + P_MAX) % (2 * P_MAX) - P_MAX  # the feedback wraps within +-4*pi
        vel = m.direction * joint.dq
        tau = joint.tau_raw if m.enabled else 0.0
    sender = m.inj.reply_as if m.inj.reply_as is not None else m.can_id
    return motor_side.feedback_frame(
        sender,
        m.model,
        position=pos,
        velocity=vel,
        torque=tau,
        temperature=temperature,
        mode=2 if m.enabled else 0,
        faults=m.inj.fault_bits,
    )


def feedback_frames(m: EmulatedMotor, joint: JointReading | None, temperature: float) -> list[framing.Frame]:
    """Type-2 feedback, then the injected type-21 fault frame and type-24 active report, if any.

    Args:
        m: the motor.
        joint: its joint now; None for an extra device.
        temperature: reported temperature, degC (an injected ``Injection.temperature`` replaces it).
    """
    if m.inj.temperature is not None:
        temperature = m.inj.temperature
    frames = [_feedback(m, joint, temperature)]
    if m.inj.fault_word:
        frames.append(motor_side.fault_frame(m.can_id, m.inj.fault_word))
    if m.inj.active_reports:
        report_id = framing.pack_id(framing.CommType.ACTIVE_REPORT, m.can_id, framing.HOST_ID)
        frames.append(framing.Frame(report_id, bytes(8)))
    return frames


def drop_reply(m: EmulatedMotor, comm_type: int | None = None) -> bool:
    """Whether an injected ``drop_replies`` swallows this reply; a finite count goes down by one.

    ``comm_type`` is the type of the request answered; with ``Injection.drop_only`` set, only replies to that
    type are dropped (and counted).
    """
    if not m.inj.drop_replies:
        return False
    if m.inj.drop_only is not None and comm_type != m.inj.drop_only:
        return False
    if m.inj.drop_replies > 0:
        m.inj.drop_replies -= 1
    return True


def _param_reply(m: EmulatedMotor, index: int, joint: JointReading | None) -> framing.Frame:
    """Type-17 reply; status 1 and a zero value for an index the motor does not have."""
    spec = framing.PARAMS.get(index)
    if spec is None or (index not in m.params and index not in _JOINT_STATE_PARAMS):
        return motor_side.param_reply_frame(m.can_id, index, bytes(4), status=1)
    if index in _JOINT_STATE_PARAMS and joint is not None:
        raw = joint.q if index == 0x7019 else joint.dq
        value: float | int = m.direction * raw + (m.offset if index == 0x7019 else 0.0)
    elif index == 0x3022:
        value = m.inj.fault_word
    else:
        value = m.params.get(index, 0.0)
    return motor_side.param_reply_frame(m.can_id, index, framing.encode_param_value(value, spec.dtype))


def _param_write(m: EmulatedMotor, index: int, raw: bytes) -> None:
    """Type-18 write; unknown, read-only and non-finite values are ignored (the reply is still type 2)."""
    spec = framing.PARAMS.get(index)
    if spec is None or index in _READ_ONLY_PARAMS:
        return
    value = framing.decode_param_value(raw, spec.dtype)
    if index == 0x700B:  # the firmware keeps the torque cap within the model's range
        value = min(max(float(value), 0.0), robstride_spec(m.model).t_max)
    if isinstance(value, float) and not math.isfinite(value):
        return
    m.params[index] = value


def handle_request(
    m: EmulatedMotor, req: motor_side.SimpleRequest, joint: JointReading | None, temperature: float
) -> list[framing.Frame] | None:
    """Apply a non-MIT request to ``m`` and return the firmware's reply frames; None: no reply.

    None rather than an empty list, so that a request the firmware does not answer (set id, save, baud,
    active report, protocol) never consumes an injected ``drop_replies``.

    Type 1 goes through ``apply_mit`` instead: its reply depends on the emulator's clock mode.

    Args:
        m: the addressed motor (changed in place).
        req: the decoded request.
        joint: the motor's joint now; None for an extra device.
        temperature: reported temperature, degC.
    """
    t = req.comm_type
    if t == framing.CommType.GET_ID:
        return [motor_side.device_id_reply_frame(m.inj.reply_as or m.can_id, m.uid)]
    if t == framing.CommType.ENABLE:
        m.enabled = True
    elif t == framing.CommType.STOP:
        reset_mode(m)
        if req.data[0] == 1:  # byte 0 = 1: clear faults
            m.inj.fault_bits = 0
            m.inj.fault_word = 0
    elif t == framing.CommType.SET_ZERO:
        if req.data[0] == 1 and joint is not None:  # the present position becomes raw zero
            m.offset = -m.direction * joint.q
    elif t == framing.CommType.PARAM_READ:
        return [_param_reply(m, req.index, joint)]
    elif t == framing.CommType.PARAM_WRITE:
        _param_write(m, req.index, req.value_bytes)
    else:
        return None
    return feedback_frames(m, joint, temperature)


# ---------------------------------------------------------------------------------------------------
# the watchdog (canTimeout)
# ---------------------------------------------------------------------------------------------------
def watchdog_window(m: EmulatedMotor, tick: float) -> float:
    """Watchdog window of ``m``, s (canTimeout ticks * ``tick`` s per tick); 0 when off.

    A motor without the parameter (an old firmware) has no watchdog.
    """
    return int(m.params.get(framing.PARAM_CAN_TIMEOUT, 0)) * tick


def watchdog_expired(m: EmulatedMotor, now: float, window: float) -> bool:
    """Whether ``m``, armed with ``window`` s, heard nothing for the whole window before ``now`` (s)."""
    return not now - m.last_rx < window


def trip_watchdog(m: EmulatedMotor, at: float) -> None:
    """Trip ``m``'s watchdog at time ``at`` (s): reset mode, and the trip recorded in ``watchdog_trips``."""
    reset_mode(m)
    m.watchdog_trips.append((m.last_rx, at))
