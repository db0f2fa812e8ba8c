"""LiteTrack in MJX: the lookahead observation by hand, step wiring, termination, metadata, FK parity, and
that the task can be solved through the action interface."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import track_fk
from mujoco import mjx

from bar_policy.motion import motion_box
from bar_policy.motion.library import clip_set_id
from bar_policy.robot.action_filter import filter_alpha
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.kinematics import Kinematics, rotation_to_6d
from bar_policy.robot.mjcf import load_model
from bar_policy.tasks.track import (
    TRACK_BODY_NAMES,
    TRACK_LOOKAHEAD_STEPS,
    track_action_scale,
    track_default_pose,
)

ROBOT = load_robot("arms")
PIANO = ROBOT.pose("piano_ready")


def c_fk(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tracked body positions (B, 3) and 6-D orientations (B, 6) straight from C MuJoCo's MjData."""
    return track_fk.c_fk(q, TRACK_BODY_NAMES)


@pytest.mark.numerics
def test_lookahead_observation_by_hand(track_env, track_fns):
    """Clip 'tiny' has frames q_k = piano_ready + 0.01 k (k = 0, 1, 2). Reset at frame 0: the observation
    holds frames 1, 2, 2, 2, 2 (K = 5; past the end the last frame repeats); one step later 2, 2, 2, 2, 2."""
    env = track_env
    _, step, reset_at = track_fns
    om = env.obs_manager
    assert om.term_names == (
        "motion_joint_pos",
        "motion_body_pos_b",
        "motion_body_ori_b",
        "joint_pos",
        "joint_vel",
        "actions",
    )
    assert env.observation_size == 5 * 14 + 5 * 4 * 3 + 5 * 4 * 6 + 3 * 14 == 292
    q = [PIANO + 0.01 * k for k in range(3)]
    s = reset_at(jax.random.PRNGKey(0), 0, 0)
    assert int(s.info["frame"]) == 0 and int(s.info["last_frame"]) == 2
    parts = om.split(np.asarray(s.obs))
    frames = [1, 2, 2, 2, 2]
    # The table is float32 copies of float64 values (q, C MuJoCo FK): one rounding of |x| <= pi
    # (ulp <= 2.4e-7) and one in the chest-frame transform: 1e-6 = 4 ulps.
    np.testing.assert_allclose(parts["motion_joint_pos"], np.concatenate([q[k] for k in frames]), atol=1e-6)
    fk = {k: c_fk(q[k]) for k in (1, 2)}
    np.testing.assert_allclose(
        parts["motion_body_pos_b"], np.concatenate([fk[k][0].ravel() for k in frames]), atol=1e-6
    )
    np.testing.assert_allclose(
        parts["motion_body_ori_b"], np.concatenate([fk[k][1].ravel() for k in frames]), atol=1e-6
    )
    # The robot starts on frame 0 (nominal: no noise) at the reference velocity: (q1 - q0) / 0.02 s
    # = 0.5 rad/s (one-sided difference at the clip's start); joint_vel has scale 0.1.
    np.testing.assert_allclose(parts["joint_pos"], q[0] - track_default_pose(), atol=1e-6)
    np.testing.assert_allclose(parts["joint_vel"], 0.05, atol=1e-6)
    # The action filter (3 Hz) starts from the action of the start pose: (q0 - default) / scale, and one step
    # of a = 0.1 moves it by alpha = 1 - exp(-2 pi 3 Hz 0.02 s) = 1 - exp(-0.376991) = 0.314078 of the way.
    assert env.config.action_filter_hz == 3.0
    a0 = (q[0] - track_default_pose()) / track_action_scale("arms")
    assert np.all(np.abs(a0) < 1)  # inside the action range: no clip
    np.testing.assert_allclose(parts["actions"], a0, atol=1e-6)
    s1 = step(s, jnp.full(14, 0.1, jnp.float32))
    assert int(s1.info["frame"]) == 1
    parts = om.split(np.asarray(s1.obs))
    np.testing.assert_allclose(parts["motion_joint_pos"], np.tile(q[2], 5), atol=1e-6)
    np.testing.assert_allclose(parts["actions"], a0 + 0.314078 * (0.1 - a0), atol=1e-6)
    s2 = step(s1, jnp.zeros(14, jnp.float32))
    s3 = step(s2, jnp.zeros(14, jnp.float32))
    assert int(s2.info["frame"]) == int(s3.info["frame"]) == 2  # holds the last frame
    # Second clip (the gesture) starts after the tiny clip's 3 frames.
    g = reset_at(jax.random.PRNGKey(0), 1, 10)
    assert (int(g.info["frame"]), int(g.info["last_frame"])) == (13, 3 + 226 - 1)
    np.testing.assert_allclose(g.data.qpos, env.reference.joint_pos[13], atol=1e-7)


def test_step_rewards_and_metrics_wiring(track_env, track_fns):
    env = track_env
    _, step, reset_at = track_fns
    s = reset_at(jax.random.PRNGKey(1), 1, 100)  # mid-gesture, moving
    s1 = step(s, jnp.zeros(14, jnp.float32))
    ref = env.reference
    f = int(s1.info["frame"])
    assert f == 3 + 100 + 1  # clip 1 starts after the tiny clip's 3 frames; one step advances one frame
    qpos = np.asarray(s1.data.qpos, np.float64)
    q_ref = ref.joint_pos[f].astype(np.float64)
    terms = {k: float(v) for k, v in s1.metrics.items() if k.startswith("reward/")}
    names = (
        "joint_pos",
        "body_pos",
        "body_ori",
        "fingertip_pos",
        "action_rate",
        "action_accel",
        "torque",
        "torque_near_cap",
    )
    assert set(terms) == {f"reward/{n}" for n in names}
    assert float(s1.reward) == pytest.approx(sum(terms.values()), rel=1e-5, abs=1e-6)
    # joint_pos = exp(-mean (q - q_ref)^2 / 0.08^2), weight 1 (the default joint_std); errors against the
    # frame the step arrives at.
    want = np.exp(-np.mean((qpos - q_ref) ** 2) / 0.08**2)
    assert terms["reward/joint_pos"] == pytest.approx(want, rel=1e-4)
    assert float(s1.metrics["joint_error"]) == pytest.approx(np.mean(np.abs(qpos - q_ref)), abs=1e-6)
    pos = np.asarray(s1.data.xpos)[[env.mj_model.body(b).id for b in TRACK_BODY_NAMES]]
    dist = np.linalg.norm(pos - ref.body_pos[f], axis=-1)
    assert float(s1.metrics["body_pos_error"]) == pytest.approx(dist.mean(), abs=1e-6)
    tips = np.asarray(s1.data.site_xpos)[[env.mj_model.site(x).id for x in FINGERTIP_SITES]]
    tip_dist = np.linalg.norm(tips - ref.fingertip_pos[f], axis=-1)
    tip_err = tip_dist.mean()
    assert float(s1.metrics["fingertip_error"]) == pytest.approx(tip_err, abs=1e-6)
    # fingertip_pos = exp(-mean |tip - tip_ref|^2 / 0.01^2), weight 1 (the default fingertip_std).
    want = np.exp(-np.mean(tip_dist**2) / 0.01**2)
    assert terms["reward/fingertip_pos"] == pytest.approx(want, rel=1e-4, abs=1e-6)
    # Zero action from the filter's start state: a = a0 (1 - alpha), so the applied action moved by
    # alpha * a0; action_rate = -0.1 * sum((alpha a0)^2).
    a0 = np.asarray(s.info["last_act"], np.float64)
    want = -0.1 * np.sum((0.314078 * a0) ** 2)
    assert terms["reward/action_rate"] == pytest.approx(want, rel=1e-4, abs=1e-7)
    # action_accel: the reset sets a_{t-2} = a_{t-1} = a0, so the second difference is the first one:
    # -0.2 * sum((alpha a0)^2).
    assert terms["reward/action_accel"] == pytest.approx(2 * want, rel=1e-4, abs=1e-7)
    want = float(np.mean(np.abs(qpos - q_ref)) <= 0.05 and tip_err <= 0.02)
    assert float(s1.metrics["success"]) == want
    assert float(s1.metrics["tracked"]) == 1.0 and float(s1.done) == 0.0 and float(s1.metrics["lost"]) == 0.0
    ratios = env.eval_ratios(s1.metrics)
    assert set(ratios) == {"success_rate", "joint_error_rad", "body_pos_error_cm", "fingertip_error_cm"}
    assert float(ratios["body_pos_error_cm"][0]) == pytest.approx(100 * dist.mean(), rel=1e-5)


def test_lost_reference_ends_the_episode(track_env, track_fns):
    """The robot in its T-pose (q = 0) while the reference is near piano-ready: the hands are 0.38 m off."""
    _, step, reset_at = track_fns
    s = reset_at(jax.random.PRNGKey(2), 0, 0)
    s = s.replace(data=s.data.replace(qpos=jnp.zeros(14), qvel=jnp.zeros(14)))
    s1 = step(s, jnp.zeros(14, jnp.float32))
    assert float(s1.done) == 1.0 and float(s1.metrics["lost"]) == 1.0
    assert float(s1.metrics["body_pos_error"]) > track_env.config.termination_distance / 2


def test_random_reset_and_metadata(track_env, track_fns, track_clips):
    env = track_env
    reset, _, _ = track_fns
    starts = {int(reset(jax.random.PRNGKey(k)).info["last_frame"]) for k in range(12)}
    assert starts <= {2, 228} and len(starts) == 2  # both clips get picked
    s = reset(jax.random.PRNGKey(3))
    assert int(s.info["frame"]) < int(s.info["last_frame"])
    meta = env.task_metadata()
    assert meta == {
        "body_names": TRACK_BODY_NAMES,
        "lookahead_steps": TRACK_LOOKAHEAD_STEPS,
        "dataset_repo_id": clip_set_id("custom", track_clips),
    }
    assert env.task_name == "track"
    np.testing.assert_allclose(env.default_pose, track_default_pose(), atol=1e-7)


@pytest.mark.numerics
def test_mjx_and_c_forward_kinematics_agree(track_env):
    """The reference poses come from C MuJoCo; the reward compares them with MJX's kinematics of the robot."""
    env = track_env
    lo, hi = motion_box()
    q = np.random.default_rng(0).uniform(lo, hi, (16, 14))
    ids = np.array([env.mj_model.body(b).id for b in TRACK_BODY_NAMES])
    sites = np.array([env.mj_model.site(x).id for x in FINGERTIP_SITES])
    d0 = mjx.make_data(env.mjx_model)

    @jax.jit
    @jax.vmap
    def fk(qq: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        d = mjx.kinematics(env.mjx_model, d0.replace(qpos=qq))
        return d.xpos[ids], d.xmat[ids], d.site_xpos[sites]

    got_pos, got_rot, got_tips = (np.asarray(x) for x in fk(jnp.asarray(q, jnp.float32)))
    pos, rot, tips = Kinematics().trajectory(q, TRACK_BODY_NAMES, FINGERTIP_SITES)
    # float32 MJX (inputs rounded to float32) against float64 C MuJoCo: a few micrometres.
    np.testing.assert_allclose(got_pos, pos, atol=2e-6)
    np.testing.assert_allclose(rotation_to_6d(got_rot.reshape(16, -1, 3, 3)), rotation_to_6d(rot), atol=2e-6)
    np.testing.assert_allclose(got_tips, tips, atol=2e-6)


def test_task_is_solvable_through_the_action_interface(track_env, track_fns):
    """An oracle tracks the hanging-to-piano-ready gesture within the issue's targets (0.05 rad, 2 cm).

    It commands ``q_cmd = q_ref + (tau_id + Kd dq_ref) / Kp`` for the next frame, with ``tau_id`` from C
    MuJoCo inverse dynamics of the reference (gravity, inertia, armature): the MIT law with dq_cmd = 0 then
    delivers tau_id on the reference. Nominal conditions; a policy must also handle latency and DR.
    """
    env = track_env
    _, step, reset_at = track_fns
    m = load_model("arms")
    d = mujoco.MjData(m)
    q_ref = env.reference.joint_pos.astype(np.float64)
    first, last = 3, 3 + 226 - 1  # the gesture's frames in the table (after the 3-frame clip)
    s = reset_at(jax.random.PRNGKey(0), 1, 0)
    alpha = filter_alpha(env.config.action_filter_hz, env.dt) if env.config.action_filter_hz else 1.0
    errors = []
    for _ in range(last - first):
        g = min(int(s.info["frame"]) + 1, last)
        prev, nxt = max(g - 1, first), min(g + 1, last)
        d.qpos[:] = q_ref[g]
        d.qvel[:] = (q_ref[nxt] - q_ref[prev]) / (2 * env.dt)
        d.qacc[:] = (q_ref[nxt] - 2 * q_ref[g] + q_ref[prev]) / env.dt**2
        mujoco.mj_inverse(m, d)
        q_cmd = q_ref[g] + (d.qfrc_inverse + env.kd * d.qvel) / env.kp
        target = (q_cmd - env.default_pose) / env.action_scale
        # Through the action low-pass: the raw action that lands the filtered one on the target,
        # a = last + (target - last) / alpha (inverting lowpass_step; alpha = 1 without a filter).
        last_applied = np.asarray(s.info["last_act"], np.float64)
        a = np.clip(last_applied + (target - last_applied) / alpha, -1, 1)
        s = step(s, jnp.asarray(a, jnp.float32))
        errors.append([float(s.metrics[k]) for k in ("joint_error", "fingertip_error", "success")])
    joint, tip, success = np.mean(errors, axis=0)
    assert joint < 0.01 and tip < 0.005 and success == 1.0, (joint, tip, success)
