"""Forward kinematics on the robot side with C MuJoCo (no jax): fingertips, body poses, self-collision.

The deploy runtime needs the fingertip positions for the reach observation (``fingertip_pos_left/right``);
the tracking task needs the poses of its tracked bodies along a motion clip (``motion_body_pos_b`` /
``motion_body_ori_b``). Both come from the same MJCF the env uses, so sim, real and training build their
observations from identical numbers. The chest is the fixed root at the world origin with the world's
orientation, so world coordinates are chest-frame coordinates.

A task's scene (``bar_policy.robot.scene``, ``scene=``) may add bodies and joints: poses are given as the
robot's q in canonical order and written at the robot joints' addresses (``RobotIndex``); the scene's other
joints stay at ``qpos0``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import SceneEdit, load_model
from bar_policy.signals import check_stop

__all__ = ["Kinematics", "rotation_to_6d"]


def rotation_to_6d(rot: np.ndarray) -> np.ndarray:
    """The 6-D orientation of rotation matrices: their first two columns, row-major.

    ``(r00, r01, r10, r11, r20, r21)`` (Zhou et al. 2019, as BeyondMimic's ``motion_anchor_ori_b``
    flattens ``R[..., :2]``). Shape ``(..., 3, 3) -> (..., 6)``; works on numpy and jax arrays.
    """
    return rot[..., :, :2].reshape(*rot.shape[:-2], 6)


class Kinematics:
    """Forward kinematics and collision queries of the Lite for one mode (C MuJoCo, float64)."""

    def __init__(self, mode: str = "arms", scene: SceneEdit | None = None) -> None:
        """The robot of ``mode`` in the scene ``scene`` adds to (None: the robot alone)."""
        import mujoco

        self._mujoco = mujoco
        self.model = load_model(mode, scene)
        self.data = mujoco.MjData(self.model)
        self.index = RobotIndex.from_model(self.model, load_robot(mode).joint_names)
        """Addresses of the robot's joints in the scene."""
        self._sites = [self.model.site(name).id for name in FINGERTIP_SITES]
        n = self.index.num_joints
        self._qadr = slice(0, n) if self.index.robot_only else self.index.qpos

    # -- ids ---------------------------------------------------------------------------------------
    def body_ids(self, names: Sequence[str]) -> list[int]:
        """MJCF body ids of ``names``; ``ValueError`` listing the bodies for an unknown name."""
        valid = [self.model.body(i).name for i in range(self.model.nbody)]
        unknown = [n for n in names if n not in valid]
        if unknown:
            raise ValueError(f"unknown bodies {unknown}; bodies of the MJCF: {valid}")
        return [valid.index(n) for n in names]

    def site_ids(self, names: Sequence[str]) -> list[int]:
        """MJCF site ids of ``names``; ``ValueError`` listing the sites for an unknown name."""
        valid = [self.model.site(i).name for i in range(self.model.nsite)]
        unknown = [n for n in names if n not in valid]
        if unknown:
            raise ValueError(f"unknown sites {unknown}; sites of the MJCF: {valid}")
        return [valid.index(n) for n in names]

    def _set(self, q: np.ndarray) -> None:
        q = np.asarray(q, dtype=np.float64)
        n = self.index.num_joints
        if q.shape != (n,):
            raise ValueError(f"q has shape {q.shape}, expected ({n},)")
        self.data.qpos[self._qadr] = q
        self._mujoco.mj_kinematics(self.model, self.data)

    # -- single pose -------------------------------------------------------------------------------
    def fingertips(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Left and right fingertip positions in the chest frame, m, each shape (3,).

        Args:
            q: joint positions in canonical order, rad, shape (num_joints,).
        """
        self._set(q)
        left, right = (self.data.site_xpos[i].copy() for i in self._sites)
        return left, right

    # -- along a trajectory ------------------------------------------------------------------------
    def trajectory(
        self, q: np.ndarray, bodies: Sequence[str], sites: Sequence[str] = ()
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body poses and site positions for every frame of a trajectory, chest frame.

        Args:
            q: joint positions, rad, shape (T, num_joints).
            bodies: body names (B of them).
            sites: site names (S of them).

        Returns:
            ``(body_pos (T, B, 3) m, body_rot (T, B, 3, 3), site_pos (T, S, 3) m)``, float64; ``body_rot``
            maps body coordinates to chest coordinates (MuJoCo's ``xmat``).
        """
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2:
            raise ValueError(f"q must have shape (T, {self.index.num_joints}), got {q.shape}")
        b, s = self.body_ids(bodies), self.site_ids(sites)
        pos = np.empty((len(q), len(b), 3))
        rot = np.empty((len(q), len(b), 3, 3))
        spos = np.empty((len(q), len(s), 3))
        for t, qt in enumerate(q):
            if t % 1000 == 0:
                check_stop("forward kinematics of a trajectory")  # a stop request acts within ~10 ms
            self._set(qt)
            pos[t] = self.data.xpos[b]
            rot[t] = self.data.xmat[b].reshape(-1, 3, 3)
            spos[t] = self.data.site_xpos[s]
        return pos, rot, spos

    def collision_free(self, q: np.ndarray, clearance: float = 0.0) -> bool:
        """True when no two bodies the MJCF checks are closer than ``clearance`` (m) at any frame of ``q``.

        ``q``: shape (num_joints,) or (T, num_joints), rad. The fast path of ``collisions``. The whole
        scene's geoms count (a task's bodies too, with their collision bits).
        """
        m, d, mj = self.model, self.data, self._mujoco
        q = np.asarray(q, dtype=np.float64).reshape(-1, self.index.num_joints)
        margin = m.geom_margin.copy()
        m.geom_margin[:] = clearance
        try:
            for qt in q:
                d.qpos[self._qadr] = qt
                mj.mj_kinematics(m, d)
                mj.mj_collision(m, d)
                if d.ncon:
                    return False
            return True
        finally:
            m.geom_margin[:] = margin

    def collisions(self, q: np.ndarray, clearance: float = 0.0) -> list[tuple[str, str, float]]:
        """Colliding body pairs at pose ``q``: ``(body1, body2, distance m)`` per geom pair too near.

        A pair is too near below ``clearance``, m (0: penetrating only); the MJCF's collision filter
        applies (arms vs. torso and arm vs. arm; the floor collides with nothing).
        """
        m, d = self.model, self.data
        margin = m.geom_margin.copy()
        m.geom_margin[:] = clearance
        try:
            self._set(q)
            self._mujoco.mj_collision(m, d)
            return [
                (m.body(m.geom_bodyid[c.geom1]).name, m.body(m.geom_bodyid[c.geom2]).name, float(c.dist))
                for c in d.contact[: d.ncon]
            ]
        finally:
            m.geom_margin[:] = margin
