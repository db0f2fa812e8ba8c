"""When the untrained policy is evaluated (``eval.initial``: start, end, off), on both backends.

The ``end`` runs are the shared ones (``brax_run``, ``rsl_run``: the default); the ``start`` and ``off``
runs are shorter (one brax epoch, two rsl-rl iterations) on the same programs, so they load from the
compile cache the shared runs filled.
"""

from __future__ import annotations

import json

import pytest
from script_modules import load_bench
from toy_configs import TOY_BRAX, TOY_RSL, toy_config

from bar_policy.training.evaluations import Evaluations
from bar_policy.training.progress import RunLogger
from bar_policy.training.startup import breakdown as sb

SHORT = {"brax": "ppo.num_timesteps=133120", "rsl": "ppo.num_timesteps=512"}
"""One epoch of 13 iterations of 10,240 env steps (brax); two iterations of 256 (rsl-rl)."""

STEPS = {
    # In metrics.jsonl, as they ran. brax: an evaluation every 2 epochs of 13 iterations and at the end;
    # rsl-rl: every 5 of 10 iterations (every 1 of 2 in the short runs).
    "brax": {"end": [266240, 532480, 0], "start": [0, 133120], "off": [133120]},
    "rsl": {"end": [1280, 2560, 0], "start": [0, 256, 512], "off": [256, 512]},
}


@pytest.fixture(scope="module")
def mode_runs(request, tmp_path_factory, toy_env) -> dict:
    """backend -> mode -> (cfg, summary): the shared ``end`` run and a short ``start`` and ``off`` run."""
    from bar_policy.training.run import run

    out: dict = {}
    for backend, shared, toy in (("brax", "brax_run", TOY_BRAX), ("rsl", "rsl_run", TOY_RSL)):
        out[backend] = {"end": request.getfixturevalue(shared)}
        for mode in ("start", "off"):
            tmp = tmp_path_factory.mktemp(f"{backend}-{mode}")
            extra = [*toy, SHORT[backend], f"eval.initial={mode}", "export_onnx=False"]
            cfg = toy_config(tmp, f"{backend}-{mode}", extra)
            out[backend][mode] = (cfg, run(cfg, env=toy_env))
    return out


def _records(summary) -> list[dict]:
    return [json.loads(x) for x in (summary.run_dir / "metrics.jsonl").read_text().splitlines()]


def _metrics(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "time_s"}


def test_evaluations_keep_step_order_and_a_late_step_0_out_of_the_time_to_threshold(tmp_path):
    logger = RunLogger(tmp_path, 300, enabled=False)  # writes nothing; the evaluations are still kept

    def record(evals: Evaluations, step: int, success: float) -> None:
        logger.follow(evals.record(step, {"success_rate": success, "episode_reward": 1.0}, lambda: None, ""))

    evals = Evaluations(0, None, 0.95)
    for step, success in ((100, 0.5), (200, 0.97), (300, 0.99), (0, 1.0)):
        record(evals, step, success)
    assert [e["step"] for e in evals.records] == [0, 100, 200, 300]
    # step 200's: the first at >= 95 %, in the order they ran
    assert evals.time_to_threshold_s == evals.records[2]["time_s"]
    # A late step 0 that alone reaches the threshold does not count: no trained policy reached it.
    evals = Evaluations(0, None, 0.95)
    for step, success in ((100, 0.5), (0, 1.0)):
        record(evals, step, success)
    assert [e["step"] for e in evals.records] == [0, 100] and evals.time_to_threshold_s is None
    # In step order (eval.initial=start), step 0 counts as before.
    evals = Evaluations(0, None, 0.95)
    record(evals, 0, 1.0)
    assert evals.time_to_threshold_s == evals.records[0]["time_s"]


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["brax", "rsl"])
@pytest.mark.parametrize("mode", ["start", "end", "off"])
def test_evaluation_steps_by_mode(mode_runs, backend, mode):
    cfg, summary = mode_runs[backend][mode]
    assert cfg.eval.initial == mode
    recs = _records(summary)
    ran = [r["step"] for r in recs if r["kind"] == "eval"]
    assert ran == STEPS[backend][mode]
    # The run's list (result and final_eval.json) is in step order: step 0 first, whenever it ran.
    final = json.loads((summary.run_dir / "final_eval.json").read_text())
    assert [e["step"] for e in summary.result.evals] == sorted(ran)
    assert [e["step"] for e in final["evals"]] == sorted(ran)
    assert summary.best["step"] != 0  # offered, never a candidate


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["brax", "rsl"])
def test_step_0_metrics_do_not_depend_on_when_it_runs(mode_runs, backend):
    """Same seed: the same initial parameters, evaluation keys and evaluation env, whether the step-0
    evaluation ran after the first epoch or after the last: the same numbers, to the bit (one program on
    the same inputs)."""
    start = mode_runs[backend]["start"][1].result.evals[0]
    end = mode_runs[backend]["end"][1].result.evals[0]
    assert start["step"] == end["step"] == 0
    assert _metrics(start) == _metrics(end)
    assert len(_metrics(end)) >= 4  # step, reward (mean, std), success, ...


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["brax", "rsl"])
def test_end_runs_the_step_0_evaluation_after_training(mode_runs, backend):
    _, summary = mode_runs[backend]["end"]
    recs = _records(summary)
    kinds = [r["kind"] for r in recs]
    step0 = next(i for i, r in enumerate(recs) if r["kind"] == "eval" and r["step"] == 0)
    last_train = max(i for i, k in enumerate(kinds) if k == "train")
    last_periodic = max(i for i, r in enumerate(recs) if r["kind"] == "eval" and r["step"] > 0)
    # After the last epoch and the last periodic evaluation (and its time with them), before the final.
    assert last_train < last_periodic < step0 < kinds.index("final")
    assert recs[step0]["time_s"] >= recs[last_periodic]["time_s"]
    # The start-up ended with the first epoch, before any evaluation, and holds none.
    (startup,) = [r for r in recs if r["kind"] == "startup"]
    assert kinds.index("train") < recs.index(startup) < kinds.index("eval")
    assert startup["until"] == sb.UNTIL_EPOCH and startup["phases"][sb.FIRST_EVAL] == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["brax", "rsl"])
def test_start_runs_it_first_and_in_the_start_up(mode_runs, backend):
    _, summary = mode_runs[backend]["start"]
    recs = _records(summary)
    kinds = [r["kind"] for r in recs]
    (startup,) = [r for r in recs if r["kind"] == "startup"]
    first_eval = kinds.index("eval")
    # After the first epoch (iteration), before the report, which counts it.
    assert recs[first_eval]["step"] == 0
    assert kinds.index("train") < first_eval < recs.index(startup)
    assert startup["until"] == sb.UNTIL_EVAL and startup["phases"][sb.FIRST_EVAL] > 0
    assert startup["total_s"] - startup["first_epoch_end_s"] >= startup["phases"][sb.FIRST_EVAL] - 0.002


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["brax", "rsl"])
def test_off_has_no_step_0_evaluation(mode_runs, backend):
    _, summary = mode_runs[backend]["off"]
    recs = _records(summary)
    (startup,) = [r for r in recs if r["kind"] == "startup"]
    assert startup["until"] == sb.UNTIL_EPOCH and startup["phases"][sb.FIRST_EVAL] == 0.0
    assert all(e["step"] > 0 for e in summary.result.evals)


def test_readers_of_metrics_jsonl_take_a_late_step_0_as_step_0(tmp_path):
    """A run with eval.initial=end writes its step-0 evaluation last. By hand: evaluations at 1M (40 %,
    at 50 s), 2M (96 %, at 80 s), then step 0 (100 %, at 90 s: a toy untrained policy that succeeds)."""
    from bar_policy.training.publish import _time_axis

    rows = [
        {"kind": "train", "step": 1_000_000, "time_s": 45.0, "sps": 1.0, "success_rate": 0.3},
        {"kind": "eval", "step": 1_000_000, "time_s": 50.0, "success_rate": 0.4, "episode_reward": 1.0},
        {"kind": "eval", "step": 2_000_000, "time_s": 80.0, "success_rate": 0.96, "episode_reward": 2.0},
        {"kind": "eval", "step": 0, "time_s": 90.0, "success_rate": 1.0, "episode_reward": 3.0},
        {"kind": "final", "step": 2_000_000, "time_s": 95.0, "success_rate": 0.97},
    ]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    # The session table's time to 95 %: the 2M evaluation at 80 s, as the run's own figure (not step 0).
    row = load_bench("session_summary").summarize(tmp_path)
    assert row["to 95% s"] == "80" and row["steps at 95%"] == "2,000,000"
    # The tracking tables: evaluations in step order, then the final one.
    got = [(r["kind"], r["step"]) for r in load_bench("track_curves").evaluations(tmp_path)]
    assert got == [("eval", 0), ("eval", 1_000_000), ("eval", 2_000_000), ("final", 2_000_000)]
    # The curve's time axis runs through 1M -> 50 s and 2M -> 80 s, not through step 0's 90 s.
    evals = sorted((r for r in rows if r["kind"] == "eval"), key=lambda r: r["step"])
    to_time, to_steps = _time_axis(evals)
    assert to_time(1.5) == pytest.approx(65.0) and to_steps(65.0) == pytest.approx(1.5)
