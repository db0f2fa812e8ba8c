"""Where the robot's joints live in a compiled scene: qpos, qvel (dof) and actuator addresses by name.

A scene (``bar_policy.robot.scene``) may hold joints besides the robot's (a task's piano keys, a door, a
free object), anywhere in the kinematic tree, so ``data.qpos[:n]`` is the robot's q only for the robot
alone. ``RobotIndex`` reads the addresses of the robot's joints from the compiled model by name, in the
canonical joint order (``RobotSpec.joint_names``, the order of every observation and action), and every
side (the MJX env, the sim target, the emulator, ``Kinematics``) reads and writes the robot's state through
it. For the robot alone the addresses are ``0 .. n-1`` and ``robot_only`` is True, so code may keep the
plain arrays there (no gather, bit-identical numerics).

numpy only; works on a ``mujoco.MjModel`` and on an ``mjx.Model`` alike (both carry ``names``, the
``name_*adr`` and the address arrays as numpy).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

__all__ = ["RobotIndex", "model_names"]

_HINGE, _SLIDE = 3, 2  # mjtJoint values: 1-dof joints
_TRN_JOINT = 0  # mjtTrn.mjTRN_JOINT


def model_names(model: Any, adr: np.ndarray) -> list[str]:
    """Names of a model's objects of one type, by id, from ``model.names`` and their ``name_*adr``.

    ``adr``: e.g. ``model.name_jntadr``, shape (count,). An unnamed object gives ``""``.
    """
    buf: bytes = model.names
    return [buf[a : buf.index(b"\0", a)].decode() for a in np.asarray(adr, dtype=np.int64)]


def _readonly(values: Sequence[int]) -> np.ndarray:
    arr = np.array(values, dtype=np.int64)
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class RobotIndex:
    """Addresses of the robot's joints in one compiled scene, in the canonical joint order.

    Build it with ``RobotIndex.from_model(model, robot.joint_names)``. Index arrays are int64, shape (n,),
    read-only (static: safe to index jax arrays with at trace time).
    """

    joint_names: tuple[str, ...]
    """The robot's joints, canonical order (n of them)."""
    joint: np.ndarray
    """Joint ids (``model.jnt_*`` rows)."""
    qpos: np.ndarray
    """Addresses in ``qpos`` (``jnt_qposadr``): ``q = data.qpos[qpos]``, rad."""
    dof: np.ndarray
    """Addresses in ``qvel``, ``qfrc_*`` and ``dof_*`` (``jnt_dofadr``): ``dq = data.qvel[dof]``, rad/s."""
    actuator: np.ndarray
    """Ids of the actuators named after each joint and driving it (``ctrl``, ``actuator_*`` rows)."""
    nq: int
    """The scene's ``nq`` (robot and everything else)."""
    nv: int
    """The scene's ``nv``."""

    @classmethod
    def from_model(cls, model: Any, joint_names: Sequence[str]) -> RobotIndex:
        """Find ``joint_names`` (1-dof joints, each driven by an actuator of its name) in ``model``.

        ``model``: a compiled ``mujoco.MjModel`` or an ``mjx.Model``.

        Raises:
            ValueError: a joint is missing, not a hinge or slide, or lacks its actuator (the message
                lists what the model has).
        """
        jnames = model_names(model, model.name_jntadr)
        missing = [n for n in joint_names if n not in jnames]
        if missing:
            raise ValueError(f"the scene lacks the robot's joints {missing}; its joints: {jnames}")
        joint = [jnames.index(n) for n in joint_names]
        jtype = np.asarray(model.jnt_type)
        multi = [n for n, j in zip(joint_names, joint, strict=True) if jtype[j] not in (_HINGE, _SLIDE)]
        if multi:
            raise ValueError(f"robot joints {multi} must be hinge or slide joints (1 dof each)")
        anames = model_names(model, model.name_actuatoradr)
        trntype, trnid = np.asarray(model.actuator_trntype), np.asarray(model.actuator_trnid)
        actuator = []
        for n, j in zip(joint_names, joint, strict=True):
            ok = [
                a for a, an in enumerate(anames) if an == n and trntype[a] == _TRN_JOINT and trnid[a, 0] == j
            ]
            if not ok:
                raise ValueError(f"no actuator named {n!r} drives joint {n!r}; actuators: {anames}")
            actuator.append(ok[0])
        qposadr, dofadr = np.asarray(model.jnt_qposadr), np.asarray(model.jnt_dofadr)
        return cls(
            joint_names=tuple(joint_names),
            joint=_readonly(joint),
            qpos=_readonly([qposadr[j] for j in joint]),
            dof=_readonly([dofadr[j] for j in joint]),
            actuator=_readonly(actuator),
            nq=int(model.nq),
            nv=int(model.nv),
        )

    @property
    def num_joints(self) -> int:
        """n, the robot's joint count."""
        return len(self.joint_names)

    @cached_property
    def robot_only(self) -> bool:
        """True when the scene's coordinates are exactly the robot's, in order (qpos = q, qvel = dq)."""
        n = self.num_joints
        ramp = np.arange(n)
        return self.nq == self.nv == n and np.array_equal(self.qpos, ramp) and np.array_equal(self.dof, ramp)

    def q(self, qpos: Any) -> Any:
        """The robot's joint positions from a scene's ``qpos`` (..., nq) -> (..., n), rad (numpy or jax)."""
        return qpos if self.robot_only else qpos[..., self.qpos]

    def dq(self, qvel: Any) -> Any:
        """The robot's joint velocities from a scene's ``qvel`` (..., nv) -> (..., n), rad/s."""
        return qvel if self.robot_only else qvel[..., self.dof]
