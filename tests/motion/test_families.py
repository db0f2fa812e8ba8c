"""The held-out clip families: what each family promises, checked against C MuJoCo and by hand."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from bar_policy.motion.families import FAMILIES, HOLD_POSES_LEFT, NOISE_RAD, family_clips, family_of
from bar_policy.motion.generator import MIRROR, RandomMotionConfig, motion_box, random_clip
from bar_policy.motion.library import clip_set, library_clip
from bar_policy.robot.constants import load_robot
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mjcf import load_model
from bar_policy.tasks.track.evaluate import ClipResult, groups


@pytest.fixture(scope="module")
def clips() -> dict[str, np.ndarray]:
    return {c.name: c.joint_pos.astype(np.float64) for c in family_clips()}


def test_two_clips_per_family_inside_the_box_and_clear_of_collisions(clips: dict[str, np.ndarray]) -> None:
    assert sorted(family_of(n) for n in clips) == sorted(f for f in FAMILIES for _ in range(2))
    lo, hi = motion_box()
    kin = Kinematics("arms")
    for name, q in clips.items():
        assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9), name
        assert kin.collision_free(q, 0.005), name
        # Start and end at rest: the first and the last step under 5e-5 rad (2.5 mrad/s at 50 Hz; a
        # minimum-jerk fade's first step is 10 u^3 of its amplitude, u = 1/75: 2.4e-5 of 0.2 rad, and a
        # B-spline's at its resting end is smaller still), against 1e-2 rad per step while moving.
        np.testing.assert_allclose(q[1], q[0], atol=5e-5, err_msg=name)
        np.testing.assert_allclose(q[-1], q[-2], atol=5e-5, err_msg=name)


def test_periodic_starts_on_piano_ready_and_repeats_every_period(clips: dict[str, np.ndarray]) -> None:
    ready = load_robot("arms").pose("piano_ready")
    for name in ("periodic-slow", "periodic-fast"):
        np.testing.assert_allclose(clips[name][0], ready, atol=1e-12)
    # 0.8 Hz at 50 Hz: two periods are 2.5 s = 125 frames; between the fades (1.5 s = 75 frames at each
    # end of the 600-frame clip) the motion repeats exactly (float64 rounding of sin: 1e-12).
    q = clips["periodic-fast"]
    np.testing.assert_allclose(q[75 + 125 : 525], q[75 : 525 - 125], atol=1e-12)
    assert np.ptp(q[75:525], axis=0).max() > 0.05  # and it does move


def test_noisy_is_a_walk_plus_noise_of_the_stated_size(clips: dict[str, np.ndarray]) -> None:
    # Rebuild the walks the way the module states (seed 2, 20 s walks), then the residual is the noise.
    rng = np.random.default_rng(2)
    kin = Kinematics("arms")
    lo, hi = motion_box()
    for i in range(2):
        walk = random_clip(rng, 20.0, name="w", kinematics=kin, config=RandomMotionConfig()).joint_pos
        noise = rng.normal(0.0, NOISE_RAD, walk.shape)  # the same draws, in the same order
        res = clips[f"noisy-{i:03d}"] - walk.astype(np.float64)
        inner = res[3:-3]
        # 995 x 14 = 13,930 samples: the sample std's relative error is about 1 / sqrt(2 N) = 0.6 %; 5 %
        # is 8 sigma. The clip to the box can only shrink a residual.
        assert inner.std() == pytest.approx(NOISE_RAD, rel=0.05)
        assert np.all(np.abs(inner) <= np.abs(noise[3:-3]) + 1e-6)
        assert np.all(res[:3] == 0) and np.all(res[-3:] == 0)
        # Frames on the box's faces were clipped, nowhere else: the residual equals the noise elsewhere.
        inside = (walk[3:-3] + noise[3:-3] > lo) & (walk[3:-3] + noise[3:-3] < hi)
        np.testing.assert_allclose(inner[inside], noise[3:-3][inside], atol=1e-6)  # float32 frames


def test_hold_holds_poses_against_gravity_for_eight_seconds(clips: dict[str, np.ndarray]) -> None:
    m = load_model("arms")
    d = mujoco.MjData(m)
    for variant in ("forward-side", "side-forward"):
        q = clips[f"hold-{variant}"]
        first = variant.split("-")[0]
        left = np.array(HOLD_POSES_LEFT[first])
        want = np.r_[left, MIRROR * left]
        # Keyframes: 0.5 s at piano_ready, a 2 s move, then the pose for 8 s: frames 125 .. 525 at 50 Hz.
        np.testing.assert_allclose(q[125:526], np.broadcast_to(want, (401, 14)), atol=1e-6)
        d.qpos[:] = want
        d.qvel[:] = 0
        mujoco.mj_forward(m, d)
        # Gravity on the shoulders (qfrc_bias at rest): the module's 4.6 N*m (pitch, forward) or 4.7 N*m
        # (roll, side) on each arm.
        joint = 0 if first == "forward" else 1
        assert abs(d.qfrc_bias[joint]) > 4.5 and abs(d.qfrc_bias[7 + joint]) > 4.5


def test_onearm_keeps_one_arm_exactly_still(clips: dict[str, np.ndarray]) -> None:
    ready = load_robot("arms").pose("piano_ready")
    for still, moving in (("left", slice(7, 14)), ("right", slice(0, 7))):
        q = clips[f"onearm-{still}-still"]
        cols = slice(0, 7) if still == "left" else slice(7, 14)
        assert np.all(q[:, cols] == ready[cols].astype(np.float32))  # clips store float32 frames
        assert np.ptp(q[:, moving], axis=0).max() > 0.5  # the other arm walks
        np.testing.assert_allclose(q[0], ready, atol=1e-6)


def test_library_names_and_report_groups() -> None:
    assert library_clip("hold-forward-side").name == "hold-forward-side"
    with pytest.raises(ValueError, match="family clips"):
        library_clip("hold-sideways")
    fam = clip_set("families")
    assert [c.name for c in fam.clips] == [c.name for c in family_clips()]
    assert fam.id == clip_set("families").id  # a pure function of its arguments
    assert family_of("random-s1-003") == "random" and family_of("wave") == "gestures"
    assert family_of("noisy-000") == "noisy" and family_of("hold") == "gestures"
    # groups(): all, then random, gestures and the families in that order; frame-weighted means.
    res = [
        ClipResult(
            name,
            steps,
            {
                "joint_error": err * steps,
                "body_pos_error": 0.0,
                "fingertip_error": 0.0,
                "success": 0.0,
                "lost": 0.0,
            },
        )
        for name, steps, err in (("hold-a", 10, 0.03), ("random-s1-000", 30, 0.01), ("wave", 10, 0.02))
    ]
    got = groups(res)
    assert [g["group"] for g in got] == ["all", "random", "gestures", "hold"]
    # all: (0.3 + 0.3 + 0.2) / 50 = 0.016 rad
    assert got[0]["joint_error_rad"] == pytest.approx(0.016, rel=1e-12)
    assert got[3]["joint_error_rad"] == pytest.approx(0.03, rel=1e-12)
