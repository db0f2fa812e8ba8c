"""One contract, two dialects: ``bar.*`` + HC keys must agree; HC-only files (as mjlab writes them) run.

Expected values are worked out by hand from the HC rules (lite-model.md 2.1): ``joint_pos = (q - default)``,
``joint_vel`` raw, ``actions`` = the previous action, target ``default + scale * action`` on the driven
joints, undriven joints pinned at 0 rad with the file's Kp / Kd.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from fault_targets import SteppedMock
from policy_factory import default_metadata, hc_props, make_hc_policy_file, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.policy import PolicyLoadError, load_policy, read_metadata
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.obs.terms import TERM_CATALOG
from bar_policy.tasks.reach.commands import SampledCommands

D = np.array([0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3, 0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3])
"""piano_ready, rad (canonical order: 7 left-arm joints, then 7 right-arm joints)."""
LEFT = (
    "left_shoulder_pitch",
    "left_shoulder_roll",
    "left_shoulder_yaw",
    "left_elbow_pitch",
    "left_wrist_yaw",
    "left_wrist_roll",
    "left_wrist_pitch",
)
REACH_TERMS = (
    "joint_pos",
    "joint_vel",
    "actions",
    "fingertip_pos_left",
    "fingertip_pos_right",
    "target_pos_left",
    "target_pos_right",
)


# ---------------------------------------------------------------------------------------------------
# Both dialects in one file: they must agree
# ---------------------------------------------------------------------------------------------------
def _swap_first_two(csv: str) -> str:
    items = csv.split(",")
    items[0], items[1] = items[1], items[0]
    return ",".join(items)


def _bump(index: int, delta: float):
    def edit(csv: str) -> str:
        items = [float(x) for x in csv.split(",")]
        items[index] += delta
        return ",".join(f"{x:.6g}" for x in items)

    return edit


MISMATCHES = [
    ("joint_names", _swap_first_two, "index 0 is 'left_shoulder_pitch' vs 'left_shoulder_roll'"),
    ("action_joint_names", _swap_first_two, "index 0 is 'left_shoulder_pitch' vs 'left_shoulder_roll'"),
    ("joint_stiffness", _bump(3, -10.0), "left_elbow_pitch: 50 vs 40"),
    ("joint_damping", _bump(13, 0.5), "right_wrist_pitch: 2 vs 2.5"),
    ("default_joint_pos", _bump(0, 0.01), "left_shoulder_pitch: 0.3 vs 0.31"),
    ("action_scale", _bump(6, 0.25), "left_wrist_pitch: 0.25 vs 0.5"),
    ("policy_dt", lambda v: "0.04", "policy_dt: 0.02 vs 0.04"),
    ("command_names", lambda v: "target_pos_right,target_pos_left", "index 0 is 'target_pos_left'"),
]


@pytest.mark.parametrize(("key", "edit", "detail"), MISMATCHES, ids=[m[0] for m in MISMATCHES])
def test_both_dialects_must_agree_and_the_refusal_names_the_key(key, edit, detail, tmp_path):
    props = default_metadata().to_props()
    path = make_policy_file(tmp_path / "p.onnx", props={key: edit(props[key])})
    with pytest.raises(PolicyLoadError) as e:
        load_policy(path)
    msg = str(e.value)
    assert f"metadata keys 'bar.{key}' and '{key}' (Humanoid Control) disagree" in msg
    assert detail in msg


def test_observation_names_must_match_the_schema_terms(tmp_path):
    props = default_metadata().to_props()
    terms = props["observation_names"].split(",")
    path = make_policy_file(tmp_path / "p.onnx", props={"observation_names": ",".join(terms[:-1])})
    with pytest.raises(PolicyLoadError, match=r"'bar\.obs_schema' .* and 'observation_names' .* disagree"):
        load_policy(path)


def test_hc_copy_within_its_six_digits_is_accepted(tmp_path):
    # The HC form is written with %.6g: 0.123456789 -> "0.123457" (relative error 1.7e-6 < 1e-5).
    scale = (0.123456789,) + (0.25,) * 13
    path = make_policy_file(tmp_path / "p.onnx", metadata=default_metadata(action_scale=scale))
    pol = load_policy(path)
    assert pol.action_scale[0] == 0.123456789  # the exact bar.* value is the one used
    assert pol.metadata.dialect == "bar"


# ---------------------------------------------------------------------------------------------------
# HC-only files
# ---------------------------------------------------------------------------------------------------
def _left_arm_policy(tmp_path):
    """HC-only, task 'tracking', drives the left arm; obs joint_pos(14), joint_vel(14), actions(7) = 35.

    actions = 0.2 + 0.5 * previous action (same index), plus 1.0 * joint_pos[right_shoulder_pitch] on
    action 0.
    """
    props = hc_props(action_joint_names=LEFT, stiffness=30.0, damping=1.5, action_scale=0.5)
    w = np.zeros((35, 7))
    w[28 + np.arange(7), np.arange(7)] = 0.5
    w[7, 0] = 1.0
    return make_hc_policy_file(tmp_path / "hc.onnx", props, obs_size=35, weight=w, bias=0.2)


def test_hc_only_file_loads_with_schema_and_gains_from_its_keys(tmp_path):
    pol = load_policy(_left_arm_policy(tmp_path))
    assert pol.metadata.dialect == "hc" and pol.metadata.task == "tracking"
    assert pol.robot.mode == "arms" and pol.metadata.physics_dt is None
    assert pol.obs_manager.term_names == ("joint_pos", "joint_vel", "actions") and pol.obs_manager.size == 35
    assert pol.obs_manager.command_names == ()
    assert pol.action_clip is None  # HC applies no action clip
    np.testing.assert_array_equal(pol.kp, 30.0)  # from the file, not the robot data (50 / 2)
    np.testing.assert_array_equal(pol.kd, 1.5)
    # HOLD goes where the policy starts: the default pose on the left arm, 0 on the undriven right arm.
    np.testing.assert_array_equal(pol.hold_pose, np.r_[D[:7], np.zeros(7)])
    assert read_metadata(pol.path).obs_fingerprint == pol.obs_manager.fingerprint


def test_hc_only_file_runs_with_hc_semantics(tmp_path):
    pol = load_policy(_left_arm_policy(tmp_path))
    target = SteppedMock()  # starts at piano_ready, echoes q_cmd into q (dq = dq_cmd = 0)
    cfg = RuntimeConfig(duration=0.06, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    rt = Runtime(pol, target, SampledCommands(()), cfg, log_dir=tmp_path / "runs")
    res = rt.run()
    assert res.ticks == 3 and res.fault_count == 0
    f32 = float(np.float32(0.2))
    # tick 0: obs 0 -> action 0.2; tick 1: action = 0.2 + 0.5 * 0.2 (+ joint_pos[7] = 0 - 0.3 on action 0);
    # tick 2: action = 0.2 + 0.5 * action_1 (+ -0.3 on action 0).
    actions = [np.full(7, 0.2), np.full(7, 0.3), np.full(7, 0.35)]
    actions[1][0], actions[2][0] = 0.0, -0.1
    for k, a in enumerate(actions):
        c = target.commands[k]
        np.testing.assert_allclose(c.q[:7], D[:7] + 0.5 * a, atol=1e-6)
        np.testing.assert_array_equal(c.q[7:], 0.0)  # undriven: pinned at 0 rad ...
        np.testing.assert_array_equal(c.kp, 30.0)  # ... with the policy's K and D
        np.testing.assert_array_equal(c.kd, 1.5)
    arrays, meta = load_log(res.log_path)
    assert meta["policy_dialect"] == "hc"
    obs1 = arrays["obs"][1]  # [q - default (14), dq (14), previous action (7)]
    np.testing.assert_allclose(obs1[:7], 0.5 * f32, atol=1e-6)
    np.testing.assert_allclose(obs1[7:14], -D[7:], atol=1e-6)
    np.testing.assert_array_equal(obs1[14:28], 0.0)
    np.testing.assert_allclose(obs1[28:], f32, atol=0)


def test_hc_only_reach_file_runs_through_bar_deploy_on_sim(tmp_path, capsys):
    # Our reach terms in an HC-only file: the command source feeds the two targets.
    props = hc_props(
        task_type="reach_from_mjlab",
        stiffness=50.0,
        damping=2.0,
        observation_names=REACH_TERMS,
        command_names=("target_pos_left", "target_pos_right"),
    )
    path = make_hc_policy_file(tmp_path / "hc_reach.onnx", props, obs_size=54, bias=0.1)
    rc = main(
        [
            "--policy",
            str(path),
            "--target",
            "sim",
            "--duration",
            "0.3",
            "--ramp-time",
            "0.1",
            "--log",
            str(tmp_path / "runs"),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    arrays, meta = load_log(next((tmp_path / "runs").iterdir()))
    assert meta["policy_dialect"] == "hc" and meta["end_reason"] == "duration reached"
    np.testing.assert_allclose(arrays["q_cmd"][-2], D + 0.5 * np.float32(0.1), atol=1e-6)
    assert np.isfinite(arrays["target_pos_left"]).all()


def test_hc_only_unknown_terms_are_refused_with_the_supported_list(tmp_path):
    path = make_hc_policy_file(
        tmp_path / "u.onnx",
        hc_props(observation_names=("base_lin_vel", "joint_pos", "joint_vel", "actions")),
        obs_size=45,
    )
    with pytest.raises(PolicyLoadError) as e:
        load_policy(path)
    msg = str(e.value)
    assert "metadata key 'observation_names' uses terms ['base_lin_vel'] that this runtime cannot feed" in msg
    supported = msg.split("supported terms: ")[1]
    for term in REACH_TERMS:  # HC's built-ins and our reach terms
        assert f"'{term}'" in supported
    assert "imu_angular_velocity" not in supported  # catalogued, but nothing feeds an IMU here


def test_hc_only_imu_term_is_refused(tmp_path):
    assert "imu_angular_velocity" in TERM_CATALOG
    props = hc_props(observation_names=("joint_pos", "imu_angular_velocity"))
    path = make_hc_policy_file(tmp_path / "imu.onnx", props, obs_size=17)
    with pytest.raises(PolicyLoadError, match=r"uses terms \['imu_angular_velocity'\] that this runtime"):
        load_policy(path)


def test_hc_only_unknown_command_is_refused(tmp_path):
    path = make_hc_policy_file(tmp_path / "c.onnx", hc_props(command_names=("motion",)), obs_size=42)
    with pytest.raises(PolicyLoadError, match=r"'command_names' uses terms \['motion'\]"):
        load_policy(path)


def test_hc_only_command_names_must_be_the_observation_commands(tmp_path):
    props = hc_props(observation_names=REACH_TERMS, command_names=("target_pos_left",))
    path = make_hc_policy_file(tmp_path / "c.onnx", props, obs_size=54)
    with pytest.raises(
        PolicyLoadError, match="'command_names' \\['target_pos_left'\\] differs from the command"
    ):
        load_policy(path)


def test_hc_only_joint_order_and_set_are_checked(tmp_path):
    joints = list(load_policy(make_policy_file(tmp_path / "ref.onnx")).robot.joint_names)
    swapped = [joints[1], joints[0], *joints[2:]]
    path = make_hc_policy_file(tmp_path / "o.onnx", hc_props(joint_names=tuple(swapped)), obs_size=42)
    with pytest.raises(PolicyLoadError, match=r"metadata key 'joint_names' order differs .* at index 0"):
        load_policy(path)
    path = make_hc_policy_file(
        tmp_path / "s.onnx",
        hc_props(joint_names=tuple(joints[:13]), default_joint_pos=tuple(D[:13])),
        obs_size=39,
    )
    with pytest.raises(PolicyLoadError, match=r"lists 13 joints .* not the joint set of any mode"):
        load_policy(path)


def test_hc_only_gains_outside_the_mit_range_are_refused(tmp_path):
    kp = (600.0,) + (30.0,) * 13  # rs-02 Kp range is 0..500
    path = make_hc_policy_file(tmp_path / "k.onnx", hc_props(stiffness=kp), obs_size=42)
    with pytest.raises(
        PolicyLoadError, match=r"'joint_stiffness' is outside .* left_shoulder_pitch: 600 not in \[0, 500\]"
    ):
        load_policy(path)


def test_hc_only_missing_keys_are_listed(tmp_path):
    props = hc_props()
    del props["lookahead_steps"], props["body_names"]
    path = make_hc_policy_file(tmp_path / "m.onnx", props, obs_size=42)
    with pytest.raises(
        PolicyLoadError,
        match=r"no bar\.\* keys and lacks the Humanoid Control keys \['body_names', 'lookahead_steps'\]",
    ):
        load_policy(path)


def test_hc_only_17_joint_file_is_the_neck_mode(tmp_path):
    props = hc_props(mode="arms_neck", action_joint_names=LEFT)
    path = make_hc_policy_file(tmp_path / "n.onnx", props, obs_size=17 + 17 + 7)
    assert load_policy(path).robot.mode == "arms_neck"
    with pytest.raises(
        PolicyLoadError,
        match="the policy drives mode 'arms_neck' \\(17 joints\\), this run drives mode 'arms'",
    ):
        load_policy(path, mode="arms")


def test_bar_file_undriven_joints_follow_the_same_rule(tmp_path):
    # A bar file with the reach layout drives every joint: its hold pose is the default pose.
    pol = load_policy(make_policy_file(tmp_path / "b.onnx"))
    np.testing.assert_array_equal(pol.hold_pose, D)
    q = pol.q_command(np.full(14, 0.4))
    np.testing.assert_allclose(q, D + 0.25 * 0.4)
    # Driving only the left arm: the right arm is pinned at 0, in a bar file too (one rule, both dialects).
    left_only = dataclasses.replace(pol, action_index=np.arange(7), action_scale=np.full(7, 0.25))
    np.testing.assert_array_equal(left_only.q_command(np.full(7, 0.4)), np.r_[D[:7] + 0.1, np.zeros(7)])
