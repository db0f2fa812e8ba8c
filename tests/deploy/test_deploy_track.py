"""Tracking on the deploy side: the lookahead observation by hand, HOLD -> POLICY -> HOLD at the last frame,
the cross-task refusals, ``--motion`` resolution and refusals, the log fields and the MCAP reference topic."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import track_fk
from fault_targets import SteppedMock
from policy_factory import default_metadata, make_hc_policy_file, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.deploy.tasks import TASK_COMMAND_TERMS, all_tasks, get_task, implied_task
from bar_policy.motion import Clip, ClipError, save_clip
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.interfaces import OptionError
from bar_policy.tasks.reach.commands import SampledCommands
from bar_policy.tasks.registry import TASKS as RECORDS
from bar_policy.tasks.track.deploy import MotionReference, load_motion, reference_for

ROBOT = load_robot("arms")
PIANO = ROBOT.pose("piano_ready")
BODIES = ("left_elbow_pitch", "left_hand", "right_elbow_pitch", "right_hand")
FRAMES = [PIANO + 0.02 + 0.01 * k for k in range(4)]
"""The tiny clip: 4 frames at 50 Hz, piano_ready + 0.02 + 0.01 k rad on every joint (0.5 rad/s)."""


def c_fk(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tracked body positions (B, 3) and 6-D orientations (B, 6) straight from C MuJoCo's MjData."""
    return track_fk.c_fk(q, BODIES)


@pytest.fixture
def tiny_clip(tmp_path):
    clip = Clip.make("tiny", 50.0, np.array(FRAMES))
    return clip, save_clip(clip, tmp_path / "tiny.npz")


@pytest.fixture
def track_policy(tmp_path):
    """A linear tracking policy with W = 0, b = 0.1: action 0.1 on every joint, q_cmd = default + 0.025."""
    return make_policy_file(tmp_path / "track.onnx", metadata=default_metadata(task="track"), bias=0.1)


def _run(policy, clip, tmp_path, **cfg):
    ref = reference_for(policy, clip)
    config = RuntimeConfig(duration=None, safety=SafetyConfig(ramp_time=0.04), end_hold=0.1, **cfg)
    target = SteppedMock()  # starts at piano_ready, echoes q_cmd into q
    rt = Runtime(policy, target, ref, config, log_dir=tmp_path / "runs")
    return rt.run(), target


def test_lookahead_observation_and_hold_policy_hold_sequence(track_policy, tiny_clip, tmp_path):
    """Ramp 0.04 s (ticks 0, 1 in HOLD), POLICY from tick 2 (phase 0) for the clip's 3 steps, then HOLD at
    the last frame for end_hold = 0.1 s (ticks 5..10), and the run ends completed.

    At phase j the observation holds frames min(j + i, 3), i = 1..5 (past the end the last frame repeats);
    before the policy starts it holds phase 0's."""
    policy = load_policy(track_policy)
    clip, _ = tiny_clip
    res, target = _run(policy, clip, tmp_path)
    assert res.completed and res.fault_count == 0 and res.ticks == 11
    assert res.end_reason == "motion 'tiny' complete (4 frames, 0.06 s)"
    assert [(tr["from"], tr["to"], round(tr["t"], 6)) for tr in res.transitions] == [
        ("ZERO_TORQUE", "DAMPING", 0.0),
        ("DAMPING", "HOLD", 0.0),
        ("HOLD", "POLICY", 0.04),
        ("POLICY", "HOLD", 0.1),
        ("HOLD", "DAMPING", 0.22),
    ]
    assert res.transitions[3]["reason"].startswith("commands finished: motion 'tiny' complete")
    arrays, meta = load_log(res.log_path)
    H, P = int(Mode.HOLD), int(Mode.POLICY)
    assert arrays["mode"].tolist() == [H, H, P, P, P, H, H, H, H, H, H]
    assert meta["completed"] is True and meta["deploy_task"] == "track"
    assert meta["command_source"]["clip"] == "tiny" and meta["command_source"]["lookahead_steps"] == 5

    om = policy.obs_manager
    f32 = [np.float32(f).astype(np.float64) for f in FRAMES]  # clips store float32 frames
    fk = [c_fk(f) for f in f32]
    phases = [0, 0, 0, 1, 2, 3, 3, 3, 3, 3, 3]  # per tick: the clip's phase (0 until POLICY starts)
    for k, j in enumerate(phases):
        parts = om.split(arrays["obs"][k])
        frames = [min(j + i, 3) for i in range(1, 6)]
        np.testing.assert_allclose(
            parts["motion_joint_pos"], np.concatenate([f32[f] for f in frames]), atol=1e-6
        )
        np.testing.assert_allclose(
            parts["motion_body_pos_b"], np.concatenate([fk[f][0].ravel() for f in frames]), atol=1e-6
        )
        np.testing.assert_allclose(
            parts["motion_body_ori_b"], np.concatenate([fk[f][1].ravel() for f in frames]), atol=1e-6
        )
        # The reference the robot should be at now, logged each tick.
        assert arrays["ref_frame"][k] == min(j, 3)
        np.testing.assert_allclose(arrays["ref_q"][k], f32[min(j, 3)], atol=0)
    # The previous action in the observation: 0 on the first POLICY tick, then the policy's 0.1.
    np.testing.assert_array_equal(om.split(arrays["obs"][2])["actions"], 0.0)
    np.testing.assert_allclose(om.split(arrays["obs"][3])["actions"], np.float32(0.1), atol=0)

    kp, kd = policy.kp, policy.kd
    cmds = target.commands
    # Start-up HOLD ramps from piano_ready to the clip's first frame (smoothstep 0.5 at tick 1, soft gains).
    np.testing.assert_allclose(cmds[1].q, PIANO + 0.5 * (f32[0] - PIANO), atol=1e-12)
    np.testing.assert_allclose(cmds[1].kp, 0.5 * kp, atol=1e-12)
    # POLICY: q_cmd = default + 0.25 * 0.1.
    default = np.asarray(om.schema.default_joint_pos)
    for k in (2, 3, 4):
        np.testing.assert_allclose(cmds[k].q, default + 0.25 * np.float32(0.1), atol=1e-7)
    # The final HOLD keeps the policy's gains from its first tick and reaches the last frame after
    # end_hold / 2 = 0.05 s (tick 8 is 0.06 s in).
    for k in range(5, 11):
        np.testing.assert_array_equal(cmds[k].kp, kp)
        np.testing.assert_array_equal(cmds[k].kd, kd)
    for k in (8, 9, 10):
        np.testing.assert_allclose(cmds[k].q, f32[3], atol=1e-12)
    np.testing.assert_allclose(cmds[6].q, cmds[5].q + 0.352 * (f32[3] - cmds[5].q), atol=1e-12)  # s(0.4)


def test_tracking_log_mcap_reference_topic(track_policy, tiny_clip, tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    from mcap.reader import make_reader

    res, _ = _run(load_policy(track_policy), tiny_clip[0], tmp_path)
    arrays, _ = load_log(res.log_path)
    assert arrays["ref_q"].shape == (11, 14) and arrays["ref_q"].dtype == np.float64
    assert arrays["ref_frame"].dtype == np.int32 and arrays["ref_frame"].tolist() == [0, 0, 0, 1, 2] + [3] * 6
    with (res.log_path.parent / MCAP_FILE).open("rb") as f:
        msgs = []
        for schema, _channel, message in make_reader(f).iter_messages(topics=["/reference"]):
            spec = json.loads(schema.data)
            assert spec["title"] == "bar_deploy.Reference" and set(spec["required"]) == {
                "tick",
                "t",
                "q",
                "frame",
            }
            body = json.loads(message.data)
            jsonschema.Draft202012Validator(spec).validate(body)
            msgs.append(body)
    assert [m["frame"] for m in msgs] == arrays["ref_frame"].tolist()
    np.testing.assert_array_equal([m["q"] for m in msgs], arrays["ref_q"])
    rec = read_mcap_log(res.log_path.parent / MCAP_FILE)  # the crash-recovery reader returns them too
    np.testing.assert_array_equal(rec.arrays["ref_q"], arrays["ref_q"])
    np.testing.assert_array_equal(rec.arrays["ref_frame"], arrays["ref_frame"])


def test_reach_log_has_targets_and_no_reference_topic(zero_policy, tmp_path):
    cfg = RuntimeConfig(duration=0.1, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    src = SampledCommands(zero_policy.obs_manager.command_names, seed=3)
    res = Runtime(zero_policy, SteppedMock(), src, cfg, log_dir=tmp_path).run()
    arrays, meta = load_log(res.log_path)
    assert "ref_q" not in arrays and arrays["target_pos_left"].shape == (5, 3)
    rec = read_mcap_log(res.log_path.parent / MCAP_FILE)
    assert "ref_q" not in rec.arrays
    np.testing.assert_array_equal(rec.arrays["target_pos_right"], arrays["target_pos_right"])
    assert meta["deploy_task"] == "reach" and meta["completed"] is False


# ---------------------------------------------------------------------------------------------------
# Cross-task refusals
# ---------------------------------------------------------------------------------------------------
def test_track_policy_refuses_reach_command_sources(track_policy, tmp_path, capsys):
    rc = main(["--policy", str(track_policy), "--target", "mock", "--commands", "sampled", "--no-log"])
    err = capsys.readouterr().err
    assert rc == 2
    want = (
        f"--commands sampled is for 'reach' policies (fingertip targets), but {track_policy} is a 'track' "
        "policy (motion tracking); give --motion NAME|PATH"
    )
    assert want in err
    rc = main(["--policy", str(track_policy), "--target", "mock", "--no-log"])
    assert (
        rc == 2
        and "is a 'track' policy (motion tracking): give --motion NAME|PATH" in capsys.readouterr().err
    )
    # At the runtime: a reach source does not feed the reference terms, and the message names both tasks.
    pol = load_policy(track_policy)
    with pytest.raises(
        ValueError, match=r"\(task 'reach'\) does not feed \['motion_joint_pos'.*\(task 'track'\)"
    ):
        Runtime(pol, SteppedMock(), SampledCommands(("target_pos_left", "target_pos_right")))


def test_reach_policy_refuses_motion(policy_path, tiny_clip, capsys):
    rc = main(["--policy", str(policy_path), "--target", "mock", "--motion", "wave", "--no-log"])
    err = capsys.readouterr().err
    assert rc == 2
    want = (
        f"--motion wave is for 'track' policies (motion tracking), but {policy_path} is a 'reach' policy "
        "(fingertip targets); give --commands sampled | sampled:PERIOD"
    )
    assert want in err
    # A motion reference cannot feed a reach layout's terms.
    pol = load_policy(policy_path)
    with pytest.raises(ValueError, match=r"a motion reference cannot feed \['target_pos_left'"):
        MotionReference(
            tiny_clip[0], pol.obs_manager.command_names, body_names=BODIES, lookahead_steps=5, control_dt=0.02
        )


def test_eval_options_of_the_other_task_are_refused(track_policy, policy_path, capsys):
    assert main(["eval", "--policy", str(track_policy), "--episodes", "3"]) == 2
    err = capsys.readouterr().err
    assert (
        "--episodes 3 is for 'reach' policies" in err and "its evaluation options: --clips, --hold-s" in err
    )
    assert main(["eval", "--policy", str(policy_path), "--clips", "gestures"]) == 2
    err = capsys.readouterr().err
    assert "--clips gestures is for 'track' policies" in err and "its evaluation options: --episodes" in err


def test_state_only_hc_policy_takes_no_command_source(tmp_path, capsys):
    from policy_factory import hc_props

    path = make_hc_policy_file(tmp_path / "hc.onnx", hc_props(), obs_size=42, bias=0.0)
    assert load_policy(path).task == "state"
    for opt in (["--motion", "wave"], ["--commands", "sampled"]):
        assert main(["--policy", str(path), "--target", "mock", "--no-log", *opt]) == 2
        err = capsys.readouterr().err
        assert "is a 'state' policy (robot state only, no commands); it takes no command source" in err
    rc = main(
        [
            "--policy",
            str(path),
            "--target",
            "mock",
            "--duration",
            "0.06",
            "--ramp-time",
            "0",
            "--log",
            str(tmp_path / "runs"),
        ]
    )
    assert rc == 0 and "commands none (state-only policy)" in capsys.readouterr().out
    assert main(["eval", "--policy", str(path)]) == 2
    assert "there is no task metric to evaluate" in capsys.readouterr().err


def test_registry_terms_and_implied_tasks(track_policy, policy_path):
    assert [t.name for t in all_tasks()] == [r.name for r in RECORDS if r.deploy] + ["state"]
    assert load_policy(track_policy).obs_manager.command_names == TASK_COMMAND_TERMS["track"]
    assert load_policy(policy_path).obs_manager.command_names == TASK_COMMAND_TERMS["reach"]
    assert implied_task(["joint_pos", "joint_vel", "actions"]) == "state"
    assert implied_task(["joint_pos", "fingertip_pos_left"]) == "reach"
    assert implied_task(["motion_body_pos_b", "joint_pos"]) == "track"
    names = re.escape(str(sorted(t.name for t in all_tasks())))
    with pytest.raises(ValueError, match=rf"no deploy task 'dance'; tasks: {names}"):
        get_task("dance")


# ---------------------------------------------------------------------------------------------------
# --motion
# ---------------------------------------------------------------------------------------------------
def test_motion_names_and_files(tiny_clip, tmp_path):
    clip, path = tiny_clip
    assert load_motion(str(path)).content_hash == clip.content_hash
    assert load_motion("wave").name == "wave"
    member = load_motion("random-s1-000")  # the heldout set's first random clip
    from bar_policy.motion import clip_set

    assert member.content_hash == clip_set("heldout", num_clips=1).clips[0].content_hash
    csv = tmp_path / "tiny.csv"
    csv.write_text(
        ",".join(ROBOT.joint_names) + "\n" + "\n".join(",".join(f"{x:.6f}" for x in f) for f in FRAMES)
    )
    assert load_motion(str(csv), rate_hz=50.0).num_frames == 4
    with pytest.raises(ClipError, match="no 'time' column; pass rate_hz"):
        load_motion(str(csv))
    with pytest.raises(ValueError, match=r"no library clip named 'wav'; gestures: \['clap', "):
        load_motion("wav")
    with pytest.raises(ClipError, match=r"no clip file 'missing\.npz'"):
        load_motion("missing.npz")


def test_motion_file_refused_by_the_clip_loader(track_policy, tmp_path, capsys):
    q = np.array(FRAMES)
    q[2, 3] = 0.5  # left_elbow_pitch above its upper limit at frame 2
    bad = Clip(name="bad", rate_hz=50.0, joint_names=ROBOT.joint_names, joint_pos=q.astype(np.float32))
    path = save_clip(bad, tmp_path / "bad.npz")
    rc = main(["--policy", str(track_policy), "--target", "mock", "--motion", str(path), "--no-log"])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"--motion {path}: clip 'bad', frame 2 (t = 0.040 s), joint 'left_elbow_pitch': position" in err
    assert "outside the joint limits" in err


def test_cli_runs_a_motion_to_completion(track_policy, tiny_clip, tmp_path, capsys):
    _, path = tiny_clip
    rc = main(
        [
            "--policy",
            str(track_policy),
            "--target",
            "sim",
            "--motion",
            str(path),
            "--ramp-time",
            "0.1",
            "--end-hold",
            "0.2",
            "--log",
            str(tmp_path / "runs"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "commands motion(tiny, 4 frames at 50 Hz, 0.06 s, lookahead 5)" in out
    assert "end: motion 'tiny' complete (4 frames, 0.06 s); final mode DAMPING" in out
    arrays, meta = load_log(next((tmp_path / "runs").iterdir()))
    # 5 ticks of HOLD, 3 of POLICY, then HOLD at the last frame from t = 0.16 s to 0.36 s (11 ticks).
    assert len(arrays["t"]) == 19 and meta["end_reason"].startswith("motion 'tiny' complete")
    assert (arrays["mode"] == int(Mode.POLICY)).sum() == 3


def test_bad_track_options(track_policy):
    pol = load_policy(track_policy)
    task = get_task("track")
    import argparse

    with pytest.raises(OptionError, match="--motion nope: no library clip named 'nope'"):
        task.command_source(pol, argparse.Namespace(motion="nope", motion_rate=None))
    with pytest.raises(OptionError, match="--motion-rate is for CSV clip files"):
        task.command_source(pol, argparse.Namespace(motion="wave", motion_rate=50.0))
