"""The key-pose prior: the blend by hand, its ONNX graph, and its poses on the C MuJoCo keyboard.

Expected values: the blend's means are worked by hand from its definition (``obs.action_prior.BlendPrior``);
the poses are checked against the keyboard's geometry (the fingertip sphere ``hover_m`` above a key's aim
point, or the key at the bottom of its travel with no other key down) in C MuJoCo with the MIT law.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from bar_policy.export import _run_onnx, build_onnx_model
from bar_policy.export_graph import MlpPolicy
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import PRIOR_BOUND, BlendPrior
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.keyboard import compact_config, key_table, press_thresholds
from bar_policy.tasks.piano.prior import KeyPosePriorConfig, key_pose_prior, key_poses
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

ROBOT = load_robot("arms")
DEFAULT = np.asarray(ROBOT.pose("piano_ready"))
SCALE = np.full(14, 0.8)
KB = compact_config()


def _tiny_blend() -> BlendPrior:
    """Two selector entries, two actions, one blend: entry 0 -> pose (0.4, -0.2) at weight 2, entry 1 ->
    pose (0.1, 0.3) at weight 1 (action 1 reads entry 0 only), rest 0 at weight 0.5."""
    numer = np.array([[[2 * 0.4, 2 * -0.2], [1 * 0.1, 0.0]]])
    denom = np.array([[[2.0, 2.0], [1.0, 0.0]]])
    return BlendPrior(
        start=1, numer=numer, denom=denom, numer_bias=np.zeros((1, 2)), denom_bias=np.full((1, 2), 0.5)
    )


def test_blend_by_hand() -> None:
    """obs[1:3] = (1, 1): action 0 = (2*0.4 + 0.1) / (2 + 1 + 0.5) = 0.9 / 3.5; action 1 = -0.4 / 2.5.
    obs[1:3] = (0, 0): the rest, 0. Negative selectors count as 0. float32 arithmetic: 1e-6."""
    p = _tiny_blend()
    obs = np.array([[9.0, 1.0, 1.0, 9.0], [9.0, 0.0, 0.0, 9.0], [9.0, -3.0, 1.0, 9.0]], np.float32)
    want = np.array([[0.9 / 3.5, -0.4 / 2.5], [0.0, 0.0], [0.1 / 1.5, 0.0]])
    np.testing.assert_allclose(p.apply(obs), want, atol=1e-6)
    np.testing.assert_allclose(np.tanh(p.pre_tanh(obs)), want, atol=1e-6)
    assert p.stop == 3 and p.action_size == 2 and p.to_dict()["blends"] == 1


def test_blend_refuses_bad_arrays() -> None:
    p = _tiny_blend()
    with pytest.raises(ValueError, match="must be"):
        BlendPrior(
            start=0, numer=p.numer, denom=p.denom[:, :1], numer_bias=p.numer_bias, denom_bias=p.denom_bias
        )
    with pytest.raises(ValueError, match="denom_bias > 0"):
        BlendPrior(
            start=0, numer=p.numer, denom=p.denom, numer_bias=p.numer_bias, denom_bias=0 * p.denom_bias
        )
    with pytest.raises(ValueError, match="entries up to 2"):
        p.check_observation_size(2)


def test_onnx_graph_computes_the_blend() -> None:
    """A zero MLP plus the blend: the ONNX file's action is tanh(atanh(prior(obs))) = prior(obs) (float32
    through onnxruntime's MatMul and Div: 1e-6), on random observations with negative selectors too."""
    p = _tiny_blend()
    pol = MlpPolicy(
        obs_mean=np.zeros(4, np.float32),
        obs_std=np.ones(4, np.float32),
        kernels=(np.zeros((4, 2), np.float32),),
        biases=(np.zeros(2, np.float32),),
        activation="swish",
        head="tanh_loc",
        prior=p,
    )
    obs = np.random.default_rng(0).uniform(-2, 2, (64, 4)).astype(np.float32)
    got = _run_onnx(build_onnx_model(pol).SerializeToString(), obs)
    np.testing.assert_allclose(got, p.apply(obs), atol=1e-6)


@pytest.fixture(scope="module")
def poses():
    return key_poses(KB)


@pytest.fixture(scope="module")
def prior():
    return key_pose_prior(ObservationManager.for_task("piano", "arms"), KB, DEFAULT, SCALE, 2)


def test_one_goal_key_gives_its_press_pose(prior, poses) -> None:
    """Goal key k in frame 0 only: its hand's actions are w / (w + rest) of the press pose's action, with
    w = decay**0 = 1 and rest 0.05; the other hand rests (action 0). Hands: left below middle C."""
    pc = KeyPosePriorConfig()
    manager = ObservationManager.for_task("piano", "arms")
    for midi, hand in ((48, 0), (61, 1)):
        k = midi - KB.lowest
        target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        target[0, k] = 1.0
        obs = np.zeros(manager.size, np.float32)
        obs[manager.term_slice("target_keys")] = target.reshape(-1)
        want = np.zeros(14)
        arm = np.arange(7) + 7 * hand
        want[arm] = (1.0 / (1.0 + pc.rest_weight)) * (poses.press[k, arm] - DEFAULT[arm]) / SCALE[arm]
        np.testing.assert_allclose(prior.apply(obs), np.clip(want, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
        # The same key 5 frames ahead (past the lead of 2): its hover pose, weight 0.6**5.
        target[:] = 0.0
        target[5, k] = 1.0
        obs[manager.term_slice("target_keys")] = target.reshape(-1)
        w = pc.decay**5
        want[arm] = w / (w + pc.rest_weight) * (poses.hover[k, arm] - DEFAULT[arm]) / SCALE[arm]
        np.testing.assert_allclose(prior.apply(obs), want, atol=1e-5)


def test_poses_hover_over_and_press_their_key(poses) -> None:
    """On the C MuJoCo keyboard with the MIT law (robot Kp/Kd, torque caps): commanding hover(k) for 1 s
    holds the fingertip sphere hover_m above the key's aim point (within 3 mm: the IK's 2 mm and friction's
    play) with no key down; then press(k) for 1 s holds key k past its press threshold and no other key."""
    pc = KeyPosePriorConfig()
    model = load_model("arms", keyboard_scene(KB))
    data = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, ROBOT.joint_names)
    keys = key_table(KB)
    key_q = np.array([model.jnt_qposadr[model.joint(f"piano_key{k.midi}").id] for k in keys])
    thr = press_thresholds(KB)
    cap = ROBOT.torque_cap
    for midi in (40, 48, 61, 64, 78):  # white and black, both hands, near and far
        k = midi - KB.lowest
        mujoco.mj_resetData(model, data)
        data.qpos[idx.qpos] = held_pose(DEFAULT)
        mujoco.mj_forward(model, data)
        tip = model.site(FINGERTIP_SITES[poses.hand[k]]).id
        for which in ("hover", "press"):
            q_cmd = getattr(poses, which)[k]
            for _ in range(500):
                tau = ROBOT.kp * (q_cmd - data.qpos[idx.qpos]) - ROBOT.kd * data.qvel[idx.dof]
                data.qfrc_applied[idx.dof] = np.clip(tau, -cap, cap)
                mujoco.mj_step(model, data)
            down = np.flatnonzero(data.qpos[key_q] >= thr) + KB.lowest
            if which == "hover":
                want = np.asarray(keys[k].site) + np.array([0.0, 0.0, KB.fingertip_radius + pc.hover_m])
                np.testing.assert_allclose(data.site_xpos[tip], want, atol=0.003, err_msg=f"key {midi}")
                assert down.size == 0, f"hovering over {midi} presses {down}"
            else:
                assert down.tolist() == [midi], f"pressing {midi} holds {down} down"
