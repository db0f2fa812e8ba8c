"""The policy loader: what it accepts, what it computes, and each refusal with its message."""

from __future__ import annotations

import dataclasses
import json
import pickle

import numpy as np
import pytest
from onnx import TensorProto
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.metadata import MetadataError
from bar_policy.deploy.policy import PolicyLoadError, load_policy, read_metadata
from bar_policy.obs import ObservationManager
from bar_policy.robot.constants import load_robot


def test_accepts_matching_file_and_computes_q_cmd_by_hand(tmp_path):
    # actions = obs @ W + b with W = 0: the action is b regardless of the observation.
    b = np.linspace(-0.5, 0.5, 14)
    pol = load_policy(make_policy_file(tmp_path / "p.onnx", bias=b))
    obs = np.random.default_rng(0).standard_normal(54).astype(np.float32)
    a = pol(obs)
    assert a.dtype == np.float32 and a.shape == (14,)
    np.testing.assert_array_equal(a, b.astype(np.float32))
    # q_cmd = default (piano_ready) + 0.25 * b, worked out per joint.
    default = np.array([0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3, 0.3, 1.0, 0.0, -1.7, 1.2, 0.0, -0.3])
    np.testing.assert_allclose(pol.q_command(a), default + 0.25 * b.astype(np.float32), rtol=0, atol=1e-12)
    assert pol.policy_dt == 0.02
    np.testing.assert_array_equal(pol.kp, np.full(14, 50.0))
    np.testing.assert_array_equal(pol.kd, np.full(14, 2.0))


def test_linear_weight_reaches_the_output(tmp_path):
    # W[0, 3] = 2: action[3] = 2 * obs[0]; everything else 0.
    w = np.zeros((54, 14))
    w[0, 3] = 2.0
    pol = load_policy(make_policy_file(tmp_path / "p.onnx", weight=w))
    obs = np.zeros(54, np.float32)
    obs[0] = 0.75
    expected = np.zeros(14, np.float32)
    expected[3] = 1.5
    np.testing.assert_array_equal(pol(obs), expected)


def test_arms_neck_policy_loads_in_its_mode(tmp_path):
    pol = load_policy(make_policy_file(tmp_path / "n.onnx", mode="arms_neck"), mode="arms_neck")
    assert pol.robot.num_joints == 17 and pol.n_actions == 17
    assert pol.obs_manager.size == ObservationManager.for_task("reach", "arms_neck").size


# -- refusals ------------------------------------------------------------------------------------------
def test_refuses_missing_file(tmp_path):
    with pytest.raises(PolicyLoadError, match="cannot read"):
        load_policy(tmp_path / "nope.onnx")


def test_refuses_corrupted_file(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx")
    data = p.read_bytes()
    (tmp_path / "trunc.onnx").write_bytes(data[: len(data) // 2])
    with pytest.raises(PolicyLoadError, match="corrupted"):
        load_policy(tmp_path / "trunc.onnx")
    (tmp_path / "garbage.onnx").write_bytes(b"this is not a protobuf \x00\xff" * 10)
    with pytest.raises(PolicyLoadError, match="not a loadable ONNX"):
        load_policy(tmp_path / "garbage.onnx")
    (tmp_path / "empty.onnx").write_bytes(b"")
    with pytest.raises(PolicyLoadError, match="empty"):
        load_policy(tmp_path / "empty.onnx")


def test_never_loads_pickles(tmp_path):
    (tmp_path / "policy.pt").write_bytes(pickle.dumps({"w": [1, 2]}))
    with pytest.raises(PolicyLoadError, match="pickle"):
        load_policy(tmp_path / "policy.pt")
    # Same bytes under an .onnx name: refused by the magic number, not unpickled.
    (tmp_path / "sneaky.onnx").write_bytes(pickle.dumps({"w": [1, 2]}))
    with pytest.raises(PolicyLoadError, match="pickle"):
        load_policy(tmp_path / "sneaky.onnx")


def test_refuses_file_without_metadata(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", drop_keys=tuple(default_metadata().to_props()))
    with pytest.raises(PolicyLoadError, match="no metadata"):
        load_policy(p)


def test_refuses_missing_keys_and_names_them(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", drop_keys=("bar.obs_fingerprint", "policy_dt"))
    with pytest.raises(PolicyLoadError, match=r"lacks keys \['bar.obs_fingerprint', 'policy_dt'\]"):
        load_policy(p)
    with pytest.raises(PolicyLoadError, match=r"bar\.obs_fingerprint"):
        read_metadata(p)


def test_refuses_malformed_metadata_value(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", props={"bar.joint_stiffness": "[50, 50"})
    with pytest.raises(PolicyLoadError, match=r"'bar\.joint_stiffness' is not valid JSON"):
        load_policy(p)


def test_refuses_fingerprint_not_matching_its_own_schema(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", props={"bar.obs_fingerprint": json.dumps("0123456789abcdef")})
    with pytest.raises(PolicyLoadError, match="does not match the embedded schema"):
        load_policy(p)


def test_refuses_schema_different_from_running_code(tmp_path):
    # A self-consistent file (fingerprint matches its schema) whose layout differs from ours: joint_vel
    # scale 0.05 instead of 0.1.
    om = ObservationManager.for_task("reach", "arms")
    schema = json.loads(om.to_json())
    for t in schema["terms"]:
        if t["name"] == "joint_vel":
            t["scale"] = 0.05
    other = ObservationManager.from_json(json.dumps(schema))
    assert other.fingerprint != om.fingerprint
    meta = default_metadata(obs_schema=other.to_json(), obs_fingerprint=other.fingerprint)
    p = make_policy_file(tmp_path / "p.onnx", metadata=meta)
    with pytest.raises(PolicyLoadError, match=f"fingerprint {other.fingerprint}.*differs.*{om.fingerprint}"):
        load_policy(p)
    with pytest.raises(PolicyLoadError, match="differing fields: \\['terms'\\]"):
        load_policy(p)


def test_refuses_wrong_joint_set(tmp_path):
    neck = make_policy_file(tmp_path / "neck.onnx", mode="arms_neck")
    with pytest.raises(
        PolicyLoadError, match=r"joint set mismatch: .*'arms_neck' \(17 joints\).*'arms' \(14"
    ):
        load_policy(neck, mode="arms")
    arms = make_policy_file(tmp_path / "arms.onnx", mode="arms")
    with pytest.raises(PolicyLoadError, match="joint set mismatch"):
        load_policy(arms, mode="arms_neck")


def test_refuses_joint_names_not_matching_the_robot(tmp_path):
    robot = load_robot("arms")
    swapped = list(robot.joint_names)
    swapped[0], swapped[1] = swapped[1], swapped[0]
    p = make_policy_file(tmp_path / "order.onnx", metadata=default_metadata(joint_names=tuple(swapped)))
    with pytest.raises(PolicyLoadError, match=r"order differs .* index 0: policy 'left_shoulder_roll'"):
        load_policy(p)
    renamed = list(robot.joint_names)
    renamed[13] = "right_wrist_twist"
    p = make_policy_file(tmp_path / "set.onnx", metadata=default_metadata(joint_names=tuple(renamed)))
    with pytest.raises(PolicyLoadError, match=r"not on the robot: \['right_wrist_twist'\]"):
        load_policy(p)


def test_refuses_wrong_gains_and_names_the_joint(tmp_path):
    kp = [50.0] * 14
    kp[3] = 40.0
    p = make_policy_file(tmp_path / "kp.onnx", metadata=default_metadata(joint_stiffness=tuple(kp)))
    with pytest.raises(PolicyLoadError, match=r"Kp .*left_elbow_pitch: policy 40, robot 50"):
        load_policy(p)
    kd = [2.0] * 14
    kd[13] = 1.0
    p = make_policy_file(tmp_path / "kd.onnx", metadata=default_metadata(joint_damping=tuple(kd)))
    with pytest.raises(PolicyLoadError, match=r"Kd .*right_wrist_pitch: policy 1, robot 2"):
        load_policy(p)


def test_refuses_policy_dt_different_from_control_dt(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", metadata=default_metadata(policy_dt=0.01))
    with pytest.raises(
        PolicyLoadError, match=r"policy dt 0.01 s differs from the runtime's control dt 0.02 s"
    ):
        load_policy(p)
    # ... and accepted when the runtime runs at that dt.
    assert load_policy(p, control_dt=0.01).policy_dt == 0.01


def test_refuses_default_pose_different_from_schema(tmp_path):
    meta = default_metadata()
    pose = list(meta.default_joint_pos)
    pose[2] = 0.1
    p = make_policy_file(
        tmp_path / "p.onnx", metadata=dataclasses.replace(meta, default_joint_pos=tuple(pose))
    )
    with pytest.raises(
        PolicyLoadError, match=r"default joint positions .*left_shoulder_yaw: policy 0\.1, robot 0"
    ):
        load_policy(p)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dtype": TensorProto.DOUBLE}, "input 'obs' has type tensor\\(double\\); float32"),
        ({"dtype": TensorProto.FLOAT16}, "input 'obs' has type tensor\\(float16\\); float32"),
        ({"input_name": "observation"}, "exactly one input named 'obs'"),
        ({"output_name": "mu"}, "no output named 'actions'"),
        ({"obs_size": 50}, "input 'obs' has shape \\['batch', 50\\]; expected \\[batch, 54\\]"),
        ({"n_actions": 12}, "output 'actions' has shape \\['batch', 12\\]; expected \\[batch, 14\\]"),
        ({"batch": 8}, "input 'obs' has shape \\[8, 54\\]"),
    ],
)
def test_refuses_wrong_io(tmp_path, kwargs, message):
    p = make_policy_file(tmp_path / "p.onnx", **kwargs)
    with pytest.raises(PolicyLoadError, match=message):
        load_policy(p)


def test_fixed_batch_of_one_is_accepted(tmp_path):
    assert load_policy(make_policy_file(tmp_path / "p.onnx", batch=1)).n_actions == 14


def test_refuses_bad_action_clip(tmp_path):
    p = make_policy_file(tmp_path / "p.onnx", props={"bar.action_clip": "-1"})
    with pytest.raises(PolicyLoadError, match=r"bar\.action_clip.*must be a number > 0 or null"):
        load_policy(p)


def test_policy_error_is_a_value_error():
    assert issubclass(PolicyLoadError, ValueError)


def test_a_file_on_the_stiff_profile_loads_with_its_gains_and_a_wrong_claim_is_refused(tmp_path):
    """``bar.gains`` names the profile the file's Kp / Kd must equal (``robot.gains``): a ``stiff`` file (Kp
    100, Kd 3 on every arm joint, by hand: 2 x 50 and 1.5 x 2) loads and runs on them; the same gains
    without the key (the ``robot`` profile) or the table's gains under ``stiff`` are refused, naming the
    profile; an unknown profile is refused naming the valid ones."""
    stiff = default_metadata(joint_stiffness=(100.0,) * 14, joint_damping=(3.0,) * 14, gains="stiff")
    assert stiff.to_props()["bar.gains"] == '"stiff"'
    assert "bar.gains" not in default_metadata().to_props()  # robot: no key, as in older files
    policy = load_policy(make_policy_file(tmp_path / "stiff.onnx", metadata=stiff))
    np.testing.assert_array_equal(policy.kp, 100.0)
    np.testing.assert_array_equal(policy.kd, 3.0)
    claim = dataclasses.replace(stiff, gains="robot")
    with pytest.raises(
        PolicyLoadError, match=r"Kp \(N\*m/rad\) differ .*left_shoulder_pitch: policy 100, robot 50"
    ):
        load_policy(make_policy_file(tmp_path / "claim.onnx", metadata=claim))
    table = default_metadata(gains="stiff")
    with pytest.raises(
        PolicyLoadError, match=r"Kp \(gain profile 'stiff', bar.gains\) .* policy 50, robot 100"
    ):
        load_policy(make_policy_file(tmp_path / "table.onnx", metadata=table))
    p = make_policy_file(tmp_path / "soft.onnx", metadata=stiff, props={"bar.gains": '"soft"'})
    with pytest.raises(
        PolicyLoadError, match=r"'bar\.gains' must be one of \['robot', 'stiff', 'actuator'\]"
    ):
        load_policy(p)
    with pytest.raises(MetadataError, match=r"gain profile must be one of \['robot', 'stiff', 'actuator'\]"):
        default_metadata(gains="soft")
