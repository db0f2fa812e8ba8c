"""The shipped motion library: the random generator's bounds, the gestures, the clip sets and their ids."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from bar_policy.motion import (
    GESTURES,
    RandomMotionConfig,
    clip_set,
    gesture,
    gestures,
    motion_box,
    random_clips,
)
from bar_policy.motion.clip import MAX_JOINT_SPEED
from bar_policy.motion.generator import MIRROR
from bar_policy.robot.constants import load_robot
from bar_policy.robot.kinematics import Kinematics

CFG = RandomMotionConfig()
RATE = 50.0


@pytest.fixture(scope="module")
def clips():
    return random_clips(7, 6, 8.0)


def _fd(q: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    q = q.astype(np.float64)
    return np.abs(np.diff(q, axis=0)) * rate, np.abs(np.diff(q, 2, axis=0)) * rate**2


def test_generator_bounds_stated_and_held(clips):
    # Defaults: 1.0 rad per 0.4 s knot -> 2.5 rad/s and 2 * 1.0 / 0.16 = 12.5 rad/s^2, below the loader's 5.
    assert CFG.speed_bound == pytest.approx(2.5) and CFG.acceleration_bound == pytest.approx(12.5)
    assert CFG.speed_bound < MAX_JOINT_SPEED
    lo, hi = motion_box()
    kin = Kinematics()
    for c in clips:
        assert c.rate_hz == RATE and c.duration_s == pytest.approx(8.0)
        v, a = _fd(c.joint_pos, RATE)
        # Finite differences of the sampled spline stay inside the analytic bounds (float32 storage: 1e-4).
        assert v.max() <= CFG.speed_bound + 1e-3 and a.max() <= CFG.acceleration_bound + 0.5
        assert np.all(c.joint_pos >= lo - 1e-6) and np.all(c.joint_pos <= hi + 1e-6)
        assert kin.collision_free(c.joint_pos, CFG.clearance * 0.99)
        # Starts and ends at rest (three equal control points at each end).
        assert v[0].max() < 1e-3 and v[-1].max() < 1e-3
    # The clips move: every joint of the set travels, and the speed factor varies between clips.
    span = np.ptp(np.concatenate([c.joint_pos for c in clips]), axis=0)
    assert np.all(span > 0.3)


def test_generator_is_seeded(clips):
    again = random_clips(7, 2, 8.0)
    assert [c.content_hash for c in again] == [c.content_hash for c in clips[:2]]
    assert random_clips(8, 1, 8.0)[0].content_hash != clips[0].content_hash
    assert [c.name for c in again] == ["random-s7-000", "random-s7-001"]


def test_motion_box_mirrors_and_stays_in_limits():
    robot = load_robot("arms")
    lo, hi = motion_box("arms")
    assert np.all(lo >= robot.lower - 1e-9) and np.all(hi <= robot.upper + 1e-9)
    # Right arm = mirror of the left: the interval of S * [lo, hi].
    np.testing.assert_allclose(
        np.sort(np.stack([MIRROR * lo[:7], MIRROR * hi[:7]]), axis=0), [lo[7:], hi[7:]]
    )
    for pose in ("piano_ready", "arms_hanging"):
        q = robot.pose(pose)
        assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9), pose
    lo17, hi17 = motion_box("arms_neck")
    assert lo17.shape == (17,) and np.all(hi17[14:] == 0.4)


def test_gestures_are_smooth_in_box_and_collision_free():
    lo, hi = motion_box()
    kin = Kinematics()
    robot = load_robot("arms")
    for c in gestures():
        assert c.name in GESTURES
        v, _ = _fd(c.joint_pos, RATE)
        # Within the random generator's speed bound, so the training set covers their speeds.
        assert v.max() <= CFG.speed_bound, (c.name, v.max())
        assert np.all(c.joint_pos >= lo - 1e-6) and np.all(c.joint_pos <= hi + 1e-6), c.name
        assert kin.collision_free(c.joint_pos, 0.005), c.name
        assert v[0].max() < 1e-6 and v[-1].max() < 1e-6  # starts and ends at rest
    hang = gesture("hanging_to_piano_ready")
    np.testing.assert_allclose(hang.joint_pos[0], robot.pose("arms_hanging"), atol=1e-6)
    np.testing.assert_allclose(hang.joint_pos[-1], robot.pose("piano_ready"), atol=1e-6)
    assert hang.duration_s == pytest.approx(4.5)
    # Clap: the fingertips come within 8 cm of each other and part again (the gesture's point).
    tips = Kinematics().trajectory(gesture("clap").joint_pos, [], ["left_finger2_tip", "right_finger2_tip"])[
        2
    ]
    gap = np.linalg.norm(tips[:, 0] - tips[:, 1], axis=-1)
    assert gap.min() < 0.08 and gap.max() > 0.3
    with pytest.raises(ValueError, match="gestures: "):
        gesture("moonwalk")
    neck = gesture("wave", mode="arms_neck")
    assert neck.joint_pos.shape[1] == 17 and np.all(neck.joint_pos[:, 14:] == 0)


def test_clip_sets_and_ids():
    a = clip_set("gestures")
    assert [c.name for c in a.clips] == list(GESTURES)
    assert a.id.startswith("bar_policy.motion/gestures@") and a.id == clip_set("gestures").id
    held = clip_set("heldout", num_clips=1, length_s=2.0)
    train = clip_set("train", num_clips=1, length_s=2.0)
    assert [c.name for c in held.clips] == ["random-s1-000", *GESTURES]
    assert train.clips[0].name == "random-s0-000" and train.id != held.id
    # Held-out random clips never appear in training: different seeds, different content.
    assert held.clips[0].content_hash != train.clips[0].content_hash
    with pytest.raises(ValueError, match="clip sets: "):
        clip_set("all")


def test_motion_and_tracking_task_import_without_jax():
    probe = (
        "import sys, bar_policy.motion, bar_policy.tasks.track; "
        "print(sorted(m for m in ('jax', 'jaxlib', 'torch', 'mujoco.mjx') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
