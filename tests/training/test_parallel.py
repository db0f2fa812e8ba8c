"""The mesh helpers on this process's devices (one CPU device in the suite)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from jax.sharding import PartitionSpec as P

from bar_policy.training.parallel import AXIS, barrier, make_data_parallel


def test_mesh_spans_every_device_and_places_trees():
    dp = make_data_parallel()
    assert dp.n_devices == jax.device_count() and dp.n_local == jax.local_device_count()
    tree = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.uint32(7)}
    rep = dp.replicate(tree)
    assert rep["a"].sharding == dp.replicated and rep["a"].shape == (2, 3)
    back = dp.to_host(rep)
    np.testing.assert_array_equal(back["a"], tree["a"])
    assert back["b"] == 7 and back["b"].dtype == np.uint32
    abstract = dp.abstract({"a": tree["a"]}, sharded=True)
    assert abstract["a"].sharding == dp.sharded and abstract["a"].shape == (2, 3)


def test_mapped_program_reduces_over_the_axis():
    dp = make_data_parallel()
    n = dp.n_devices
    # Each device sums its shard, psum adds the devices: the total of 0..(4n-1) = 4n(4n-1)/2.
    f = dp.sharded_jit(lambda x: jax.lax.psum(x.sum(), AXIS), (P(AXIS),), P())
    x = jax.device_put(np.arange(4 * n, dtype=np.float32), dp.sharded)
    assert float(f(x)) == 4 * n * (4 * n - 1) / 2


def test_bad_device_limits_are_refused():
    with pytest.raises(ValueError, match="max_devices_per_host must be positive or None, got 0"):
        make_data_parallel(0)
    assert make_data_parallel(1).n_devices == 1
    barrier("single process: returns at once")
