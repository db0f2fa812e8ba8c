"""The Robstride actuator model inside the MJX env: latency, gain scaling, wire quantisation, torque cap.

Per control step the policy action becomes an MIT command ``(q_cmd, dq_cmd = 0, Kp, Kd, tau_ff)`` (tau_ff
0, or the modelled hand-load compensation: ``payload_ff``); per physics substep the motor applies
``bar_policy.robot.mit.firmware_torque`` to the *measured* joint state (true q plus the per-episode encoder
offset). The 16-bit wire quantisation of the command is done once per control step (``quantize_command``),
because the command is constant over the substeps; the substeps then call ``firmware_torque(...,
quantize_wire=False)``. This is arithmetically identical to quantising inside every substep and saves ten
quantisations per control step.

Each effect is switchable through ``ActuatorConfig`` (bar_policy.envs.robot_config).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from bar_policy.envs.device_arrays import to_device
from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.mit import MitCommand, WireRanges, firmware_torque, quantize_command, wire_ranges

__all__ = [
    "ActuatorParams",
    "apply_latency",
    "implicit_damping",
    "make_command",
    "motor_torque",
    "robot_force",
]


@dataclass(frozen=True)
class ActuatorParams:
    """Per-joint constant arrays of the actuator model (float32, shape ``(n,)`` each)."""

    kp: jax.Array
    """Nominal Kp, N*m/rad."""
    kd: jax.Array
    """Nominal Kd, N*m*s/rad."""
    tau_cap: jax.Array
    """Torque the law is clipped to, N*m (firmware cap, or +inf with saturation off)."""
    ranges: WireRanges
    """16-bit MIT wire ranges (float32 arrays)."""
    quantize_wire: bool
    """Whether the command goes through the 16-bit encoding."""

    @classmethod
    def from_robot(cls, robot: RobotSpec, *, quantize_wire: bool, torque_saturation: bool) -> ActuatorParams:
        """Build from the robot data; ``torque_saturation=False`` leaves the law unclipped."""
        f32 = lambda x: to_device(x, np.float32)  # noqa: E731
        cap = robot.torque_cap if torque_saturation else np.full(robot.num_joints, np.inf)
        r = wire_ranges(robot.models)
        return cls(
            kp=f32(robot.kp),
            kd=f32(robot.kd),
            tau_cap=f32(cap),
            ranges=WireRanges(*(np.asarray(x, dtype=np.float32) for x in r)),
            quantize_wire=quantize_wire,
        )


def apply_latency(buffer: jax.Array, action: jax.Array, latency: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Push ``action`` into the action buffer and return ``(new_buffer, delayed_action)``.

    Args:
        buffer: past actions, newest first, shape ``(max_latency + 1, n)``.
        action: the new action, shape ``(n,)``.
        latency: control steps of delay for this episode, int32 scalar in ``[0, max_latency]``.

    Returns:
        The buffer with ``action`` at index 0, and ``new_buffer[latency]`` (the action issued ``latency``
        control steps ago; 0 gives ``action`` itself).
    """
    new = jnp.concatenate([action[None], buffer[:-1]], axis=0)
    return new, new[latency]


def make_command(
    q_cmd: jax.Array,
    kp: jax.Array,
    kd: jax.Array,
    params: ActuatorParams,
    tau_ff: jax.Array | None = None,
) -> MitCommand:
    """The MIT command the firmware decodes: ``(q_cmd, 0, kp, kd, tau_ff)``, quantised when enabled.

    Shapes: ``(n,)`` each (q_cmd in rad, kp in N*m/rad, kd in N*m*s/rad, tau_ff in N*m). ``tau_ff`` None:
    0 (the policy's command alone); given, it goes through the wire's 16-bit torque field like the others.
    """
    z = jnp.zeros_like(q_cmd)
    cmd = MitCommand(q=q_cmd, dq=z, kp=kp, kd=kd, tau_ff=z if tau_ff is None else tau_ff)
    if params.quantize_wire:
        cmd = quantize_command(cmd, params.ranges)
    return cmd


def motor_torque(
    cmd: MitCommand,
    q_meas: jax.Array,
    dq: jax.Array,
    params: ActuatorParams,
    strength: jax.Array | None = None,
) -> jax.Array:
    """Torque applied by the motors for an already wire-decoded ``cmd``: MIT law clipped to the cap.

    ``q_meas``: measured positions (true q + encoder offset), rad; ``dq``: velocities, rad/s; shape (n,).
    ``strength``: per-joint factor on the produced torque, shape (n,) (``ActuatorConfig.strength``): the
    result is ``strength * clip(law, cap)``, i.e. the torque and its cap both scaled; None: 1 (no multiply,
    bit for bit the unscaled law). Returns N*m, shape (n,).
    """
    tau = firmware_torque(cmd, q_meas, dq, params.ranges, params.tau_cap, quantize_wire=False)
    return tau if strength is None else strength * tau


def robot_force(tau: jax.Array, dof: np.ndarray | None, nv: int) -> jax.Array:
    """A generalised force of the whole scene from the robot's joint torques.

    Args:
        tau: torque per robot joint, N*m, shape (n,).
        dof: the robot joints' dof addresses (``RobotIndex.dof``), or None when the scene's dofs are exactly
            the robot's in order (``RobotIndex.robot_only``): then ``tau`` itself is returned.
        nv: the scene's dof count.

    Returns:
        Shape (nv,): ``tau`` at the robot's dofs, 0 on every other dof.
    """
    return tau if dof is None else jnp.zeros(nv, tau.dtype).at[dof].set(tau)


def implicit_damping(
    model: mjx.Model,
    kd: jax.Array,
    tau: jax.Array,
    dq: jax.Array,
    tau_cap: jax.Array,
    dof: np.ndarray | None = None,
) -> tuple[mjx.Model, jax.Array]:
    """Let Euler integrate the law's damping implicitly without changing the applied torque.

    MuJoCo's Euler integrator (C and MJX) solves ``(M + h D) dv = h f`` with ``D = dof_damping``, and the
    passive force already contains ``-D dq``. Setting ``D = Kd`` on unsaturated joints and applying
    ``tau + D dq`` through ``qfrc_applied`` keeps the force at time t exactly the firmware torque ``tau``
    while the velocity update becomes ``(M + h Kd) v' = M v + h (Kp e + ...)``: the MIT damping term is
    integrated implicitly, which is unconditionally stable for it. Saturated joints (``|tau| = cap``) get
    no implicit damping, because their torque does not depend on dq. Any MJCF joint damping is kept, and
    the scene's other dofs keep theirs and get no force.

    Args:
        model: the model of this env (possibly randomised).
        kd: the decoded Kd per joint, N*m*s/rad, shape (n,).
        tau: the firmware torque, N*m, shape (n,).
        dq: joint velocities, rad/s, shape (n,).
        tau_cap: the torque cap, N*m, shape (n,) (+inf when saturation is off).
        dof: the robot joints' dof addresses in the model, shape (n,); None when the model's dofs are the
            robot's joints in order and nothing else (``RobotIndex.robot_only``).

    Returns:
        ``(model with dof_damping = MJCF damping + D at the robot's dofs, qfrc_applied (nv,) = tau + D * dq
        at the robot's dofs and 0 elsewhere)``.
    """
    d_law = jnp.where(jnp.abs(tau) < tau_cap, kd, 0.0)
    qfrc = tau + d_law * dq
    if dof is None:
        return model.replace(dof_damping=model.dof_damping + d_law), qfrc
    damping = model.dof_damping.at[dof].add(d_law)
    return model.replace(dof_damping=damping), robot_force(qfrc, dof, model.nv)
