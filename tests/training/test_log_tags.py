"""The logged training figures: tag table, loss names, per-window ratios and sums, --logger (no jax)."""

from __future__ import annotations

import importlib.util
import io

import pytest

from bar_policy.training.cli import parse_config
from bar_policy.training.config import TrainConfig
from bar_policy.training.log_tags import brax_losses, rsl_rl_losses, tag
from bar_policy.training.rollout_sums import RatioWindow, SumLayout, window_metrics
from bar_policy.training.writers import check_logger

BRAX_ONLY = {"loss/kl", "loss/total", "policy_std"}
"""Record keys only the brax backend's update gives (rsl-rl's PPO.update returns no KL nor total loss; its
std is read from the actor by the backend instead)."""


def test_tags_follow_rsl_rl_and_isaac_lab():
    assert tag("train", "episode_reward") == "Train/mean_reward"
    assert tag("train", "episode_length") == "Train/mean_episode_length"
    assert tag("train", "reward/action_rate") == "Episode_Reward/action_rate"
    assert tag("train", "success_rate") == "Metrics/success_rate"
    assert tag("train", "final_distance") == "Metrics/final_distance"
    assert tag("train", "loss/value_function") == "Loss/value_function"
    assert tag("train", "sps") == "Perf/total_fps"
    assert tag("train", "policy_std") == "Policy/mean_std"
    assert tag("eval", "quality/chatter_max_mrad") == "Eval/quality/chatter_max_mrad"
    assert tag("final", "success_rate") == "Final/success_rate"


def test_both_backends_losses_get_the_same_names_and_units():
    # brax: v_loss = 0.5 * vf * mean(err^2), entropy_loss = -cost * mean entropy. With vf 0.5 and cost
    # 0.005: v_loss 0.25 is a mean squared error of 0.25 / (0.5 * 0.5) = 1.0; entropy_loss -0.015 is an
    # entropy of 3.0 nats (exact in binary to well under 1e-12).
    brax = brax_losses(
        {
            "total_loss": 0.1,
            "policy_loss": -0.02,
            "v_loss": 0.25,
            "entropy_loss": -0.015,
            "kl": 0.01,
            "learning_rate": 5e-4,
            "policy_dist_mean_std": 0.7,
        },
        entropy_cost=0.005,
        vf_coefficient=0.5,
    )
    assert brax["loss/value_function"] == pytest.approx(1.0, abs=1e-12)
    assert brax["loss/entropy"] == pytest.approx(3.0, abs=1e-12)
    assert brax["loss/surrogate"] == -0.02 and brax["policy_std"] == 0.7
    rsl = rsl_rl_losses({"value": 1.0, "surrogate": -0.02, "entropy": 3.0}, learning_rate=5e-4)
    assert rsl == {
        "loss/value_function": 1.0,
        "loss/surrogate": -0.02,
        "loss/entropy": 3.0,
        "loss/learning_rate": 5e-4,
    }
    assert set(brax) - BRAX_ONLY == set(rsl)
    # A zero weight leaves the unweighted figure unknown: left out, not divided by zero.
    assert "loss/entropy" not in brax_losses(
        {"total_loss": 0, "policy_loss": 0, "v_loss": 0, "entropy_loss": 0}, 0.0, 0.5
    )


def reach_like_iterations(n: int, steps_per_env: int, period: int, envs: int, rates: list[float]):
    """(num, den) of success per iteration when ``envs`` envs reset together and each reaches a segment
    end every ``period`` steps: an iteration holds ``envs`` segment ends when one of its steps is a multiple
    of ``period``, else none. The k-th batch of segment ends succeeds at ``rates[k]``."""
    out, k = [], 0
    for i in range(n):
        steps = range(i * steps_per_env + 1, (i + 1) * steps_per_env + 1)
        ends = sum(1 for s in steps if s % period == 0)
        num = 0.0
        for _ in range(ends):
            num += rates[k] * envs
            k += 1
        out.append((num, float(ends * envs)))
    return out


def test_success_column_does_not_flip_to_zero_between_segment_ends():
    # Reach on rsl-rl at 4096 envs and 24 steps per env: segment ends at steps 125, 250, ..., so
    # iterations 6 (steps 121-144) and 11 (241-264) hold one batch each, the others none.
    seq = reach_like_iterations(12, 24, 125, 4096, rates=[0.98, 0.96])
    assert [i for i, (_, d) in enumerate(seq) if d] == [5, 10]
    # The old per-iteration figure, num / max(den, 1): 0.0 % on every iteration without a segment end.
    old = [n / max(d, 1.0) for n, d in seq]
    assert old[4:7] == [0.0, pytest.approx(0.98), 0.0]
    # The window: nothing before the first batch, then that batch's rate until the next one.
    window = RatioWindow()
    got = []
    for n, d in seq:
        window.add(n, d)
        got.append(window.take())
    assert got[:5] == [None] * 5
    assert got[5:10] == [pytest.approx(0.98)] * 5  # 4014.08 / 4096, float64 rounding
    assert got[10:] == [pytest.approx(0.96)] * 2


def test_progress_line_rate_is_over_the_lines_window():
    # Lines every 4 iterations (96 steps per env) of the sequence above: the windows cover steps 1-96
    # (no segment end: no rate yet), 97-192 (the batch at 125: 0.98), 193-288 (250: 0.96), 289-384 (375:
    # 0.97) and 385-480 (none: 0.97 kept).
    seq = reach_like_iterations(20, 24, 125, 4096, rates=[0.98, 0.96, 0.97])
    layout = SumLayout(terms=(), ratios=())
    ratios: dict[str, RatioWindow] = {}
    lines = []
    for start in range(0, 20, 4):
        num = sum(n for n, _ in seq[start : start + 4])
        den = sum(d for _, d in seq[start : start + 4])
        sums = dict.fromkeys(layout.columns, 0.0)
        sums.update({"success_rate/num": num, "success_rate/den": den})
        lines.append(window_metrics(sums, 4 * 24 * 4096, 250, ratios).get("success_rate"))
    assert lines == [None, pytest.approx(0.98), pytest.approx(0.96), pytest.approx(0.97), pytest.approx(0.97)]


def test_window_figures_by_hand():
    # 10 envs x 24 steps = 240 steps: reward 120 in all (0.5 per step) over 250-step episodes is 125 per
    # episode; terms 90 and 30 are 93.75 and 31.25 (their sum, 125). Two episodes ended, 500 steps in all:
    # 250 each. final_distance 0.3 m over 20 segment ends = 1.5 cm. Exact in binary but for 0.3 / 20.
    layout = SumLayout(terms=("reach", "action_rate"), ratios=("final_distance",))
    assert layout.columns == (
        "reward",
        "success_rate/num",
        "success_rate/den",
        "episodes",
        "episode_steps",
        "reward/reach",
        "reward/action_rate",
        "final_distance/num",
        "final_distance/den",
    )
    sums = layout.named([120.0, 19.0, 20.0, 2.0, 500.0, 90.0, 30.0, 0.3, 20.0])
    m = window_metrics(sums, 240, 250, {})
    assert m["episode_reward"] == 125.0
    assert m["reward/reach"] == 93.75 and m["reward/action_rate"] == 31.25
    assert m["episode_length"] == 250.0 and m["success_rate"] == 0.95
    assert m["final_distance"] == pytest.approx(0.015, rel=1e-12)
    sums["episodes"] = sums["episode_steps"] = 0.0
    assert "episode_length" not in window_metrics(sums, 240, 250, {})  # no episode ended: no mean length
    with pytest.raises(ValueError, match="layout has 9"):
        layout.named([1.0, 2.0])


def test_logger_choices_and_a_missing_wandb(monkeypatch, capsys):
    with pytest.raises(ValueError, match="unknown logger 'tb'; choices: tensorboard, wandb, none"):
        check_logger("tb")
    with pytest.raises(ValueError, match="unknown logger"):
        TrainConfig(logger="tb")  # type: ignore[arg-type]
    with pytest.raises(SystemExit) as e:
        parse_config(["--logger", "tb"])
    assert e.value.code == 2 and "tensorboard" in capsys.readouterr().err
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "wandb" else real(n, *a))
    with pytest.raises(SystemExit) as e:
        parse_config(["--logger", "wandb"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "pip install 'bar-policy[wandb]'" in err
    assert parse_config(["--logger", "none"]).logger == "none"


def test_wandb_offline_writes_a_local_run_and_the_event_files(tmp_path, monkeypatch):
    # wandb is optional (the wandb extra): this runs where it is installed. Offline, no network.
    pytest.importorskip("wandb")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from bar_policy.training.progress import RunLogger

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    logger = RunLogger(tmp_path / "run", 100, logger="wandb", stream=io.StringIO())
    logger.log(10, {"episode_reward": 1.5, "reward/reach": 1.0, "success_rate": 0.5}, kind="train")
    logger.log(20, {"episode_reward": 2.5, "reward/reach": 2.0, "success_rate": 0.75}, kind="train")
    logger.log(0, {"success_rate": 0.0, "episode_reward": 0.1}, kind="eval")  # step 0 after training
    logger.close()
    (run,) = (tmp_path / "run" / "wandb").glob("offline-run-*")
    assert list(run.glob("run-*.wandb"))  # the local run file that `wandb sync` uploads
    acc = EventAccumulator(str(tmp_path / "run" / "tb"))
    acc.Reload()
    assert [(e.step, e.value) for e in acc.Scalars("Episode_Reward/reach")] == [(10, 1.0), (20, 2.0)]
    assert [e.step for e in acc.Scalars("Eval/success_rate")] == [0]
