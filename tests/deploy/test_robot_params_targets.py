"""``bar-deploy --robot-params FILE``: the sim target and the emulator are built from the identified robot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bar_policy.deploy.cli_parser import run_parser
from bar_policy.deploy.targets.perturbed import sim_target
from bar_policy.deploy.targets.sim import SimConfig
from bar_policy.robot.constants import load_robot
from bar_policy.robot.params import Estimate, JointParams, Payload, RobotParams
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.robstride.emulator_perturb import emulator

ROBOT = load_robot("arms")


def _params() -> RobotParams:
    jp = JointParams(Estimate(0.7), Estimate(0.05), Estimate(0.004), Estimate(0.8))
    return RobotParams({"left_elbow_pitch": jp}, {"right": Payload(Estimate(0.3), (0.0, -0.1, 0.0))})


def test_sim_target_models_the_file() -> None:
    t = sim_target("arms", SimConfig(), scene=None, perturbation=None, robot_params=_params())
    dof = t.model.joint("left_elbow_pitch").dofadr[0]
    assert (t.model.dof_frictionloss[dof], t.model.dof_damping[dof], t.model.dof_armature[dof]) == (
        0.7,
        0.05,
        0.004,
    )
    assert t.model.body("right_hand_payload").mass[0] == pytest.approx(0.3)
    expect = np.ones(ROBOT.num_joints)
    expect[ROBOT.joint_names.index("left_elbow_pitch")] = 0.8
    np.testing.assert_array_equal(t.motors.strength, expect)
    # a perturbation on top: its strength multiplies the file's (0.8 * 0.5 = 0.4 on the elbow)
    t2 = sim_target(
        "arms",
        SimConfig(),
        scene=None,
        perturbation=parse_perturbation("strength=0.5"),
        robot_params=_params(),
    )
    assert t2.motors.strength[ROBOT.joint_names.index("left_elbow_pitch")] == pytest.approx(0.4)


def test_emulator_models_the_file() -> None:
    ch = {"can0": "rp-test-0", "can1": "rp-test-1"}
    emu = emulator(ROBOT, ch, perturbation=None, robot_params=_params(), mode="lockstep")
    try:
        dof = emu.model.joint("left_elbow_pitch").dofadr[0]
        assert emu.model.dof_frictionloss[dof] == 0.7
        assert emu.model.body("right_hand_payload").mass[0] == pytest.approx(0.3)
        assert emu.motor_perturbation.strength[ROBOT.joint_names.index("left_elbow_pitch")] == 0.8
    finally:
        emu.close()


def test_bad_file_is_refused_by_the_parser(tmp_path, capsys) -> None:
    path = tmp_path / "p.json"
    obj = _params().to_json()
    obj["joints"]["left_elbow_pitch"]["friction"] = obj["joints"]["left_elbow_pitch"].pop("friction_nm")
    path.write_text(json.dumps(obj))
    with pytest.raises(SystemExit) as e:
        run_parser().parse_args(["--target", "sim", "--robot-params", str(path)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "unknown key 'friction'; did you mean 'friction_nm'?" in err


def _run(policy, tmp_path, capsys, *extra: str) -> tuple[list[str], dict]:
    """``bar-deploy`` on the sim target for 0.1 s: (its WARNING lines on stderr, run.json)."""
    from bar_policy.deploy.cli import main

    logs = tmp_path / f"runs{len(list(tmp_path.glob('runs*')))}"
    argv = ["--policy", str(policy), "--target", "sim", "--duration", "0.1", "--log", str(logs), *extra]
    assert main(argv) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("WARNING:")]
    (run,) = logs.iterdir()
    return warnings, json.loads((run / "run.json").read_text())


def test_runtime_warns_on_robot_parameters_other_than_the_trained_ones(tmp_path, capsys) -> None:
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from policy_factory import default_metadata, make_policy_file

    from bar_policy.robot.params import params_record

    trained, other = _params(), RobotParams({}, {"left": Payload(Estimate(0.5), (0.0, 0.1, 0.0))})
    trained_file, other_file = tmp_path / "trained.json", tmp_path / "other.json"
    trained.save(trained_file)
    other.save(other_file)
    policy = make_policy_file(
        tmp_path / "p.onnx", metadata=default_metadata(robot_params=params_record(trained))
    )
    # The same file: no warning, the record says 0.
    warnings, rec = _run(policy, tmp_path, capsys, "--robot-params", str(trained_file))
    assert warnings == []
    assert rec["robot_params"] == {
        "trained_sha256": trained.sha256,
        "run_sha256": trained.sha256,
        "mismatch_warnings": 0,
    }
    # Another file: one line naming both hashes' first 12 digits, counted once.
    warnings, rec = _run(policy, tmp_path, capsys, "--robot-params", str(other_file))
    assert warnings == [
        f"WARNING: robot parameters mismatch: the policy was trained on robot parameters sha256 "
        f"{trained.sha256[:12]}, this run models --robot-params sha256 {other.sha256[:12]}"
    ]
    assert rec["robot_params"]["mismatch_warnings"] == 1 and rec["robot_params"]["run_sha256"] == other.sha256
    # No file: the nominal model, which the policy was not trained on.
    warnings, rec = _run(policy, tmp_path, capsys)
    assert len(warnings) == 1 and "this run models the nominal model (no --robot-params)" in warnings[0]
    assert rec["robot_params"] == {
        "trained_sha256": trained.sha256,
        "run_sha256": None,
        "mismatch_warnings": 1,
    }
    # A policy trained on the nominal model, run nominal: no warning.
    nominal = make_policy_file(tmp_path / "n.onnx")
    warnings, rec = _run(nominal, tmp_path, capsys)
    assert warnings == [] and rec["robot_params"]["mismatch_warnings"] == 0


def test_eval_runs_on_the_identified_robot_and_warns_on_a_mismatch(tmp_path, capsys) -> None:
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from policy_factory import make_policy_file

    from bar_policy.deploy.cli import main
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy

    params_file = tmp_path / "p.json"
    _params().save(params_file)
    policy_file = make_policy_file(tmp_path / "n.onnx")  # trained on the nominal model
    # The runner's target is the file's robot (the same values as test_sim_target_models_the_file).
    target = SimEpisodes(load_policy(policy_file), robot_params=_params()).target()
    dof = target.model.joint("left_elbow_pitch").dofadr[0]
    assert target.model.dof_frictionloss[dof] == 0.7
    assert target.model.body("right_hand_payload").mass[0] == pytest.approx(0.3)
    assert target.motors.strength[ROBOT.joint_names.index("left_elbow_pitch")] == 0.8
    out = tmp_path / "eval.json"
    argv = ["--policy", str(policy_file), "--robot-params", str(params_file), "--episodes", "1"]
    assert main(["eval", *argv, "--episode-length", "0.2", "-q", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "WARNING: robot parameters mismatch: the policy was trained on the nominal model" in err
    rec = json.loads(out.read_text())["robot_params"]
    assert rec == {"trained_sha256": None, "run_sha256": _params().sha256, "mismatch_warnings": 1}
