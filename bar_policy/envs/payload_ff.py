"""The deploy runtime's hand-load compensation, modelled: the payload's gravity torque as the MIT ``tau_ff``.

On the robot ``deploy.hand_load`` fits each hand's load and sends its gravity torque ``Phi(q) theta`` as
the command's feed-forward (the piano's ``tare`` reads about 0.68 of a fingertip load). With
``ModelRandomizationConfig.payload_ff_share`` the training env does the same with the model it simulates:
each episode draws a share per hand (``draw_share``), and every command carries that share of the payload
bodies' gravity torque at the state the command is sent from (``payload_feed_forward``). Without it a
policy trained on a payload learns to hold a load the deployed arm no longer feels.

For a point mass ``m_b`` at ``p_b`` on body ``b`` the torque that holds it against gravity is
``J_p(b, p_b)^T (0, 0, m_b g)`` (``J_p``: the point's translational Jacobian, ``g = -opt.gravity_z``):
what the body adds to ``qfrc_bias`` at rest. The payload bodies (``randomize.payload_scene``) are massless
until the randomiser gives them a mass, so a slot or episode without a payload feeds nothing forward.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from bar_policy.robot.perturb import HAND_BODIES

__all__ = ["draw_share", "payload_feed_forward"]

_SHARE_KEY = 0x484C46
"""Folded into an episode's reset key 3 for its share draw (no other draw's key changes)."""


def draw_share(key: jax.Array, share: tuple[float, float]) -> jax.Array:
    """An episode's feed-forward share per hand ~ U(low, high), dimensionless, shape (2,) (``HAND_BODIES``).

    ``key``: the reset's key 3 (``LiteRobotEnv._reset``); the draw uses ``fold_in(key, _SHARE_KEY)``.
    """
    k = jax.random.fold_in(key, _SHARE_KEY)
    return jax.random.uniform(k, (len(HAND_BODIES),), minval=share[0], maxval=share[1])


def payload_feed_forward(
    model: mjx.Model,
    data: mjx.Data,
    body_ids: np.ndarray,
    share: jax.Array,
    dof: np.ndarray | None,
) -> jax.Array:
    """The share of the payloads' gravity torque on the robot's joints, N*m, shape (n,) (float32).

    ``tau = sum_b share_b J_p(b)^T (0, 0, m_b g)``: ``J_p(b)`` the translational Jacobian (``mjx.jac``)
    at the body's centre of mass ``xipos[b]``, ``m_b = body_mass[b]`` of ``model`` (the slot's randomised
    model), ``g = -opt.gravity[2]`` (m/s^2). It is the torque the hand-load compensation sends as
    ``tau_ff``: with share 1 it cancels what the payloads add to the gravity torque at this pose.

    Args:
        model: the env's model (possibly randomised; unbatched).
        data: the state the command is sent from; only ``qpos`` is read (the kinematics are recomputed, so
            a reset's state, never forwarded, works too).
        body_ids: the payload bodies, shape (k,) (``randomize.payload_body_ids``).
        share: the share fed forward per payload body, dimensionless, shape (k,).
        dof: the robot joints' dof addresses (``RobotIndex.dof``), or None when the scene's dofs are
            exactly the robot's in order (``RobotIndex.robot_only``).

    Returns:
        The feed-forward per robot joint, N*m, shape (n,), canonical order.
    """
    d = mjx.com_pos(model, mjx.kinematics(model, data))
    g = -model.opt.gravity[2]
    tau = jnp.zeros(model.nv, d.qpos.dtype)
    for i, b in enumerate(body_ids):
        jacp, _ = mjx.jac(model, d, d.xipos[b], int(b))
        tau = tau + (share[i] * model.body_mass[b] * g) * jacp[:, 2]
    return tau if dof is None else tau[dof]
