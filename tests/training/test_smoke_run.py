"""The smoke run a newcomer starts with: ``bar-train --preset tiny`` on LiteReach, on the CPU.

One run of the tiny preset (the real env, its programs compiled with ``quick_compile``) through ``run``,
as the command line runs it; its printed lines are checked: the start-up's lines about its programs
(``startup.compiler.Heartbeat``), the labelled evaluations and the final evaluation with its env steps and
what it ran on. Its wall time is a benchmark (docs/training.md, "Smoke run"), not checked here. The labels on
both backends are checked on the shared stand-in runs (``brax_run``, ``rsl_run``).
"""

from __future__ import annotations

import json
import re

import pytest

from bar_policy.training.config import apply_overrides, preset
from bar_policy.training.summary import evaluation_set, final_eval_line, summary_table

BRAX_PROGRAMS = ("reset", "rollout", "update", "init", "evaluate")
"""The brax trainer's programs (``training.brax.programs.to_compile``)."""


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> tuple:
    """``(cfg, summary, printed lines)`` of one tiny-preset run (stdout captured around ``run``)."""
    import contextlib
    import io

    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("smoke")
    cfg = apply_overrides(preset("tiny"), [f"runs_dir={tmp}", "run_name=smoke"])
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        summary = run(cfg)
    return cfg, summary, out.getvalue().splitlines()


def test_the_tiny_preset_is_a_smoke_run():
    cfg = preset("tiny")
    # Quick compiles, one batch per evaluation, one periodic evaluation (the last): 4 iterations of
    # 16 x 4 segments of 8 steps = 2,048 env steps.
    assert cfg.quick_compile and cfg.final_eval_envs == cfg.eval.num_eval_envs == 16
    assert cfg.eval.num_evals == 2 and cfg.ppo.num_timesteps == 4 * 16 * 4 * 8
    assert not preset("gpu").quick_compile and not preset("cpu").quick_compile


def test_the_suite_compiles_as_the_tiny_preset():
    """``tests/conftest.py`` writes ``QUICK_COMPILE`` out as ``XLA_FLAGS`` (it imports no package code):
    every option of the preset's is there, with its value."""
    import os

    from bar_policy.training.startup.compile_cache import QUICK_COMPILE

    flags = os.environ["XLA_FLAGS"].split()
    for name, value in QUICK_COMPILE.items():
        assert f"--{name}={str(value).lower()}" in flags, name


def test_evaluation_labels_by_hand():
    assert evaluation_set(16.0, held_out=False) == "16 fresh episodes, randomised as in training"
    held_out = "4,096 episodes of the held-out evaluation set, nominal model"
    assert evaluation_set(4096, held_out=True) == held_out
    final = {"success_rate": 0.5, "episode_reward": 12.345, "final_distance": 0.0123, "episodes": 16.0}
    assert final_eval_line(2048, "16 fresh episodes, randomised as in training", final) == (
        "final evaluation (2,048 env steps, on 16 fresh episodes, randomised as in training): "
        "success 50.0%, episode reward 12.35, final distance 1.23 cm"
    )


@pytest.mark.slow
def test_smoke_run_says_what_it_compiles_and_labels_its_evaluations(smoke):
    _, summary, lines = smoke
    assert any(s.startswith("quick compile: XLA's LLVM at -O1") for s in lines)
    # A line per program once it is ready: compiled, or loaded from the suite's persistent cache.
    ready = {}
    for s in lines:
        m = re.fullmatch(r"  program (\w+): (compiled|loaded from the compile cache) in (\d+\.\d) s", s)
        if m:
            ready[m[1]] = m[2]
    assert sorted(ready) == sorted(BRAX_PROGRAMS), lines
    # Status lines (every 5 s while a program traces or compiles) name a program and its stage.
    status = [s for s in lines if s.startswith("start-up ")]
    stage = r"(queued|tracing|lowering|compiling \(XLA\)|loading from the executable cache)"
    for s in status:
        assert re.match(rf"start-up \d+ s: \w+ {stage} \(\d+ s\)", s), s
    # Evaluations: the periodic one at the end, then the untrained policy's, labelled; nothing reads
    # "eval @ 0 steps".
    assert any(s.startswith("  eval @ 2,048 steps: success ") for s in lines)
    assert any(s.startswith("  initial evaluation (the untrained policy): success ") for s in lines)
    assert not any("eval @ 0 steps" in s for s in lines)
    # The final evaluation, labelled with its env steps and what it ran on, with the figures of the run's
    # final_eval.json (success and distance as printed: 0.1 % and 0.01 cm).
    final = json.loads((summary.run_dir / "final_eval.json").read_text())
    head = "final evaluation (2,048 env steps, on 16 fresh episodes, randomised as in training): "
    [line] = [s for s in lines if s.startswith("final evaluation (")]
    assert line.startswith(head), line
    fe = final["final_eval"]
    assert f"success {100 * fe['success_rate']:.1f}%" in line
    assert f"final distance {100 * fe['final_distance']:.2f} cm" in line
    assert final["final_eval_on"] == "16 fresh episodes, randomised as in training"
    assert summary.env_steps == 2048 and fe["episodes"] == 16.0
    # It comes after the training lines and the step-0 evaluation, before the summary table.
    at = lines.index(line)
    assert at > max(i for i, s in enumerate(lines) if s.startswith("  initial evaluation"))
    assert lines[at + 1].startswith("-----")


@pytest.mark.slow
@pytest.mark.parametrize("shared", ["brax_run", "rsl_run"])
def test_both_backends_label_the_final_evaluation(request, shared):
    cfg, summary = request.getfixturevalue(shared)
    on = f"{cfg.final_eval_envs} fresh episodes, randomised as in training"  # the stand-in: no held-out set
    assert summary.final_eval_on == on
    assert json.loads((summary.run_dir / "final_eval.json").read_text())["final_eval_on"] == on
    rows = [" ".join(r.split()) for r in summary_table(summary, cfg)]  # columns' padding out
    assert f"final evaluation {summary.env_steps:,} env steps, on {on}" in rows
