"""A policy whose action on the default observation is not finite is refused at load, in one line."""

from __future__ import annotations

import numpy as np
import pytest
from policy_factory import make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.deploy.contract import PolicyLoadError
from bar_policy.deploy.policy import default_observation, load_policy
from bar_policy.robot.constants import load_robot


def _status(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 1


@pytest.mark.parametrize("value", [np.nan, np.inf], ids=["nan", "inf"])
def test_nonfinite_default_action_refused_at_load(tmp_path, capsys, value):
    robot = load_robot("arms")
    bias = np.zeros(14)
    bias[5] = value  # the linear policy answers obs @ 0 + bias: action 5 is not finite on any observation
    path = make_policy_file(tmp_path / "nan.onnx", bias=bias)
    with pytest.raises(PolicyLoadError) as err:
        load_policy(path)
    msg = str(err.value)
    assert f"not finite for 1 of 14 joints ({robot.joint_names[5]} {value})" in msg, msg
    assert "default observation" in msg and "re-export" in msg and "\n" not in msg
    argv = ["--policy", str(path), "--target", "mock", "--log", str(tmp_path / "runs"), "--duration", "1"]
    assert _status(argv) == 2  # refused before anything starts
    err_lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err_lines) == 1 and "not finite" in err_lines[0], err_lines
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_default_observation_is_the_rest_pose(tmp_path):
    """joint_pos at the default pose is 0 after its offset, gravity straight down, the rest 0 (hand-built)."""
    pol = load_policy(make_policy_file(tmp_path / "p.onnx"))
    om = pol.obs_manager
    obs = default_observation(om)
    assert obs.shape == (om.size,) and obs.dtype == np.float32
    for t in om.schema.terms:
        part = obs[om.term_slice(t.name)]
        if t.name == "projected_gravity":
            np.testing.assert_array_equal(part, np.float32(np.clip(-t.scale, -t.clip, t.clip)) * [0, 0, 1])
        elif t.name == "imu_quaternion":
            np.testing.assert_array_equal(part, np.float32(np.clip(t.scale, -t.clip, t.clip)) * [1, 0, 0, 0])
        else:
            np.testing.assert_array_equal(part, 0.0)  # q - default = 0 exactly in float32
