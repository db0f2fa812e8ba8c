"""The deploy side's tracking observation equals the MJX env's for the same state and phase.

The env (jax, ``LiteTrack`` on the session fixture's clips, nominal: no noise, no encoder offset) steps a
few times from a chosen clip and phase; the deploy side (numpy: ``MotionReference`` of that clip alone,
``StateInputs`` of the measured q / dq / previous action, the policy layout's ``ObservationManager``) builds
the observation for the same q, dq, action and phase. They must agree to float32 precision, through the
clip's middle, its end (the past-the-end hold) and a clip that is not the table's first.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.deploy.inputs import StateInputs
from bar_policy.obs import ObservationManager
from bar_policy.robot.action_filter import filter_alpha, lowpass_step, pose_action
from bar_policy.tasks import track as task
from bar_policy.tasks.track.config import default_config
from bar_policy.tasks.track.env import SUCCESS_FINGERTIP_M, SUCCESS_JOINT_RAD
from bar_policy.tasks.track.reference import MotionReference

pytestmark = pytest.mark.numerics  # compares XLA floats with another implementation / a recording


def _deploy_obs(clip, phase: int, q, dq, action) -> np.ndarray:
    om = ObservationManager.for_task("track", "arms")
    ref = MotionReference(
        clip,
        om.command_names,
        body_names=om.schema.body_names,
        lookahead_steps=om.schema.lookahead_steps,
        control_dt=0.02,
    )
    ref.begin(1.5)  # POLICY started at run time 1.5 s: phase j at 1.5 + 0.02 j
    state = StateInputs(om, "arms")
    inputs = state(np.asarray(q, np.float64), np.asarray(dq, np.float64), np.asarray(action))
    inputs.update(ref(1.5 + 0.02 * phase))
    return om.compute(inputs)


@pytest.mark.parametrize(
    ("clip", "phase", "steps"),
    [(1, 100, 3), (1, 222, 3), (0, 0, 0), (0, 0, 2)],
    ids=["gesture-mid", "gesture-end", "tiny-reset", "tiny-past-end"],
)
def test_deploy_observation_equals_the_env_observation(track_env, track_fns, track_clips, clip, phase, steps):
    _, step, reset_at = track_fns
    s = reset_at(jax.random.PRNGKey(7), clip, phase)
    actions = [jnp.linspace(-0.4, 0.6, 14) * (k + 1) / 3 for k in range(steps)]
    for a in actions:
        s = step(s, a.astype(jnp.float32))
    start = int(track_env.reference.clip_start[clip])
    frame = int(s.info["frame"]) - start
    assert frame == min(phase + steps, track_clips[clip].num_frames - 1)
    # The deploy side's filter state, with the shared functions: from the start pose's action, one low-pass
    # step per action (the env's initial_action / filtered_action).
    cfg = track_env.config
    alpha = filter_alpha(cfg.action_filter_hz, cfg.ctrl_dt)
    start_q = track_env.reference.joint_pos[start + phase].astype(np.float64)
    last_action = pose_action(start_q, task.track_default_pose(), task.track_action_scale("arms"))
    for a in actions:
        last_action = lowpass_step(last_action, np.clip(np.asarray(a, np.float64), -1, 1), alpha)
    want = np.asarray(s.obs)
    got = _deploy_obs(
        track_clips[clip], phase + steps, s.data.qpos, s.data.qvel, last_action.astype(np.float32)
    )
    assert got.dtype == np.float32 and got.shape == want.shape == (292,)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_shared_thresholds_match_the_env():
    """The deploy evaluation's success and lost thresholds are the env's."""
    assert task.SUCCESS_JOINT_RAD == SUCCESS_JOINT_RAD
    assert task.SUCCESS_FINGERTIP_M == SUCCESS_FINGERTIP_M
    assert default_config().termination_distance == task.LOST_DISTANCE


def _env_policy(env, path, **kwargs):
    """A deploy policy file carrying ``env``'s action filter, default pose and action scale, loaded.

    ``kwargs`` go to the test policy factory (``bias``: the constant action).
    """
    import dataclasses
    import sys
    from pathlib import Path

    from bar_policy.deploy.policy import load_policy

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "deploy"))
    from policy_factory import default_metadata, make_policy_file

    meta = dataclasses.replace(
        default_metadata("arms", task="track"),
        action_filter_hz=env.config.action_filter_hz,
        action_scale=tuple(float(x) for x in task.track_action_scale("arms")),
        default_joint_pos=tuple(float(x) for x in task.track_default_pose()),
    )
    return load_policy(make_policy_file(path, metadata=meta, **kwargs))


def test_action_filter_parity_env_and_deploy(track_env, track_fns, tmp_path):
    """The robot's ``ActionPath`` applies the env's action filter: the same applied actions, tick by tick.

    The env (``reset_at`` on a gesture frame, then steps) and the deploy side (a policy file carrying the
    env's cutoff, default pose and action scale; ``ActionPath.start`` at the same pose, then the same raw
    actions, some outside [-1, 1] so the clip matters) must hold the same filter state after every tick:
    both are ``robot.action_filter.lowpass_step`` of the clipped action, one in float32 XLA, one in float64
    numpy rounded to float32; 1e-6 covers a few float32 ulps on |a| <= 1 (6e-8 each) over 6 ticks.
    """
    from bar_policy.deploy.action_path import ActionPath

    _, step, reset_at = track_fns
    cfg = track_env.config
    policy = _env_policy(track_env, tmp_path / "p.onnx")
    path = ActionPath(policy)
    assert path.alpha == pytest.approx(filter_alpha(cfg.action_filter_hz, cfg.ctrl_dt), rel=1e-12)
    s = reset_at(jax.random.PRNGKey(3), 1, 40)
    start = int(track_env.reference.clip_start[1])
    path.start(track_env.reference.joint_pos[start + 40].astype(np.float64))
    np.testing.assert_allclose(path.last, np.asarray(s.info["last_act"]), atol=1e-6)
    rng = np.random.default_rng(0)
    for k in range(6):
        raw = rng.uniform(-1.5, 1.5, 14).astype(np.float32)  # a third of the entries clip
        s = step(s, jnp.asarray(raw))
        applied, n_clipped = path(raw, 0.02 * k)
        assert n_clipped == int(np.count_nonzero(np.abs(raw) > 1))
        np.testing.assert_allclose(applied, np.asarray(s.info["last_act"]), atol=1e-6)


def test_first_policy_tick_after_the_hold_ramp_sees_the_env_reset_observation(
    track_env, track_fns, track_clips, tmp_path
):
    """The deploy run's first POLICY tick, after the HOLD ramp to the clip's first frame, observes what the
    env shows after ``reset_at`` on that frame: the lookahead frames 1..5, q - default, the velocity, and the
    applied action of the start pose (the filter's start state, not 0).

    The mock target starts on the gesture's first frame (``arms_hanging``, where the gesture rests for
    0.5 s, so the env's reset velocity is 0 as the robot's is) and echoes each command, so the measured
    state at that tick is the frame exactly. Float32 observation rounding: 1e-6.
    """
    from bar_policy.deploy.log.read import load_log
    from bar_policy.deploy.runtime import Runtime, RuntimeConfig
    from bar_policy.deploy.safety import Mode, SafetyConfig
    from bar_policy.tasks.track.reference import reference_for

    policy = _env_policy(track_env, tmp_path / "p.onnx", bias=0.1)  # puts tests/deploy on the path
    from fault_targets import SteppedMock

    _, _, reset_at = track_fns
    clip = track_clips[1]
    frame0 = clip.joint_pos[0].astype(np.float64)
    assert np.array_equal(clip.joint_pos[0], clip.joint_pos[1])  # the gesture rests: reset velocity 0
    config = RuntimeConfig(duration=0.2, safety=SafetyConfig(ramp_time=0.1))
    target = SteppedMock(initial_q=frame0)
    result = Runtime(policy, target, reference_for(policy, clip), config, log_dir=tmp_path / "runs").run()
    arrays, _ = load_log(result.log_path)
    first = int(np.flatnonzero(arrays["mode"] == int(Mode.POLICY))[0])
    assert first == 5  # 0.1 s of HOLD ramp at 50 Hz
    want = np.asarray(reset_at(jax.random.PRNGKey(0), 1, 0).obs)
    np.testing.assert_allclose(arrays["obs"][first], want, rtol=1e-6, atol=1e-6)
    # Not trivially zero: the start pose's action is far from 0 (arms_hanging vs the motion box centre).
    om = policy.obs_manager
    assert np.abs(om.split(arrays["obs"][first])["actions"]).max() > 0.3
