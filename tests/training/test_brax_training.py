"""The brax backend on the stand-in env: learning, run artifacts, export, resume."""

from __future__ import annotations

import json
import re

import jax
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from flax import serialization
from toy_configs import TOY_BRAX, toy_config

from bar_policy.deploy.metadata import BAR_KEYS, HC_KEYS, PolicyMetadata
from bar_policy.training.checkpoint import latest_checkpoint, load_checkpoint

pytestmark = pytest.mark.slow


def _records(run_dir, kind):
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    return [r for r in map(json.loads, lines) if r["kind"] == kind]


def test_training_improves_eval_reward(brax_run):
    _, summary = brax_run
    evals = _records(summary.run_dir, "eval")
    # eval.initial=end (the default): the untrained policy is evaluated after training, so its record is
    # written last; the run's own list is in step order (tests/training/test_initial_eval.py).
    assert [e["step"] for e in evals] == [266240, 532480, 0]
    evals = sorted(evals, key=lambda e: e["step"])
    first, last = evals[0]["episode_reward"], evals[-1]["episode_reward"]
    # Episode = 20 steps, reward per step in [0, 1]: the untrained policy scores ~2 (fingertips ~25 cm
    # off); after 0.5 M steps the policy should at least halve the distance, doubling the reward.
    assert last > 2.0 * first and last > first + 3.0, (first, last)
    assert evals[-1]["final_distance"] < 0.6 * evals[0]["final_distance"]


def test_run_directory_holds_config_metrics_checkpoints(brax_run):
    cfg, summary = brax_run
    d = summary.run_dir
    record = json.loads((d / "config.json").read_text())
    assert record["train"]["ppo"]["num_envs"] == cfg.ppo.num_envs == 128
    assert record["train"]["backend"] == "brax"
    train = _records(d, "train")
    assert len(train) == 4 and all(r["sps"] > 0 for r in train)
    assert train[-1]["step"] == summary.env_steps == 50 * 128 * 8 * 10 + 2 * 128 * 8 * 10  # 52 iterations
    assert any(p.name.startswith("events") for p in (d / "tb").iterdir())
    assert latest_checkpoint(d).name == f"step_{summary.env_steps:012d}.msgpack"
    final = json.loads((d / "final_eval.json").read_text())
    assert final["final_eval"]["episodes"] == 128
    assert final["env_steps"] == summary.env_steps


def test_export_writes_every_metadata_key(brax_run, toy_env):
    _, summary = brax_run
    model = onnx.load(str(summary.onnx_path))
    onnx.checker.check_model(model, full_check=True)
    props = {p.key: p.value for p in model.metadata_props}
    assert set(BAR_KEYS) | set(HC_KEYS) <= set(props)
    meta = PolicyMetadata.from_props(props)
    assert meta.joint_names == toy_env.robot.joint_names
    np.testing.assert_allclose(meta.joint_stiffness, toy_env.kp, rtol=1e-6)
    np.testing.assert_allclose(meta.joint_damping, toy_env.kd, rtol=1e-6)
    np.testing.assert_allclose(meta.default_joint_pos, toy_env.default_pose, rtol=1e-6)
    np.testing.assert_allclose(meta.action_scale, toy_env.action_scale, rtol=1e-6)
    assert meta.policy_dt == 0.02 and meta.physics_dt == 0.002
    assert meta.action_semantics == "delta_from_default"
    assert meta.obs_fingerprint == toy_env.obs_manager.fingerprint
    assert meta.command_names == ("target_pos_left", "target_pos_right")
    assert meta.training["backend"] == "brax" and meta.training["env_steps"] == summary.env_steps
    assert meta.randomization["actuator"]["latency_steps"] == [0, 0]
    assert meta.code_version.startswith("0.1.0")
    # Humanoid Control keys: comma-separated, 14 joints, 50 Hz.
    assert len(props["joint_names"].split(",")) == 14 and float(props["policy_dt"]) == 0.02
    assert props["observation_names"].split(",")[:3] == ["joint_pos", "joint_vel", "actions"]
    assert json.loads(props["bar.action_clip"]) == 1.0


@pytest.mark.numerics
def test_exported_graph_matches_the_jax_policy(brax_run):
    """Independent of the gate: the graph's I/O and its outputs against brax's inference function."""
    _, summary = brax_run
    sess = ort.InferenceSession(str(summary.onnx_path), providers=["CPUExecutionProvider"])
    (inp,), (out,) = sess.get_inputs(), sess.get_outputs()
    assert (inp.name, inp.type, inp.shape[1]) == ("obs", "tensor(float)", 54)
    assert (out.name, out.type, out.shape[1]) == ("actions", "tensor(float)", 14)
    assert isinstance(inp.shape[0], str)  # dynamic batch
    # Rebuild brax's policy from the final checkpoint (what was exported).
    from brax.training.agents.ppo import networks as ppo_networks

    from bar_policy.training.brax.networks import make_networks
    from bar_policy.training.config import preset

    net = make_networks(54, 14, preset("tiny").network, True)
    raw = serialization.msgpack_restore(latest_checkpoint(summary.run_dir).read_bytes())["state"]
    from brax.training.acme import running_statistics, specs

    norm = serialization.from_state_dict(
        running_statistics.init_state(specs.Array((54,), np.float32)), raw["normalizer_params"]
    )
    pol = serialization.from_state_dict(
        net.policy_network.init(jax.random.PRNGKey(0)), raw["params"]["policy"]
    )
    policy = ppo_networks.make_inference_fn(net)((norm, pol, None), deterministic=True)
    obs = np.asarray(norm.mean) + np.asarray(norm.std) * np.random.default_rng(7).standard_normal((3000, 54))
    obs = obs.astype(np.float32)
    with jax.default_matmul_precision("float32"):
        want = np.asarray(jax.jit(policy)(obs, jax.random.PRNGKey(0))[0])
    got = sess.run(["actions"], {"obs": obs})[0]
    # Two float32 MLPs (ONNX Runtime, XLA) summing in different orders: export.parity.PARITY_TOLERANCE
    # (its docstring derives it from the layer widths and float32 rounding).
    assert np.max(np.abs(got - want)) <= 1e-5
    assert np.max(np.abs(want)) > 0.1  # a trained, non-trivial policy
    assert summary.export["max_abs_error"] <= 1e-5


def test_resume_continues_the_step_count(brax_run, toy_env, tmp_path, capsys):
    from bar_policy.training.run import run

    _, first = brax_run
    total = first.env_steps + 13 * 128 * 8 * 10  # one more epoch of 13 iterations (same compiled program)
    cfg = toy_config(
        tmp_path,
        "resumed",
        [*TOY_BRAX, f"resume={first.run_dir}", f"ppo.num_timesteps={total}", "export_onnx=False"],
    )
    capsys.readouterr()
    resumed = run(cfg, env=toy_env)
    out = capsys.readouterr().out
    # The same training settings (another run name, budget, export and step count): nothing to list.
    assert "resumed " in out and "settings differ" not in out
    # No ONNX file: the summary says so, and gives no parity figure (once "nan").
    table = dict(
        re.split(r"\s{2,}", line, maxsplit=1) for line in out.splitlines() if re.search(r"\S\s{2,}\S", line)
    )
    assert table["ONNX"] == "not exported" and table["parity max abs error"] == "-"
    train = _records(resumed.run_dir, "train")
    assert train[0]["step"] > first.env_steps
    assert resumed.env_steps == total == train[-1]["step"] and len(train) == 1
    # No evaluation at step 0 after a resume: the run continues, it does not restart.
    assert all(e["step"] > first.env_steps for e in _records(resumed.run_dir, "eval"))


def test_checkpoint_restores_params_normaliser_and_optimizer(brax_run):
    _, summary = brax_run
    path = latest_checkpoint(summary.run_dir)
    raw = serialization.msgpack_restore(path.read_bytes())
    ckpt = load_checkpoint(path, raw["state"])
    assert ckpt.env_steps == summary.env_steps and ckpt.iteration == 52
    leaves = jax.tree_util.tree_leaves(ckpt.state)
    assert set(ckpt.state) == {"optimizer_state", "params", "normalizer_params"}
    # Adam moments are non-zero after training: the optimizer state was really saved.
    mu = jax.tree_util.tree_leaves(raw["state"]["optimizer_state"])
    assert any(np.abs(np.asarray(x)).max() > 0 for x in mu if np.asarray(x).ndim >= 1)
    assert len(leaves) > 10
    with pytest.raises(FileNotFoundError, match=r"no step_<N>\.msgpack"):
        latest_checkpoint(summary.run_dir / "tb")


def test_publish_ships_onnx_json_curve_and_results(brax_run, tmp_path):
    from bar_policy.deploy.policy import load_policy
    from bar_policy.training.publish import RESULTS_END, RESULTS_START, publish

    _, summary = brax_run
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "reach.md").write_text(f"# T\n\nintro\n\n{RESULTS_START}\nold\n{RESULTS_END}\n\ntail\n")
    paths = publish(summary.run_dir, checkpoints_dir=tmp_path / "ck", docs_dir=docs)
    assert load_policy(paths["onnx"]).n_actions == 14
    shipped = json.loads(paths["json"].read_text())
    assert shipped["env_steps"] == summary.env_steps and "final_eval" in shipped
    assert paths["curve"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = paths["docs"].read_text()
    assert "old" not in md and md.startswith("# T\n\nintro") and md.rstrip().endswith("tail")
    assert f"| env steps trained | {summary.env_steps:,} |" in md
