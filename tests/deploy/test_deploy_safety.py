"""Modes and faults: every fault ends in DAMPING with its reason; the ramp, the clip count, the supervisor."""

from __future__ import annotations

import dataclasses
import logging
import os
import signal

import numpy as np
import pytest
from fault_targets import SlowMock, SteppedMock
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import CapDwell, Mode, SafetyConfig, SafetySupervisor
from bar_policy.deploy.targets.base import JointState
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.reach.commands import SampledCommands

DEFAULT = np.array([0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3, 0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3])
"""piano_ready, the default pose of the reach layout, rad."""


def _run(policy, target, *, duration=1.0, start="policy", log_dir=None, on_tick=None, **safety):
    cfg = RuntimeConfig(
        duration=duration,
        start_mode=start,
        damping_after_fault=0.1,
        # Damping alone (tau_ff = 0) in these tests of the fault rules; the gravity-compensated damping (the
        # default) has its own tests in test_stop_sequence.py.
        stop_damping="plain",
        safety=SafetyConfig(**({"ramp_time": 0.0} | safety)),
    )
    cmds = SampledCommands(policy.obs_manager.command_names, seed=0)
    rt = Runtime(policy, target, cmds, cfg, log_dir=log_dir, on_tick=on_tick)
    return rt, rt.run()


def _fault_transition(result):
    faults = [tr for tr in result.transitions if tr["reason"].startswith("fault")]
    assert len(faults) == 1, result.transitions
    return faults[0]


def _assert_damping_after(target, tick, q_captured, kd=1.0):
    """Every command from ``tick + 1`` on is damping: Kp = 0, Kd = kd, q_cmd = captured q, dq = tau_ff = 0."""
    after = target.commands[tick + 1 :]
    assert after, "no command after the fault"
    for c in after:
        np.testing.assert_array_equal(c.kp, 0.0)
        np.testing.assert_array_equal(c.kd, kd)
        np.testing.assert_array_equal(c.q, q_captured)
        np.testing.assert_array_equal(c.dq, 0.0)
        np.testing.assert_array_equal(c.tau_ff, 0.0)


def test_policy_mode_commands_default_plus_scaled_action_clipped_and_counted(make_policy):
    # action_scale 1.1 on left_elbow_pitch (index 3), 0.25 elsewhere (reach -1.7 -+ 1.1 = [-2.8, -0.6] rad:
    # within 0.5 rad of the range [-2.356, 0], so the policy is not refused).
    # b[3] = -0.9: -1.7 - 1.1 * 0.9 = -2.69 < lower limit -2.356 -> q_cmd clipped to it (a joint-limit clip).
    # b[5] = 3.0: outside the action bound +-1 -> used as 1.0 (an action clip): 0 + 0.25 * 1 = 0.25.
    scale = [0.25] * 14
    scale[3] = 1.1
    b = np.zeros(14)
    b[0], b[3], b[5], b[9] = 0.4, -0.9, 3.0, -0.8
    pol = load_policy(make_policy(bias=b, metadata=default_metadata(action_scale=tuple(scale))))
    target = SteppedMock()
    _, res = _run(pol, target, duration=0.2)
    assert res.ticks == 10 and res.fault_count == 0
    a = b.astype(np.float32).astype(np.float64)
    expected = DEFAULT + 0.25 * a
    expected[3] = load_robot("arms").lower[3]
    expected[5] = 0.25
    for c in target.commands[:10]:
        np.testing.assert_allclose(c.q, expected, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(c.kp, 50.0)
        np.testing.assert_array_equal(c.kd, 2.0)
        np.testing.assert_array_equal(c.dq, 0.0)
        np.testing.assert_array_equal(c.tau_ff, 0.0)
    assert res.clip_count == 10  # one joint clipped to its limit in each of the 10 ticks
    assert res.action_clip_count == 10  # one action entry clipped to +-1 in each tick
    assert res.end_reason == "duration reached" and res.final_mode == Mode.DAMPING


def test_action_clip_from_metadata_or_disabled(make_policy):
    b = np.zeros(14)
    b[5] = 3.0
    # bar.action_clip = null: no action clip; q_cmd = 0 + 0.25 * 3 = 0.75, then the wrist_roll limit
    # 0.698132 rad clips it (a joint-limit clip, counted).
    pol = load_policy(make_policy(name="n.onnx", bias=b, props={"bar.action_clip": "null"}))
    assert pol.action_clip is None
    target = SteppedMock()
    _, res = _run(pol, target, duration=0.04)
    assert res.action_clip_count == 0 and res.clip_count == 2
    assert target.commands[0].q[5] == pytest.approx(0.698132, abs=1e-6)
    pol = load_policy(make_policy(name="h.onnx", bias=b, props={"bar.action_clip": "0.5"}))
    assert pol.action_clip == 0.5
    target = SteppedMock()
    _run(pol, target, duration=0.04)
    assert target.commands[0].q[5] == pytest.approx(0.125, abs=1e-12)  # 0.25 * 0.5


def test_hold_ramps_pose_and_gains_then_hands_over_to_policy(zero_policy):
    q0 = DEFAULT + 0.2
    target = SteppedMock(initial_q=q0)
    _, res = _run(zero_policy, target, duration=1.4, start="hold", ramp_time=1.0)
    modes = [(tr["from"], tr["to"], tr["tick"]) for tr in res.transitions]
    assert modes[:3] == [("ZERO_TORQUE", "DAMPING", 0), ("DAMPING", "HOLD", 0), ("HOLD", "POLICY", 50)]
    # Tick 25: t = 0.5 s, alpha = 0.5, smoothstep(0.5) = 0.5 -> halfway, Kp = 25, Kd = 1 + 0.5 * (2 - 1).
    c = target.commands[25]
    np.testing.assert_allclose(c.q, q0 + 0.5 * (DEFAULT - q0), atol=1e-12)
    np.testing.assert_allclose(c.kp, 25.0, atol=1e-12)
    np.testing.assert_allclose(c.kd, 1.5, atol=1e-12)
    # Tick 0: Kp = 0, Kd = the damping Kd, q_cmd = the starting pose.
    np.testing.assert_allclose(target.commands[0].kp, 0.0)
    np.testing.assert_allclose(target.commands[0].kd, 1.0)
    np.testing.assert_allclose(target.commands[0].q, q0)
    # Tick 50 (POLICY, action 0): the default pose with the full gains.
    np.testing.assert_allclose(target.commands[50].q, DEFAULT, atol=1e-12)
    np.testing.assert_allclose(target.commands[50].kp, 50.0)


class _NanAfterLoad:
    """An onnxruntime session stand-in: the loaded network's answer with action 5 NaN.

    A network that is finite on the default observation (``load_policy`` refuses one that is not) but turns
    NaN on a live one: the runtime's own check must catch it.
    """

    def __init__(self, session) -> None:
        self.session = session

    def run(self, names, feeds):
        out = self.session.run(names, feeds)
        out[0][0, 5] = np.nan
        return out


def test_nan_action_goes_to_damping(make_policy):
    pol = load_policy(make_policy())
    pol = dataclasses.replace(pol, session=_NanAfterLoad(pol.session))
    target = SteppedMock()
    _, res = _run(pol, target)
    tr = _fault_transition(res)
    assert (tr["from"], tr["to"], tr["tick"]) == ("POLICY", "DAMPING", 0)
    assert "nonfinite_action" in tr["reason"] and "[5]" in tr["reason"]
    assert res.final_mode == Mode.DAMPING
    _assert_damping_after(target, -1, DEFAULT)  # damping from the very first command
    # 0.1 s of damping after the fault, then the run ends: ticks 0..5.
    assert res.ticks == 6 and res.end_reason.startswith("fault nonfinite_action")


def test_nan_state_goes_to_damping_holding_the_last_finite_q(zero_policy):
    target = SteppedMock(nan_from=7)
    _, res = _run(zero_policy, target)
    tr = _fault_transition(res)
    assert tr["tick"] == 7 and "nonfinite_state" in tr["reason"] and "left_shoulder_yaw" in tr["reason"]
    _assert_damping_after(target, 6, DEFAULT)


def test_stale_state_goes_to_damping(zero_policy):
    # Stamp frozen at read 10 (t = 0.2 s); timeout 0.05 s: age at tick k is (k - 10) * 0.02 s, so tick 12
    # is 0.04 s (fresh enough) and tick 13 is 0.06 s: stale.
    target = SteppedMock(freeze_from=10)
    _, res = _run(zero_policy, target, stale_timeout=0.05)
    tr = _fault_transition(res)
    assert tr["tick"] == 13 and "stale_state" in tr["reason"] and "60.0 ms old" in tr["reason"]
    _assert_damping_after(target, 13, DEFAULT)


def test_joint_beyond_limit_margin_goes_to_damping(zero_policy):
    # left_elbow_pitch upper limit 0 rad, default -1.7: +1.85 reports 0.15 rad, beyond 0 + margin 0.1.
    off = np.zeros(14)
    off[3] = 1.85
    target = SteppedMock(offset_from=5, offset=off)
    _, res = _run(zero_policy, target)
    tr = _fault_transition(res)
    assert tr["tick"] == 5 and "joint_limit" in tr["reason"] and "left_elbow_pitch q=0.150" in tr["reason"]
    expected = DEFAULT + off
    _assert_damping_after(target, 5, expected)


def test_joint_within_limit_margin_is_no_fault(zero_policy):
    off = np.zeros(14)
    off[3] = 1.75  # 0.05 rad beyond the limit: inside the 0.1 rad margin
    _, res = _run(zero_policy, SteppedMock(offset_from=0, offset=off), duration=0.2, saturation_time=10.0)
    assert res.fault_count == 0


def test_torque_at_cap_too_long_goes_to_damping(zero_policy):
    # The target reports left_shoulder_pitch 1 rad below its command: demand Kp * 1 = 50 N*m >= cap 17.
    # Tick 0's reading has no torque (no command written yet); from tick 1 on the motor reports its cap,
    # 17 N*m (its law at the reported q). Time at the cap after tick k is k * 0.02 s, past 0.5 s at k = 26.
    off = np.zeros(14)
    off[0] = -1.0
    target = SteppedMock(offset_from=0, offset=off)
    _, res = _run(zero_policy, target)
    tr = _fault_transition(res)
    assert tr["tick"] == 26 and "torque_saturation" in tr["reason"] and "left_shoulder_pitch" in tr["reason"]
    assert "50.00 N*m asked, 17.00 reported, cap 17" in tr["reason"]
    # The fault tick itself already sends damping (the command is recomputed after the check).
    _assert_damping_after(target, 25, DEFAULT + off)


def test_a_demand_over_the_cap_while_the_motor_reports_little_is_no_fault(zero_policy):
    # The same 1 rad gap, but the motor reports the echo's torque (the law at the true q, which followed
    # the command: ~0 N*m), as a motor applying an older command under latency does: 50 N*m asked for
    # 1 s, never a fault (the demand alone would fault at tick 25, test above), and the quality meter
    # counts no tick at the cap either.
    off = np.zeros(14)
    off[0] = -1.0

    class LeadMock(SteppedMock):
        def read_state(self):
            s = super().read_state()
            return JointState(q=s.q, dq=s.dq, tau=np.full(14, 0.5), stamp=s.stamp, faults=s.faults)

    rt, res = _run(zero_policy, LeadMock(offset_from=0, offset=off), duration=1.0)
    assert res.fault_count == 0 and res.end_reason.startswith("duration reached"), res.end_reason
    assert rt.quality.cap_ticks == 0 and rt.quality.ticks == 50


def test_target_fault_report_goes_to_damping(zero_policy):
    target = SteppedMock(faults_from=3)
    _, res = _run(zero_policy, target)
    tr = _fault_transition(res)
    assert tr["tick"] == 3 and "MOTOR_FAULT id 13" in tr["reason"]
    _assert_damping_after(target, 3, DEFAULT)  # damping holds the pose of the faulty reading


def test_loop_overruns_go_to_damping(make_policy, tmp_path):
    pol = load_policy(make_policy())
    # Asynchronous mock, 50 Hz; from read 3 on every read takes 30 ms > 20 ms, so ticks 3, 4, 5 overrun
    # and the third consecutive overrun (tick 5) trips max_overruns = 3. (On a loaded machine an earlier
    # tick may overrun too; the fault is then at the first run of 3 consecutive overruns in the log.)
    target = SlowMock(slow_from=3, delay=0.03)
    _, res = _run(pol, target, duration=2.0, max_overruns=3, log_dir=tmp_path)
    tr = _fault_transition(res)
    assert "overrun" in tr["reason"] and "3 consecutive" in tr["reason"]
    ov = load_log(res.log_path)[0]["overrun"]
    first_run_of_3 = next(k for k in range(2, ov.size) if ov[k - 2 : k + 1].all())
    assert tr["tick"] == first_run_of_3 <= 5
    assert ov[3:6].all()  # the slow reads always overrun


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_stop_signal_goes_to_damping_and_is_not_a_fault(zero_policy, sig, tmp_path):
    target = SteppedMock()

    def on_tick(k, t, rt):
        if k == 10:
            os.kill(os.getpid(), sig)

    previous = signal.getsignal(sig)
    _rt, res = _run(zero_policy, target, on_tick=on_tick, log_dir=tmp_path)
    assert signal.getsignal(sig) is previous  # handler restored
    # The request is seen at the next tick (11): POLICY -> DAMPING with the signal as reason.
    (tr,) = [tr for tr in res.transitions if tr["reason"].startswith("stop requested")]
    assert tr["tick"] == 11 and tr["reason"] == f"stop requested: {sig.name} received"
    assert (tr["from"], tr["to"]) == ("POLICY", "DAMPING")
    assert res.fault_count == 0 and res.stop_reason == f"{sig.name} received"
    # damping_after_fault 0.1 s = 5 ticks of damping after tick 11: ticks 0..16 ran, then the safe stop.
    assert (
        res.ticks == 17
        and res.end_reason == f"{sig.name} received"
        and res.safe_stop.startswith("stop confirmed")
    )
    _assert_damping_after(target, 10, DEFAULT)
    arrays, meta = load_log(res.log_path)
    assert meta["stop_signal"] == sig.name and meta["stop_signals_received"] == 1
    assert meta["safe_stop"].startswith("stop confirmed") and meta["status"] == "closed"
    np.testing.assert_array_equal(arrays["mode"][11:], int(Mode.DAMPING))


def test_second_signal_is_counted_and_cannot_skip_the_stop(zero_policy, tmp_path):
    target = SteppedMock()

    def on_tick(k, t, rt):
        if k in (2, 4):
            os.kill(os.getpid(), signal.SIGINT if k == 2 else signal.SIGTERM)

    rt = Runtime(
        zero_policy,
        target,
        SampledCommands(zero_policy.obs_manager.command_names),
        RuntimeConfig(duration=1.0, start_mode="policy", damping_after_fault=0.2, stop_damping="plain"),
        log_dir=tmp_path,
        on_tick=on_tick,
    )
    res = rt.run()  # no KeyboardInterrupt: the second signal is counted, never raised
    # Stop seen at tick 3; 0.2 s (10 ticks) of damping: ticks 0..13, then the safe stop's damping command.
    assert res.ticks == 14 and res.end_reason == "SIGINT received" and res.fault_count == 0
    assert len(target.commands) == 15
    _assert_damping_after(target, 2, DEFAULT)
    arrays, meta = load_log(rt.log_path)
    assert arrays["t"].shape == (14,)
    assert meta["stop_signal"] == "SIGINT" and meta["stop_signals_received"] == 2
    assert meta["safe_stop"].startswith("stop confirmed")


def test_exception_mid_run_still_writes_the_log(zero_policy, tmp_path):
    target = SteppedMock(raise_at=30)
    rt = Runtime(
        zero_policy,
        target,
        SampledCommands(zero_policy.obs_manager.command_names),
        RuntimeConfig(duration=2.0, start_mode="policy"),
        log_dir=tmp_path,
    )
    # A target error ends the run as a fault (the target is past commanding): no exception, the end line
    # and exit status 1, the log holds the 30 ticks before it.
    res = rt.run()
    arrays, meta = load_log(rt.log_path)
    assert arrays["q"].shape == (30, 14)
    np.testing.assert_allclose(arrays["t"], np.arange(30) * 0.02, atol=1e-12)
    assert meta["end_reason"] == res.end_reason == "fault target: injected bus failure at read 30"
    assert res.exit_status == 1 and res.end_line().startswith("end: fault target: injected bus failure")
    assert meta["transitions"][-1]["to"] == "DAMPING"
    assert meta["transitions"][-1]["reason"] == "fault target: injected bus failure at read 30"
    assert rt.safety.mode == Mode.DAMPING


def test_fault_transitions_are_logged_with_reason(zero_policy, caplog):
    with caplog.at_level(logging.INFO, logger="bar_policy.deploy"):
        _run(zero_policy, SteppedMock(nan_from=3))
    msgs = [r.getMessage() for r in caplog.records if r.name == "bar_policy.deploy.safety"]
    assert any("POLICY -> DAMPING" in m and "nonfinite_state" in m for m in msgs)
    warn = [r for r in caplog.records if "POLICY -> DAMPING" in r.getMessage()]
    assert warn[0].levelno == logging.WARNING


def test_start_refused_when_first_state_is_bad(zero_policy):
    _, res = _run(zero_policy, SteppedMock(nan_from=0))
    assert res.transitions[0]["to"] == "DAMPING" and "start refused" in res.transitions[0]["reason"]
    assert all(tr["to"] != "POLICY" for tr in res.transitions)


# -- the supervisor alone ---------------------------------------------------------------------------
def _supervisor(**cfg) -> SafetySupervisor:
    r = load_robot("arms")
    return SafetySupervisor(
        joint_names=r.joint_names,
        lower=r.lower,
        upper=r.upper,
        torque_cap=r.torque_cap,
        kp=r.kp,
        kd=r.kd,
        default_q=DEFAULT,
        config=SafetyConfig(**cfg),
    )


def test_zero_torque_mode_is_all_zeros():
    sf = _supervisor()
    c = sf.command(0.0)
    for f in c:
        np.testing.assert_array_equal(f, np.zeros(14))


def test_damping_latches_faults_do_not_leave_it():
    sf = _supervisor()
    state = JointState(q=DEFAULT.copy(), dq=np.zeros(14), tau=np.zeros(14), stamp=0.0)
    assert sf.check_state(state, 0.0) is None
    sf.transition(Mode.DAMPING, "test", 0.0)
    assert sf.fault("overrun", "x", 0.1) is False
    assert sf.mode == Mode.DAMPING and sf.fault_count == 1
    c = sf.command(0.2)
    np.testing.assert_array_equal(c.q, DEFAULT)
    np.testing.assert_array_equal(c.kd, 1.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"ramp_time": -1.0},
        {"damping_kd": 0.0},
        {"saturation_fraction": 1.5},
        {"saturation_reported_fraction": 1.2},
        {"max_overruns": -1},
    ],
)
def test_safety_config_validates(kwargs):
    with pytest.raises(ValueError, match="SafetyConfig"):
        SafetyConfig(**kwargs)


def test_make_policy_file_is_reusable(tmp_path):
    # The factory is the fixture other test suites use: a loadable file with the full key set.
    p = make_policy_file(tmp_path / "x.onnx", bias=0.1)
    assert load_policy(p).metadata.code_version == "test"


def test_cap_dwell_counts_unbroken_runs_at_the_cap_per_joint():
    # Caps 2 and 4 N*m, 0.05 s allowed, 0.02 s ticks; worked by hand. A sign flip at the cap (25 Hz
    # bang-bang, what the shipped tracker does on 3 held-out clips) stays at the cap.
    d = CapDwell(np.array([2.0, 4.0]), 0.05)
    steps = [
        ([2.0, 0.0], [0.02, 0.0], []),
        ([-2.5, 4.0], [0.04, 0.02], []),
        ([2.0, -3.9], [0.06, 0.0], [0]),  # joint 0 past 0.05 s; joint 1 left the cap
        ([1.9, 5.0], [0.0, 0.02], []),
        ([-2.0, -4.0], [0.02, 0.04], []),
    ]
    for demand, want_time, want_over in steps:
        over = d.update(np.array(demand), 0.02)
        np.testing.assert_allclose(d.time, want_time, atol=1e-12)
        assert over.tolist() == want_over
    d.reset()
    assert d.time.tolist() == [0.0, 0.0] and d.over().size == 0


def test_cap_dwell_with_a_reported_level_needs_the_motor_at_it_too():
    # Caps 2 and 4 N*m, reported levels 1.6 and 3.2 N*m (0.8 x), 0.05 s allowed, 0.02 s ticks; by hand.
    d = CapDwell(np.array([2.0, 4.0]), 0.05, np.array([1.6, 3.2]))
    steps = [
        ([2.0, 5.0], [1.6, 0.3], [0.02, 0.0], []),  # joint 1: asked 5, the motor reports 0.3 (a lead)
        ([2.5, 5.0], [-2.0, 3.2], [0.04, 0.02], []),
        ([2.1, -4.0], [1.9, -3.5], [0.06, 0.04], [0]),
        ([3.0, 4.0], [1.5, 3.3], [0.0, 0.06], [1]),  # joint 0's motor below its level: the run breaks
        ([3.0, 4.0], None, [0.02, 0.08], [1]),  # no reading of the torque: the demand alone
    ]
    for demand, reported, want_time, want_over in steps:
        over = d.update(np.array(demand), 0.02, None if reported is None else np.array(reported))
        np.testing.assert_allclose(d.time, want_time, atol=1e-12)
        assert over.tolist() == want_over
