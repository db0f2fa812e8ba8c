"""Training on a robot-parameters file (``RobotEnvConfig.robot_params``, ``bar-train --robot-params FILE``).

The env's model must be the file's robot (every listed field equal to the file's value, the unlisted ones
the description's), its motors the file's strengths, the randomisation centred on the file's values (the
draws of the same keys without a file, shifted by the range's centre), and the exported policy's metadata
must record the file's sha256, computed here by hand from the file's canonical JSON. Env builds only (no
step is compiled): a reset is jitted once.
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import replace
from pathlib import Path

import jax
import numpy as np
import onnx
import pytest

from bar_policy import envs
from bar_policy.envs.randomize import make_randomizer
from bar_policy.robot.constants import load_robot
from bar_policy.robot.params import Estimate, JointParams, Payload, RobotParams
from bar_policy.robot.scene import load_model
from bar_policy.tasks.robust_preset import ROBUST_ENV_OVERRIDES
from bar_policy.training.cli import robot_params_of
from bar_policy.training.metadata import policy_metadata

sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
from policy_factory import make_policy_file

ROBOT = load_robot("arms")
ELBOW = "left_elbow_pitch"
WRIST = "right_wrist_roll"
PAYLOAD_LEFT = (0.4, (0.01, 0.2, -0.005))
"""kg, m in the left hand's frame."""


@pytest.fixture(scope="module")
def params_file(tmp_path_factory) -> Path:
    elbow = JointParams(Estimate(0.6, (0.55, 0.65)), Estimate(0.3), Estimate(0.004), Estimate(0.9))
    wrist = JointParams(Estimate(0.2), Estimate(0.0), Estimate(0.0015), Estimate(1.1))
    p = RobotParams(
        {ELBOW: elbow, WRIST: wrist},
        {"left": Payload(Estimate(PAYLOAD_LEFT[0]), PAYLOAD_LEFT[1])},
        {"kind": "identify", "date": "2026-12-02T07:00:00Z"},
    )
    path = tmp_path_factory.mktemp("params") / "robot.json"
    p.save(path)
    return path


def _config(path: Path, *overrides: str):
    return envs.apply_overrides(
        envs.nominal_config(envs.default_config("LiteReach")), (f"robot_params={path}", *overrides)
    )


def test_the_trained_model_is_the_files(params_file):
    env = envs.load("LiteReach", config=_config(params_file))
    m, desc = env.mj_model, load_model("arms")
    for name, (f, d, a) in {ELBOW: (0.6, 0.3, 0.004), WRIST: (0.2, 0.0, 0.0015)}.items():
        dof = m.joint(name).dofadr[0]
        assert (m.dof_frictionloss[dof], m.dof_damping[dof], m.dof_armature[dof]) == (f, d, a)
    other = m.joint("left_shoulder_roll").dofadr[0]  # not in the file: the description's values
    d_other = desc.joint("left_shoulder_roll").dofadr[0]
    assert m.dof_frictionloss[other] == desc.dof_frictionloss[d_other]
    assert m.dof_armature[other] == desc.dof_armature[d_other]
    body = m.body("left_hand_payload")
    assert body.mass[0] == PAYLOAD_LEFT[0]
    np.testing.assert_allclose(body.pos, PAYLOAD_LEFT[1], rtol=0, atol=1e-15)
    # A 1 cm sphere: 2/5 * 0.4 kg * (0.01 m)^2 = 1.6e-5 kg*m^2 on each axis (float64 rounding).
    np.testing.assert_allclose(body.inertia, [1.6e-5] * 3, rtol=1e-12)
    assert "right_hand_payload" not in [m.body(i).name for i in range(m.nbody)]
    # The MJX model the env steps holds the same values (float32 of them: 1 ulp, 6e-8 relative).
    dof = m.joint(ELBOW).dofadr[0]
    assert float(env.mjx_model.dof_frictionloss[dof]) == pytest.approx(0.6, rel=1e-7)
    # The motors: the file's strengths on every episode (randomisation off), 1 on the unlisted joints.
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    expect = np.ones(ROBOT.num_joints, np.float32)
    expect[ROBOT.joint_names.index(ELBOW)] = 0.9
    expect[ROBOT.joint_names.index(WRIST)] = 1.1
    np.testing.assert_array_equal(np.asarray(state.info["strength"]), expect)


def test_the_randomisation_is_centred_on_the_files_values(params_file):
    # The robust preset's ranges: friction (0.05, 1.35) N*m, damping (0, 1) N*m*s/rad, payload (0, 0.6) kg.
    # With the file, each drawn value is the file's + (the same key's draw without it - the range's
    # centre), at least 0: checked against the draw of the same keys on the description's model.
    # No nominal slots: every slot's draw is the centred one (a nominal slot takes the file's values).
    base = envs.apply_overrides(
        envs.default_config("LiteReach"), (*ROBUST_ENV_OVERRIDES, "randomization.nominal_share=0.0")
    )
    with_file = replace(base, robot_params=str(params_file))
    plain = envs.load("LiteReach", config=base)
    filed = envs.load("LiteReach", config=with_file)
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    a, _ = make_randomizer(base)(plain.mjx_model, keys)
    b, _ = make_randomizer(with_file)(filed.mjx_model, keys)
    dof = filed.mj_model.joint(ELBOW).dofadr[0]
    tol = 4e-7  # float32: two roundings of sums below 2 (ulp 1.2e-7) on each side of the comparison
    f_plain = np.asarray(a.dof_frictionloss[:, dof])
    np.testing.assert_allclose(
        np.asarray(b.dof_frictionloss[:, dof]), np.maximum(0.6 + f_plain - 0.7, 0), rtol=0, atol=tol
    )
    d_mjcf = float(plain.mj_model.dof_damping[dof])
    d_plain = np.asarray(a.dof_damping[:, dof]) - d_mjcf  # the draw U(0, 1)
    np.testing.assert_allclose(
        np.asarray(b.dof_damping[:, dof]), np.maximum(0.3 + d_plain - 0.5, 0), rtol=0, atol=tol
    )
    # Armature: the file's value times the armature_scale draw (0.8..1.2), not the motor-range draw.
    arm = np.asarray(b.dof_armature[:, dof])
    assert np.all((arm >= 0.004 * 0.8 - 1e-9) & (arm <= 0.004 * 1.2 + 1e-9))
    # Payload: left = 0.4 + (U(0, 0.6) - 0.3), right (none in the file) = max(U - 0.3, 0); the left
    # one stays at the file's centre, the right one goes where payload_at=either puts it.
    ids_a = [plain.mj_model.body(f"{h}_payload").id for h in ("left_hand", "right_hand")]
    ids_b = [filed.mj_model.body(f"{h}_payload").id for h in ("left_hand", "right_hand")]
    m_plain = np.asarray(a.body_mass[:, ids_a])
    m_file = np.asarray(b.body_mass[:, ids_b])
    np.testing.assert_allclose(m_file[:, 0], np.maximum(0.4 + m_plain[:, 0] - 0.3, 0), rtol=0, atol=tol)
    np.testing.assert_allclose(m_file[:, 1], np.maximum(m_plain[:, 1] - 0.3, 0), rtol=0, atol=tol)
    centre = np.broadcast_to(PAYLOAD_LEFT[1], (8, 3))
    np.testing.assert_allclose(np.asarray(b.body_pos[:, ids_b[0]]), centre, rtol=0, atol=1e-8)  # float32
    np.testing.assert_array_equal(np.asarray(b.body_pos[:, ids_b[1]]), np.asarray(a.body_pos[:, ids_a[1]]))


def test_the_exported_metadata_records_the_files_hash(params_file, tmp_path):
    env = envs.load("LiteReach", config=_config(params_file))
    meta = policy_metadata(env, provenance={})
    # The hash worked out from the file on disk: sha256 of its JSON with sorted keys and no whitespace.
    by_hand = hashlib.sha256(
        json.dumps(json.loads(params_file.read_text()), sort_keys=True, separators=(",", ":")).encode()
    ).hexdigest()
    path = make_policy_file(tmp_path / "p.onnx", metadata=meta)
    props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    record = json.loads(props["bar.robot_params"])
    assert record["sha256"] == by_hand
    assert record["summary"]["friction_nm"] == [0.2, 0.6]
    assert record["summary"]["strength"] == [0.9, 1.1]
    assert record["summary"]["payload_kg"] == {"left": 0.4}
    # An env without a file records nothing (the key is absent: the nominal model).
    nominal = policy_metadata(envs.load("LiteReach", config=envs.nominal_config()), provenance={})
    assert "bar.robot_params" not in nominal.to_props()


def test_bar_train_robot_params_flag_is_an_env_override():
    assert robot_params_of(["--preset", "tiny", "--robot-params", "p.json", "--seed", "1"]) == (
        ["--preset", "tiny", "--seed", "1"],
        "p.json",
    )
    assert robot_params_of(["--robot-params=q.json"]) == ([], "q.json")
    assert robot_params_of(["--seed", "1"]) == (["--seed", "1"], None)
