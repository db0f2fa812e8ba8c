"""Which keys each fingertip reaches: damped least-squares IK on the keyboard scene (C MuJoCo, no jax).

``sweep`` decides the keyboard's span (``keyboard.LEFT_REACH`` / ``RIGHT_REACH``, docs/piano.md): a key
counts as reachable by a hand when IK puts that hand's fingertip sphere on the key's aim point (the
``piano_key{m}_top`` site, sphere resting on the key top) *and* at the same point pressed to the bottom of
the key's travel, each within ``tol`` with the joints inside their limits and:

- no contact among the robot's own geoms (the model's collision filter: arm-torso, arm-arm);
- no arm geom inside the keyboard's body (a box under the keys, from 3 mm below the white key tops down to
  10 cm below, over the keys' depth and span plus 5 cm each side): a real keyboard stops the palm and
  wrist, which the simulated keys do not (they touch fingertips only);
- the finger points away from the robot (its direction has x > 0), as a pianist's does.

The other arm stays at ``piano_ready``. Keys are swept outward from the key under the fingertip at
``piano_ready``, each IK starting from the previous key's solution, and a hand's range ends at its first
failure. IK moves one arm's 7 joints (``solve``), with a null-space pull toward ``piano_ready``.
"""

from __future__ import annotations

import mujoco
import numpy as np

from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.links import COLLISION_BITS
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.keyboard import Key, KeyboardConfig, default_config, key_table
from bar_policy.tasks.piano.scene import keyboard_scene

__all__ = ["HANDS", "TILTS", "ReachChecker", "sweep"]

HANDS: tuple[str, str] = ("left", "right")
"""Hand names, in ``FINGERTIP_SITES`` order."""
TILTS: tuple[float, ...] = (0.0, 0.35, 0.7, 1.05)
"""Finger tilts below horizontal that IK tries in turn, rad (0, 20, 40 and 60 degrees)."""
_CASE = "piano_reach_case"
_CASE_BELOW = 0.012  # m: the case's top below the white key tops (the key bed: travel + 2 mm)
_CASE_DEPTH = 0.10  # m
_CASE_SIDE = 0.05  # m beyond the lowest and highest key


class ReachChecker:
    """IK and the reach tests above, on the keyboard scene plus the check-only keyboard case."""

    def __init__(self, config: KeyboardConfig | None = None) -> None:
        """Build the check model for ``config`` (default: ``default_config()``)."""
        self.config = cfg = default_config() if config is None else config
        self.keys = key_table(cfg)
        keyboard = keyboard_scene(cfg)
        ys = [k.y for k in self.keys]

        def scene(spec: mujoco.MjSpec) -> None:
            keyboard(spec)
            half_y = (max(ys) - min(ys)) / 2 + cfg.white_pitch / 2 + _CASE_SIDE
            spec.worldbody.add_geom(
                name=_CASE,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[cfg.white_length / 2, half_y, _CASE_DEPTH / 2],
                pos=[
                    cfg.front_x + cfg.white_length / 2,
                    (max(ys) + min(ys)) / 2,
                    cfg.top_z - _CASE_BELOW - _CASE_DEPTH / 2,
                ],
                contype=0,
                conaffinity=COLLISION_BITS["left"][0] | COLLISION_BITS["right"][0],
            )

        self.model = load_model("arms", scene)
        self.data = mujoco.MjData(self.model)
        robot = load_robot("arms")
        self.index = RobotIndex.from_model(self.model, robot.joint_names)
        self.q_ready = robot.pose("piano_ready")
        self.lower, self.upper = robot.lower, robot.upper
        self._sites = [self.model.site(s).id for s in FINGERTIP_SITES]
        self._case = self.model.geom(_CASE).id
        names = [self.model.geom(i).name for i in range(self.model.ngeom)]
        self._task_geom = np.array([n.startswith("piano_") for n in names])
        self._task_geom[self._case] = False

    def _arm(self, hand: str) -> np.ndarray:
        return np.arange(7) if hand == "left" else np.arange(7, 14)

    def fingertip(self, q: np.ndarray, hand: str) -> np.ndarray:
        """Fingertip site of ``hand`` at robot pose ``q`` (14,), chest frame, m, shape (3,)."""
        self.data.qpos[self.index.qpos] = q
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self._sites[HANDS.index(hand)]].copy()

    def solve(
        self,
        hand: str,
        target: np.ndarray,
        q0: np.ndarray,
        tilt: float = 0.0,
        iters: int = 300,
        damping: float = 0.02,
        posture: np.ndarray | None = None,
    ) -> tuple[np.ndarray, float]:
        """Move ``hand``'s 7 joints from ``q0`` (14,) to put its fingertip site on ``target`` (3,), m.

        Damped least squares with joint clipping; in its null space, the finger turns toward pointing
        forward (+x) and ``tilt`` rad down, and the joints are pulled weakly toward ``posture`` (14,)
        (default ``piano_ready``).
        Returns the pose (14,), rad, and the remaining position error, m.
        """
        m, d = self.model, self.data
        arm = self._arm(hand)
        dof = self.index.dof[arm]
        site = self._sites[HANDS.index(hand)]
        q = np.array(q0, dtype=np.float64)
        jac, jac_r = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        body = m.body(f"{hand}_hand").id
        sign = 1.0 if hand == "left" else -1.0  # the finger is the hand's +y (left) or -y (right)
        aim = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
        rest = self.q_ready if posture is None else np.asarray(posture, dtype=np.float64)
        err = np.inf
        for _ in range(iters):
            d.qpos[self.index.qpos] = q
            mujoco.mj_kinematics(m, d)
            e = target - d.site_xpos[site]
            err = float(np.linalg.norm(e))
            if err < 1e-5:
                break
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jac, jac_r, site)
            J, Jr = jac[:, dof], jac_r[:, dof]
            JJt = J @ J.T + damping**2 * np.eye(3)
            step = J.T @ np.linalg.solve(JJt, e)
            null = np.eye(7) - J.T @ np.linalg.solve(JJt, J)
            finger = sign * d.xmat[body].reshape(3, 3)[:, 1]
            turn = np.cross(finger, aim)  # angular velocity turning the finger onto ``aim``
            second = Jr.T @ np.linalg.solve(Jr @ Jr.T + damping * np.eye(3), turn)
            step += null @ (0.5 * second + 0.05 * (rest[arm] - q[arm]))
            q[arm] = np.clip(q[arm] + np.clip(step, -0.2, 0.2), self.lower[arm], self.upper[arm])
        return q, err

    def valid(self, q: np.ndarray, hand: str) -> bool:
        """True when pose ``q`` (14,) passes the tests above (self-contact, keyboard case, finger forward)."""
        m, d = self.model, self.data
        d.qpos[self.index.qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        for c in d.contact[: d.ncon]:
            if not (self._task_geom[c.geom1] or self._task_geom[c.geom2]):
                return False  # robot-robot or arm-case
        body = m.body(f"{hand}_hand").id
        finger = d.xmat[body].reshape(3, 3)[:, 1] * (1.0 if hand == "left" else -1.0)
        return bool(finger[0] > 0.0)

    def reach(self, key: Key, hand: str, q0: np.ndarray, tol: float = 0.002) -> np.ndarray | None:
        """A pose (14,) with ``hand``'s fingertip on ``key`` at rest and fully pressed, or None."""
        r = self.config.fingertip_radius
        x, y, z = key.site
        lever_at_site = key.lever - self.config.press_depth
        down = lever_at_site * key.angle_max  # drop of the aim point at full travel, m
        for start, tilt in ((s, t) for s in (q0, self.q_ready) for t in TILTS):
            q, ok = start, True
            for dz in (r - down, r):
                q, err = self.solve(hand, np.array([x, y, z + dz]), q, tilt)
                ok = ok and err <= tol and self.valid(q, hand)
            if ok:
                return q
        return None


def sweep(config: KeyboardConfig | None = None) -> dict[str, tuple[int, int]]:
    """MIDI range ``(lowest, highest)`` each hand reaches, swept outward from its ``piano_ready`` key.

    The keyboard of ``config`` should be wider than the reach (the sweep stops at its ends too).
    """
    checker = ReachChecker(config)
    keys = checker.keys
    out: dict[str, tuple[int, int]] = {}
    for hand in HANDS:
        tip = checker.fingertip(checker.q_ready, hand)
        whites = [k for k in keys if not k.black]
        start = min(whites, key=lambda k: abs(k.y - tip[1])).index
        ends = []
        for direction in (-1, 1):
            q, last = checker.q_ready, keys[start].midi
            i = start
            while 0 <= i < len(keys):
                found = checker.reach(keys[i], hand, q)
                if found is None:
                    break
                q, last = found, keys[i].midi
                i += direction
            ends.append(last)
        out[hand] = (ends[0], ends[1])
    return out
