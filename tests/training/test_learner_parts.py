"""The learner's parts (``brax.learner``): the rollout's layout, and the rollout and update as one loop.

``one_loop.overlapped`` runs a rollout and the update of other data in one loop, each of the rollout's first
control steps beside one SGD pass; ``one_loop.streamed`` puts each pass on a GPU stream of its own, its Adam
steps written out (``bench/stream_overlap.py`` asks whether a GPU then runs them side by side). Their
results must be those of ``rollout`` and ``update`` called apart, from the same state and keys, whether the
rollout has more control steps than the update has passes or fewer (``streamed`` refuses fewer).

``ppo.update_precision`` sets the precision of the update's matrix products and of no other.
"""

from __future__ import annotations

import jax
import jax.extend.core as jex
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from toy_configs import TOY_BRAX, toy_config

from bar_policy import envs
from bar_policy.training import one_loop
from bar_policy.training.brax.learner import make_learner, segments
from bar_policy.training.brax.programs import host_key, make_programs, slot_env
from bar_policy.training.parallel import AXIS, DataParallel


def test_segments_put_each_env_s_steps_in_one_row():
    """(unrolls, T, envs) -> (unrolls * envs, T): row u * envs + e holds unroll u of env e, in step order."""
    unrolls, steps, n = 2, 3, 4
    x = np.arange(unrolls * steps * n).reshape(unrolls, steps, n)  # value = (u * T + t) * envs + e
    out = np.asarray(segments({"x": jnp.asarray(x)})["x"])
    assert out.shape == (unrolls * n, steps)
    for u in range(unrolls):
        for e in range(n):
            assert out[u * n + e].tolist() == [(u * steps + t) * n + e for t in range(steps)]


# (name, extra overrides): the toy config's 8 unrolls of 10 steps against 2 passes (steps > passes), and one
# unroll of 2 steps against 4 passes (passes > steps).
CASES = [
    ("steps_first", []),
    ("passes_first", ["ppo.unroll_length=2", "ppo.num_minibatches=1", "ppo.num_updates_per_batch=4"]),
]


@pytest.mark.numerics
@pytest.mark.parametrize("form", ["overlapped", "streamed"])
@pytest.mark.parametrize("name,extra", CASES, ids=[c[0] for c in CASES])
def test_one_loop_equals_the_rollout_and_the_update(tmp_path, toy_env, name, extra, form):
    cfg = toy_config(tmp_path, f"{name}_{form}", [*TOY_BRAX, *extra])
    ppo = cfg.ppo
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs
    passes = ppo.num_updates_per_batch
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(toy_env.observation_size, toy_env.action_size, ppo, cfg.network)
    progs = make_programs(toy_env, cfg, learner, dp, envs.wrap_for_brax_training, None)

    def batch(keys):
        return slot_env(toy_env, envs.wrap_for_brax_training, None, keys)

    def apart(ts, carry, key, data, sgd_key):
        state, new_data, stats = learner.rollout(ts, carry[0], key, batch(carry[1]), unrolls)
        new_ts, metrics = learner.update(ts, data, sgd_key)
        # Each loss metric's per-minibatch values' sum of magnitudes (the update's passes again).
        normalizer, prepared = learner.prepare_update(ts, data)
        init = (ts.optimizer_state, ts.params, sgd_key)
        _, raw = jax.lax.scan(
            lambda c, _: learner.sgd_pass(c, prepared, normalizer), init, None, length=passes
        )
        magnitude = jax.tree.map(lambda x: jnp.abs(x).sum(), raw)
        return new_ts, state.obs, new_data, jax.lax.psum(stats, AXIS), (metrics, magnitude)

    def together(ts, carry, key, data, sgd_key):
        new_ts, state, new_data, stats, metrics = getattr(one_loop, form)(
            learner, ts, carry[0], key, batch(carry[1]), unrolls, data, sgd_key
        )
        return new_ts, state.obs, new_data, jax.lax.psum(stats, AXIS), (metrics, metrics)

    rep, shard = P(), P(AXIS)
    specs = ((rep, shard, rep, shard, rep), (rep, shard, shard, rep, rep))
    ts = progs.init(dp.replicate(host_key(0, 1)))
    carry = progs.reset(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
    k_roll, k_sgd, k_data = (dp.replicate(host_key(0, i)) for i in (4, 5, 6))
    # The update's data: a rollout from the same start with another key (as a trainer's previous one).
    first = dp.map(
        lambda t, c, k: learner.rollout(t, c[0], k, batch(c[1]), unrolls)[1], (rep, shard, rep), shard
    )
    data = first(ts, carry, k_data)
    if form == "streamed" and unrolls * ppo.unroll_length < passes:
        with pytest.raises(ValueError, match=r"2 control steps per iteration, fewer than the 4 SGD passes"):
            dp.map(together, *specs)(ts, carry, k_roll, data, k_sgd)
        return
    want = dp.to_host(dp.map(apart, *specs)(ts, carry, k_roll, data, k_sgd))
    got = dp.to_host(dp.map(together, *specs)(ts, carry, k_roll, data, k_sgd))
    assert jax.tree.structure(got) == jax.tree.structure(want)
    # Same keys, same arithmetic: the new params, Adam moments, normaliser, env state and data agree to
    # float32 rounding (bit for bit on this project's CPU). XLA fuses the one loop and the two calls apart
    # (and ``streamed`` writes the Adam steps out instead of a scan), so a sum may round in another order:
    # 1e-6 relative (a few float32 ulps, 2**-23 = 1.2e-7, over one update of at most 8 Adam steps and 80
    # control steps) plus 1e-6 absolute for values near 0, as tests/training/test_epoch_programs.py allows
    # the epoch's two programs against its one scan.
    for (path, a), b in zip(
        jax.tree_util.tree_leaves_with_path(got[:3]), jax.tree.leaves(want[:3]), strict=True
    ):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6, err_msg=jax.tree_util.keystr(path))
    eps = float(np.finfo(np.float32).eps)
    # The stats ([reward, success numerator, denominator] summed over the control steps) are the same
    # per-step sums added in another order: float32 rounding of a sum of n_steps terms, at most
    # n_steps * eps * (sum of the terms' magnitudes) <= n_steps * eps * sum |reward|.
    n_steps = unrolls * ppo.unroll_length
    bound = n_steps * eps * float(np.abs(np.asarray(want[2].reward, np.float64)).sum())
    np.testing.assert_allclose(got[3], want[3], rtol=0, atol=bound)
    # The loss metrics are means of the same per-minibatch values, summed in another order: a mean's
    # rounding differs by at most eps * (the values' sum of magnitudes + the mean's own magnitude).
    means, magnitude = want[4]
    for name, value in means.items():
        limit = eps * (float(magnitude[name]) + abs(float(value)))
        np.testing.assert_allclose(got[4][0][name], value, rtol=0, atol=limit, err_msg=name)


def _dot_precisions(jaxpr: jex.Jaxpr) -> list[str]:
    """Each ``dot_general``'s precision in ``jaxpr``, in program order (sub-jaxprs in place)."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            precision = eqn.params["precision"]  # (lhs, rhs) Precisions, or a DotAlgorithmPreset
            found.append(precision[0].name if isinstance(precision, tuple) else precision.name)
        for sub in jex.jaxprs_in_params(eqn.params):
            found += _dot_precisions(sub)
    return found


@pytest.mark.parametrize(
    "setting,printed",
    [
        ("run", "HIGHEST"),
        ("tensorfloat32", "HIGH"),
        ("BF16_BF16_F32_X3", "BF16_BF16_F32_X3"),
    ],
)
def test_update_precision_sets_the_sgd_passes_products_only(tmp_path, toy_env, setting, printed):
    """``ppo.update_precision`` reaches every product of the update (the pass's value targets, the loss and
    its gradient) and none of the policy's in the same program: a rollout keeps the run's full float32."""
    cfg = toy_config(tmp_path, setting, [*TOY_BRAX, f"ppo.update_precision={setting}"])
    ppo = cfg.ppo
    learner = make_learner(toy_env.observation_size, toy_env.action_size, ppo, cfg.network)
    ts = jax.jit(learner.init)(jax.random.PRNGKey(0))
    rows, obs, act = ppo.batch_size * ppo.num_minibatches, toy_env.observation_size, toy_env.action_size
    z = lambda *s: jnp.zeros((rows, ppo.unroll_length, *s))  # noqa: E731
    data = types.Transition(
        observation=z(obs),
        action=z(act),
        reward=z(),
        discount=z(),
        next_observation=z(obs),
        extras={
            "policy_extras": {"log_prob": z(), "raw_action": z(act)},
            "state_extras": {"truncation": z()},
        },
    )

    def both(ts, data, key):  # the policy before and after the update, as a trainer's programs run them
        policy = learner.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))
        first = policy(data.observation[:, 0], key)[0]
        new_ts, _ = learner.update(ts, data, key)
        return first, new_ts, policy(data.observation[:, 1], key)[0]

    key = jax.random.PRNGKey(1)
    with jax.default_matmul_precision("highest"):  # the run's (TrainConfig.matmul_precision = highest)
        found = _dot_precisions(jax.make_jaxpr(both, axis_env=[(AXIS, 1)])(ts, data, key).jaxpr)
    layers = len(cfg.network.policy_hidden) + 1  # one product per policy layer
    assert found[:layers] == found[-layers:] == ["HIGHEST"] * layers
    update = found[layers:-layers]
    # The pass's targets (critic forward) and the loss's forward and backward passes: at least one product
    # per layer of each network, each at the setting.
    assert len(update) >= layers + len(cfg.network.value_hidden) + 1
    assert update == [printed] * len(update)
