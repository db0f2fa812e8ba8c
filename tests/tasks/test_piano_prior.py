"""The key-pose prior: its blend of the key poses, and its poses on the C MuJoCo keyboard.

Expected values: the blend's means are worked by hand from its definition (``obs.action_prior.BlendPrior``,
tested on its own in tests/training/test_action_prior.py); the poses are checked against the keyboard's
geometry (the fingertip sphere ``hover_m`` above a key's aim point, or the key at the bottom of its travel
with no other key down) in C MuJoCo with the MIT law.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import PRIOR_BOUND
from bar_policy.robot.action_filter import filter_alpha
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


@pytest.fixture(scope="module")
def poses():
    return key_poses(KB)


@pytest.fixture(scope="module")
def prior():
    return key_pose_prior(ObservationManager.for_task("piano", "arms"), KB, DEFAULT, SCALE, 2)


def test_one_goal_key_gives_its_press_pose(prior, poses) -> None:
    """Goal key k in frame 0 only: its hand's actions are w / (w + rest) of the press pose's action, with
    w = decay**0 = 1 and rest 0.02, plus the edge blend's lift, -0.45 of (press - hover) (frame 0: the
    note's last step); the other hand rests (action 0). Hands: left below middle C."""
    pc = KeyPosePriorConfig()
    assert pc.edge_gain == 0.45 and pc.rest_weight == 0.02
    manager = ObservationManager.for_task("piano", "arms")
    for midi, hand in ((48, 0), (61, 1)):
        k = midi - KB.lowest
        target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        target[0, k] = 1.0
        obs = np.zeros(manager.size, np.float32)
        obs[manager.term_slice("target_keys")] = target.reshape(-1)
        want = np.zeros(14)
        arm = np.arange(7) + 7 * hand
        want[arm] = (1.0 / 1.02) * (poses.press[k, arm] - DEFAULT[arm]) / SCALE[arm] - 0.45 * (
            poses.press[k, arm] - poses.hover[k, arm]
        ) / SCALE[arm]
        np.testing.assert_allclose(prior.apply(obs), np.clip(want, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
        # The same key 5 frames ahead (past the lead of 2): its hover pose, weight 0.6**5 (no edge term).
        target[:] = 0.0
        target[5, k] = 1.0
        obs[manager.term_slice("target_keys")] = target.reshape(-1)
        w = pc.decay**5
        want[arm] = w / (w + pc.rest_weight) * (poses.hover[k, arm] - DEFAULT[arm]) / SCALE[arm]
        np.testing.assert_allclose(prior.apply(obs), want, atol=1e-5)


def test_edge_blend_pushes_before_a_note_and_lifts_before_its_end(prior, poses) -> None:
    """A 20-step note of one key (E4, right hand) at steps 30..49, the window at step t holding it in the
    frames j with 30 <= t + j < 50. The place blend, per the module docstring: press weights 0.6**j for
    j <= 2, hover weights 0.6**j later, rest 0.02. The edge blend adds c_j (press - hover) per frame the key
    is in, c_0 = -0.45, c_2 = +0.45: worked out per step,

    - t = 28 (frames 2..10): place (0.36 press + H hover) / (0.36 + H + 0.02), H = sum 0.6**j, j = 3..10;
      edge +0.45 (pushed: frame 2 on, frame 0 off);
    - t = 35 (frames 0..10, held): place (1.96 press + H hover) / (1.96 + H + 0.02); edge 0;
    - t = 48 (frames 0, 1): place 1.6 press / 1.62; edge -0.45 (lifted: frame 0 on, frame 2 off);
    - t = 50 (gone): 0; the left arm stays at 0 throughout."""
    manager = ObservationManager.for_task("piano", "arms")
    k = 64 - KB.lowest
    arm = np.arange(7, 14)
    press = (poses.press[k, arm] - DEFAULT[arm]) / SCALE[arm]
    hover = (poses.hover[k, arm] - DEFAULT[arm]) / SCALE[arm]
    h = sum(0.6**j for j in range(3, 11))
    assert h == pytest.approx(0.216 * (1 - 0.6**8) / 0.4) == pytest.approx(0.53093, abs=1e-5)
    cases = {
        28: (0.36 * press + h * hover) / (0.36 + h + 0.02) + 0.45 * (press - hover),
        35: (1.96 * press + h * hover) / (1.96 + h + 0.02),
        48: 1.6 * press / 1.62 - 0.45 * (press - hover),
        50: np.zeros(7),
    }
    for t, right in cases.items():
        target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        for j in range(TARGET_FRAMES):
            target[j, k] = 1.0 if 30 <= t + j < 50 else 0.0
        obs = np.zeros(manager.size, np.float32)
        obs[manager.term_slice("target_keys")] = target.reshape(-1)
        want = np.concatenate([np.zeros(7), right])
        np.testing.assert_allclose(prior.apply(obs), np.clip(want, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
    # The edge blend is the BlendPrior's second blend, linear: no weight per entry, weight 1 at rest pose 0
    # (then the release blends: 25, one per key rank of the larger hand; test_release_blend_...).
    assert prior.numer.shape[0] == 2 + 25 and not np.any(prior.denom[1])
    np.testing.assert_array_equal(prior.denom_bias[1], np.ones(14))
    np.testing.assert_array_equal(prior.numer_bias[1], np.zeros(14))


def test_between_notes_the_hand_leans_on_the_next_key_not_the_rest_pose(prior, poses) -> None:
    """Why the rest weight is 0.02: the rest pose (piano_ready, held under gravity) puts the fingertip sphere
    in front of the black keys and below their tops, so its share of the blend between two notes pulls the
    hand's path low and forward, where it wedged against black keys' sides (docs/piano.md, "The place blend").

    Geometry (``KeyboardConfig``): black keys' tops at 0.180 + 0.012 = 0.192 m, their front edges 55 mm behind
    the white keys' front edge, 0.336 + 0.055 = 0.391 m; the held sphere (centre ~(0.357, ±0.157, 0.191),
    radius 6 mm) lies below the one and in front of the other. The blend, by hand: the next note (F#4, black,
    right hand) in frames 6..10 only (a gap before it), hover weights H = sum 0.6**j, j = 6..10 =
    0.6**6 (1 - 0.6**5) / 0.4 = 0.107570; the hand's action is H / (H + 0.02) = 0.84322 of hover(F#4)'s
    (0.68268 at the former 0.05), no edge term (frames 0 and 2 empty)."""
    keys = key_table(KB)
    black_top = KB.top_z + KB.black_rise
    black_front = KB.front_x + (KB.white_length - KB.black_length)
    assert black_top == pytest.approx(0.192) and black_front == pytest.approx(0.391)
    assert [k.top_z for k in keys if k.black] == pytest.approx([black_top] * 20)
    assert [k.front_x for k in keys if k.black] == pytest.approx([black_front] * 20)
    model = load_model("arms", keyboard_scene(KB))
    data = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, ROBOT.joint_names)
    data.qpos[idx.qpos] = held_pose(DEFAULT)
    mujoco.mj_kinematics(model, data)
    for site in FINGERTIP_SITES:
        tip = data.site_xpos[model.site(site).id]
        assert tip[2] - KB.fingertip_radius < black_top - 0.005, f"{site} {tip}"
        assert tip[0] + KB.fingertip_radius < black_front - 0.02, f"{site} {tip}"

    h = sum(0.6**j for j in range(6, 11))
    assert h == pytest.approx(0.6**6 * (1 - 0.6**5) / 0.4) == pytest.approx(0.107570, abs=1e-6)
    assert h / (h + 0.02) == pytest.approx(0.84322, abs=1e-5)
    assert h / (h + 0.05) == pytest.approx(0.68268, abs=1e-5)
    manager = ObservationManager.for_task("piano", "arms")
    k = 66 - KB.lowest
    assert keys[k].black and poses.hand[k] == 1
    target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
    target[6:, k] = 1.0
    obs = np.zeros(manager.size, np.float32)
    obs[manager.term_slice("target_keys")] = target.reshape(-1)
    want = np.zeros(14)
    arm = np.arange(7, 14)
    want[arm] = 0.84322 * (poses.hover[k, arm] - DEFAULT[arm]) / SCALE[arm]
    np.testing.assert_allclose(prior.apply(obs), want, atol=1e-4)


@pytest.mark.slow
def test_edge_gain_zero_is_the_single_place_blend(poses) -> None:
    """``edge_gain=0`` (and no release blend): one blend, the prior before the edge blend (key k in frame 0:
    press / 1.02)."""
    manager = ObservationManager.for_task("piano", "arms")
    plain = key_pose_prior(
        manager, KB, DEFAULT, SCALE, 2, KeyPosePriorConfig(edge_gain=0.0, release_gain=0.0)
    )
    assert plain.numer.shape[0] == 1
    k = 64 - KB.lowest
    target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
    target[0, k] = 1.0
    obs = np.zeros(manager.size, np.float32)
    obs[manager.term_slice("target_keys")] = target.reshape(-1)
    want = np.zeros(14)
    want[7:] = (poses.press[k, 7:] - DEFAULT[7:]) / SCALE[7:] / 1.02
    np.testing.assert_allclose(plain.apply(obs), want, atol=1e-5)


def test_frame_weights_and_edge_factors() -> None:
    """The blend's weight per frame (lead 2) and the edge factors, worked by hand for each setting."""
    pc = KeyPosePriorConfig()
    assert [pc.frame_weight(j, 2) for j in (0, 1, 2, 3, 10)] == pytest.approx([1, 0.6, 0.36, 0.216, 0.6**10])
    np.testing.assert_allclose(pc.edge_factors(2), [-0.45, 0, 0.45] + [0] * 8)
    np.testing.assert_allclose(pc.edge_factors(3), [-0.45, 0, 0, 0.45] + [0] * 7)
    assert pc.edge_factors(0) is None and KeyPosePriorConfig(edge_gain=0).edge_factors(2) is None
    g = KeyPosePriorConfig(press_gain=2.0)
    assert [g.frame_weight(j, 2) for j in (0, 2, 3)] == pytest.approx([2.0, 0.72, 0.216])
    hd = KeyPosePriorConfig(hover_decay=0.5)
    assert [hd.frame_weight(j, 2) for j in (2, 3, 4)] == pytest.approx([0.36, 0.18, 0.09])
    fw = KeyPosePriorConfig(frame_weights=tuple(range(11)))
    assert fw.frame_weight(7, 2) == 7.0
    ew = KeyPosePriorConfig(edge_weights=(0.1,) + (0.0,) * 10)
    np.testing.assert_allclose(ew.edge_factors(2), [0.1] + [0] * 10)
    bad_settings = (
        {"frame_weights": (1.0,) * 10},
        {"edge_weights": (0.0,) * 12},
        {"edge_gain": -0.1},
        {"press_gain": 0.0},
        {"hover_decay": 1.5},
        {"frame_weights": (-1.0,) + (1.0,) * 10},
        {"release_gain": -0.1},
        {"release_block": 0.0},
    )
    for bad in bad_settings:
        with pytest.raises(ValueError):
            KeyPosePriorConfig(**bad)


@pytest.mark.slow
def test_release_blend_lifts_a_key_held_down_off_its_goal(prior, poses) -> None:
    """The release blend (feedback from ``key_pressed``): a key observed down adds
    ``0.2 (hover(k) - press(k))`` to its hand, divided by ``1 + 100 goal_0(k)`` (its own frame-0 goal bit).
    Worked per case (right arm; actions in units of SCALE; place and edge blends as in the tests above):

    - E4 down, no goal key: place 0 (rest pose only), edge 0, release 0.2 (hover_E4 - press_E4);
    - E4 down and E4 the goal (frame 0 only): press_E4 / 1.02 - 0.45 (press_E4 - hover_E4) + the release
      term / 101 (blocked by its goal);
    - E4 down and D4 the goal (frame 0 only; the finger held against D4's side, docs/piano.md "Release
      blend"): press_D4 / 1.02 - 0.45 (press_D4 - hover_D4) + 0.2 (hover_E4 - press_E4), unblocked (D4's
      goal bit is not E4's);
    - C3 (left, rank 12 of the left hand's keys) down and C5 (right, rank 12: the same blend) the goal:
      the left arm gets C3's full release term, the right arm C5's press and lift only."""
    pc = KeyPosePriorConfig()
    assert pc.release_gain == 0.2 and pc.release_block == 100.0
    manager = ObservationManager.for_task("piano", "arms")
    scale = {t.name: t.scale for t in manager.schema.terms}

    def action(goal: dict[int, int], down: list[int]) -> np.ndarray:
        target = np.zeros((TARGET_FRAMES, PIANO_KEYS), np.float32)
        for midi, frame in goal.items():
            target[frame, midi - KB.lowest] = 1.0
        pressed = np.zeros(PIANO_KEYS, np.float32)
        pressed[[m - KB.lowest for m in down]] = 1.0
        obs = np.zeros(manager.size, np.float32)
        obs[manager.term_slice("target_keys")] = scale["target_keys"] * target.reshape(-1)
        obs[manager.term_slice("key_pressed")] = scale["key_pressed"] * pressed
        return prior.apply(obs)

    def unit(pose: np.ndarray, k: int, arm: np.ndarray) -> np.ndarray:
        return (pose[k - KB.lowest, arm] - DEFAULT[arm]) / SCALE[arm]

    right, left = np.arange(7, 14), np.arange(7)
    p_e, h_e = unit(poses.press, 64, right), unit(poses.hover, 64, right)
    p_d, h_d = unit(poses.press, 62, right), unit(poses.hover, 62, right)
    release_e = 0.2 * (h_e - p_e)
    cases = [
        (({}, [64]), release_e),
        (({64: 0}, [64]), p_e / 1.02 - 0.45 * (p_e - h_e) + release_e / 101),
        (({62: 0}, [64]), p_d / 1.02 - 0.45 * (p_d - h_d) + release_e),
    ]
    for (goal, down), want in cases:
        got = action(goal, down)
        np.testing.assert_allclose(got[right], np.clip(want, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
        np.testing.assert_allclose(got[left], np.zeros(7), atol=1e-6)
    got = action({72: 0}, [48])
    p_c5, h_c5 = unit(poses.press, 72, right), unit(poses.hover, 72, right)
    want_left = 0.2 * (unit(poses.hover, 48, left) - unit(poses.press, 48, left))
    np.testing.assert_allclose(got[left], np.clip(want_left, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
    want_right = p_c5 / 1.02 - 0.45 * (p_c5 - h_c5)
    np.testing.assert_allclose(got[right], np.clip(want_right, -PRIOR_BOUND, PRIOR_BOUND), atol=1e-5)
    # open_loop(): the goal keys' part alone (the reference's): no release blend, 2 blends.
    open_prior = key_pose_prior(manager, KB, DEFAULT, SCALE, 2, pc.open_loop())
    assert open_prior.numer.shape[0] == 2 and open_prior.stop == manager.term_slice("target_keys").stop


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


def test_litepiano_serves_the_key_pose_prior() -> None:
    """The piano's env serves ``key_pose`` (its ``EnvEntry.action_prior``), a ``--network.action-prior``
    choice read from the record (tests/training/test_action_prior.py)."""
    from bar_policy.tasks.registry import env_entries
    from bar_policy.training.config import ACTION_PRIORS

    assert env_entries()["LitePiano"][1].action_prior == "key_pose"
    assert "key_pose" in ACTION_PRIORS


def test_key_switches_stay_under_the_caps(poses) -> None:
    """The cap ticks of 2026-11-26: IK put the right hand's C4 at a 40 degree finger tilt (at tilt 0 the
    wrist met the chest) and C#4, D#4 (left: G#3, A#3) at 20 degrees (the case), beside 0 for D4, E4: a
    C4 <-> D4 switch of the blend stepped the right wrist pitch's target by 0.49 rad, of which the 3 Hz
    action filter passes alpha = 1 - exp(-2 pi 3 Hz 0.02 s) = 0.314 in one tick:
    kp 50 x 0.314 x 0.49 = 7.7 N*m on a 4 N*m wrist.

    Now every key is solved at the flattest tilt (0), other null-space postures tried first. Checked here:
    each hover command's finger points within 10 degrees of horizontal (the IK's 0, and up to 6 from the
    gravity fold-in; 20 and 40 degrees before), and a full switch of the blend between two keys of one
    hand a fifth apart or less, or from a key to the rest pose (piano_ready), demands less than the cap on
    every joint in the filter's first tick, ``kp alpha |press(a) - press(b)|``."""
    alpha = 1.0 - np.exp(-2.0 * np.pi * 3.0 * 0.02)
    assert alpha == pytest.approx(0.3141, abs=1e-4)
    assert filter_alpha(3.0, 0.02) == pytest.approx(alpha)  # the env's and the deploy side's filter
    model = load_model("arms", keyboard_scene(KB))
    data = mujoco.MjData(model)
    idx = RobotIndex.from_model(model, ROBOT.joint_names)
    hold = held_pose(DEFAULT)
    for k in range(KB.n_keys):
        h = poses.hand[k]
        name = ("left", "right")[h]
        arm = np.arange(7) + 7 * h
        data.qpos[idx.qpos] = poses.hover[k]  # the command (IK pose + gravity fold-in)
        mujoco.mj_kinematics(model, data)
        finger = data.xmat[model.body(f"{name}_hand").id].reshape(3, 3)[:, 1] * (1.0 if h == 0 else -1.0)
        tilt = np.degrees(np.arcsin(-finger[2]))
        assert abs(tilt) < 10.0, f"key {k + KB.lowest}: finger {tilt:.1f} deg below horizontal"
        for other in [hold] + [
            poses.press[j] for j in range(KB.n_keys) if poses.hand[j] == h and abs(j - k) <= 7
        ]:
            demand = ROBOT.kp[arm] * alpha * np.abs(poses.press[k, arm] - other[arm])
            assert np.all(demand < ROBOT.torque_cap[arm]), f"key {k + KB.lowest}: {demand.round(2)} N*m"


def test_key_poses_and_the_held_pose_fold_in_the_gains_they_are_for() -> None:
    """A key's press command is its IK pose plus the holding torque over Kp (``q + hold(q, hand, 1.5 N) /
    Kp``), so the stiff profile's (Kp 100) folds in half of the table's (Kp 50) at the same IK pose:
    ``q = 2 press_100 - press_50``, and that q must give back ``press_50`` with C MuJoCo's holding torque
    (``HoldingTorque``) by hand, on every key's arm: float64 round-off of a fold-in under 0.1 rad, 1e-9 rad.
    Hovers alike without the key force. The held start pose solves ``q = q0 - g(q) / Kp`` at either Kp."""
    from bar_policy.robot.gains import profile_gains
    from bar_policy.tasks.piano.held import HoldingTorque

    kp50 = profile_gains(ROBOT, "robot")[0]
    kp100 = profile_gains(ROBOT, "stiff")[0]
    table = key_poses(KB, "arms")
    stiff = key_poses(KB, "arms", None, tuple(kp100))
    hold = HoldingTorque("arms")
    force = KeyPosePriorConfig().press_force_n
    for i, h in enumerate(table.hand):
        arm = np.arange(7) + 7 * int(h)
        name = ("left", "right")[int(h)]
        for pose, args in ((table.press, (name, force)), (table.hover, ())):
            other = stiff.press if pose is table.press else stiff.hover
            q = 2 * other[i] - pose[i]
            back = q + hold(q, *args) / kp50
            np.testing.assert_allclose(back[arm], pose[i][arm], atol=1e-9)
        assert np.max(np.abs(stiff.press[i] - table.press[i])) > 1e-3  # the fold-in is there to halve
    for kp in (kp50, kp100):
        q = held_pose(DEFAULT, kp=kp)
        np.testing.assert_allclose(q, DEFAULT - hold(q) / kp, atol=1e-9)
