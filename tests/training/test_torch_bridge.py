"""The torch <-> jax bridge (DLPack): equal values on both sides, one shared buffer, counted copies.

On CPU here (jax's CPU client, torch ``cpu``); the same calls share a GPU buffer as a ``cuda`` tensor.
"""

from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch

from bar_policy.envs import wrap_for_brax_training
from bar_policy.training.rsl_rl.env import RslRlVecEnv
from bar_policy.training.rsl_rl.torch_bridge import COPIES, jax_to_torch, torch_device_for_jax, torch_to_jax

SHAPES = [(), (7,), (4, 14), (2, 3, 5)]
DTYPES = [(jnp.float32, torch.float32), (jnp.int32, torch.int32), (jnp.bool_, torch.bool)]


@pytest.fixture(autouse=True)
def _zero_copies():
    COPIES.reset()
    yield
    COPIES.reset()


def _sample(shape: tuple[int, ...], dtype: jnp.dtype) -> jax.Array:
    x = jax.random.normal(jax.random.PRNGKey(len(shape)), shape) * 10
    return x > 0 if dtype == jnp.bool_ else x.astype(dtype)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize(("jdt", "tdt"), DTYPES)
def test_jax_to_torch_shares_the_buffer(shape, jdt, tdt):
    x = _sample(shape, jdt)
    t = jax_to_torch(x)
    assert t.dtype == tdt and tuple(t.shape) == shape and t.device.type == "cpu"
    np.testing.assert_array_equal(t.numpy(), np.asarray(x))
    assert t.data_ptr() == x.unsafe_buffer_pointer()  # no copy: one buffer, two views


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize(("jdt", "tdt"), DTYPES)
def test_torch_to_jax_shares_the_buffer(shape, jdt, tdt):
    t = torch.tensor(np.asarray(_sample(shape, jdt)))  # torch-allocated (aligned) memory
    x = torch_to_jax(t, copy=False)  # copy=False: raises rather than copy
    assert x.dtype == jdt and x.shape == shape
    np.testing.assert_array_equal(np.asarray(x), t.numpy())
    assert x.unsafe_buffer_pointer() == t.data_ptr()
    assert COPIES.count == 0


def test_round_trip_is_the_same_buffer():
    x = jnp.arange(12.0).reshape(3, 4)
    back = torch_to_jax(jax_to_torch(x), copy=False)
    assert back.unsafe_buffer_pointer() == x.unsafe_buffer_pointer()
    np.testing.assert_array_equal(np.asarray(back), np.asarray(x))


def test_a_requires_grad_tensor_crosses_without_its_graph():
    w = torch.ones(3, requires_grad=True)
    t = w * 2
    x = torch_to_jax(t, copy=False)
    assert x.unsafe_buffer_pointer() == t.data_ptr()
    np.testing.assert_array_equal(np.asarray(x), [2.0, 2.0, 2.0])


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda: torch.arange(6, dtype=torch.int64), "dtype int64->int32"),
        (lambda: torch.arange(6, dtype=torch.float64), "dtype float64->float32"),
        (lambda: torch.arange(12.0).reshape(3, 4)[:, ::2], "non-contiguous"),
        # A float32 view 4 bytes into an allocation: XLA's CPU client wants 16-byte alignment, so jax
        # copies it (found by comparing the two pointers).
        (lambda: torch.arange(65.0)[1:], "not aliased"),
    ],
)
def test_a_copy_is_counted_and_logged_never_silent(make, reason, caplog):
    t = make()
    with caplog.at_level(logging.WARNING, logger="bar_policy.training.rsl_rl.torch_bridge"):
        x = torch_to_jax(t)
        torch_to_jax(t)
    np.testing.assert_array_equal(np.asarray(x), t.numpy().astype(np.asarray(x).dtype))
    assert COPIES.count == 2 and COPIES.by_reason == {reason: 2}
    warned = [r for r in caplog.records if reason in r.getMessage()]
    assert len(warned) == 1  # a warning on the first copy of a reason; later ones are counted
    with pytest.raises(BufferError, match="copy=False"):
        torch_to_jax(t, copy=False)


def test_torch_device_for_jax_on_cpu():
    assert torch_device_for_jax() == "cpu"
    assert torch_device_for_jax(jax.devices("cpu")[0]) == "cpu"


@pytest.mark.slow
def test_vec_env_step_crosses_without_copies(toy_env):
    env = RslRlVecEnv.from_env(toy_env, 8, wrap_fn=wrap_for_brax_training, seed=0, device="cpu")
    actions = torch.full((8, 14), 0.25)
    obs, rew, done, extras = env.step(actions)
    s = env.state
    # Every tensor returned is a view of the jitted step's output buffer, with the same values.
    pairs = [
        (obs["policy"], s.obs),
        (rew, s.reward),
        (done, s.done),
        (extras["time_outs"], s.info["truncation"]),
        (env.episode_length_buf, s.info["steps"]),
        *((extras["log"][f"Metrics/{k}"], v) for k, v in s.metrics.items()),
    ]
    for t, x in pairs:
        assert t.data_ptr() == x.unsafe_buffer_pointer()
        np.testing.assert_array_equal(t.numpy(), np.asarray(x))
    assert set(extras["log"]) == {f"Metrics/{k}" for k in s.metrics}
    assert COPIES.count == 0  # the actions crossed into jax without a copy too
    # The runner's init_at_random_ep_len writes episode_length_buf: the wrapper's counter takes it, and
    # an env 3 steps from its limit (20) times out 3 steps later.
    env.episode_length_buf = torch.tensor([17.0] + [0.0] * 7)
    for _ in range(3):
        _, _, done, extras = env.step(actions)
    assert done.tolist() == [1.0] + [0.0] * 7 and extras["time_outs"][0] == 1.0


@pytest.mark.slow
def test_vec_env_steps_make_no_host_round_trip(toy_env, monkeypatch):
    # After the first step, 25 steps (one auto-reset at 20) with every host crossing made to fail: jax's
    # transfer guard refuses host->device transfers, and reading a jax array's value on the host (numpy,
    # float(), device_get) goes through ArrayImpl._value, replaced by a trap.
    from jax._src.array import ArrayImpl

    env = RslRlVecEnv.from_env(toy_env, 8, wrap_fn=wrap_for_brax_training, seed=0, device="cpu", quality=True)
    actions = torch.full((8, 14), 0.1)
    env.step(actions)

    def trap(self):
        raise AssertionError("a jax array was read on the host during a step")

    monkeypatch.setattr(ArrayImpl, "_value", property(trap))
    with jax.transfer_guard("disallow"):
        for _ in range(25):
            _, _, done, _ = env.step(actions)
    monkeypatch.undo()
    assert done.sum() == 0 and env.take_stats()["success"][1] > 0  # the steps did run
    # One signature throughout: the reset's state is committed to the device as the step's outputs are,
    # so the jitted step compiled once (a second compile would have read constants on the host, above).
    # ``env._step`` calls it with the env's reward weights appended (``EnvPrograms.step``).
    assert env.programs.step_jit._cache_size() == 1
