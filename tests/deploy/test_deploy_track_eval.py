"""Tracking evaluation (``bar-deploy eval`` for track policies) worked by hand on an echoing target, its CLI
wiring on the sim target, and the reference overlay of ``bar-deploy plot``."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
from fault_targets import SteppedMock
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.motion import Clip, save_clip
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mjcf import load_model
from bar_policy.tasks.track.deploy import reference_for
from bar_policy.tasks.track.evaluate import ClipResult, evaluate_track, summarise

ROBOT = load_robot("arms")
BODIES = ("left_elbow_pitch", "left_hand", "right_elbow_pitch", "right_hand")
TIPS = ("left_finger2_tip", "right_finger2_tip")


def fk(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tracked body positions (4, 3) and fingertip sites (2, 3), chest frame, straight from C MuJoCo."""
    m = load_model("arms")
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    return np.stack([d.body(b).xpos for b in BODIES]), np.stack([d.site(s).xpos for s in TIPS])


class ResettableMock(SteppedMock):
    """The stepped echo mock with the evaluation's ``reset(q, dq)``."""

    def reset(self, q: np.ndarray, dq: np.ndarray | None = None) -> None:
        self._q = np.asarray(q, dtype=np.float64).copy()
        self._dq = np.zeros(14)
        self.steps = 0


@pytest.fixture
def track_policy(tmp_path):
    """W = 0, b = 0.1: q_cmd = default + 0.025 rad on every joint, whatever the observation."""
    return load_policy(
        make_policy_file(tmp_path / "t.onnx", metadata=default_metadata(task="track"), bias=0.1)
    )


def test_tracking_metrics_by_hand(track_policy):
    """On the echo mock the measured q after every tick is q_c = default + 0.025. Clip 'near' has frames
    q_c + 0.01 k (k = 0..3), clip 'far' is piano_ready + 0.01 k. With hold_s = 0.04 (2 ticks) each clip
    runs 3 + 2 = 5 steps, and step k is scored against frame min(k + 1, 3): frames 1, 2, 3, 3, 3."""
    q_c = np.asarray(track_policy.obs_manager.schema.default_joint_pos) + 0.25 * np.float32(0.1)
    piano = ROBOT.pose("piano_ready")
    clips = [
        Clip.make("near", 50.0, q_c + 0.01 * np.arange(4)[:, None]),
        Clip.make("far", 50.0, piano + 0.01 * np.arange(4)[:, None]),
    ]
    res = evaluate_track(
        track_policy,
        clips,
        runner=SimEpisodes(track_policy),
        hold_s=0.04,
        target=ResettableMock(),
        label="mock",
    )
    pos_c, tips_c = fk(q_c)
    for clip, r in zip(clips, res.clips, strict=True):
        assert r.clip == clip.name and r.steps == 5 and not r.faulted
        want = dict.fromkeys(("joint_error", "body_pos_error", "fingertip_error", "success", "lost"), 0.0)
        for f in (1, 2, 3, 3, 3):
            ref = clip.joint_pos[f].astype(np.float64)
            pos_r, tips_r = fk(ref)
            joint = np.mean(np.abs(q_c - ref))
            dist = np.linalg.norm(pos_c - pos_r, axis=1)
            tip = np.mean(np.linalg.norm(tips_c - tips_r, axis=1))
            want["joint_error"] += joint
            want["body_pos_error"] += dist.mean()
            want["fingertip_error"] += tip
            want["success"] += float(joint <= 0.05 and tip <= 0.02)
            want["lost"] += float(dist.max() > 0.25)
        for key, value in want.items():
            assert r.sums[key] == pytest.approx(value, abs=1e-6), (clip.name, key)
    near, far = res.clips
    # near: joint errors 0.01, 0.02, 0.03 rad: a success while the fingertips are within 2 cm too.
    assert near.mean("joint_error") == pytest.approx((0.01 + 0.02 + 3 * 0.03) / 5, abs=1e-6)
    assert near.sums["success"] >= 1 and far.sums["success"] == 0 and far.mean("joint_error") > 0.3
    s = summarise(res.clips, "all")
    assert s["steps"] == 10
    assert s["joint_error_rad"] == pytest.approx((near.sums["joint_error"] + far.sums["joint_error"]) / 10)
    assert s["fingertip_error_cm"] == pytest.approx(
        100 * (near.sums["fingertip_error"] + far.sums["fingertip_error"]) / 10
    )
    assert "mean joint error" in res.format() and res.to_dict()["groups"][0]["clips"] == 2


def test_summary_counts_clips_at_the_torque_cap_on_every_target():
    sums = dict.fromkeys(("joint_error", "body_pos_error", "fingertip_error", "success", "lost"), 0.0)
    results = [
        ClipResult("a", 10, sums),
        ClipResult("b", 10, sums, cap_dwell="t=3.50 s: right_wrist_yaw"),  # MJX: counted, not stopped
        ClipResult("c", 4, sums, faulted=True, end_reason="fault torque_saturation: torque at the cap"),
        ClipResult("d", 4, sums, faulted=True, end_reason="fault stale_state: no state for 0.1 s"),
    ]
    s = summarise(results, "all")
    assert (s["faults"], s["cap_dwell_clips"], s["steps"]) == (2, 2, 28)


def test_eval_cli_reports_the_tracking_metric(track_policy, tmp_path, capsys):
    piano = ROBOT.pose("piano_ready")
    clip = Clip.make("tiny", 50.0, piano + 0.01 * np.arange(4)[:, None])
    path = save_clip(clip, tmp_path / "tiny.npz")
    out_json = tmp_path / "eval.json"
    rc = main(
        [
            "eval",
            "--policy",
            str(track_policy.path),
            "--clips",
            str(path),
            "--hold-s",
            "0.1",
            "--json",
            str(out_json),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    first, progress, report = out.split("\n", 2)
    assert first.startswith("provenance: not recorded")  # bar-deploy's first line: the file's provenance
    assert progress.startswith("eval clip 1/1: tiny, joint error ")  # then one progress line per clip
    assert report.startswith(f"tracking (C MuJoCo sim target) policy {track_policy.path}")
    data = json.loads(out_json.read_text())
    assert [c["clip"] for c in data["clips"]] == ["tiny"] and data["clips"][0]["steps"] == 3 + 5
    # The same protocol in process (the sim is deterministic): the CLI printed and wrote these numbers.
    direct = evaluate_track(track_policy, [clip], runner=SimEpisodes(track_policy), hold_s=0.1)
    g = direct.summary
    assert data["groups"][0]["joint_error_rad"] == pytest.approx(g["joint_error_rad"], rel=1e-12)
    want = (
        f"mean joint error {g['joint_error_rad']:.4f} rad, tracked-body position error "
        f"{g['body_pos_error_cm']:.2f} cm, fingertip error {g['fingertip_error_cm']:.2f} cm"
    )
    assert want in out
    # The progress line's figure is the clip's own (one clip: the same means as the summary).
    figure = f"joint error {g['joint_error_rad']:.4f} rad, fingertip {g['fingertip_error_cm']:.2f} cm ("
    assert progress.startswith(f"eval clip 1/1: tiny, {figure}")


def test_plot_overlays_the_reference(track_policy, tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.axes import Axes

    from bar_policy.deploy.log.plot import plot_log, tracking_errors

    piano = ROBOT.pose("piano_ready")
    clip = Clip.make("tiny", 50.0, piano + 0.01 * np.arange(4)[:, None])
    cfg = RuntimeConfig(duration=None, safety=SafetyConfig(ramp_time=0.04), end_hold=0.1)
    res = Runtime(track_policy, SteppedMock(), reference_for(track_policy, clip), cfg, log_dir=tmp_path).run()
    arrays, _ = load_log(res.log_path)

    drawn: list[tuple[str, np.ndarray]] = []
    real_plot = Axes.plot

    def spy(self, *args, **kwargs):
        drawn.append((kwargs.get("label", ""), np.asarray(args[1]) if len(args) > 1 else None))
        return real_plot(self, *args, **kwargs)

    monkeypatch.setattr(Axes, "plot", spy)
    files = plot_log(res.log_path.parent)
    assert [f.name for f in files] == ["joints.png", "torques.png", "tracking.png", "timing.png"]
    refs = [y for label, y in drawn if label == "reference"]
    assert len(refs) == 14  # one reference line per joint panel, the logged ref_q
    for i, y in enumerate(refs):
        np.testing.assert_array_equal(y, arrays["ref_q"][:, i])
    err = tracking_errors(arrays)
    np.testing.assert_allclose(err["joint_error"], np.mean(np.abs(arrays["q"] - arrays["ref_q"]), axis=1))
    k = 4  # a POLICY tick
    tips_q, tips_r = fk(arrays["q"][k])[1], fk(arrays["ref_q"][k])[1]
    np.testing.assert_allclose(err["fingertip_error"][k], np.linalg.norm(tips_q - tips_r, axis=1), atol=1e-12)


def test_emulated_bus_column_follows_the_sim(track_policy):
    """The bench's bus column (RealTarget over virtual CAN to the lockstep emulator) against the sim target
    on a constant command that swings the arms from piano_ready to the default pose: the same steps and no
    fault, errors within 2 % (the emulator feeds back 16-bit states and integrates the law at each step's mean
    state; its start-up round takes no time: 1.4 % measured on the fingertip)."""
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget

    piano = ROBOT.pose("piano_ready")
    clip = Clip.make("tiny", 50.0, piano + 0.01 * np.arange(4)[:, None])
    runner = SimEpisodes(track_policy)
    sim = evaluate_track(track_policy, [clip], runner=runner, hold_s=0.2).clips[0]
    bus_target = EmulatedBusTarget("arms", 0.02)
    try:
        bus = evaluate_track(
            track_policy, [clip], runner=runner, hold_s=0.2, target=bus_target, label="bus"
        ).clips[0]
    finally:
        bus_target.close()
    assert sim.steps == bus.steps == 3 + 10 and not sim.faulted and not bus.faulted
    for key in ("joint_error", "body_pos_error", "fingertip_error"):
        assert bus.sums[key] == pytest.approx(sim.sums[key], rel=0.02), key
    assert sim.mean("joint_error") > 0.3  # a real swing, not a trivially equal standstill
