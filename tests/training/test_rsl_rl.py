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
from bar_policy.export.parity import ParityError
from bar_policy.export.policy import export_policy
from bar_policy.training.rsl_rl.backend import mlp_policy_from_rsl_rl, torch_policy_reference
from bar_policy.training.rsl_rl.env import RslRlVecEnv
from bar_policy.training.rsl_rl.policy import evaluate_torch_policy
from bar_policy.training.startup import breakdown as sb

pytestmark = pytest.mark.slow


def test_vec_env_shares_buffers_with_jax(toy_env):
    env = RslRlVecEnv.from_env(toy_env, 8, wrap_fn=wrap_for_brax_training, seed=0, device="cpu")
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
    # Every 5 iterations, then the untrained actor's step-0 evaluation after training (eval.initial=end).
    assert [r["step"] for r in records if r["kind"] == "eval"] == [1280, 2560, 0]
    # The toy config keeps PPOConfig's brax defaults (fixed rate, targets per pass, value weight 0.5) beside
    # RslRlConfig's (adaptive, 1.0): the run says and records the three it runs without, nothing else.
    (note,) = [r for r in records if r["kind"] == "not_applied"]
    assert [line.split(" not applied")[0] for line in note["settings"]] == [
        "ppo.schedule=fixed",
        "ppo.value_targets=pass",
        "ppo.vf_loss_coefficient=0.5",
    ]
    model = onnx.load(str(summary.onnx_path))
    props = {p.key: p.value for p in model.metadata_props}
    assert set(BAR_KEYS) | set(HC_KEYS) <= set(props)
    assert PolicyMetadata.from_props(props).training["backend"] == "rsl-rl"
    assert summary.export["max_abs_error"] <= 1e-5
    ckpts = sorted((summary.run_dir / "checkpoints").glob("step_*.msgpack"))
    assert ckpts[-1].name == f"step_{summary.env_steps:012d}.msgpack"


def test_rsl_rl_resume_continues_the_step_count(rsl_run, toy_env, tmp_path, capsys):
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
    capsys.readouterr()
    resumed = run(cfg, env=toy_env)
    out = capsys.readouterr().out
    # The same training settings (another run name, export and step count): nothing to list.
    assert "resumed " in out and "settings differ" not in out
    steps = [
        json.loads(x)["step"]
        for x in (resumed.run_dir / "metrics.jsonl").read_text().splitlines()
        if json.loads(x)["kind"] == "train"
    ]
    assert steps == [first.env_steps + 256, first.env_steps + 512]
    # A resume evaluates no untrained actor: its only evaluation is the last one, and the start-up report
    # (finished after the first iteration) has no step-0 evaluation in it.
    assert [e["step"] for e in resumed.result.evals] == [first.env_steps + 512]
    startup = json.loads((resumed.run_dir / "final_eval.json").read_text())["startup"]
    assert startup["phases"][sb.FIRST_EVAL] == 0.0 and startup["phases"][sb.FIRST_EPOCH] > 0


def test_rsl_rl_evaluates_the_initial_actor_at_step_0(rsl_run):
    # The step-0 evaluation runs after training (eval.initial=end; with start, after the first iterations
    # once the eval step is compiled: tests/training/test_initial_eval.py), on a copy of the actor taken
    # before training. Expected: rsl-rl's deterministic module of a freshly built initial
    # actor (torch seeded with the run's seed, as train_rsl_rl seeds it before building its runner),
    # evaluated on the step-0 seeds (cfg.seed + 1000).
    from rsl_rl.runners import OnPolicyRunner

    from bar_policy.training.rsl_rl.config import rsl_rl_train_cfg

    cfg, summary = rsl_run
    res = summary.result
    steps = [e["step"] for e in res.evals]
    assert steps[0] == 0 and steps == sorted(steps) and steps.count(0) == 1
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        runner = OnPolicyRunner(res.eval_env, rsl_rl_train_cfg(cfg), log_dir=None, device="cpu")
    module = runner.alg.actor.as_onnx(verbose=False).eval()
    seed0 = cfg.seed + 1000
    initial = evaluate_torch_policy(lambda o: module(o), res.eval_env, res.episode_length, seed=seed0)
    trained = evaluate_torch_policy(res.policy_fn(), res.eval_env, res.episode_length, seed=seed0)
    for k in ("episode_reward", "episode_reward_std", "success_rate", "quality/action_rate"):
        assert res.evals[0][k] == pytest.approx(initial[k], rel=1e-5, abs=1e-7), k
    # ... and not the trained actor's (nor one after the first iteration, which would differ as well).
    assert trained["episode_reward"] != pytest.approx(initial["episode_reward"], rel=1e-3)
    assert trained["quality/action_rate"] != pytest.approx(initial["quality/action_rate"], rel=1e-3)


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


def test_rsl_rls_own_runner_learns_and_logs_on_the_adapter(toy_env, tmp_path):
    # rsl-rl as its users run it: OnPolicyRunner.learn on our VecEnv, rsl-rl's logger writing TensorBoard.
    from rsl_rl.runners import OnPolicyRunner
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from bar_policy.training.rsl_rl.config import rsl_rl_train_cfg

    cfg = toy_config(tmp_path, "own-runner", TOY_RSL)
    env = RslRlVecEnv.from_env(
        toy_env, cfg.ppo.num_envs, wrap_fn=wrap_for_brax_training, seed=0, device="cpu"
    )
    runner = OnPolicyRunner(env, rsl_rl_train_cfg(cfg), log_dir=str(tmp_path / "tb"), device="cpu")
    # Random initial episode lengths (written into the wrapper's step counter): episodes end within the
    # 2 x 8 steps, so rsl-rl's own episode statistics have entries.
    runner.learn(2, init_at_random_ep_len=True)
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {"Train/mean_reward", "Train/mean_episode_length", "Loss/learning_rate", "Perf/total_fps"} <= tags
    assert {f"Metrics/{k}" for k in env.state.metrics} <= tags  # extras["log"], averaged by rsl-rl
    assert len(acc.Scalars("Metrics/dist_left")) == 2


def test_both_backends_write_the_same_run_record(brax_run, rsl_run):
    (_, brax), (_, rsl) = brax_run, rsl_run

    def kinds(summary) -> dict[str, set[str]]:
        out: dict[str, set[str]] = {}
        for line in (summary.run_dir / "metrics.jsonl").read_text().splitlines():
            rec = json.loads(line)
            keys = {k for k in rec.get("metrics", rec) if not k.startswith("loss/")}
            out.setdefault(rec["kind"], set()).update(keys)
        return out

    # rsl-rl's record also names the brax settings it ran without (test_rsl_rl_run_trains_checkpoints_...).
    assert kinds(brax).keys() == kinds(rsl).keys() - {"not_applied"}
    assert "not_applied" not in kinds(brax)  # the toy brax run leaves every rsl_rl.* at its default
    for kind in kinds(brax):
        assert kinds(brax)[kind] <= kinds(rsl)[kind], kind
    # The files, but the best iterate's ONNX, written only when an earlier iterate ranked higher.
    files = lambda s: {p.name for p in s.run_dir.iterdir()} - {"policy_best.onnx"}  # noqa: E731
    assert files(brax) == files(rsl)
    fb, fr = (json.loads((s.run_dir / "final_eval.json").read_text()) for s in (brax, rsl))
    assert fb.keys() == fr.keys() and fb["final_eval"].keys() == fr["final_eval"].keys()
    q = fr["final_eval"]  # the rsl-rl evaluation's quality figures are real counts, as brax's
    assert q["quality/episodes"] == 32 and 0 <= q["quality/completion_pct"] <= 100
    assert {p.key for p in onnx.load(str(brax.onnx_path)).metadata_props} == {
        p.key for p in onnx.load(str(rsl.onnx_path)).metadata_props
    }


def test_vec_env_quality_figures_by_hand(toy_env):
    # Actions alternating +-0.3 on every joint: each tick after the first moves 0.6 on 14 joints, so the
    # action rate is 14 * 0.6^2 = 5.04 per tick; the toy never terminates, so all 8 episodes complete.
    env = RslRlVecEnv.from_env(toy_env, 8, wrap_fn=wrap_for_brax_training, seed=0, device="cpu", quality=True)
    env.reset_all(seed=3)
    for t in range(env.max_episode_length):
        env.step(torch.full((8, 14), 0.3 if t % 2 == 0 else -0.3))
    q = env.take_stats()["quality"]
    assert q["quality/episodes"] == 8 and q["quality/completion_pct"] == 100.0
    assert q["quality/action_rate"] == pytest.approx(14 * 0.6**2, rel=1e-5)
    assert q["quality/chatter_unmeasured"] == 0 and q["quality/chatter_max_mrad"] > 0


def test_tf32_covers_rsl_rls_update_and_not_its_rollout(toy_env, tmp_path, monkeypatch):
    """``ppo.update_precision=tensorfloat32`` on rsl-rl (``torch_precision``): every ``PPO.update`` call
    runs with CUDA float32 matmuls at TF32, every ``PPO.act`` (the rollout's actor) with the setting the
    process had, which is back in place after the run. Read from torch's own flag (this CPU has no TF32)."""
    from rsl_rl.algorithms import PPO

    from bar_policy.training.run import run

    seen: dict[str, set] = {"update": set(), "act": set()}
    matmul = torch.backends.cuda.matmul
    before = matmul.fp32_precision
    for name in seen:
        original = getattr(PPO, name)

        def spy(self, *a, _name=name, _original=original, **k):
            seen[_name].add(matmul.fp32_precision)
            return _original(self, *a, **k)

        monkeypatch.setattr(PPO, name, spy)
    run(toy_config(tmp_path, "tf32", [*TOY_RSL, "ppo.update_precision=tensorfloat32"]), env=toy_env)
    assert seen == {"update": {"tf32"}, "act": {before}} and before != "tf32"
    assert matmul.fp32_precision == before


def test_update_precision_restores_torchs_setting_when_the_update_raises():
    from bar_policy.training.rsl_rl.torch_precision import update_precision

    matmul = torch.backends.cuda.matmul
    before = matmul.fp32_precision
    with pytest.raises(RuntimeError, match="boom"), update_precision("tensorfloat32"):
        assert matmul.fp32_precision == "tf32"
        raise RuntimeError("boom")
    assert matmul.fp32_precision == before
    for setting in ("run", "BF16_BF16_F32_X3"):  # torch's own default, and a product torch lacks: unchanged
        with update_precision(setting):
            assert matmul.fp32_precision == before
