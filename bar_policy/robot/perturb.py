"""A ``Perturbation`` applied to the robot: the model edits (MjSpec), the motors' part, and the pushes.

Three seams, one per place a perturbation lives:

- the MuJoCo model (``perturbed_scene``: a ``SceneEdit`` that runs the task's own scene edit, then scales
  the arm links' masses and inertias, adds a payload body on each hand, adds friction and damping and
  scales the armature of the arm joints). The sim target and the emulator build their model from it, so
  both simulate the same perturbed robot;
- the motors (``MotorPerturbation``: per-joint strength and encoder offset, the two delays), which the sim
  target and the emulator apply around the one actuator model (``mit.firmware_torque``);
- the pushes (``Pusher``: ``xfrc_applied`` on the hand bodies, scheduled on the physics clock).

No jax, no torch: the deploy side imports it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from bar_policy.robot import links
from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.perturb_spec import Perturbation, arm_joint_mask
from bar_policy.robot.scene import SceneEdit

__all__ = [
    "ARM_BODIES",
    "ARM_JOINTS",
    "HAND_BODIES",
    "PAYLOAD_POS",
    "PUSH_DURATION_S",
    "PUSH_INTERVAL_S",
    "MotorPerturbation",
    "Pusher",
    "apply_to_spec",
    "payload_body_name",
    "perturbed_scene",
]

ARM_BODIES: tuple[str, ...] = tuple(link.name for link in (*links.LEFT_ARM, *links.RIGHT_ARM))
"""The arm links whose mass and inertia ``mass_scale`` scales (shoulder to hand, both arms)."""
ARM_JOINTS: tuple[str, ...] = tuple(links.JOINT_OF_BODY.get(name, name) for name in ARM_BODIES)
"""The arm joints (each link's joint), left arm then right, shoulder to wrist: those friction, damping and
armature change (a task's scene may hold joints of its own: they are not the robot's)."""
HAND_BODIES: tuple[str, str] = ("left_hand", "right_hand")
"""The bodies that carry the payload and take the pushes."""


def _palm(capsule: links.Capsule) -> tuple[float, float, float]:
    a, b = np.asarray(capsule.fromto[:3]), np.asarray(capsule.fromto[3:])
    return tuple(float(x) for x in (a + b) / 2)  # type: ignore[return-value]


PAYLOAD_POS: dict[str, dict[str, tuple[float, float, float]]] = {
    "fingertip": {
        "left_hand": links.FINGERTIP_SITE_POS["left_finger2_tip"],
        "right_hand": links.FINGERTIP_SITE_POS["right_finger2_tip"],
    },
    "palm": {"left_hand": _palm(links.LEFT_COLLIDERS[2]), "right_hand": _palm(links.RIGHT_COLLIDERS[2])},
}
"""Payload position in each hand's frame, m: the fingertip site, or the palm collider's centre (the
3.5 cm capsule across the hand)."""

PAYLOAD_RADIUS = 0.01
"""The payload's inertia is a solid sphere of this radius, m (``2/5 m r^2``): a point mass to the arm,
with an inertia MuJoCo accepts."""

PUSH_DURATION_S = 0.1
"""How long each push lasts, s."""
PUSH_INTERVAL_S = (1.0, 3.0)
"""Time from one push's start to the next, s, uniform in this range."""


def payload_body_name(hand: str) -> str:
    """The payload body's name on ``hand``."""
    return f"{hand}_payload"


def apply_to_spec(spec: mujoco.MjSpec, p: Perturbation) -> None:
    """Edit the robot's spec in place: link masses and inertias, payloads, arm joints' friction and more.

    Friction and damping are added to each arm joint's own (``frictionloss``, ``damping``), the armature
    and the links' masses and full inertias multiplied. The payload is a child body of each hand at
    ``PAYLOAD_POS[p.payload_at]`` with ``p.payload_kg`` and a 1 cm sphere's inertia, no geom (it touches
    nothing). ``~`` draws follow ``Perturbation.values``: per link in ``ARM_BODIES`` order for the mass,
    per joint in ``ARM_JOINTS`` order for the rest.
    """
    masses = p.values("mass_scale", len(ARM_BODIES))
    for name, s in zip(ARM_BODIES, masses, strict=True):
        body = spec.body(name)
        body.mass = body.mass * s
        body.fullinertia = np.asarray(body.fullinertia) * s
    joints = [spec.joint(name) for name in ARM_JOINTS]
    fr = p.values("friction_nm", len(joints))
    dp = p.values("damping", len(joints))
    ar = p.values("armature_scale", len(joints))
    for j, f, d, a in zip(joints, fr, dp, ar, strict=True):
        j.frictionloss = j.frictionloss + f
        # MuJoCo 3.17's joint damping is [linear, then the polynomial's higher-order terms]: the key adds to
        # the linear term only (adding to all three made the force d (v + v|v| + v^3): 14 N*m at 2 rad/s).
        damping = np.array(j.damping, dtype=np.float64)
        damping[0] += d
        j.damping = damping
        j.armature = j.armature * a
    if p.payload_kg > 0:
        m = p.payload_kg
        i = 0.4 * m * PAYLOAD_RADIUS**2
        for hand in HAND_BODIES:
            body = spec.body(hand).add_body(name=payload_body_name(hand), pos=PAYLOAD_POS[p.payload_at][hand])
            body.explicitinertial = True
            body.mass = m
            body.ipos = [0.0, 0.0, 0.0]
            body.fullinertia = [i, i, i, 0.0, 0.0, 0.0]


def perturbed_scene(p: Perturbation, scene: SceneEdit | None = None) -> SceneEdit | None:
    """The scene edit of the perturbed robot: ``scene`` (a task's additions, or None) then ``apply_to_spec``.

    Returns ``scene`` itself when ``p`` leaves the model as it is.
    """
    if not p.changes_model:
        return scene

    def edit(spec: mujoco.MjSpec) -> None:
        if scene is not None:
            scene(spec)
        apply_to_spec(spec, p)

    return edit


@dataclass(frozen=True)
class MotorPerturbation:
    """The motors' side of a perturbation, per joint in canonical order."""

    strength: np.ndarray
    """Factor on the produced torque and its cap, shape (n,)."""
    offset: np.ndarray
    """Encoder offset, rad, joint frame, shape (n,): the measured q is ``q + offset``."""
    action_delay_ticks: int
    obs_delay_ticks: int

    @classmethod
    def of(cls, p: Perturbation, robot: RobotSpec) -> MotorPerturbation:
        """Per-joint values for ``robot``'s joints (the arm joints only; others keep 1 and 0)."""
        arm = arm_joint_mask([j.group for j in robot.joints])
        n_arm = int(arm.sum())
        strength = np.ones(robot.num_joints)
        offset = np.zeros(robot.num_joints)
        strength[arm] = p.values("strength", n_arm)
        offset[arm] = p.values("offset_rad", n_arm)
        return cls(strength, offset, p.action_delay_ticks, p.obs_delay_ticks)


class Pusher:
    """Pushes on the hands through ``xfrc_applied``: ``force_n`` newtons for 0.1 s every 1-3 s.

    The schedule lives on the physics clock (``data.time``): the first push starts 1-3 s after t = 0,
    each next one 1-3 s after the previous one's start; during a push each hand gets its own random unit
    direction, the force at the hand body's centre of mass. Seeded: two simulations (the sim target and the
    emulator) stepped through the same times push the same way.
    """

    def __init__(
        self, model: mujoco.MjModel, force_n: float, seed: int, hands: Sequence[str] = HAND_BODIES
    ) -> None:
        self.force_n = float(force_n)
        self.seed = seed
        self.bodies = np.array([model.body(h).id for h in hands])
        self.pushes = 0
        """Pushes started so far (counted once each)."""
        self.reset()

    def reset(self) -> None:
        """Restart the schedule at t = 0."""
        self._rng = np.random.default_rng([self.seed, 0x505553])
        self._start = float(self._rng.uniform(*PUSH_INTERVAL_S))
        self._forces = self._draw()
        self._counted = False

    def _draw(self) -> np.ndarray:
        d = self._rng.normal(size=(len(self.bodies), 3))
        return self.force_n * d / np.linalg.norm(d, axis=1, keepdims=True)

    def force_at(self, t: float) -> np.ndarray:
        """The force on each hand at physics time ``t``, N, shape (hands, 3); advances the schedule."""
        while t >= self._start + PUSH_DURATION_S:
            self._start += float(self._rng.uniform(*PUSH_INTERVAL_S))
            self._forces = self._draw()
            self._counted = False
        if t >= self._start:
            if not self._counted:
                self.pushes += 1
                self._counted = True
            return self._forces
        return np.zeros((len(self.bodies), 3))

    def apply(self, data: mujoco.MjData) -> None:
        """Write this step's forces to ``data.xfrc_applied`` of the hands (torques 0)."""
        data.xfrc_applied[self.bodies, :3] = self.force_at(float(data.time))
        data.xfrc_applied[self.bodies, 3:] = 0.0
