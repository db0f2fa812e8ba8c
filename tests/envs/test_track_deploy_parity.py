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
from bar_policy.deploy.tasks.track import MotionReference
from bar_policy.envs.track import SUCCESS_FINGERTIP_M, SUCCESS_JOINT_RAD
from bar_policy.envs.track_config import default_config
from bar_policy.obs import ObservationManager
from bar_policy.tasks import track as task

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
    last_action = np.asarray(actions[-1], np.float32) if actions else np.zeros(14, np.float32)
    want = np.asarray(s.obs)
    got = _deploy_obs(track_clips[clip], phase + steps, s.data.qpos, s.data.qvel, last_action)
    assert got.dtype == np.float32 and got.shape == want.shape == (292,)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def test_shared_thresholds_match_the_env():
    """The deploy evaluation's success and lost thresholds are the env's."""
    assert task.SUCCESS_JOINT_RAD == SUCCESS_JOINT_RAD
    assert task.SUCCESS_FINGERTIP_M == SUCCESS_FINGERTIP_M
    assert default_config().termination_distance == task.LOST_DISTANCE
