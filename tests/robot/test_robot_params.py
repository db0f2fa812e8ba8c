"""The robot-parameters file: round trip, canonical hash, refusals in one line, and its edits of the model."""

from __future__ import annotations

import copy
import json
import math

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.params import (
    Estimate,
    JointParams,
    ParamsError,
    Payload,
    RobotParams,
    load_params,
    motor_strength,
    parse_params,
    scene_edit,
)
from bar_policy.robot.scene import load_model


def _params() -> RobotParams:
    jp = JointParams(
        friction_nm=Estimate(0.6, (0.55, 0.65)),
        damping=Estimate(0.05, (0.0, 0.1)),
        armature=Estimate(0.004, (0.003, 0.005)),
        strength=Estimate(0.9, (0.88, 0.92)),
    )
    pay = Payload(
        Estimate(0.4, (0.38, 0.42)), (0.01, -0.12, 0.0), ((0.0, 0.02), (-0.13, -0.11), (-0.01, 0.01))
    )
    return RobotParams({"left_elbow_pitch": jp}, {"left": pay}, {"kind": "identify", "emulated": True})


def test_round_trip_and_canonical_hash(tmp_path) -> None:
    p = _params()
    path = tmp_path / "p.json"
    p.save(path)
    back = load_params(path, load_robot("arms"))
    assert back == p
    # the hash is of the canonical bytes: a file laid out otherwise (indent, key order) hashes the same
    obj = json.loads(path.read_text())
    other = tmp_path / "q.json"
    other.write_text(json.dumps(dict(reversed(list(obj.items()))), indent=7))
    assert load_params(other).sha256 == p.sha256
    # and a changed value changes it
    obj["joints"]["left_elbow_pitch"]["strength"]["value"] = 0.91
    assert parse_params(obj).sha256 != p.sha256


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda o: o.update(version=2), "version 2 is not supported (valid: 1)"),
        (lambda o: o.pop("version"), "missing 'version'"),
        (lambda o: o.update(joint={}), "unknown key 'joint'; did you mean 'joints'?"),
        (
            lambda o: o["joints"]["left_elbow_pitch"].update(
                frictio_nm=o["joints"]["left_elbow_pitch"].pop("friction_nm")
            ),
            "unknown key 'frictio_nm'; did you mean 'friction_nm'?",
        ),
        (
            lambda o: o["joints"]["left_elbow_pitch"]["damping"].update(value=math.nan),
            "joints.left_elbow_pitch.damping.value: nan is not a finite number",
        ),
        (
            lambda o: o["joints"]["left_elbow_pitch"]["strength"].update(value=3.0, ci95=None),
            "joints.left_elbow_pitch.strength.value=3 is out of range: valid 0.3..1.5 x",
        ),
        (
            lambda o: o["payload"]["left"]["mass_kg"].update(value=-0.1, ci95=None),
            "payload.left.mass_kg.value=-0.1 is out of range: valid 0..2 kg",
        ),
        (
            lambda o: o["joints"]["left_elbow_pitch"]["armature"].update(ci95=[0.005, 0.006]),
            "ci95 [0.005, 0.006] does not hold its value 0.004",
        ),
        (lambda o: o["payload"].update(middle=o["payload"]["left"]), "unknown key 'middle'"),
        (
            lambda o: o["joints"].update(left_elbow_pich=o["joints"]["left_elbow_pitch"]),
            "did you mean 'left_elbow_pitch'?",
        ),
        (lambda o: o["source"].update(emulated="yes"), "source.emulated: 'yes' has the wrong type"),
    ],
)
def test_refusals_are_one_line(edit, message) -> None:
    obj = copy.deepcopy(_params().to_json())
    edit(obj)
    with pytest.raises(ParamsError) as e:
        parse_params(obj, load_robot("arms").joint_names)
    assert message in str(e.value)
    assert "\n" not in str(e.value)


def test_nan_in_the_file_text_is_refused(tmp_path) -> None:
    path = tmp_path / "p.json"
    path.write_text(json.dumps(_params().to_json()).replace('"value": 0.6', '"value": NaN'))
    with pytest.raises(ParamsError, match=r"friction_nm\.value: nan is not a finite number"):
        load_params(path)


def test_applied_to_the_model_and_the_motors() -> None:
    robot = load_robot("arms")
    p = _params()
    m = load_model("arms", scene_edit(p))
    j = m.joint("left_elbow_pitch").dofadr[0]
    assert (m.dof_frictionloss[j], m.dof_damping[j], m.dof_armature[j]) == (0.6, 0.05, 0.004)
    # a joint the file does not list keeps the model's own values
    k = m.joint("right_elbow_pitch").dofadr[0]
    base = load_model("arms")
    assert m.dof_frictionloss[k] == base.dof_frictionloss[k]
    # the payload: 0.4 kg at (0.01, -0.12, 0) in the left hand's frame: the total mass grows by 0.4 kg
    assert m.body("left_hand_payload").mass[0] == pytest.approx(0.4)
    np.testing.assert_allclose(m.body("left_hand_payload").pos, [0.01, -0.12, 0.0])
    assert mujoco.mj_getTotalmass(m) == pytest.approx(mujoco.mj_getTotalmass(base) + 0.4, abs=1e-12)
    s = motor_strength(p, robot)
    assert s[robot.joint_names.index("left_elbow_pitch")] == 0.9
    assert (np.delete(s, robot.joint_names.index("left_elbow_pitch")) == 1.0).all()
