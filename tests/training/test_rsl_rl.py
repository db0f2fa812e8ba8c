"""The rsl-rl backend on the stand-in env: VecEnv (DLPack), training, checkpoint, export parity."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch
from toy_configs import TOY_RSL, toy_config

from bar_policy.deploy.metadata import BAR_KEYS, HC_KEYS, PolicyMetadata
from bar_policy.envs import wrap_for_brax_training
from bar_policy.export import ParityError, export_policy
from bar_policy.training.rsl_rl_backend import mlp_policy_from_rsl_rl, torch_policy_reference
from bar_policy.training.rsl_rl_env import RslRlVecEnv

pytestmark = pytest.mark.slow


def test_vec_env_shares_buffers_with_jax(toy_env):
    env = RslRlVecEnv(toy_env, 8, wrap_fn=wrap_for_brax_training, seed=0, device="cpu")
    obs = env.get_observations()["policy"]
    assert obs.shape == (8, 54) and obs.dtype == torch.float32
    # Zero copy: the torch tensor points at the jax buffer.
    assert obs.data_ptr() == env.state.obs.unsafe_buffer_pointer()
    actions = torch.full((8, 14), 0.25)
    assert env.jax_actions(actions).unsafe_buffer_pointer() == actions.data_ptr()
    obs2, rew, done, extras = env.step(actions)
    # Toy dynamics: q moves 30 % of the way to default + 0.8 * 0.25 from the default pose.
    q_rel = obs2["policy"][:, :14]
    np.testing.assert_allclose(q_rel.numpy(), 0.3 * 0.8 * 0.25, rtol=1e-5)
    assert rew.shape == (8,) and done.shape == (8,) and extras["time_outs"].shape == (8,)
    # 20-step episodes: the 20th step is a time-out, flagged for rsl-rl's bootstrapping.
    for _ in range(19):
        _, _, done, extras = env.step(actions)
    assert torch.all(done == 1) and torch.all(extras["time_outs"] == 1)


def test_rsl_rl_run_trains_checkpoints_and_exports(rsl_run):
    _, summary = rsl_run
    assert summary.env_steps == 10 * 32 * 8
    lines = (summary.run_dir / "metrics.jsonl").read_text().splitlines()
    records = [json.loads(x) for x in lines]
    assert len([r for r in records if r["kind"] == "train"]) == 10
    assert next(r["step"] for r in records if r["kind"] == "eval") == 0
    model = onnx.load(str(summary.onnx_path))
    props = {p.key: p.value for p in model.metadata_props}
    assert set(BAR_KEYS) | set(HC_KEYS) <= set(props)
    assert PolicyMetadata.from_props(props).training["backend"] == "rsl-rl"
    assert summary.export["max_abs_error"] <= 1e-5
    ckpts = sorted((summary.run_dir / "checkpoints").glob("step_*.msgpack"))
    assert ckpts[-1].name == f"step_{summary.env_steps:012d}.msgpack"


def test_rsl_rl_resume_continues_the_step_count(rsl_run, toy_env, tmp_path):
    from bar_policy.training.run import run

    _, first = rsl_run
    cfg = toy_config(
        tmp_path,
        "rsl-resumed",
        [
            *TOY_RSL,
            f"resume={first.run_dir}",
            f"ppo.num_timesteps={first.env_steps + 512}",
            "export_onnx=False",
        ],
    )
    resumed = run(cfg, env=toy_env)
    steps = [
        json.loads(x)["step"]
        for x in (resumed.run_dir / "metrics.jsonl").read_text().splitlines()
        if json.loads(x)["kind"] == "train"
    ]
    assert steps == [first.env_steps + 256, first.env_steps + 512]


def test_rsl_rl_parity_gate_refuses_a_corrupted_actor(toy_env, tmp_path):
    # A fresh rsl-rl actor with a non-trivial normaliser; the gate passes, then refuses a changed kernel.
    from rsl_rl.models import MLPModel
    from tensordict import TensorDict

    from bar_policy.training.metadata import policy_metadata

    obs = TensorDict({"policy": torch.zeros(1, 54)}, batch_size=[1])
    actor = MLPModel(
        obs,
        {"actor": ["policy"]},
        "actor",
        14,
        hidden_dims=[32, 32],
        activation="elu",
        obs_normalization=True,
        distribution_cfg={"class_name": "GaussianDistribution"},
    )
    actor.obs_normalizer.update(torch.randn(256, 54) * 2 + 1)
    good = mlp_policy_from_rsl_rl(actor)
    meta = policy_metadata(toy_env)
    export_policy(good, meta, tmp_path / "ok.onnx", torch_policy_reference(actor))
    kernels = list(good.kernels)
    kernels[0] = kernels[0] * 1.001
    import dataclasses

    with pytest.raises(ParityError):
        export_policy(
            dataclasses.replace(good, kernels=tuple(kernels)),
            meta,
            tmp_path / "bad.onnx",
            torch_policy_reference(actor),
        )
    assert not (tmp_path / "bad.onnx").exists()
