"""Motion tracking: the reference with lookahead, shared by the MJX env (jax) and the deploy side (numpy).

A clip set becomes a ``ReferenceTable``: every frame's joint positions plus the poses of the tracked bodies
(``TRACK_BODY_NAMES``) and the fingertips from C MuJoCo forward kinematics (``Kinematics.trajectory``),
concatenated over the clips. The env indexes the same arrays on the device; the deploy side indexes them in
numpy. Both build the observation's reference terms with ``lookahead_frames`` + ``reference_inputs``.

Semantics (fixed by the ``lite_track_*`` observation layouts):

- At control step t (the state after t steps, frame ``f`` of the clip), the observation holds the reference
  frames ``f + 1 .. f + K`` (K = ``TRACK_LOOKAHEAD_STEPS``), the targets of the next K control steps;
  frames past the clip's end repeat its last frame (the reference holds the final pose).
- ``motion_joint_pos``: those frames' joint positions, rad, frame-major (K x n).
- ``motion_body_pos_b``: tracked body origins in the chest (torso) frame, m, frame-major, then body, then
  xyz (K x B x 3). The chest is the fixed root, so this is the world frame of the MJCF.
- ``motion_body_ori_b``: tracked body orientations in the chest frame as 6-D (first two columns of the
  rotation matrix, row-major; ``rotation_to_6d``), frame-major, then body (K x B x 6).
- Clip frames are at the control rate (50 Hz); clips at another rate are resampled (``Clip.resample``).

The action stays Humanoid Control's ``delta_from_default``: ``q_cmd = default + action_scale * action``
with ``default`` = the centre of the motion box and ``action_scale`` = its half-width plus
``ACTION_MARGIN`` per joint (``track_default_pose``, ``track_action_scale``), so every reference pose is
reachable with |action| <= 1 and room to spare for gravity and lead.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy._array_cache import cached_arrays
from bar_policy.motion.clip import Clip
from bar_policy.motion.generator import motion_box
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.kinematics import Kinematics, rotation_to_6d

__all__ = [
    "ACTION_MARGIN",
    "COMMAND_TERMS",
    "LOST_DISTANCE",
    "SUCCESS_FINGERTIP_M",
    "SUCCESS_JOINT_RAD",
    "TRACK_BODY_NAMES",
    "TRACK_LOOKAHEAD_STEPS",
    "ReferenceTable",
    "lookahead_frames",
    "reference_inputs",
    "track_action_scale",
    "track_default_pose",
]

TRACK_BODY_NAMES: tuple[str, ...] = ("left_elbow_pitch", "left_hand", "right_elbow_pitch", "right_hand")
"""Tracked bodies (Humanoid Control's ``body_names``): per arm the elbow (its origin is the elbow joint,
its orientation the forearm's) and the hand (origin = wrist centre, orientation = the hand's)."""

TRACK_LOOKAHEAD_STEPS = 5
"""Reference frames in the observation (Humanoid Control's ``lookahead_steps``): 5 x 20 ms = 100 ms."""

COMMAND_TERMS = ("motion_joint_pos", "motion_body_pos_b", "motion_body_ori_b")
"""The observation terms the reference feeds (the deploy command source's, ``reference_inputs``'s keys)."""

ACTION_MARGIN = 0.25
"""Action range beyond the motion box on each side, rad (gravity compensation and lead)."""

SUCCESS_JOINT_RAD = 0.05
"""A tracking step succeeds when the mean joint error is at most this, rad (the env's metric)."""
SUCCESS_FINGERTIP_M = 0.02
"""... and the mean fingertip error at most this, m."""
LOST_DISTANCE = 0.25
"""A tracked body farther than this from its reference is lost, m (the env's ``termination_distance``)."""


def track_default_pose(mode: str = "arms") -> np.ndarray:
    """The tracking layout's default pose: the centre of the motion box, rad, shape (n,)."""
    lo, hi = motion_box(mode)
    return 0.5 * (lo + hi)


def track_action_scale(mode: str = "arms") -> np.ndarray:
    """Per-joint action scale: half the motion box plus ``ACTION_MARGIN``, rad per unit action, shape (n,)."""
    lo, hi = motion_box(mode)
    return 0.5 * (hi - lo) + ACTION_MARGIN


@dataclass(frozen=True, eq=False)
class ReferenceTable:
    """The frames of a clip set with their kinematics, concatenated over clips (float32 numpy arrays).

    F frames in total, C clips, B tracked bodies, n joints.
    """

    joint_pos: np.ndarray
    """Joint positions, rad. Shape (F, n)."""
    body_pos: np.ndarray
    """Tracked body positions, chest frame, m. Shape (F, B, 3)."""
    body_ori: np.ndarray
    """Tracked body orientations, 6-D (``rotation_to_6d``). Shape (F, B, 6)."""
    fingertip_pos: np.ndarray
    """Fingertip sites (left, right), chest frame, m. Shape (F, 2, 3)."""
    clip_start: np.ndarray
    """First frame of each clip in the table. Shape (C,), int32."""
    clip_length: np.ndarray
    """Frames of each clip. Shape (C,), int32."""
    clip_names: tuple[str, ...]
    """Clip names, table order."""
    body_names: tuple[str, ...]
    """Tracked bodies, table order."""
    rate_hz: float
    """Frame rate, Hz."""

    @classmethod
    def build(
        cls,
        clips: Sequence[Clip],
        body_names: Sequence[str] = TRACK_BODY_NAMES,
        *,
        rate_hz: float = 50.0,
        kinematics: Kinematics | None = None,
        cache: bool = False,
    ) -> ReferenceTable:
        """Concatenate ``clips`` (resampled to ``rate_hz``) and compute their kinematics with C MuJoCo.

        ``cache``: keep the kinematics (body and fingertip poses) on disk (``bar_policy._array_cache``),
        keyed on the mode, the body names and the resampled clips' content hashes (plus the package's files
        and the numpy and mujoco versions): the training set's 96k frames take 0.8 s of forward kinematics
        on the project's 2-core CPU. The table is the same either way, bit for bit. The cached kinematics
        are the robot's alone (``Kinematics(mode)``), so ``cache`` takes no ``kinematics``.

        Raises:
            ValueError: no clips, clips of different joint sets, an unknown body name, or both ``cache``
                and ``kinematics``.
        """
        if not clips:
            raise ValueError("a reference table needs at least one clip")
        modes = {c.mode for c in clips}
        if len(modes) != 1:
            raise ValueError(f"clips of different joint sets: {sorted(modes)}")
        if cache and kinematics is not None:
            raise ValueError(
                "cache=True computes the robot's own kinematics; pass kinematics or cache, not both"
            )
        mode = modes.pop()
        body_names = tuple(body_names)
        clips = [c.resample(rate_hz) for c in clips]
        q = np.concatenate([c.joint_pos for c in clips]).astype(np.float64)
        f32 = np.float32

        def poses() -> dict[str, np.ndarray]:
            pos, rot, tips = (kinematics or Kinematics(mode)).trajectory(q, body_names, FINGERTIP_SITES)
            return {
                "body_pos": pos.astype(f32),
                "body_ori": rotation_to_6d(rot).astype(f32),
                "fingertip_pos": tips.astype(f32),
            }

        if cache:
            parts = {"mode": mode, "body_names": body_names, "clips": [c.content_hash for c in clips]}
            fk = cached_arrays("track_reference", parts, ("body_pos", "body_ori", "fingertip_pos"), poses)
        else:
            fk = poses()
        lengths = np.array([c.num_frames for c in clips], dtype=np.int32)
        return cls(
            joint_pos=q.astype(f32),
            body_pos=fk["body_pos"],
            body_ori=fk["body_ori"],
            fingertip_pos=fk["fingertip_pos"],
            clip_start=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int32),
            clip_length=lengths,
            clip_names=tuple(c.name for c in clips),
            body_names=body_names,
            rate_hz=float(rate_hz),
        )

    @property
    def num_frames(self) -> int:
        """F."""
        return int(self.joint_pos.shape[0])

    @property
    def num_clips(self) -> int:
        """C."""
        return int(self.clip_start.shape[0])


def lookahead_frames(frame: Array, last: Array, steps: int) -> Array:
    """Table indices of the reference frames in the observation: ``min(frame + k, last)``, k = 1..steps.

    Args:
        frame: current frame index in the table (int scalar or array, any leading shape).
        last: index of the current clip's last frame (same shape).
        steps: K.

    Returns:
        Indices, shape ``(..., K)``, same array type as ``frame``.
    """
    xp = array_namespace(frame, last)
    k = xp.arange(1, steps + 1)
    return xp.minimum(xp.asarray(frame)[..., None] + k, xp.asarray(last)[..., None])


def reference_inputs(joint_pos: Array, body_pos: Array, body_ori: Array, idx: Array) -> dict[str, Array]:
    """The reference terms of the observation for table indices ``idx`` (shape (K,)).

    Args:
        joint_pos: table joint positions, shape (F, n) (numpy or jax, like the others).
        body_pos: table body positions, shape (F, B, 3).
        body_ori: table body orientations (6-D), shape (F, B, 6).
        idx: frame indices from ``lookahead_frames``, shape (K,).

    Returns:
        ``motion_joint_pos`` (K*n,), ``motion_body_pos_b`` (K*B*3,), ``motion_body_ori_b`` (K*B*6,),
        flattened frame-major.
    """
    return {
        "motion_joint_pos": joint_pos[idx].reshape(-1),
        "motion_body_pos_b": body_pos[idx].reshape(-1),
        "motion_body_ori_b": body_ori[idx].reshape(-1),
    }
