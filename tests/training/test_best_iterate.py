"""The best iterate: its ranking (worked by hand), the keeper, and the run's record, evaluation and export."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import numpy as np
import onnxruntime as ort
import pytest

from bar_policy.deploy.metadata import PolicyMetadata
from bar_policy.quality.gate import excess
from bar_policy.training.best import (
    BestIterate,
    BestKeeper,
    best_onnx_path,
    held_out_report,
    is_better,
    score,
)
from bar_policy.training.summary import finish_best


def _ev(success: float, reward: float) -> dict[str, float]:
    return {"success_rate": success, "episode_reward": reward}


def test_ranking_is_success_then_reward_and_nan_is_worst():
    assert score(_ev(0.5, 3.0)) == (0.5, 3.0)
    assert is_better(_ev(0.9, 1.0), _ev(0.8, 50.0))  # success first
    assert is_better(_ev(1.0, 12.5), _ev(1.0, 12.0))  # then reward
    assert not is_better(_ev(1.0, 12.0), _ev(1.0, 12.0))  # a tie keeps the earlier one
    assert is_better(_ev(0.0, -5.0), _ev(math.nan, 10.0))
    assert not is_better(_ev(math.nan, math.nan), _ev(0.0, -1e9))
    assert is_better(_ev(0.0, 0.0), None)


def test_keeper_skips_untrained_and_resumed_steps_and_snapshots_only_improvements():
    calls: list[int] = []

    def snap(step: int):
        return lambda: calls.append(step) or f"params@{step}"

    k = BestKeeper(first_step=1000)
    # step 0 and the resume point are not this run's parameters; then 0.5, 0.9, 0.7, 0.9 (tie), 0.95.
    seq = [
        (0, 1.0, 9.0),
        (1000, 1.0, 9.0),
        (2000, 0.5, 1.0),
        (3000, 0.9, 2.0),
        (4000, 0.7, 3.0),
        (5000, 0.9, 2.0),
        (6000, 0.95, 0.5),
    ]
    kept = [k.offer(s, _ev(a, r), snap(s)) for s, a, r in seq]
    assert kept == [False, False, True, True, False, False, True]
    assert calls == [2000, 3000, 6000]
    assert k.best == BestIterate(step=6000, metrics=_ev(0.95, 0.5), params="params@6000")


def test_best_onnx_path_sits_next_to_the_policy(tmp_path):
    assert best_onnx_path(tmp_path / "policy.onnx") == tmp_path / "policy_best.onnx"
    assert best_onnx_path("out/lite_track") == best_onnx_path("out/lite_track.onnx")


def _expected_best_step(evals: list[dict], first_step: int) -> int:
    """The documented order: with quality figures (both backends' evaluations), the least total excess
    beyond the reach gate (quality.gate.excess, tested by hand in tests/quality), then success; without
    them, success then reward. The first of equal ones."""
    cands = [e for e in evals if e["step"] > first_step]

    def key(e: dict) -> tuple:
        if "quality/completion_pct" in e:
            return (-excess("reach", held_out_report(e)), 100 * e["success_rate"])
        return (e["success_rate"], e["episode_reward"])

    return max(cands, key=key)["step"]


@pytest.mark.slow
@pytest.mark.parametrize("which", ["brax_run", "rsl_run"])
def test_run_records_the_best_evaluated_iterate(which, request):
    _, summary = request.getfixturevalue(which)
    final = json.loads((summary.run_dir / "final_eval.json").read_text())
    want = _expected_best_step(final["evals"], 0)
    rec = final["best_iterate"]
    assert rec["step"] == want == summary.best["step"]
    assert rec["is_last"] == (want == summary.env_steps)
    assert best_onnx_path(summary.onnx_path).exists() == (not rec["is_last"])
    if not rec["is_last"]:  # evaluated on the final evaluation's seeds, same episode count
        assert rec["final_eval"]["episodes"] == final["final_eval"]["episodes"]


def _brax_best_at_mid(summary, toy_env, scale: float, export_to, **record) -> tuple[dict, tuple, dict]:
    """The brax run's result with its policy weights times ``scale`` posing as the best iterate at the
    second evaluation; ``finish_best`` on it (128 episodes, the run's final-evaluation seed 10_000)."""
    from bar_policy.training.metadata import policy_metadata

    res = summary.result
    mid = res.evals[1]
    assert 0 < mid["step"] < res.env_steps
    norm, pol, val = res.params
    params = (norm, jax.tree_util.tree_map(lambda x: scale * np.asarray(x), pol), val)
    fake = dataclasses.replace(res, best=BestIterate(step=mid["step"], metrics=mid, params=params))
    rec = finish_best(
        fake,
        final_step=res.env_steps,
        episodes=128,
        seed=10_000,
        export_to=export_to,
        metadata=policy_metadata(toy_env, training=record),
    )
    return rec, params, mid


@pytest.mark.slow
def test_a_best_iterate_before_the_last_is_evaluated_and_exported(brax_run, toy_env, tmp_path):
    _, summary = brax_run
    res = summary.result
    rec, halved, mid = _brax_best_at_mid(  # other, valid params
        summary,
        toy_env,
        0.5,
        tmp_path / "policy.onnx",
        backend="brax",
        env_steps=res.env_steps,
        iterate="last",
    )
    assert rec["step"] == mid["step"] and rec["is_last"] is False and rec["eval_during_training"] == mid
    # The same deterministic evaluation as the run's final one (seed cfg.seed + 10_000), on the best params.
    assert rec["final_eval"] == res.at(halved).final_evaluation(128, seed=10_000)
    assert rec["final_eval"] != summary.final_eval
    path = tmp_path / "policy_best.onnx"
    assert rec["onnx"] == str(path) and rec["export"]["max_abs_error"] <= 1e-5
    meta = PolicyMetadata.from_props(
        {p.key: p.value for p in __import__("onnx").load(str(path)).metadata_props}
    )
    assert meta.training["iterate"] == "best" and meta.training["env_steps"] == mid["step"]
    assert meta.training["final_eval"] == rec["final_eval"]
    # The file holds the halved policy, not the last one: outputs against brax's own inference function.
    obs = np.random.default_rng(3).standard_normal((64, 54)).astype(np.float32)
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(["actions"], {"obs": obs})[
        0
    ]
    last = ort.InferenceSession(str(summary.onnx_path), providers=["CPUExecutionProvider"]).run(
        ["actions"], {"obs": obs}
    )[0]
    with jax.default_matmul_precision("float32"):
        want = np.asarray(res.make_policy(halved, deterministic=True)(obs, jax.random.PRNGKey(0))[0])
    assert np.max(np.abs(got - want)) <= 1e-5 and np.max(np.abs(got - last)) > 1e-3


def test_finish_best_without_a_better_earlier_iterate_does_nothing():
    class NoBest:
        best = None

    assert finish_best(NoBest(), final_step=7, episodes=1, seed=0, export_to=None) == {
        "step": 7,
        "is_last": True,
    }


@pytest.mark.slow
def test_rsl_rl_best_iterate_loads_into_a_spare_actor_and_exports(rsl_run, toy_env, tmp_path):
    import torch

    from bar_policy.training.metadata import policy_metadata

    _, summary = rsl_run
    res = summary.result
    trained = {k: v.detach().clone() for k, v in res.actor.state_dict().items()}
    halved = {k: (0.5 * v if k.startswith("mlp.") else v) for k, v in trained.items()}
    fake = dataclasses.replace(
        res, best=BestIterate(step=res.evals[1]["step"], metrics=res.evals[1], params=halved)
    )
    rec = finish_best(
        fake,
        final_step=res.env_steps,
        episodes=32,
        seed=10_000,
        export_to=tmp_path / "policy.onnx",
        metadata=policy_metadata(toy_env, training={"backend": "rsl-rl"}),
    )
    assert rec["export"]["max_abs_error"] <= 1e-5 and rec["final_eval"]["episodes"] == 32
    # The trained actor is untouched; the exported file is the halved MLP on the same normaliser.
    for k, v in res.actor.state_dict().items():
        assert torch.equal(v, trained[k]), k
    obs = np.random.default_rng(5).standard_normal((16, 54)).astype(np.float32)
    sess = ort.InferenceSession(str(tmp_path / "policy_best.onnx"), providers=["CPUExecutionProvider"])
    got = sess.run(["actions"], {"obs": obs})[0]
    x = torch.as_tensor(obs)
    norm = res.actor.obs_normalizer
    x = (x - norm._mean) / (norm._std + norm.eps) if hasattr(norm, "_mean") else x
    layers = [m for m in res.actor.mlp]
    with torch.no_grad():
        for m in layers:
            x = (
                torch.nn.functional.linear(x, 0.5 * m.weight, 0.5 * m.bias)
                if isinstance(m, torch.nn.Linear)
                else m(x)
            )
    np.testing.assert_allclose(got, x.numpy(), atol=1e-5)


@pytest.mark.slow
def test_publish_ships_the_chosen_iterate(brax_run, toy_env, tmp_path):
    import shutil

    from bar_policy.training.publish import publish

    _, summary = brax_run
    res = summary.result
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for f in ("policy.onnx", "metrics.jsonl"):
        shutil.copyfile(summary.run_dir / f, run_dir / f)
    rec, _, mid = _brax_best_at_mid(summary, toy_env, 0.0, run_dir / "policy.onnx")  # all-zero actions
    final = json.loads((summary.run_dir / "final_eval.json").read_text())
    (run_dir / "final_eval.json").write_text(json.dumps({**final, "best_iterate": rec}))
    last_fe, best_fe = final["final_eval"], rec["final_eval"]
    # Zero actions hold the default pose: the trained last iterate scores a higher reward (success ties at 0
    # on the toy task or favours the last one), so "auto" ships the last iterate.
    assert (last_fe["success_rate"], last_fe["episode_reward"]) > (
        best_fe["success_rate"],
        best_fe["episode_reward"],
    )
    docs = tmp_path / "docs"
    for iterate, src, steps, fe in [
        ("last", "policy.onnx", res.env_steps, last_fe),
        ("best", "policy_best.onnx", mid["step"], best_fe),
        ("auto", "policy.onnx", res.env_steps, last_fe),
    ]:
        paths = publish(
            run_dir, name=f"p_{iterate}", checkpoints_dir=tmp_path / "ck", docs_dir=docs, iterate=iterate
        )
        assert paths["onnx"].read_bytes() == (run_dir / src).read_bytes(), iterate
        shipped = json.loads(paths["json"].read_text())
        assert shipped["env_steps"] == steps and shipped["final_eval"] == fe, iterate
        assert f"| env steps trained | {steps:,} |" in paths["docs"].read_text()
    # A record whose best iterate scored higher at the final evaluation: "auto" then ships it.
    higher = {**best_fe, "success_rate": 1.0, "episode_reward": last_fe["episode_reward"] + 1.0}
    (run_dir / "final_eval.json").write_text(
        json.dumps({**final, "best_iterate": {**rec, "final_eval": higher}})
    )
    paths = publish(run_dir, name="p_auto2", checkpoints_dir=tmp_path / "ck", docs_dir=docs, iterate="auto")
    assert paths["onnx"].read_bytes() == (run_dir / "policy_best.onnx").read_bytes()
    shipped = json.loads(paths["json"].read_text())
    assert shipped["iterate"] == "best" and shipped["last_iterate"]["env_steps"] == res.env_steps
    with pytest.raises(ValueError, match="iterate must be one of last, best, auto, got 'first'"):
        publish(run_dir, checkpoints_dir=tmp_path / "ck", docs_dir=docs, iterate="first")
