"""The data-parallel path on 2 simulated CPU devices (XLA_FLAGS=--xla_force_host_platform_device_count=2)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent(
    """
    import sys, json
    sys.path.insert(0, {tests!r})
    import jax
    assert jax.local_device_count() == 2, jax.devices()
    from toy_env import ToyReach
    from toy_configs import toy_config
    from bar_policy.training.run import run
    cfg = toy_config({tmp!r}, "md", [
        "ppo.num_envs=64", "ppo.batch_size=64", "ppo.num_minibatches=4", "ppo.unroll_length=10",
        "ppo.num_updates_per_batch=2", "ppo.num_timesteps=10240", "eval.num_evals=2",
        "eval.num_eval_envs=32", "final_eval_envs=32", "log_every_iterations=2",
    ])
    s = run(cfg, env=ToyReach())
    print("RESULT", json.dumps({{"steps": s.env_steps, "err": s.export["max_abs_error"]}}))
    """
)


def test_training_runs_data_parallel_on_two_devices(tmp_path):
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
        "JAX_PLATFORMS": "cpu",
    }
    tests = str(Path(__file__).parent)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(tests=tests, tmp=str(tmp_path))],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.split("RESULT", 1)[1])
    # 64 envs x 10 steps x 4 minibatches... = 2,560 env steps per iteration, 2 iterations per epoch.
    assert result["steps"] == 4 * 2560 and result["err"] <= 1e-5
    record = json.loads((tmp_path / "md" / "config.json").read_text())
    assert len(record["device"]["devices"]) == 2
    lines = [json.loads(x) for x in (tmp_path / "md" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines if r["kind"] == "train"] == [5120, 10240]
