"""The MIT torque law, once, for numpy and jax alike; and the Robstride 16-bit wire quantisation.

``tau = Kp * (q_cmd - q) + Kd * (dq_cmd - dq) + tau_ff``, clipped to the joint's torque cap. This is what
the Robstride firmware computes on the motor, what mujoco_ros2_control's MujocoSystem writes to
``qfrc_applied``, and what our MJX env, C MuJoCo sim target and bus emulator apply. The functions are plain
array arithmetic: called with numpy arrays they return numpy, called with jax arrays (inside jit / vmap,
batched or not) they return jax, so sim, deploy and training share the exact same expression.

The wire quantiser reproduces the official ``float_to_uint`` of the Robstride manuals (section 4.4):
clamp to [lo, hi], then truncate ``(x - lo) * 65535 / (hi - lo)``; the firmware decodes
``u * (hi - lo) / 65535 + lo``. Position/velocity/torque are symmetric ranges, Kp/Kd are [0, max].
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from bar_policy._array import Array
from bar_policy._array import array_namespace as _xp
from bar_policy.robot.actuators import robstride_spec

__all__ = [
    "U16_MAX",
    "MitCommand",
    "WireRanges",
    "clip_effort",
    "decode_u16",
    "encode_u16",
    "firmware_torque",
    "mit_torque",
    "quantize",
    "quantize_command",
    "wire_ranges",
]

U16_MAX = 65535
"""Largest value of a 16-bit MIT field."""


class MitCommand(NamedTuple):
    """The five MIT command fields of every joint. Each field has shape ``(..., num_joints)``.

    A NamedTuple, hence a jax pytree: it passes through ``jit``/``vmap``/``lax.scan`` unchanged.
    """

    q: Array
    """Target position q_cmd, rad."""
    dq: Array
    """Target velocity dq_cmd, rad/s."""
    kp: Array
    """Stiffness Kp, N*m/rad."""
    kd: Array
    """Damping Kd, N*m*s/rad."""
    tau_ff: Array
    """Feed-forward torque, N*m."""

    @classmethod
    def zero_torque(cls, n: int) -> MitCommand:
        """Everything 0: "alive but inert" (ZeroTorqueController)."""
        z = np.zeros(n)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy())

    @classmethod
    def damping(cls, q: Array, kd: Array | float) -> MitCommand:
        """Kp = 0, Kd > 0, q_cmd = captured q: the compliant fail-safe (DampingController)."""
        q = np.asarray(q, dtype=np.float64)
        z = np.zeros_like(q)
        return cls(q.copy(), z, z.copy(), np.broadcast_to(kd, q.shape).astype(np.float64), z.copy())

    @classmethod
    def position(cls, q: Array, kp: Array, kd: Array) -> MitCommand:
        """Impedance control around ``q`` (dq_cmd = 0, tau_ff = 0)."""
        q = np.asarray(q, dtype=np.float64)
        z = np.zeros_like(q)
        return cls(
            q.copy(),
            z,
            np.broadcast_to(kp, q.shape).astype(np.float64),
            np.broadcast_to(kd, q.shape).astype(np.float64),
            z.copy(),
        )


def clip_effort(tau: Array, tau_max: Array) -> Array:
    """Clip torques to +-tau_max (the firmware torque cap), elementwise. Shapes broadcast."""
    xp = _xp(tau, tau_max)
    return xp.clip(tau, -tau_max, tau_max)


def mit_torque(cmd: MitCommand, q: Array, dq: Array, tau_max: Array | None = None) -> Array:
    """The MIT law: ``Kp (q_cmd - q) + Kd (dq_cmd - dq) + tau_ff``, optionally clipped to ``+-tau_max``.

    Args:
        cmd: the five command fields, each shape ``(..., n)``.
        q: measured joint positions, rad, shape ``(..., n)``.
        dq: measured joint velocities, rad/s, shape ``(..., n)``.
        tau_max: torque cap, N*m, shape ``(n,)`` or broadcastable; None leaves the torque unclipped.

    Returns:
        Joint torques, N*m, shape ``(..., n)``; numpy for numpy inputs, jax for jax inputs.
    """
    tau = cmd.kp * (cmd.q - q) + cmd.kd * (cmd.dq - dq) + cmd.tau_ff
    if tau_max is None:
        return tau
    return clip_effort(tau, tau_max)


def encode_u16(x: Array, lo: Array, hi: Array) -> Array:
    """Official ``float_to_uint``: clamp to [lo, hi], truncate to 0..65535. Returns floats holding integers.

    Non-finite input must be rejected before this point (the codec does); NaN would propagate here.
    """
    xp = _xp(x, lo, hi)
    span = hi - lo
    return xp.floor((xp.clip(x, lo, hi) - lo) * (U16_MAX / span))


def decode_u16(u: Array, lo: Array, hi: Array) -> Array:
    """Official ``uint_to_float``: ``u * (hi - lo) / 65535 + lo``."""
    return u * ((hi - lo) / U16_MAX) + lo


def quantize(x: Array, lo: Array, hi: Array) -> Array:
    """What the firmware decodes when the host encodes ``x``: ``decode(encode(x))``."""
    return decode_u16(encode_u16(x, lo, hi), lo, hi)


class WireRanges(NamedTuple):
    """Per-joint MIT ranges, each shape ``(num_joints,)``: +-p, +-v, +-t, [0, kp], [0, kd]."""

    p_max: np.ndarray
    v_max: np.ndarray
    t_max: np.ndarray
    kp_max: np.ndarray
    kd_max: np.ndarray


def wire_ranges(models: Sequence[str]) -> WireRanges:
    """Per-joint wire ranges of a list of Robstride models (e.g. ``RobotSpec.models``)."""
    specs = [robstride_spec(m) for m in models]
    return WireRanges(
        p_max=np.array([s.p_max for s in specs]),
        v_max=np.array([s.v_max for s in specs]),
        t_max=np.array([s.t_max for s in specs]),
        kp_max=np.array([s.kp_max for s in specs]),
        kd_max=np.array([s.kd_max for s in specs]),
    )


def quantize_command(cmd: MitCommand, ranges: WireRanges) -> MitCommand:
    """The command exactly as the firmware receives it after 16-bit encoding of each field.

    Out-of-range fields saturate at the range ends, as the official encoder clamps; the CAN codec counts and
    logs such clamps before encoding, this function models only the arithmetic.
    """
    zero = 0.0 * ranges.kp_max
    return MitCommand(
        q=quantize(cmd.q, -ranges.p_max, ranges.p_max),
        dq=quantize(cmd.dq, -ranges.v_max, ranges.v_max),
        kp=quantize(cmd.kp, zero, ranges.kp_max),
        kd=quantize(cmd.kd, zero, ranges.kd_max),
        tau_ff=quantize(cmd.tau_ff, -ranges.t_max, ranges.t_max),
    )


def firmware_torque(
    cmd: MitCommand,
    q: Array,
    dq: Array,
    ranges: WireRanges,
    tau_cap: Array,
    *,
    quantize_wire: bool = True,
) -> Array:
    """The torque a Robstride motor applies for ``cmd``: 16-bit wire quantisation, MIT law, torque cap.

    This is the one actuator model shared by the MJX env (jax), the C MuJoCo sim target and the CAN bus
    emulator (numpy).

    Args:
        cmd: commanded fields, each shape ``(..., n)``.
        q: joint positions, rad, shape ``(..., n)``.
        dq: joint velocities, rad/s, shape ``(..., n)``.
        ranges: per-joint wire ranges (``wire_ranges(robot.models)``).
        tau_cap: firmware torque cap per joint, N*m, shape ``(n,)`` (``RobotSpec.torque_cap``).
        quantize_wire: apply the 16-bit encoding of every field (True on every faithful path).

    Returns:
        Applied torque, N*m, shape ``(..., n)``.
    """
    if quantize_wire:
        cmd = quantize_command(cmd, ranges)
    return mit_torque(cmd, q, dq, tau_cap)
