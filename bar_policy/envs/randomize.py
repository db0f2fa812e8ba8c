"""Model-level domain randomisation: a pure ``(mjx_model, rng) -> (batched_model, in_axes)``.

Brax PPO calls the randomiser once at the start of training with one key per env slot (``rng`` shape
``(num_envs, 2)``); each slot then keeps its randomised model for the whole run, while the episode-level
effects (latency, Kp/Kd scale, encoder offset, observation noise, initial pose, targets) are sampled at
every reset by the env itself. The randomiser reads only the robot part of a config (``RobotEnvConfig``:
``mode`` and ``randomization``), so it is the same for every task. ``in_axes`` has the model's structure
with ``0`` on the randomised fields and ``None`` elsewhere, for ``jax.vmap(..., in_axes=(in_axes, 0))``.

In a task's scene (``bar_policy.robot.scene``) armature and friction are drawn for the robot's joints and
written at their dof addresses (``RobotIndex``, read from the model by name); the scene's other dofs keep
theirs. The link-mass factor applies to every body of the scene.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np
from mujoco import mjx

from bar_policy.envs.robot_config import RobotEnvConfig
from bar_policy.robot.actuators import ROBSTRIDE_MODELS
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex

__all__ = ["armature_bounds", "make_randomizer"]

Randomizer = Callable[[mjx.Model, jax.Array], tuple[mjx.Model, mjx.Model]]


def armature_bounds(mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint armature range ``(description, identified)``, kg*m^2, shape (n,) each.

    The identified value is the motor model's ``armature_identified`` (robstride-protocol.md section 8:
    rs-00 0.0149, rs-02 0.01369, rs-05 0.00678); a model without an identification keeps its description
    value (zero-width range). The range is ordered (low <= high) whichever is larger.
    """
    robot = load_robot(mode)
    desc = robot.armature
    ident = np.array(
        [ROBSTRIDE_MODELS[m].armature_identified or d for m, d in zip(robot.models, desc, strict=True)]
    )
    return np.minimum(desc, ident), np.maximum(desc, ident)


def make_randomizer(config: RobotEnvConfig) -> Randomizer:
    """The randomiser for any task's ``config`` (its ``randomization`` field and ``mode``).

    Returns:
        ``domain_randomize(model, rng)``: ``rng`` is a batch of keys, shape ``(B, 2)``; returns the model
        with the randomised fields given a leading axis B, and the matching ``in_axes`` tree.
    """
    rc = config.randomization
    arm_lo, arm_hi = (x.astype(np.float32) for x in armature_bounds(config.mode))
    joint_names = load_robot(config.mode).joint_names

    def domain_randomize(model: mjx.Model, rng: jax.Array) -> tuple[mjx.Model, mjx.Model]:
        if rng.ndim != 2 or rng.shape[-1] != 2:
            raise ValueError(f"rng must be a batch of keys, shape (B, 2); got shape {rng.shape}")
        index = RobotIndex.from_model(model, joint_names)

        def robot_dofs(field: jax.Array, values: jax.Array) -> jax.Array:
            """``field`` (nv,) with ``values`` (n,) at the robot's dofs (``values`` itself, robot alone)."""
            return values if index.robot_only else field.at[index.dof].set(values)

        def one(key: jax.Array) -> dict[str, jax.Array]:
            k_arm, k_fric, k_mass = jax.random.split(key, 3)
            out = {}
            if rc.armature:
                # Armature: U(description, identified) per joint (up to 7.4x for rs-00).
                arm = jax.random.uniform(k_arm, arm_lo.shape, minval=arm_lo, maxval=arm_hi)
                out["dof_armature"] = robot_dofs(model.dof_armature, arm)
            if rc.frictionloss is not None:
                # Joint Coulomb friction: U(frictionloss) per joint, N*m (MJCF 0.1, identified 0.16-0.31).
                lo, hi = rc.frictionloss
                fric = jax.random.uniform(k_fric, (index.num_joints,), minval=lo, maxval=hi)
                out["dof_frictionloss"] = robot_dofs(model.dof_frictionloss, fric)
            if rc.link_mass_scale is not None:
                # Link mass and inertia: *U(link_mass_scale) per body (same factor: density scaling).
                lo, hi = rc.link_mass_scale
                s = jax.random.uniform(k_mass, model.body_mass.shape, minval=lo, maxval=hi)
                out["body_mass"] = model.body_mass * s
                out["body_inertia"] = model.body_inertia * s[:, None]
            return out

        fields = jax.vmap(one)(rng)
        in_axes = jax.tree.map(lambda _: None, model)
        in_axes = in_axes.tree_replace(dict.fromkeys(fields, 0))
        return model.tree_replace(fields), in_axes

    return domain_randomize
