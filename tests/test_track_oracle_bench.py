"""bench/track_oracle.py: the feed-forward is the perturbed model's extra inverse-dynamics torque over Kp,
added to the file's command and nothing else.

Expected values by hand: with the reference held still (every lookahead frame the same pose) velocity and
acceleration are 0, so the ``full`` and ``gravity`` parts are the payload's holding torque, ``0.5 g J_z^T``
of each fingertip site (``mj_jacSite``), over Kp; the ``dynamic`` part is 0; the nominal model against
itself adds 0.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from script_modules import load_bench

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import load_policy
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.perturb_spec import parse_perturbation

oracle = load_bench("track_oracle")


@pytest.fixture(scope="module")
def setup():
    policy = load_policy(str(Path(__file__).resolve().parents[1] / "checkpoints" / "lite_track_arms.onnx"))
    nominal = SimEpisodes(policy).target().model
    payload = SimEpisodes(policy, perturbation=parse_perturbation("payload_kg=0.5")).target().model
    return policy, nominal, payload


def _still_obs(policy, q: np.ndarray) -> np.ndarray:
    """An observation whose reference frames all hold ``q`` (rad); every other term 0."""
    om = policy.obs_manager
    inputs = {t.name: np.zeros(t.size, np.float32) for t in om.schema.terms}
    inputs["motion_joint_pos"] = np.tile(q, om.schema.lookahead_steps).astype(np.float32)
    return np.asarray(om.compute(inputs), np.float32)


def _payload_torque(model: mujoco.MjModel, names, q: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, names)
    d.qpos[idx.qpos] = q
    mujoco.mj_forward(model, d)
    out = np.zeros(len(names))
    for site in FINGERTIP_SITES:
        jac = np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, d, jac, None, model.site(site).id)
        out += 0.5 * 9.81 * jac[2, idx.dof]
    return out


def test_feedforward_is_the_payloads_holding_torque_over_kp(setup):
    """Float32 frames of a pose (1e-7 rad) move the Jacobian by less than 1e-6 relative: 1e-6 rad."""
    policy, nominal, payload = setup
    q = np.asarray(policy.robot.pose("piano_ready"), np.float64)
    obs = _still_obs(policy, q)
    q32 = obs[policy.obs_manager.term_slice("motion_joint_pos")][: len(q)].astype(np.float64)
    want = _payload_torque(nominal, policy.robot.joint_names, q32) / np.asarray(policy.robot.kp)
    a = policy(obs)
    for part, expect in (("full", want), ("gravity", want), ("dynamic", 0 * want)):
        ff = oracle.ModelFeedforward(policy, nominal, payload, frame=2, part=part)
        np.testing.assert_array_equal(ff(obs), a)  # the file's action, untouched
        np.testing.assert_allclose(ff.q_command(a) - policy.q_command(a), expect, atol=1e-6, err_msg=part)
    same = oracle.ModelFeedforward(policy, nominal, nominal, frame=2, part="full")
    same(obs)
    np.testing.assert_allclose(same.q_command(a), policy.q_command(a), atol=1e-12)
    with pytest.raises(ValueError, match=r"--frame must be in 2..4 \(central differences\), got 1"):
        oracle.ModelFeedforward(policy, nominal, payload, frame=1, part="full")
