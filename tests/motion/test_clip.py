"""The clip format: NPZ round trip, content hash, CSV import, resampling, and every refusal of the loader."""

from __future__ import annotations

import re

import numpy as np
import pytest

from bar_policy.motion import MAX_JOINT_SPEED, Clip, ClipError, load_clip, load_csv, save_clip
from bar_policy.motion.clip import CLIP_FORMAT, validate_clip
from bar_policy.robot.constants import load_robot

ROBOT = load_robot("arms")
PIANO = ROBOT.pose("piano_ready")


def frames(n: int = 5, step: float = 0.01) -> np.ndarray:
    """n frames from piano_ready, every joint moving by ``step`` rad per frame."""
    return PIANO + step * np.arange(n)[:, None] * np.ones(14)


def test_npz_round_trip_and_hash(tmp_path):
    clip = Clip.make("demo", 50.0, frames())
    path = save_clip(clip, tmp_path / "demo.npz")
    back = load_clip(path)
    assert back.name == "demo" and back.rate_hz == 50.0 and back.joint_names == ROBOT.joint_names
    np.testing.assert_array_equal(back.joint_pos, clip.joint_pos)
    assert back.content_hash == clip.content_hash and re.fullmatch("[0-9a-f]{16}", clip.content_hash)
    assert back.num_frames == 5 and back.duration_s == pytest.approx(4 / 50)
    # The name is not content; the rate and every frame are.
    assert Clip.make("other", 50.0, frames()).content_hash == clip.content_hash
    assert Clip.make("demo", 25.0, frames()).content_hash != clip.content_hash
    assert Clip.make("demo", 50.0, frames(step=0.011)).content_hash != clip.content_hash
    with np.load(path) as f:
        assert str(f["format"]) == CLIP_FORMAT and f["joint_pos"].dtype == np.float32


def test_loader_refuses_an_edited_file(tmp_path):
    clip = Clip.make("demo", 50.0, frames())
    path = save_clip(clip, tmp_path / "demo.npz")
    with np.load(path) as f:
        data = {k: f[k] for k in f.files}
    data["joint_pos"] = data["joint_pos"] + np.float32(0.001)
    np.savez(tmp_path / "edited.npz", **data)
    with pytest.raises(ClipError, match=r"content hash \w+ differs from the stored"):
        load_clip(tmp_path / "edited.npz")
    del data["rate_hz"]
    np.savez(tmp_path / "short.npz", **data)
    with pytest.raises(ClipError, match=r"lacks keys \['rate_hz'\]"):
        load_clip(tmp_path / "short.npz")


def test_refuses_a_joint_limit_naming_frame_time_and_joint():
    q = frames(10)
    # left_elbow_pitch (index 3) has the upper limit 0; frame 7 asks for +0.02 rad.
    q[7, 3] = 0.02
    with pytest.raises(ClipError) as e:
        Clip.make("bad", 50.0, q)
    msg = str(e.value)
    assert "frame 7 (t = 0.140 s)" in msg and "'left_elbow_pitch'" in msg and "0.0200 rad outside" in msg


def test_refuses_a_speed_limit_naming_frame_time_and_joint():
    q = frames(10, step=0.0)
    # right_wrist_yaw (index 11) jumps by 0.2 rad between frames 3 and 4 at 50 Hz: 10 rad/s > 5 rad/s.
    q[4:, 11] += 0.2
    with pytest.raises(ClipError) as e:
        Clip.make("jump", 50.0, q)
    msg = str(e.value)
    assert "frame 4 (t = 0.080 s)" in msg and "'right_wrist_yaw'" in msg
    assert "10.00 rad/s" in msg and f"speed limit {MAX_JOINT_SPEED} rad/s" in msg
    # The same jump over 0.1 s (10 Hz) is 2 rad/s: accepted.
    assert Clip.make("slow", 10.0, q).num_frames == 10


def test_refuses_non_finite_wrong_shape_and_wrong_joint_set():
    q = frames(4)
    q[2, 0] = np.nan
    with pytest.raises(ClipError, match=r"frame 2 \(t = 0.040 s\), joint 'left_shoulder_pitch': non-finite"):
        Clip.make("nan", 50.0, q)
    with pytest.raises(ClipError, match=r"shape \(T >= 2, 14\)"):
        Clip.make("one", 50.0, frames(1))
    with pytest.raises(ClipError, match="rate must be a positive"):
        Clip.make("rate", 0.0, frames())
    # 17 neck-mode columns for an arms clip: the joint set is checked by the loader.
    bad = Clip(
        name="x", rate_hz=50.0, joint_names=load_robot("arms_neck").joint_names, joint_pos=np.zeros((3, 17))
    )

    with pytest.raises(ClipError, match=r"does not match mode 'arms' \(missing \[\], unknown \['neck_yaw'"):
        validate_clip(bad, ROBOT)
    swapped = Clip(name="x", rate_hz=50.0, joint_names=ROBOT.joint_names[::-1], joint_pos=frames(3))
    with pytest.raises(ClipError, match="order differs"):
        validate_clip(swapped, ROBOT)


def test_csv_import_any_column_order_with_time(tmp_path):
    q = frames(4)
    order = list(ROBOT.joint_names[::-1])  # reversed columns
    rows = ["time," + ",".join(order)]
    for i, f in enumerate(q):
        rows.append(f"{i * 0.04}," + ",".join(repr(float(f[ROBOT.index(j)])) for j in order))
    (tmp_path / "wave.csv").write_text("\n".join(rows) + "\n")
    clip = load_csv(tmp_path / "wave.csv")
    assert clip.name == "wave" and clip.rate_hz == pytest.approx(25.0)
    np.testing.assert_allclose(clip.joint_pos, q, atol=1e-6)


def test_csv_refusals(tmp_path):
    q = frames(3)
    head = ",".join(ROBOT.joint_names)
    body = "\n".join(",".join(str(x) for x in f) for f in q)
    (tmp_path / "ok.csv").write_text(f"{head}\n{body}\n")
    with pytest.raises(ClipError, match="no 'time' column; pass rate_hz"):
        load_csv(tmp_path / "ok.csv")
    assert load_csv(tmp_path / "ok.csv", rate_hz=50.0).num_frames == 3
    (tmp_path / "missing.csv").write_text(
        head.replace("right_wrist_pitch", "right_wrist_pitchh") + "\n" + body
    )
    with pytest.raises(ClipError, match=r"missing \['right_wrist_pitch'\], unknown \['right_wrist_pitchh'\]"):
        load_csv(tmp_path / "missing.csv", rate_hz=50.0)
    times = [0.0, 0.02, 0.05]
    (tmp_path / "jitter.csv").write_text(
        "time,"
        + head
        + "\n"
        + "\n".join(f"{t}," + ",".join(str(x) for x in f) for t, f in zip(times, q, strict=True))
    )
    with pytest.raises(ClipError, match="increase uniformly"):
        load_csv(tmp_path / "jitter.csv")
    with pytest.raises(ClipError, match="either a 'time' column or rate_hz"):
        load_csv(tmp_path / "jitter.csv", rate_hz=50.0)
    (tmp_path / "text.csv").write_text(f"{head}\n" + ",".join(["abc"] * 14) + "\n" + body)
    with pytest.raises(ClipError, match="not a number"):
        load_csv(tmp_path / "text.csv", rate_hz=50.0)
    # A limit violation inside a CSV names the frame and the joint like the NPZ loader.
    q2 = q.copy()
    q2[2, 5] = 0.8  # left_wrist_roll limit +-0.698
    (tmp_path / "limit.csv").write_text(f"{head}\n" + "\n".join(",".join(str(x) for x in f) for f in q2))
    with pytest.raises(ClipError, match=r"frame 2 \(t = 0.200 s\), joint 'left_wrist_roll'"):
        load_csv(tmp_path / "limit.csv", rate_hz=10.0)


def test_resample_by_linear_interpolation():
    # 10 Hz, joint 0 goes 0.30 -> 0.40 -> 0.30; at 20 Hz the midpoints are 0.35.
    q = np.tile(PIANO, (3, 1))
    q[:, 0] = [0.30, 0.40, 0.30]
    clip = Clip.make("tri", 10.0, q).resample(20.0)
    assert clip.rate_hz == 20.0 and clip.num_frames == 5 and clip.duration_s == pytest.approx(0.2)
    np.testing.assert_allclose(clip.joint_pos[:, 0], [0.30, 0.35, 0.40, 0.35, 0.30], atol=1e-6)
    np.testing.assert_allclose(clip.joint_pos[:, 1:], np.tile(PIANO[1:], (5, 1)), atol=1e-6)
