"""The tracking reference on the numpy side: C MuJoCo kinematics, the table, lookahead indices, obs inputs."""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy.motion import Clip
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.kinematics import Kinematics, rotation_to_6d
from bar_policy.tasks.track import (
    TRACK_BODY_NAMES,
    ReferenceTable,
    lookahead_frames,
    reference_inputs,
    track_action_scale,
    track_default_pose,
)

ROBOT = load_robot("arms")


def test_kinematics_matches_the_reference_numbers():
    kin = Kinematics()
    q = np.stack([np.zeros(14), ROBOT.pose("piano_ready")])
    pos, rot, tips = kin.trajectory(q, ["left_hand", "right_elbow_pitch"], FINGERTIP_SITES)
    # lite-model.md 1.2/1.3: at q = 0 (T-pose) the left wrist centre is at (0, 0.48, 0.39) and its fingertip
    # at (0.0225, 0.705, 0.397); the right elbow at (0.01, -(0.09 + 0.12 + 0.08), 0.39). Every body has the
    # world orientation at q = 0 (4.1).
    np.testing.assert_allclose(pos[0, 0], [0.0, 0.48, 0.39], atol=1e-9)
    np.testing.assert_allclose(pos[0, 1], [0.01, -0.29, 0.39], atol=1e-9)
    np.testing.assert_allclose(tips[0, 0], [0.0225, 0.705, 0.397], atol=1e-9)
    np.testing.assert_allclose(rot[0], np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-12)
    # Piano-ready fingertips (0.361, +-0.159, 0.21) (lite-model.md 1.2, 3 decimals).
    np.testing.assert_allclose(tips[1], [[0.361, 0.159, 0.21], [0.361, -0.159, 0.21]], atol=1e-3)
    with pytest.raises(ValueError, match="unknown bodies \\['left_foot'\\]; bodies of the MJCF"):
        kin.trajectory(q, ["left_foot"])


def test_collisions_with_clearance():
    # Hanging arms: the wrist-yaw capsules pass 10.7 mm from the chest (lite-model.md 4.4 notes the
    # shoulder capsules sit inside it, which the MJCF excludes): clear at 5 mm, too near at 20 mm.
    kin = Kinematics()
    hang = ROBOT.pose("arms_hanging")
    assert kin.collision_free(hang, 0.005) and kin.collisions(hang, 0.005) == []
    near = kin.collisions(hang, 0.02)
    assert {tuple(sorted(p[:2])) for p in near} == {("chest", "left_wrist_yaw"), ("chest", "right_wrist_yaw")}
    assert min(p[2] for p in near) == pytest.approx(0.0107, abs=5e-4)
    assert not kin.collision_free(np.stack([ROBOT.pose("piano_ready"), hang]), 0.02)
    # Geom margins are restored: the env's model copy is not changed by a query.
    assert np.all(kin.model.geom_margin == 0.0)


def test_rotation_to_6d_hand_value():
    # 90 deg about z: columns (0, 1, 0) and (-1, 0, 0) -> rows (r00, r01), (r10, r11), (r20, r21).
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(rotation_to_6d(rz), [0.0, -1.0, 1.0, 0.0, 0.0, 0.0])
    assert rotation_to_6d(np.zeros((4, 2, 3, 3))).shape == (4, 2, 6)


def test_reference_table_layout():
    zero = np.zeros((3, 14))
    piano = np.tile(ROBOT.pose("piano_ready"), (2, 1))
    table = ReferenceTable.build([Clip.make("z", 50.0, zero), Clip.make("p", 50.0, piano)])
    assert table.num_frames == 5 and table.num_clips == 2
    np.testing.assert_array_equal(table.clip_start, [0, 3])
    np.testing.assert_array_equal(table.clip_length, [3, 2])
    assert table.body_pos.shape == (5, 4, 3) and table.body_ori.shape == (5, 4, 6)
    assert table.body_names == TRACK_BODY_NAMES and table.clip_names == ("z", "p")
    # q = 0: identity orientations -> (1, 0, 0, 1, 0, 0); left hand at (0, 0.48, 0.39).
    np.testing.assert_allclose(table.body_ori[0], np.tile([1, 0, 0, 1, 0, 0], (4, 1)), atol=1e-7)
    np.testing.assert_allclose(table.body_pos[0, 1], [0.0, 0.48, 0.39], atol=1e-7)
    np.testing.assert_allclose(
        table.fingertip_pos[3], [[0.361, 0.159, 0.21], [0.361, -0.159, 0.21]], atol=1e-3
    )
    # A clip at 25 Hz is resampled to the control rate: 3 frames over 0.08 s -> 5 frames at 50 Hz.
    t25 = ReferenceTable.build([Clip.make("slow", 25.0, zero)])
    assert t25.num_frames == 5 and t25.rate_hz == 50.0


def test_lookahead_frames_by_hand():
    # Frame 3 of a clip whose last frame is 5, K = 5: frames 4, 5, then the last frame repeats.
    np.testing.assert_array_equal(lookahead_frames(3, 5, 5), [4, 5, 5, 5, 5])
    np.testing.assert_array_equal(
        lookahead_frames(np.array([0, 5]), np.array([9, 5]), 3), [[1, 2, 3], [5, 5, 5]]
    )


def test_reference_inputs_flatten_frame_major():
    # Table of 3 frames, n = 2 joints, B = 1 body, values encode (frame, item).
    jp = np.array([[0.0, 0.1], [1.0, 1.1], [2.0, 2.1]])
    bp = np.array([[[0.0, 0.01, 0.02]], [[1.0, 1.01, 1.02]], [[2.0, 2.01, 2.02]]])
    bo = np.arange(18.0).reshape(3, 1, 6)
    out = reference_inputs(jp, bp, bo, np.array([1, 2, 2]))
    np.testing.assert_array_equal(out["motion_joint_pos"], [1.0, 1.1, 2.0, 2.1, 2.0, 2.1])
    np.testing.assert_array_equal(
        out["motion_body_pos_b"], [1.0, 1.01, 1.02, 2.0, 2.01, 2.02, 2.0, 2.01, 2.02]
    )
    np.testing.assert_array_equal(out["motion_body_ori_b"], [*range(6, 12), *range(12, 18), *range(12, 18)])


def test_action_map_covers_the_motion_box():
    # default = box centre, scale = half-width + 0.25 rad: the box edges are at |action| = w / (w + 0.25).
    from bar_policy.motion import motion_box

    lo, hi = motion_box()
    d, s = track_default_pose(), track_action_scale()
    np.testing.assert_allclose(d + s * 1.0, hi + 0.25)
    np.testing.assert_allclose(d - s * 1.0, lo - 0.25)
    # left elbow: box [-2.2, 0] -> default -1.1, scale 1.35.
    assert (d[3], s[3]) == pytest.approx((-1.1, 1.35))


def test_reference_table_cache_keys_on_content_and_bodies(tmp_path, monkeypatch):
    """``cache=True`` stores the kinematics under the clips' content (not their names) and the bodies."""
    monkeypatch.setenv("BAR_POLICY_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("BAR_POLICY_ARRAY_CACHE", "1")
    piano = np.tile(ROBOT.pose("piano_ready"), (3, 1))
    clip = Clip.make("p", 50.0, piano)
    plain = ReferenceTable.build([clip])
    for _ in range(2):  # a miss, then a hit: the same bytes as the uncached table
        cached = ReferenceTable.build([clip], cache=True)
        for k in ("joint_pos", "body_pos", "body_ori", "fingertip_pos"):
            a, b = getattr(plain, k), getattr(cached, k)
            assert a.dtype == b.dtype == np.float32 and a.shape == b.shape and a.tobytes() == b.tobytes()
    entries = lambda: len(list((tmp_path / "arrays").glob("track_reference-*.npz")))  # noqa: E731
    assert entries() == 1
    ReferenceTable.build([Clip.make("p", 50.0, piano + 0.01)], cache=True)  # same name, other frames
    ReferenceTable.build([clip], TRACK_BODY_NAMES[:2], cache=True)  # other bodies
    assert entries() == 3
    with pytest.raises(ValueError, match="pass kinematics or cache, not both"):
        ReferenceTable.build([clip], kinematics=Kinematics(), cache=True)
