"""The ONNX metadata contract: round trip, the Humanoid Control keys, and refusals."""

from __future__ import annotations

import json

import pytest

from bar_policy.deploy.metadata import BAR_KEYS, HC_KEYS, MetadataError, PolicyMetadata
from bar_policy.obs import ObservationManager
from bar_policy.robot import load_robot


def make(**changes: object) -> PolicyMetadata:
    robot = load_robot("arms")
    om = ObservationManager.for_task("reach", "arms")
    base = {
        "task": "reach",
        "robot": "lite_dummy",
        "mode": "arms",
        "joint_names": robot.joint_names,
        "action_joint_names": robot.joint_names,
        "joint_stiffness": tuple(robot.kp),
        "joint_damping": tuple(robot.kd),
        "default_joint_pos": tuple(robot.pose("piano_ready")),
        "action_scale": (0.5,) * 14,
        "action_semantics": "delta_from_default",
        "policy_dt": 0.02,
        "physics_dt": 0.002,
        "obs_schema": om.to_json(),
        "obs_fingerprint": om.fingerprint,
        "command_names": om.command_names,
        "randomization": {"kp_scale": [0.9, 1.1]},
        "code_version": "0.1.0+abc",
        "training": {"steps": 1},
    }
    base.update(changes)
    return PolicyMetadata(**base)  # type: ignore[arg-type]


def test_round_trip_and_hc_keys() -> None:
    md = make()
    props = md.to_props()
    assert set(props) == set(BAR_KEYS) | set(HC_KEYS)
    assert all(isinstance(v, str) for v in props.values())
    back = PolicyMetadata.from_props(props)
    assert back == make(obs_schema=json.dumps(json.loads(md.obs_schema), sort_keys=True))
    # Humanoid Control form: comma-separated names and numbers.
    assert props["joint_names"].split(",")[0] == "left_shoulder_pitch"
    assert props["joint_stiffness"] == ",".join(["50"] * 14)
    assert props["observation_names"].split(",") == list(ObservationManager.for_task().term_names)
    assert props["policy_dt"] == "0.02" and props["task_type"] == "reach"


def test_missing_and_malformed_keys_are_named() -> None:
    props = make().to_props()
    del props["bar.obs_fingerprint"], props["lookahead_steps"]
    with pytest.raises(MetadataError, match=r"lacks keys \['bar\.obs_fingerprint', 'lookahead_steps'\]"):
        PolicyMetadata.from_props(props)
    props = make().to_props()
    props["bar.joint_stiffness"] = '["a"]'
    with pytest.raises(MetadataError, match=r"'bar\.joint_stiffness' must be a list of numbers"):
        PolicyMetadata.from_props(props)
    props = make().to_props()
    props["bar.metadata_version"] = "7"
    with pytest.raises(MetadataError, match="version 7 is not supported"):
        PolicyMetadata.from_props(props)


def test_inconsistent_fields_refused() -> None:
    with pytest.raises(MetadataError, match="joint_damping has 13 entries, expected 14"):
        make(joint_damping=(2.0,) * 13)
    with pytest.raises(MetadataError, match="unknown action_semantics 'absolute'"):
        make(action_semantics="absolute")
    with pytest.raises(MetadataError, match="policy_dt must be a positive"):
        make(policy_dt=0.0)
