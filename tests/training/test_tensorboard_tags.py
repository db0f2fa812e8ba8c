"""The event files of the shared tiny runs (``conftest``: one brax and one rsl-rl run on the stand-in env):
per-term rewards, episode figures and losses under the same tags on both backends (``log_tags``)."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow

BRAX_ONLY = {"Loss/kl", "Loss/total"}
"""Tags only the brax backend's update gives (rsl-rl's ``PPO.update`` returns neither)."""


def scalars(run_dir) -> dict[str, list]:
    """Every scalar series of the run's ``tb/`` event files: tag -> [(step, value)]."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    return {t: [(e.step, e.value) for e in acc.Scalars(t)] for t in acc.Tags()["scalars"]}


def test_both_backends_write_per_term_rewards_under_the_same_tags(brax_run, rsl_run):
    (_, brax), (_, rsl) = brax_run, rsl_run
    tb = {"brax": scalars(brax.run_dir), "rsl-rl": scalars(rsl.run_dir)}
    expected = {
        "Episode_Reward/reach_left",  # the stand-in env's two reward terms (reward/<term>)
        "Episode_Reward/reach_right",
        "Train/mean_reward",
        "Train/mean_episode_length",
        "Metrics/success_rate",
        "Metrics/final_distance",
        "Loss/value_function",
        "Loss/surrogate",
        "Loss/entropy",
        "Loss/learning_rate",
        "Policy/mean_std",
        "Perf/total_fps",
        "Eval/success_rate",
        "Final/success_rate",
    }
    for name, tags in tb.items():
        assert expected <= set(tags), (name, sorted(expected - set(tags)))
    train = {n: {t for t in tags if not t.startswith(("Eval/", "Final/"))} for n, tags in tb.items()}
    assert train["brax"] - BRAX_ONLY == train["rsl-rl"]
    assert set(tb["brax"]) - BRAX_ONLY == set(tb["rsl-rl"])
    for name, tags in tb.items():
        # The terms are the reward's parts: at every record they sum to the episode reward. Each figure is
        # a float32 device sum of 10^3-10^4 terms of order 1 (relative rounding below 1e-5), scaled on the
        # host, then stored as float32 in the event file: 1e-5 relative.
        total = dict(tags["Train/mean_reward"])
        left, right = dict(tags["Episode_Reward/reach_left"]), dict(tags["Episode_Reward/reach_right"])
        assert set(total) == set(left) == set(right) and total
        for step, value in total.items():
            assert left[step] + right[step] == pytest.approx(value, rel=1e-5), (name, step)
        # The stand-in env never terminates: every episode is truncated at 0.4 s / 20 ms = 20 steps.
        assert {v for _, v in tags["Train/mean_episode_length"]} == {20.0}, name
        # Reach's rates are rates: within [0, 1] where they are reported.
        assert all(0.0 <= v <= 1.0 for _, v in tags["Metrics/success_rate"]), name


def test_rsl_rls_runner_logger_writes_into_the_run(rsl_run):
    # rsl-rl's own runner logger is on and writes into the run's tb/: its event file and the code state
    # it records (a git diff per repository it finds; this checkout's is one when run from git).
    _, summary = rsl_run
    tb = summary.run_dir / "tb"
    assert any(p.name.startswith("events.out.tfevents") for p in tb.iterdir())
    assert (tb / "git").is_dir()
