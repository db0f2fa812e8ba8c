"""Trusting the end of a run: the end reason names the first fault, the stop is confirmed per joint, a policy
far beyond its action range faults, and an ``action_scale`` that reaches beyond the joint ranges is refused.

Runs use the stepped mock (``fault_targets.SteppedMock``: synchronous, clock ``k * dt``) at dt = 0.02 s and
the emulated real target (``targets.emulated``: the real CAN code over an in-process lockstep emulator).
"""

from __future__ import annotations

import numpy as np
import pytest
from fault_targets import SteppedMock
from policy_factory import default_metadata

from bar_policy.deploy.action_path import check_action_scale
from bar_policy.deploy.contract import PolicyLoadError
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.run_config import EXIT_FAULT, EXIT_OK, EXIT_STOP_UNCONFIRMED
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.deploy.targets.base import StopReport
from bar_policy.tasks.reach.commands import SampledCommands

DT = 0.02
TARGET_FAULT = "fault target: target reports faults ['MOTOR_FAULT id 13']"
"""SteppedMock's ``faults_from`` fault, as the supervisor words it."""


def _runtime(policy, target, *, duration, damping=0.5, log_dir=None, on_tick=None, **safety) -> Runtime:
    cfg = RuntimeConfig(
        duration=duration,
        start_mode="policy",
        damping_after_fault=damping,
        handle_signals=False,
        safety=SafetyConfig(**({"ramp_time": 0.0} | safety)),
    )
    cmds = SampledCommands(policy.obs_manager.command_names, seed=0)
    return Runtime(policy, target, cmds, cfg, log_dir=log_dir, on_tick=on_tick)


# -- item 3: the end reason names the first fault --------------------------------------------------------
def test_fault_within_the_damping_time_before_the_end_names_the_fault(zero_policy, tmp_path):
    # duration 1.0 s = 50 ticks (0..49); the fault is reported from read 40 (t = 0.8 s) on, every tick:
    # the damping (0.5 s) would end at t = 1.3 s, after the duration: the loop ends on the duration at
    # tick 49. Faults: reads 40..49 = 10 ticks -> fault_count 10. Before the fix: "duration reached".
    rt = _runtime(zero_policy, SteppedMock(faults_from=40), duration=1.0, log_dir=tmp_path)
    res = rt.run()
    assert res.ticks == 50 and res.fault_count == 10
    assert res.end_reason == TARGET_FAULT
    assert res.final_mode == Mode.DAMPING and res.exit_status == EXIT_FAULT
    _, meta = load_log(res.log_path.parent)
    assert meta["end_reason"] == TARGET_FAULT and meta["fault_count"] == 10
    assert res.end_line().startswith(f"end: {TARGET_FAULT}; final mode DAMPING;")


def test_fault_during_a_requested_stop_is_named_with_the_stop(zero_policy):
    # Stop requested at tick 10 (DAMPING from tick 11, t = 0.22 s; damping 0.5 s -> the end at t = 0.72 s,
    # tick 36); the fault comes at read 20 (t = 0.4 s), while damping: it does not change the mode, but it is
    # the run's first fault, so the end reason names it, with the stop.
    def on_tick(k, t, rt):
        if k == 10:
            rt.request_stop("test stop")

    res = _runtime(zero_policy, SteppedMock(faults_from=20), duration=2.0, on_tick=on_tick).run()
    assert res.stop_reason == "test stop" and res.fault_count == 17  # reads 20..36
    assert res.end_reason == f"{TARGET_FAULT} (during the stop: test stop)"
    assert res.exit_status == EXIT_FAULT


def test_a_run_without_faults_still_ends_on_the_duration(zero_policy):
    res = _runtime(zero_policy, SteppedMock(), duration=0.2).run()
    assert res.end_reason == "duration reached" and res.fault_count == 0 and res.exit_status == EXIT_OK


# -- item 4: the safe stop is confirmed per joint ----------------------------------------------------------
def test_answering_target_confirms_the_stop(zero_policy, tmp_path):
    res = _runtime(zero_policy, SteppedMock(), duration=0.1, log_dir=tmp_path).run()
    assert res.safe_stop == "stop confirmed (damping and stop frames answered by all 14 joints)"
    assert res.stop_confirmed and res.stop_unconfirmed == () and res.exit_status == EXIT_OK
    assert "; safe stop: stop confirmed (" in res.end_line()
    _, meta = load_log(res.log_path.parent)
    assert meta["stop_report"]["confirmed"] is True and meta["stop_report"]["unconfirmed_joints"] == []


class UnansweredStop(SteppedMock):
    """Its ``safe_stop`` reports that ``joint`` answered the damping but not the stop frame."""

    def __init__(self, joint: str) -> None:
        super().__init__()
        self.joint = joint

    def safe_stop(self, q=None, kd=1.0, *, hold_s=None) -> StopReport:
        super().safe_stop(q, kd, hold_s=hold_s)
        names = self.joint_names
        return StopReport(names, (True,) * len(names), tuple(n != self.joint for n in names))


def test_unanswered_stop_names_the_joint_and_the_exit_status_says_so(zero_policy, tmp_path):
    res = _runtime(zero_policy, UnansweredStop("left_elbow_pitch"), duration=0.1, log_dir=tmp_path).run()
    assert res.fault_count == 0 and not res.stop_confirmed
    assert res.stop_unconfirmed == ("left_elbow_pitch",)
    assert "stop confirmed" not in res.safe_stop
    assert res.safe_stop == (
        "stop NOT confirmed for ['left_elbow_pitch']: no reply to the stop frames from ['left_elbow_pitch']"
    )
    assert res.exit_status == EXIT_STOP_UNCONFIRMED == 3
    _, meta = load_log(res.log_path.parent)
    assert meta["safe_stop"] == res.safe_stop and meta["stop_report"]["no_stop_reply"] == ["left_elbow_pitch"]


def test_emulated_real_target_reports_the_motor_that_ignores_the_stop_frame(zero_policy):
    pytest.importorskip("can")
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget
    from bar_policy.robstride.framing import CommType

    target = EmulatedBusTarget("arms", DT, reply_timeout=0.2)
    try:
        target.reset()  # activation (it polls with stop frames) before the injection
        target.emu.inject("right_wrist_roll", drop_replies=-1, drop_only=int(CommType.STOP))
        res = _runtime(zero_policy, target, duration=0.1).run()
    finally:
        target.close()
    assert res.fault_count == 0 and res.stop_unconfirmed == ("right_wrist_roll",)
    assert res.safe_stop == (
        "stop NOT confirmed for ['right_wrist_roll']: no reply to the stop frames from ['right_wrist_roll']"
    )
    assert res.exit_status == EXIT_STOP_UNCONFIRMED


def test_emulated_real_target_with_a_bus_fallen_silent_is_not_confirmed(zero_policy, tmp_path):
    pytest.importorskip("can")
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget

    target = EmulatedBusTarget("arms", DT, reply_timeout=0.1)
    right = tuple(n for n in target.joint_names if n.startswith("right_"))

    def on_tick(k, t, rt):
        if k == 3:
            target.emu.silence("can1")  # the right arm's bus says nothing from now on

    rt = _runtime(zero_policy, target, duration=1.0, log_dir=tmp_path, on_tick=on_tick)
    try:
        res = rt.run()  # tick 4's round misses the right arm's replies: a fault, the run ends, no exception
    finally:
        target.close()
    assert res.end_reason.startswith("fault target: can1: no reply within 100.0 ms from [(21,")
    assert res.exit_status == EXIT_STOP_UNCONFIRMED and res.ticks == 4
    # Neither the damping nor the stop frames of the silent bus (can1: the right arm) were answered; the left
    # arm answered both: the summary names the 7 right joints and never says "stop confirmed".
    report = rt.stop_report
    assert report is not None and not report.confirmed
    assert report.no_damping_reply == right and report.no_stop_reply == right and report.unconfirmed == right
    assert rt.safe_stop_summary.startswith(f"stop NOT confirmed for {list(right)}")
    _, meta = load_log(rt.log_path.parent)
    assert meta["end_reason"] == res.end_reason and meta["safe_stop"] == rt.safe_stop_summary
    assert meta["stop_report"]["unconfirmed_joints"] == list(right)


def test_emulated_real_target_confirms_an_answered_stop(zero_policy):
    pytest.importorskip("can")
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget

    target = EmulatedBusTarget("arms", DT, reply_timeout=0.2)
    try:
        res = _runtime(zero_policy, target, duration=0.1).run()
    finally:
        target.close()
    assert res.stop_confirmed and res.safe_stop.startswith("stop confirmed") and res.exit_status == EXIT_OK


# -- item 6: actions far beyond their range; clip counts; action_scale vs the joint ranges ----------------
def test_policy_far_beyond_its_action_range_faults(make_policy):
    # Bias 1e9 on every action: |a| = 1e9 >= 4 x clip 1.0 from tick 0 (t = 0, POLICY from the first tick).
    # Time out of range after tick k: (k + 1) * 0.02 s; the fault needs > 0.2 s: k + 1 = 11 -> tick 10,
    # t = 0.2 s = 0.2 s after the first such tick (the stated 0.2 s; < 0.2 s + 1 tick). Ticks 0..9 are applied
    # (clipped to +-1): 10 x 14 = 140 action entries clipped, of 140 applied; q_cmd = default + 0.25 stays
    # within every joint's range (largest: right_wrist_yaw 1.2 + 0.25 = 1.45 < 1.571) -> 0 q_cmd clips.
    # Then DAMPING for 0.1 s: the run ends at t = 0.3 s, tick 15 -> 16 ticks.
    pol = load_policy(make_policy(bias=1e9))
    target = SteppedMock()
    res = _runtime(pol, target, duration=5.0, damping=0.1).run()
    faults = [tr for tr in res.transitions if tr["from"] == "POLICY"]
    assert faults[0]["reason"].startswith("fault action_out_of_range: raw action beyond 4 x the clip bound 1")
    assert faults[0]["tick"] == 10 and faults[0]["t"] == pytest.approx(0.2)
    assert res.end_reason.startswith("fault action_out_of_range:") and res.ticks == 16
    assert res.final_mode == Mode.DAMPING and res.exit_status == EXIT_FAULT
    # The safe state: damping (Kp = 0) from the fault on, and the safe stop's damping command last.
    for c in target.commands[10:]:
        np.testing.assert_array_equal(c.kp, 0.0)
    assert len(target.commands) == 16 + 1
    assert res.action_clip_count == 140 and res.action_count == 140 and res.clip_count == 0
    assert "; q_cmd clipped 0 joint-ticks; actions clipped 140 of 140 entries; safe stop: stop confirmed" in (
        res.end_line()
    )


def test_policy_within_its_action_range_factor_runs_to_the_end(make_policy):
    # Bias 2: clipped every tick (14 entries x 10 ticks = 140) but |a| = 2 < 4 x 1: no fault.
    res = _runtime(load_policy(make_policy(bias=2.0)), SteppedMock(), duration=0.2).run()
    assert res.fault_count == 0 and res.end_reason == "duration reached"
    assert res.action_clip_count == 140 and "actions clipped 140 of 140 entries" in res.end_line()


def test_action_scale_beyond_the_joint_range_is_refused(make_policy):
    # left_elbow_pitch (action 3): default -1.7, range [-2.356, 0] rad; action_scale 3.0 at +-1 reaches
    # [-1.7 - 3, -1.7 + 3] = [-4.7, 1.3] rad: 2.344 rad below and 1.3 rad above the range (> 0.5 rad margin).
    scale = [0.25] * 14
    scale[3] = 3.0
    # Refused at load (load_policy), and again by the Runtime for a policy object built otherwise.
    path = make_policy(metadata=default_metadata(action_scale=tuple(scale)))
    with pytest.raises(PolicyLoadError) as at_load:
        load_policy(path)
    assert "left_elbow_pitch: action_scale 3 rad x +-1" in str(at_load.value)
    from unittest import mock

    with mock.patch("bar_policy.deploy.policy.check_action_scale", return_value=[]):
        pol = load_policy(path)
    with pytest.raises(PolicyLoadError) as err:
        _runtime(pol, SteppedMock(), duration=0.1)
    msg = str(err.value)
    assert "left_elbow_pitch: action_scale 3 rad x +-1 from the default -1.7 rad" in msg  # 4 digits
    assert "reaches [-4.7, +1.3] rad, beyond its range [-2.356, +0] rad by more than 0.5 rad" in msg
    assert msg.count("action_scale 3 ") == 1  # the other joints (0.25) are fine


def test_check_action_scale_is_pure_and_passes_the_shipped_policies():
    # One joint, range [-1, 1]: default 0, scale 1.4 reaches [-1.4, 1.4]: 0.4 beyond, within the 0.5 margin.
    lo, up = np.array([-1.0]), np.array([1.0])
    assert check_action_scale([0.0], [1.4], lo, up, ["j"]) == []
    # scale 1.6 reaches 0.6 beyond: refused; with a clip of 0.5 it reaches [-0.8, 0.8]: fine.
    assert check_action_scale([0.0], [1.6], lo, up, ["j"])[0].startswith("j: action_scale 1.6 rad x +-1")
    assert check_action_scale([0.0], [1.6], lo, up, ["j"], bound=0.5) == []
    assert "not a finite number" in check_action_scale([0.0], [np.nan], lo, up, ["j"])[0]
    from pathlib import Path

    for name in ("lite_reach_arms.onnx", "lite_track_arms.onnx"):
        path = Path(__file__).resolve().parents[2] / "checkpoints" / name
        pol = load_policy(path)
        idx = pol.action_index
        names = [pol.robot.joint_names[i] for i in idx]
        default = pol.default_joint_pos[idx]
        assert (
            check_action_scale(default, pol.action_scale, pol.robot.lower[idx], pol.robot.upper[idx], names)
            == []
        )
