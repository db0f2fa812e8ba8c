"""``training.brax.ppo_loss``: brax's PPO loss in fewer kernels gives brax's numbers (values and gradients);
the targets fixed per pass or per iteration (``PPOConfig.value_targets``) are brax's at the parameters they
were taken at, and stay fixed after; the normaliser's variance floor (``PPOConfig.obs_std_eps``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from kl_reference import approx_kl

from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.ppo_loss import gae, ppo_loss, with_value_targets
from bar_policy.training.config import NetworkConfig, PPOConfig
from bar_policy.training.parallel import AXIS

T, B, N_OBS, N_ACT = 10, 64, 7, 3
# float32 throughout. The GAE recursion adds at most T = 10 terms of size O(1) with factors <= 1, in the
# same order as brax's scan, so the two differ by a few ulps of O(10) values: 1e-5 absolute bounds it
# with margin. The loss terms are means over T * B = 640 summands of size O(1) (advantages normalised to
# unit std, ratios near 1, unit-scale rewards), computed by networks that may pick other GEMM blockings for
# T + 1 rows than for T; a mean can cancel to far below its summands (the policy term here is ~2e-4), so
# its error is bounded in absolute terms, eps(float32) * 640 = 8e-5 at the very worst and ~sqrt(640) eps
# = 3e-6 typically: 1e-5 absolute, 1e-5 relative.
TOL = 1e-5


def _flags(key: jax.Array, p: float) -> jax.Array:
    return jax.random.bernoulli(key, p, (T, B)).astype(jnp.float32)


def test_gae_matches_brax_with_truncations_and_terminations():
    ks = jax.random.split(jax.random.PRNGKey(1), 5)
    trunc, term = _flags(ks[0], 0.1), _flags(ks[1], 0.1)
    term = term * (1 - trunc)  # as the loss builds it: a truncated step is not a termination
    rewards, values = jax.random.normal(ks[2], (T, B)), jax.random.normal(ks[3], (T, B))
    boot = jax.random.normal(ks[4], (B,))
    kw = dict(lambda_=0.95, discount=0.97)
    want = ppo_losses.compute_gae(trunc, term, rewards, values, boot, **kw)
    got = gae(trunc, term, rewards, values, boot, **kw)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=TOL, rtol=0)
    # By hand, one env of three steps, no flags: acc_2 = d_2, acc_1 = d_1 + 0.97 * 0.95 * acc_2, ...
    r, v, b = jnp.array([1.0, 0.0, 2.0]), jnp.array([0.5, 1.0, -1.0]), 3.0
    d = r + 0.97 * jnp.array([1.0, -1.0, b]) - v
    acc2 = d[2]
    acc1 = d[1] + 0.97 * 0.95 * acc2
    acc0 = d[0] + 0.97 * 0.95 * acc1
    zeros = jnp.zeros((3, 1))
    vs, _ = gae(zeros, zeros, r[:, None], v[:, None], jnp.array([b]), **kw)
    np.testing.assert_allclose(vs[:, 0], jnp.array([acc0, acc1, acc2]) + v, rtol=1e-6)


@pytest.fixture(scope="module")
def case():
    learner = make_learner(
        N_OBS, N_ACT, PPOConfig(), NetworkConfig(policy_hidden=(16, 16), value_hidden=(32,))
    )
    nets = learner.networks
    ks = jax.random.split(jax.random.PRNGKey(0), 9)
    params = ppo_losses.PPONetworkParams(
        policy=nets.policy_network.init(ks[0]), value=nets.value_network.init(ks[1])
    )
    norm = running_statistics.init_state(specs.Array((N_OBS,), jnp.float32))
    norm = running_statistics.update(norm, jax.random.normal(ks[2], (256, N_OBS)) * 2.0 + 0.5)
    obs = jax.random.normal(ks[3], (B, T, N_OBS))
    next_obs = jnp.concatenate([obs[:, 1:], jax.random.normal(ks[4], (B, 1, N_OBS))], axis=1)
    dist = nets.parametric_action_distribution
    # The behaviour policy: the parameters before a small step, so the ratio is not 1 everywhere.
    behaviour = jax.tree.map(lambda p: p * 0.9, params.policy)
    logits = nets.policy_network.apply(norm, behaviour, obs)
    raw = dist.sample_no_postprocessing(logits, ks[5])
    trunc = _flags(ks[6], 0.1).T
    data = types.Transition(
        observation=obs,
        action=dist.postprocess(raw),
        reward=jax.random.normal(ks[7], (B, T)),
        discount=1.0 - _flags(ks[8], 0.05).T * (1 - trunc),
        next_observation=next_obs,
        extras={
            "state_extras": {"truncation": trunc},
            "policy_extras": {
                "raw_action": raw,
                "log_prob": dist.log_prob(logits, raw),
                "distribution_params": logits,
            },
        },
    )
    return learner, params, norm, data


KW = dict(
    entropy_cost=5e-3,
    discounting=0.97,
    reward_scaling=1.0,
    gae_lambda=0.95,
    clipping_epsilon=0.2,
    normalize_advantage=True,
    vf_coefficient=0.5,
)


def test_loss_gradients_and_metrics_match_brax(case):
    learner, params, norm, data = case
    rng = jax.random.PRNGKey(3)
    brax_fn = jax.value_and_grad(ppo_losses.compute_ppo_loss, has_aux=True)
    ours_fn = jax.value_and_grad(ppo_loss, has_aux=True)
    (want, want_m), want_g = brax_fn(params, norm, data, rng, learner.networks, **KW)
    (got, got_m), got_g = ours_fn(params, norm, data, rng, learner.networks, **KW)
    np.testing.assert_allclose(got, want, atol=TOL, rtol=TOL)
    for k in ("total_loss", "policy_loss", "v_loss", "entropy_loss", "policy_dist_mean_std"):
        np.testing.assert_allclose(got_m[k], want_m[k], atol=TOL, rtol=TOL, err_msg=k)
    # Every gradient leaf, relative to the leaf's largest entry (entries near 0 carry only rounding).
    for g, w in zip(jax.tree.leaves(got_g), jax.tree.leaves(want_g), strict=True):
        np.testing.assert_allclose(g, w, atol=TOL * float(jnp.max(jnp.abs(w))), rtol=TOL)
    # Not trivially equal: the critic is untrained, and both networks' gradients are far from zero.
    assert float(want_m["v_loss"]) > 1e-2
    assert min(float(jnp.max(jnp.abs(w))) for w in jax.tree.leaves(want_g)) > 1e-3
    # The KL metric is the learner's estimate of the same parameters on the same minibatch.
    np.testing.assert_allclose(got_m["kl"], approx_kl(learner, params, norm, data), rtol=1e-5)
    assert float(got_m["kl"]) > 1e-4


def test_fixed_targets_are_brax_targets_at_their_parameters(case):
    """Targets taken at ``params`` and fed back in: brax's loss and gradients at ``params`` (the critic
    computes the same GAE; brax stops its gradient), to the tolerance of the first test."""
    learner, params, norm, data = case
    rng = jax.random.PRNGKey(3)
    (want, want_m), want_g = jax.value_and_grad(ppo_losses.compute_ppo_loss, has_aux=True)(
        params, norm, data, rng, learner.networks, **KW
    )
    fixed = with_value_targets(params, norm, data, learner.networks, 0.97, 1.0, 0.95)
    ours_fn = jax.value_and_grad(ppo_loss, has_aux=True)
    (got, got_m), got_g = ours_fn(params, norm, fixed, rng, learner.networks, **KW)
    np.testing.assert_allclose(got, want, atol=TOL, rtol=TOL)
    for k in ("policy_loss", "v_loss", "entropy_loss"):
        np.testing.assert_allclose(got_m[k], want_m[k], atol=TOL, rtol=TOL, err_msg=k)
    for g, w in zip(jax.tree.leaves(got_g), jax.tree.leaves(want_g), strict=True):
        np.testing.assert_allclose(g, w, atol=TOL * float(jnp.max(jnp.abs(w))), rtol=TOL)


def test_fixed_targets_do_not_follow_the_critic(case):
    """At another critic the value loss regresses on the stored targets: 0.5 * vf * mean((vs - V)^2) with
    ``vs`` from the first critic and ``V`` the new critic's values, by hand in numpy (float64)."""
    learner, params, norm, data = case
    fixed = with_value_targets(params, norm, data, learner.networks, 0.97, 1.0, 0.95)
    moved = params.replace(value=jax.tree.map(lambda p: p * 1.5, params.value))
    _, m = ppo_loss(moved, norm, fixed, jax.random.PRNGKey(3), learner.networks, **KW)
    vs = np.asarray(fixed.extras["value_targets"]["vs"], np.float64)  # [B, T]
    v_new = np.asarray(learner.networks.value_network.apply(norm, moved.value, data.observation), np.float64)
    want = 0.5 * 0.5 * np.mean((vs - v_new) ** 2)
    np.testing.assert_allclose(float(m["v_loss"]), want, rtol=1e-5)
    # brax's loss at the moved critic recomputes the targets with it: a different value loss.
    _, brax_m = ppo_losses.compute_ppo_loss(moved, norm, data, jax.random.PRNGKey(3), learner.networks, **KW)
    assert abs(float(brax_m["v_loss"]) - want) > 1e-2 * want


def _update(case, **ppo):
    data = case[3]
    cfg = PPOConfig(num_envs=64, batch_size=32, num_minibatches=2, **ppo)
    learner = make_learner(N_OBS, N_ACT, cfg, NetworkConfig(policy_hidden=(16, 16), value_hidden=(32,)))
    ts = learner.init(jax.random.PRNGKey(5))
    update = jax.jit(jax.vmap(lambda t, d, k: learner.update(t, d, k)[0], axis_name=AXIS))
    out = update(*jax.tree.map(lambda x: jnp.asarray(x)[None], (ts, data, jax.random.PRNGKey(7))))
    return jax.tree.leaves(out.params)


def test_target_modes_agree_where_their_critics_do(case):
    """One pass: ``pass`` takes its targets from the critic ``iteration`` does (bit for bit). Two passes:
    the second pass of ``pass`` takes them from the critic after the first pass, so the two differ."""
    one_pass = _update(case, value_targets="pass", num_updates_per_batch=1)
    one_iter = _update(case, value_targets="iteration", num_updates_per_batch=1)
    for a, b in zip(one_pass, one_iter, strict=True):
        np.testing.assert_array_equal(a, b)
    two_pass = _update(case, value_targets="pass", num_updates_per_batch=2)
    two_iter = _update(case, value_targets="iteration", num_updates_per_batch=2)
    assert max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(two_pass, two_iter, strict=True)) > 1e-6


def test_normaliser_std_floor():
    """A constant observation has variance 0: its std is sqrt(obs_std_eps) = 0.01, or brax's floor 1e-6."""
    batch = jnp.full((128, N_OBS), 0.25, jnp.float32)
    for eps, want in ((1e-4, 0.01), (0.0, 1e-6)):
        learner = make_learner(N_OBS, N_ACT, PPOConfig(obs_std_eps=eps), NetworkConfig())
        norm = learner.init(jax.random.PRNGKey(0)).normalizer_params
        np.testing.assert_allclose(running_statistics.update(norm, batch).std, want, rtol=1e-6)
    with pytest.raises(ValueError, match="obs_std_eps"):
        PPOConfig(obs_std_eps=-1.0)
