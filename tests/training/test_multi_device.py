"""The data-parallel path on 2 simulated CPU devices (XLA_FLAGS=--xla_force_host_platform_device_count=2).

One subprocess (the device count is fixed when jax starts) runs both checks: a short training run through
``run`` on a 2-device mesh, and a probe of which randomised model each env slot steps on.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent(
    """
    import sys, json
    sys.path.insert(0, {tests!r})
    import jax, jax.numpy as jnp, numpy as np
    from jax.sharding import Mesh, PartitionSpec as P
    assert jax.local_device_count() == 2, jax.devices()
    from toy_env import ToyReach
    from toy_configs import toy_config
    from bar_policy.envs import wrap_for_brax_training
    from bar_policy.training.run import run
    from bar_policy.training.brax.programs import slot_env, slot_keys
    from bar_policy.training.brax.state import host_key
    from bar_policy.training.parallel import AXIS, DataParallel

    cfg = toy_config({tmp!r}, "md", [
        "ppo.num_envs=64", "ppo.batch_size=64", "ppo.num_minibatches=4", "ppo.unroll_length=10",
        "ppo.num_updates_per_batch=2", "ppo.num_timesteps=10240", "eval.num_evals=2",
        "eval.num_eval_envs=32", "final_eval_envs=32", "log_every_iterations=2",
    ])
    s = run(cfg, env=ToyReach())

    # Probe: 8 slots, each with its own toy gain drawn from its model key; one step at action 0.5.
    def randomizer(model, rng):
        gains = jax.vmap(lambda k: jax.random.uniform(k, (), minval=0.1, maxval=0.5))(rng)
        return {{"gain": gains}}, {{"gain": 0}}

    env = ToyReach()
    def probe(model_key, reset_key, n_local):
        batch = slot_env(env, wrap_for_brax_training, randomizer, slot_keys(model_key, 8, n_local))
        state = batch.reset(slot_keys(reset_key, 8, n_local))
        return batch.step(state, jnp.full((n_local, 14), 0.5)).obs[:, :14]

    out = {{}}
    for n in (1, 2):
        dp = DataParallel(Mesh(np.asarray(jax.devices()[:n]), (AXIS,)))
        f = dp.sharded_jit(lambda a, b, n=n: probe(a, b, 8 // n), (P(), P()), P(AXIS))
        q = f(dp.replicate(host_key(3, 1)), dp.replicate(host_key(3, 2)))
        out[n] = np.asarray(q).tolist()
    try:
        dp.check_divisible(**{{"ppo.num_envs": 4096, "ppo.batch_size": 3}})
        refusal = ""
    except ValueError as e:
        refusal = str(e)
    print("RESULT", json.dumps({{"steps": s.env_steps, "err": s.export["max_abs_error"], "probe": out,
                                "refusal": refusal}}))
    """
)


@pytest.fixture(scope="module")
def two_device_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    tmp = tmp_path_factory.mktemp("md")
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
        "JAX_PLATFORMS": "cpu",
    }
    tests = str(Path(__file__).parent)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(tests=tests, tmp=str(tmp))],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return tmp, json.loads(out.stdout.split("RESULT", 1)[1])


def test_training_runs_data_parallel_on_two_devices(two_device_run):
    tmp, result = two_device_run
    # 64 envs x 10 steps x 4 minibatches... = 2,560 env steps per iteration, 2 iterations per epoch.
    assert result["steps"] == 4 * 2560 and result["err"] <= 1e-5
    record = json.loads((tmp / "md" / "config.json").read_text())
    assert len(record["device"]["devices"]) == 2
    assert record["device"]["xla_flags"] == "--xla_force_host_platform_device_count=2"  # a CPU run adds none
    lines = [json.loads(x) for x in (tmp / "md" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines if r["kind"] == "train"] == [5120, 10240]


def test_every_slot_steps_on_its_own_model_whatever_the_device_count(two_device_run):
    import jax

    from bar_policy.training.brax.state import host_key

    _, result = two_device_run
    # Toy dynamics from the default pose: q - default = gain * action_scale * action = gain * 0.8 * 0.5.
    # Slot i's gain is U(0.1, 0.5) drawn with key i of split(model_key, 8), computed here independently.
    keys = jax.random.split(np.asarray(host_key(3, 1)), 8)
    gains = np.array([float(jax.random.uniform(k, (), minval=0.1, maxval=0.5)) for k in keys])
    for n in ("1", "2"):
        q = np.asarray(result["probe"][n])
        assert q.shape == (8, 14)
        np.testing.assert_allclose(q, np.repeat(gains[:, None] * 0.4, 14, axis=1), rtol=1e-5)
    # Not one set of models per device repeated on each device (the old pmap layout): 8 distinct gains.
    assert len(set(np.round(gains, 6))) == 8


def test_sizes_that_do_not_split_over_the_devices_are_refused_by_name(two_device_run):
    _, result = two_device_run
    assert result["refusal"].startswith("ppo.batch_size = 3 must be a multiple of the device count 2")
    assert "ppo.num_envs" not in result["refusal"]
