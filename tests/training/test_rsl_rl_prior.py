"""The action prior on the rsl-rl backend: the env commands prior(obs) + the actor's action, the exported
file carries the prior, and a tiny tracker run on LiteTrack trains with it and exports it.

Expected values are worked out by hand or in numpy from the definitions (``rsl_rl.prior``,
``obs.action_prior``), never read back from the code under test.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import onnx
import pytest
import torch
from toy_configs import TOY_RSL, toy_config

from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.envs import wrap_for_brax_training
from bar_policy.export.parity import _run_onnx
from bar_policy.export.policy import export_policy
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import ActionPrior, reference_prior
from bar_policy.tasks.track import track_action_scale, track_default_pose
from bar_policy.training.rsl_rl.backend import mlp_policy_from_rsl_rl, torch_policy_reference
from bar_policy.training.rsl_rl.env import RslRlVecEnv
from bar_policy.training.rsl_rl.prior import commanded_action, start_actor_at_prior

N = 14
K = 5  # the tracking layout's lookahead frames


def test_commanded_action_is_prior_plus_residual_by_hand():
    """obs = (0.5, -2, 1, 3); prior = clip(gain * obs[index] + offset, -0.99, 0.99) with index (0, 2, 3),
    gain (2, -0.5, 0.1), offset (0.1, 0.2, -0.05):
    2 * 0.5 + 0.1 = 1.1 -> 0.99; -0.5 * 1 + 0.2 = -0.3; 0.1 * 3 - 0.05 = 0.25.
    Plus the residual (0.25, 0.5, -0.125): (1.24, 0.2, 0.125) (unclipped: the env clips). float32: 1e-6."""
    prior = ActionPrior(index=(0, 2, 3), gain=(2.0, -0.5, 0.1), offset=(0.1, 0.2, -0.05))
    obs = jnp.asarray([[0.5, -2.0, 1.0, 3.0]], jnp.float32)
    residual = jnp.asarray([[0.25, 0.5, -0.125]], jnp.float32)
    got = np.asarray(commanded_action(prior, obs, residual))
    np.testing.assert_allclose(got, [[1.24, 0.2, 0.125]], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(commanded_action(None, obs, residual)), np.asarray(residual))


def test_vec_env_commands_prior_plus_residual(toy_env):
    """On the toy (``q += 0.3 * (default + 0.8 * clip(a, -1, 1) - q)``, obs[28:42] = the clipped action), a
    prior reading the targets (obs[48:54], fingertips within +-0.25) twice over plus obs[0:2] (q - default = 0
    at reset) with gain 2, offset 0.1, and a residual of 0.25: a = 2 * obs0[index] + 0.1 + 0.25, inside
    [-1, 1]; after one step obs[28:42] = a and obs[0:14] = 0.3 * 0.8 * a (float32: 1e-5 relative)."""
    index = (*range(48, 54), *range(48, 54), 0, 1)
    prior = ActionPrior(index=index, gain=(2.0,) * N, offset=(0.1,) * N)
    env = RslRlVecEnv.from_env(toy_env, 4, wrap_fn=wrap_for_brax_training, seed=0, device="cpu", prior=prior)
    obs0 = env.get_observations()["policy"].numpy().copy()
    want = 2.0 * obs0[:, list(index)] + 0.1 + 0.25
    assert np.all(np.abs(want) < 1.0) and np.ptp(want[:, 0]) > 0  # inside the clip; differs per env
    obs1, _, _, _ = env.step(torch.full((4, N), 0.25))
    obs1 = obs1["policy"].numpy()
    np.testing.assert_allclose(obs1[:, 28:42], want, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(obs1[:, :14], 0.3 * 0.8 * want, rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="the action prior has 3 actions, the env 14"):
        RslRlVecEnv.from_env(
            toy_env,
            4,
            wrap_fn=wrap_for_brax_training,
            device="cpu",
            prior=ActionPrior(index=(0, 1, 2), gain=(1.0,) * 3, offset=(0.0,) * 3),
        )


# ----------------------------------------------------------------------------------------------------------
# Export of an rsl-rl actor with the reference prior (the tracking layout: 292 observations, 14 actions)
# ----------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def track_setup():
    """(layout, reference prior at lead 5, default pose, action scale, track metadata)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "deploy"))
    from policy_factory import default_metadata

    layout = ObservationManager.for_task("track", "arms")
    default = np.asarray(track_default_pose(), np.float64)
    scale = np.asarray(track_action_scale("arms"), np.float64)
    prior = reference_prior(layout, default, scale, 5)
    return layout, prior, default, scale, default_metadata("arms", task="track")


def _track_obs(layout, q_ref: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A tracking observation whose reference frames are ``q_ref`` (K, N); every other term random."""
    inputs = {t.name: rng.uniform(-0.5, 0.5, t.size).astype(np.float32) for t in layout.schema.terms}
    inputs["motion_joint_pos"] = q_ref.reshape(-1).astype(np.float32)
    return np.asarray(layout.compute(inputs), np.float32)


def _actor(obs_size: int, seed: int):
    """A fresh rsl-rl Gaussian actor (32, 32 elu) with a non-trivial normaliser."""
    from rsl_rl.models import MLPModel
    from tensordict import TensorDict

    torch.manual_seed(seed)
    actor = MLPModel(
        TensorDict({"policy": torch.zeros(1, obs_size)}, batch_size=[1]),
        {"actor": ["policy"]},
        "actor",
        N,
        hidden_dims=[32, 32],
        activation="elu",
        obs_normalization=True,
        distribution_cfg={"class_name": "GaussianDistribution"},
    )
    actor.obs_normalizer.update(torch.randn(256, obs_size) * 0.3 + 0.1)
    return actor.eval()


def _deterministic(actor, obs: np.ndarray) -> np.ndarray:
    """rsl-rl's own forward (``stochastic_output=False``: the Gaussian's mean), numpy float32."""
    from tensordict import TensorDict

    with torch.inference_mode():
        td = TensorDict({"policy": torch.as_tensor(obs)}, batch_size=[len(obs)])
        return actor(td).numpy()


def test_exported_actor_with_prior_is_prior_plus_actor(track_setup, tmp_path):
    """The file's action = numpy ``prior.apply(obs)`` + the actor's deterministic output, on 6 observations
    (references inside and beyond the action box: the latter clip at 0.99). The prior is checked against
    its definition by hand: (q_ref[lead - 1] - default) / scale where inside the box.

    Tolerance 1e-5: both sides are float32; the MLP part differs only in summation order (onnxruntime vs
    torch) over dots of 292, 32 and 32 terms of magnitude <= ~3 (normalised inputs times weights of
    ~1/sqrt(292)): a few 1e-7 each, and the prior's Gather/Mul/Add/Clip is the same float32 arithmetic on
    both sides (<= 1 ulp, 6e-8 at |a| < 1); 1e-5 is the export gate's own bound at one sigma."""
    layout, prior, default, scale, meta = track_setup
    actor = _actor(layout.size, 0)
    rng = np.random.default_rng(5)
    boxes = [0.5, 0.5, 0.9, 0.9, 2.0, 2.0]  # |action| of the reference up to 0.5, 0.9 and 2 (clipped)
    q_refs = [default + scale * rng.uniform(-b, b, (K, N)) for b in boxes]
    obs = np.stack([_track_obs(layout, q, rng) for q in q_refs])
    by_hand = np.clip(np.stack([(q[4] - default) / scale for q in q_refs]), -0.99, 0.99)
    np.testing.assert_allclose(prior.apply(obs), by_hand, atol=1e-6)
    summary = export_policy(
        mlp_policy_from_rsl_rl(actor, prior), meta, tmp_path / "p.onnx", torch_policy_reference(actor, prior)
    )
    assert summary["max_abs_error"] <= 1e-5  # the gate compared the file with torch + the prior
    data = (tmp_path / "p.onnx").read_bytes()
    got = _run_onnx(data, obs)
    want = by_hand.astype(np.float32) + _deterministic(actor, obs)
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.max(np.abs(got - _deterministic(actor, obs))) > 0.1  # the prior is in the graph


def test_parity_gate_covers_the_prior(track_setup, tmp_path):
    """A file without the prior fails the gate against the reference with it, and vice versa."""
    from bar_policy.export.parity import ParityError

    layout, prior, _, _, meta = track_setup
    actor = _actor(layout.size, 1)
    with pytest.raises(ParityError):
        export_policy(
            mlp_policy_from_rsl_rl(actor), meta, tmp_path / "a.onnx", torch_policy_reference(actor, prior)
        )
    with pytest.raises(ParityError):
        export_policy(
            mlp_policy_from_rsl_rl(actor, prior), meta, tmp_path / "b.onnx", torch_policy_reference(actor)
        )
    assert not any(tmp_path.iterdir())


def test_start_at_prior_makes_the_first_mean_the_prior(track_setup):
    """The last layer at 0.01 x torch's init with a zero bias: the mean is a sum of 32 elu features (|.| of
    order 1) times weights <= 0.01 / sqrt(32): |mean| <= 32 * 1.8e-3 * O(1), a few 1e-3 in practice; the
    bound checked is 0.02."""
    layout, _, default, scale, _ = track_setup
    actor = _actor(layout.size, 2)
    rng = np.random.default_rng(6)
    obs = np.stack(
        [_track_obs(layout, default + scale * rng.uniform(-0.5, 0.5, (K, N)), rng) for _ in range(8)]
    )
    assert np.max(np.abs(_deterministic(actor, obs))) > 0.05
    start_actor_at_prior(actor)
    assert np.max(np.abs(_deterministic(actor, obs))) < 0.02


def test_actor_warmup_stays_refused_on_rsl_rl(toy_env, tmp_path):
    """network.action_prior is accepted now; ppo.actor_warmup_iterations is still a brax-only option."""
    from bar_policy.training.evaluations import Evaluations
    from bar_policy.training.rsl_rl.entry import run_rsl_rl

    cfg = toy_config(tmp_path, "warm", [*TOY_RSL, "ppo.actor_warmup_iterations=2"])
    with pytest.raises(
        ValueError, match=r"actor_warmup_iterations=2 is a brax-backend option.*valid here: 0"
    ):
        run_rsl_rl(toy_env, cfg, evaluations=Evaluations(0, None, 0.9), randomizer=None)


# ----------------------------------------------------------------------------------------------------------
# A tiny tracker run with the reference prior
# ----------------------------------------------------------------------------------------------------------

TINY_TRACK_RSL = [
    "backend=rsl-rl",
    "env_name=LiteTrack",
    "network.action_prior=reference",
    "network.policy_hidden=(16,)",
    "network.value_hidden=(16,)",
    "network.activation=elu",
    "ppo.num_envs=8",
    "ppo.batch_size=4",
    "ppo.num_minibatches=2",
    "ppo.unroll_length=4",
    "ppo.num_updates_per_batch=1",
    "ppo.num_timesteps=64",
    "eval.num_evals=2",
    "eval.num_eval_envs=8",
    "final_eval_envs=8",
    "seed=0",
]
"""Two iterations of 32 env steps (8 envs x 4 steps) on a 20-step LiteTrack, 16-unit networks."""


@pytest.mark.slow
def test_tiny_track_run_trains_and_exports_the_reference_prior(tmp_path):
    """The run's file is its actor plus the reference prior; with the actor's last layer zeroed (a zero
    residual) the exported action is the reference pose 5 frames ahead, (q_ref[4] - default) / scale, by
    hand (1e-6: float32 Gather/Mul/Add/Clip, |a| < 1)."""
    from bar_policy import envs
    from bar_policy.motion import Clip, gesture
    from bar_policy.robot.constants import load_robot
    from bar_policy.training.run import run

    piano = load_robot("arms").pose("piano_ready")
    clips = (Clip.make("tiny", 50.0, piano + 0.01 * np.arange(3)[:, None]), gesture("hanging_to_piano_ready"))
    env_cfg = dataclasses.replace(envs.nominal_config(envs.default_config("LiteTrack")), episode_length_s=0.4)
    env = envs.LiteTrack(env_cfg, clips=clips)
    summary = run(toy_config(tmp_path, "track-rsl", TINY_TRACK_RSL), env=env)
    result = summary.result
    assert summary.env_steps == 64 and result.prior is not None and result.eval_env.prior is result.prior
    assert result.eval_env.task is not env  # evaluated on the held-out clips (evaluation_env), as brax
    assert summary.export["max_abs_error"] <= 1e-5  # the gate: torch actor + numpy prior vs the file

    layout = env.obs_manager
    default = np.asarray(track_default_pose(), np.float64)
    scale = np.asarray(track_action_scale("arms"), np.float64)
    rng = np.random.default_rng(7)
    q_refs = [default + scale * rng.uniform(-0.8, 0.8, (K, N)) for _ in range(4)]
    obs = np.stack([_track_obs(layout, q, rng) for q in q_refs])
    by_hand = np.stack([(q[4] - default) / scale for q in q_refs]).astype(np.float32)
    # The run's file: the trained actor's deterministic output plus the reference prior (1e-5, as above).
    got = _run_onnx(summary.onnx_path.read_bytes(), obs)
    np.testing.assert_allclose(got, by_hand + _deterministic(result.actor.cpu(), obs), atol=1e-5)
    # A zero residual: the actor's last layer zeroed, exported with the run's own metadata.
    state = {k: v.clone() for k, v in result.actor.state_dict().items()}
    last = max(k for k in state if k.startswith("mlp.") and k.endswith(".weight"))
    state[last].zero_()
    state[last.replace("weight", "bias")].zero_()
    props = {p.key: p.value for p in onnx.load(str(summary.onnx_path)).metadata_props}
    zero = result.at(state)
    zero.export_onnx(PolicyMetadata.from_props(props), tmp_path / "zero.onnx")
    np.testing.assert_allclose(_run_onnx((tmp_path / "zero.onnx").read_bytes(), obs), by_hand, atol=1e-6)
