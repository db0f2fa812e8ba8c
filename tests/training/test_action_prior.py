"""The action prior: its map from a tracking observation, the brax network around it, and the ONNX graph;
the blend prior (weighted means of poses) by hand and through its ONNX graph.

Expected values are worked out from the layout by hand: the reference prior at lead L reads frame L of
``motion_joint_pos`` and gives ``(q_ref - default) / scale``, the action whose command is that pose.
"""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import networks as ppo_networks

from bar_policy.export.graph import MlpPolicy, build_onnx_model
from bar_policy.export.parity import _run_onnx
from bar_policy.export.policy import export_brax_policy, mlp_policy_from_brax
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import PRIOR_BOUND, ActionPrior, BlendPrior, reference_prior
from bar_policy.tasks.track import track_action_scale, track_default_pose
from bar_policy.training.brax.networks import PRIOR_INIT_SCALE, make_networks
from bar_policy.training.config import NetworkConfig

N = 14
K = 5  # the tracking layout's lookahead frames


@pytest.fixture(scope="module")
def layout():
    return ObservationManager.for_task("track", "arms")


@pytest.fixture(scope="module")
def pose_scale():
    return np.asarray(track_default_pose(), np.float64), np.asarray(track_action_scale("arms"), np.float64)


def _obs(layout, q_ref: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A tracking observation whose reference frames are ``q_ref`` (K, N); every other term random."""
    inputs = {}
    for t in layout.schema.terms:
        inputs[t.name] = rng.uniform(-0.5, 0.5, t.size).astype(np.float32)
    inputs["motion_joint_pos"] = q_ref.reshape(-1).astype(np.float32)
    return np.asarray(layout.compute(inputs), np.float32)


def test_reference_prior_commands_the_reference_frame(layout, pose_scale):
    """prior(obs) = (q_ref[L - 1] - default) / scale for each lead L, by hand; float32: |a| <= 1, a few
    ulps (6e-8 each) through one multiply-add, so 1e-6."""
    default, scale = pose_scale
    rng = np.random.default_rng(0)
    q_ref = default + scale * rng.uniform(-0.9, 0.9, (K, N))  # poses whose action is inside (-0.9, 0.9)
    obs = _obs(layout, q_ref, rng)
    for lead in range(1, K + 1):
        prior = reference_prior(layout, default, scale, lead)
        want = (q_ref[lead - 1] - default) / scale
        np.testing.assert_allclose(prior.apply(obs), want, atol=1e-6, err_msg=f"lead {lead}")
        np.testing.assert_allclose(np.tanh(prior.pre_tanh(obs)), want, atol=1e-6)


def test_prior_clips_at_its_bound(layout, pose_scale):
    """A reference beyond the action box gives +-bound, never atanh(+-1) = inf."""
    default, scale = pose_scale
    q_ref = np.tile(default + 3.0 * scale, (K, 1))  # action 3 everywhere
    prior = reference_prior(layout, default, scale, 2)
    obs = _obs(layout, q_ref, np.random.default_rng(1))
    np.testing.assert_array_equal(prior.apply(obs), np.float32(PRIOR_BOUND))
    assert np.all(np.isfinite(prior.pre_tanh(obs)))


def test_prior_refuses_what_it_cannot_map(layout, pose_scale):
    default, scale = pose_scale
    with pytest.raises(ValueError, match=r"lead_steps must be in 1\.\.5"):
        reference_prior(layout, default, scale, 6)
    with pytest.raises(ValueError, match="no motion_joint_pos"):
        reference_prior(ObservationManager.for_task("reach", "arms"), default, scale, 1)
    with pytest.raises(ValueError, match=r"bound must be in \(0, 1\)"):
        ActionPrior(index=(0,), gain=(1.0,), offset=(0.0,), bound=1.0)
    with pytest.raises(ValueError, match="one entry per action"):
        ActionPrior(index=(0, 1), gain=(1.0,), offset=(0.0, 0.0))
    with pytest.raises(ValueError, match="reads observation entry 300"):
        ActionPrior(index=(300,), gain=(1.0,), offset=(0.0,)).check_observation_size(292)


@pytest.fixture(scope="module")
def toy_track_metadata():
    """The deploy tests' tracking metadata (292-entry layout, 14 actions)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "deploy"))
    from policy_factory import default_metadata

    return default_metadata("arms", task="track")


@pytest.fixture(scope="module")
def prior_net(layout, pose_scale):
    """Brax networks with the reference prior on the tracking layout, and params with a real normaliser."""
    default, scale = pose_scale
    prior = reference_prior(layout, default, scale, 5)
    net_cfg = NetworkConfig(policy_hidden=(32, 32), value_hidden=(16,), action_prior="reference")
    net = make_networks(layout.size, N, net_cfg, True, prior)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(7), 3)
    norm = running_statistics.init_state(specs.Array((layout.size,), jnp.float32))
    norm = running_statistics.update(norm, 0.3 * jax.random.normal(k3, (2048, layout.size)))
    params = (norm, net.policy_network.init(k1), net.value_network.init(k2))
    return net, params, prior


def test_network_adds_the_prior_to_the_mlp_mean(prior_net, layout, pose_scale):
    """Deterministic action = tanh(mlp_loc(normalised obs) + atanh(prior(raw obs))), the mlp computed
    without the prior by brax's own network on the same params (float32, 1e-5: the same XLA ops but for
    one add and an atanh/tanh round trip on |a| < 0.99)."""
    net, params, prior = prior_net
    default, scale = pose_scale
    rng = np.random.default_rng(2)
    obs = np.stack([_obs(layout, default + scale * rng.uniform(-0.8, 0.8, (K, N)), rng) for _ in range(4)])
    plain = make_networks(layout.size, N, NetworkConfig(policy_hidden=(32, 32), value_hidden=(16,)), True)
    loc = np.asarray(plain.policy_network.apply(params[0], params[1], obs))[:, :N]
    want = np.tanh(loc + np.arctanh(prior.apply(obs)))
    got, _ = ppo_networks.make_inference_fn(net)(params, deterministic=True)(obs, jax.random.PRNGKey(0))
    np.testing.assert_allclose(np.asarray(got), want, atol=1e-5)


def test_initial_policy_starts_at_the_prior(prior_net, layout, pose_scale):
    """The loc half of the output layer starts at PRIOR_INIT_SCALE x brax's init with a zero bias, so the
    first deterministic action is within a few 1e-3 of the prior; with that half zeroed, it is the prior."""
    net, params, prior = prior_net
    default, scale = pose_scale
    rng = np.random.default_rng(3)
    obs = np.stack([_obs(layout, default + scale * rng.uniform(-0.8, 0.8, (K, N)), rng) for _ in range(8)])
    act = np.asarray(ppo_networks.make_inference_fn(net)(params, deterministic=True)(obs, None)[0])
    layers = params[1]["params"]
    last = layers["hidden_2"]
    np.testing.assert_array_equal(np.asarray(last["bias"])[:N], 0.0)
    # The loc output is a sum of 32 hidden units x kernel entries of lecun scale x 0.01: a few 1e-3 at most
    # for unit-scale swish features; tanh's slope is <= 1, so the action moves no more than that.
    assert np.max(np.abs(act - prior.apply(obs))) < 10 * PRIOR_INIT_SCALE
    zeroed = {**layers, "hidden_2": {**last, "kernel": np.asarray(last["kernel"]).copy()}}
    zeroed["hidden_2"]["kernel"][:, :N] = 0.0
    p0 = (params[0], {"params": zeroed}, params[2])
    act0 = np.asarray(ppo_networks.make_inference_fn(net)(p0, deterministic=True)(obs, None)[0])
    np.testing.assert_allclose(act0, prior.apply(obs), atol=1e-6)  # tanh(atanh(a)) in float32


def test_onnx_graph_carries_the_prior(prior_net, layout, tmp_path, toy_track_metadata):
    """The exported file reproduces brax's policy with the prior (the parity gate passes), and its graph
    is still obs -> actions: the prior's Gather/Clip/Atanh sit inside it."""
    net, params, prior = prior_net
    info = export_brax_policy(
        params,
        ppo_networks.make_inference_fn(net),
        toy_track_metadata,
        tmp_path / "p.onnx",
        activation="swish",
        num_parity_obs=512,
        prior=prior,
    )
    assert info["max_abs_error"] <= 1e-5
    pol = mlp_policy_from_brax(params, N, "swish", prior)
    ops = [n.op_type for n in build_onnx_model(pol).graph.node]
    assert {"Gather", "Clip", "Atanh"} <= set(ops) and ops[-1] == "Tanh"
    # Without the prior the same weights give another policy: the gate would have caught a lost prior.
    no_prior = mlp_policy_from_brax(params, N, "swish")
    obs = _obs(layout, np.zeros((K, N)), np.random.default_rng(4))[None]
    diff = _run_onnx(build_onnx_model(pol).SerializeToString(), obs) - _run_onnx(
        build_onnx_model(no_prior).SerializeToString(), obs
    )
    assert np.max(np.abs(diff)) > 0.05


def test_reach_has_no_prior_and_rsl_rl_refuses_one():
    """rsl-rl takes the env's prior as brax does: reach serves none, so the message names ``none``."""
    from bar_policy import envs

    reach = envs.load("LiteReach", config=envs.nominal_config())
    with pytest.raises(ValueError, match=r"no action prior.*valid network.action_prior values for it: none"):
        reach.action_prior(5)
    from bar_policy.training.config import TrainConfig
    from bar_policy.training.evaluations import Evaluations
    from bar_policy.training.rsl_rl.entry import run_rsl_rl

    cfg = TrainConfig(env_name="LiteReach", network=NetworkConfig(action_prior="reference"))
    with pytest.raises(ValueError, match=r"LiteReach has no action prior; valid values for it: \['none'\]"):
        run_rsl_rl(reach, cfg, evaluations=Evaluations(0, None, 0.9), randomizer=None)


def test_prior_noise_std_sets_the_initial_std(layout, pose_scale):
    """With prior_noise_std, brax's tanh-normal std (softplus(raw) + 0.001) starts at that value for every
    action: the kernel is 0.01 x brax's (lecun-uniform entries <= sqrt(3 / 32) = 0.31 on 32 swish features
    of order 0.1-1), so the raw output moves by a few 1e-3 at most and softplus (slope < 1) passes less:
    5e-3. Without it, brax's softplus of a random output, about 0.69."""
    default, scale = pose_scale
    prior = reference_prior(layout, default, scale, 5)
    obs = np.stack([_obs(layout, default + 0 * np.ones((K, N)), np.random.default_rng(i)) for i in range(4)])
    for std in (0.1, 0.3):
        cfg = NetworkConfig(
            policy_hidden=(32,), value_hidden=(8,), action_prior="reference", prior_noise_std=std
        )
        net = make_networks(layout.size, N, cfg, False, prior)
        out = np.asarray(net.policy_network.apply(None, net.policy_network.init(jax.random.PRNGKey(0)), obs))
        np.testing.assert_allclose(np.log1p(np.exp(out[:, N:])) + 0.001, std, atol=5e-3)
    with pytest.raises(ValueError, match=r"prior_noise_std must be > 0.001"):
        NetworkConfig(prior_noise_std=0.0)


def test_env_serves_only_its_own_prior():
    """network.action_prior must name the prior the env serves: the message names the valid values."""
    from bar_policy import envs
    from bar_policy.training.prior import action_prior

    reach = envs.load("LiteReach", config=envs.nominal_config())
    with pytest.raises(ValueError, match=r"LiteReach has no action prior; valid values for it: \['none'\]"):
        action_prior(reach, NetworkConfig(action_prior="reference"), "LiteReach")
    assert action_prior(reach, NetworkConfig(), "LiteReach") is None


def test_action_prior_choices_come_from_the_task_records():
    """The valid ``network.action_prior`` values are ``none`` plus what the records' env entries serve, in
    registry order; so no task name is written in training/config.py.

    By hand for reach (serves none) and track (``reference``); another task pins its env's prior in its own
    tests.
    """
    from bar_policy.task_records import EnvEntry
    from bar_policy.tasks.registry import env_entries
    from bar_policy.training.config import ACTION_PRIORS

    served = {name: entry.action_prior for name, (_, entry) in env_entries().items()}
    assert {k: served[k] for k in ("LiteReach", "LiteReachNeck", "LiteTrack")} == {
        "LiteReach": "",
        "LiteReachNeck": "",
        "LiteTrack": "reference",
    }
    assert ("none", *dict.fromkeys(p for p in served.values() if p)) == ACTION_PRIORS
    assert ACTION_PRIORS[:2] == ("none", "reference")
    valid = re.escape(str(list(ACTION_PRIORS)))
    with pytest.raises(ValueError, match=rf"unknown action_prior 'bogus'; valid: {valid}"):
        NetworkConfig(action_prior="bogus")
    with pytest.raises(ValueError, match=r"env 'X': action_prior must be an identifier other than 'none'"):
        EnvEntry(name="X", env="m:A", config="m:f", action_prior="none")


# ---------------------------------------------------------------------------------------------------
# The blend prior (obs.action_prior.BlendPrior): weighted means of poses that observation entries select
# ---------------------------------------------------------------------------------------------------
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
