"""Reward weights as a program's argument (``envs.reward_weights``), against the config's own weights.

The brax programs take the weights as an argument so that a compiled rollout serves any weights. The
step must then compute what the env computes with the weights in its config. With a constant weight XLA
may fold it into a constant factor of the term (``mean(x) * w`` is ``sum(x) * (1/n)`` times ``w``: it
may multiply ``(1/n) * w`` first), so the two programs round a term's product in another order. Each
path is within two float32 roundings (2 x 2**-24 relative) of the exact product, hence the terms agree
within 4 x 2**-24 relative. The total adds the same terms in the same order, and each of its n - 1
sums may round either way too: within (4 + 2 (n - 1)) x 2**-24 of the sum of the terms' magnitudes.
Doubling every weight in the same program doubles each scaled term and their sum exactly: a binary
float times 2 is exact, and so is a sum of doubled values (no overflow at these magnitudes).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy import envs
from bar_policy.envs.reward_weights import weights, with_weights

U = 2.0**-24
"""Half a float32 ulp at 1 (the unit roundoff)."""


@pytest.fixture(scope="module")
def weighted_step(nominal_env):
    """``(state, action, weights) -> state``: the nominal env's step with the weights as an argument."""
    return jax.jit(lambda s, a, w: with_weights(nominal_env, w).step(s, a))


def _start(nominal_fns, nominal_env):
    reset, _ = nominal_fns
    state = reset(jax.random.PRNGKey(3))
    action = 0.4 * jnp.sin(jnp.arange(nominal_env.action_size, dtype=jnp.float32))
    return state, action


def test_weights_are_the_config_fields_in_order(nominal_env):
    scales = nominal_env.config.reward.scales
    w = weights(nominal_env)
    assert list(w) == [f.name for f in dataclasses.fields(scales)]
    assert all(w[k] == np.float32(getattr(scales, k)) and w[k].dtype == np.float32 for k in w)


def test_the_argument_step_equals_the_config_step_and_one_program_serves_any_weights(
    nominal_env, nominal_fns, weighted_step
):
    _, step = nominal_fns
    state, action = _start(nominal_fns, nominal_env)
    expected = step(state, action)
    w = weights(nominal_env)
    got = weighted_step(state, action, w)
    terms = np.array([float(expected.metrics[f"reward/{k}"]) for k in w])
    for k in w:  # module docstring: two roundings each way
        np.testing.assert_allclose(got.metrics[f"reward/{k}"], expected.metrics[f"reward/{k}"], rtol=4 * U)
    bound = (4 + 2 * (len(w) - 1)) * U * np.sum(np.abs(terms))
    assert abs(float(got.reward) - float(expected.reward)) <= bound
    np.testing.assert_array_equal(np.asarray(got.obs), np.asarray(expected.obs))

    doubled = weighted_step(state, action, {k: 2 * v for k, v in w.items()})
    assert np.asarray(doubled.reward) == 2 * np.asarray(got.reward)
    for k in w:
        term = f"reward/{k}"
        assert np.asarray(doubled.metrics[term]) == 2 * np.asarray(got.metrics[term]), k
    np.testing.assert_array_equal(np.asarray(doubled.obs), np.asarray(expected.obs))  # physics untouched
    assert weighted_step._cache_size() == 1  # both weights ran the one compiled program


def test_names_that_are_not_the_env_s_terms_are_refused(nominal_env):
    w = weights(nominal_env)
    with pytest.raises(ValueError, match=r"reward weights \[.*'bogus'.*\] do not match LiteReach's terms"):
        with_weights(nominal_env, {**w, "bogus": 1.0})
    with pytest.raises(ValueError, match="do not match"):
        with_weights(nominal_env, {k: v for k, v in list(w.items())[1:]})


def test_the_env_is_left_as_it_was(nominal_env):
    """``with_weights`` copies: the original keeps its config, the copy shares everything else."""
    w = {k: np.float32(0.5) for k in weights(nominal_env)}
    before = nominal_env.config
    copy = with_weights(nominal_env, w)
    assert nominal_env.config is before
    assert weights(copy) == w and copy.mj_model is nominal_env.mj_model
    assert dataclasses.replace(copy.config, reward=before.reward) == before  # only the weights differ


def test_an_env_without_weights_has_none():
    class NoReward:
        config = None

    env = NoReward()
    assert weights(env) == {}
    assert with_weights(env, {}) is env
    with pytest.raises(ValueError, match=r"\['x'\] do not match NoReward's terms \[\]"):
        with_weights(env, {"x": 1.0})


def test_the_track_env_s_weights_round_trip(track_env):
    w = weights(track_env)
    assert w and list(w) == [f.name for f in dataclasses.fields(track_env.config.reward.scales)]
    assert weights(with_weights(track_env, w)) == w
    assert isinstance(envs.default_config("LiteTrack").reward.scales, type(track_env.config.reward.scales))
