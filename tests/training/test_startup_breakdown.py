"""The start-up breakdown: exclusive main-thread phases, the env's model-build row, the run record."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from bar_policy._phases import MODEL_BUILD, PhaseClock, phase
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.breakdown import PHASES, ProgramTimes, StartupTimer

ROUNDING_S = 0.001 * (len(PHASES) + 2)
"""Tolerance of sums over the record: each value is rounded to 1 ms (half a ms of error each, and a few
phases beyond ``PHASES`` at most)."""


def test_nested_phases_are_exclusive_and_other_threads_record_nothing():
    clock = PhaseClock()
    t0 = time.monotonic()
    with clock.phase("outer"):
        time.sleep(0.02)
        with clock.phase("inner"):
            time.sleep(0.05)
        clock.add("measured", 0.01)  # taken out of "outer" like a nested phase

        def work() -> None:
            with clock.phase("worker"):
                time.sleep(0.01)

        worker = threading.Thread(target=work)
        worker.start()
        worker.join()
    wall = time.monotonic() - t0
    s = clock.seconds
    assert set(s) == {"outer", "inner", "measured"}
    assert s["inner"] >= 0.05 and s["measured"] == 0.01
    # outer = its wall less inner and measured: at least its own 20 ms sleep, and the three add up to
    # no more than the wall time around them.
    assert s["outer"] >= 0.02 - 0.01  # less the 10 ms that add() claimed
    assert s["outer"] + s["inner"] + s["measured"] <= wall + 1e-9


def test_module_phase_records_only_into_the_active_clock():
    with phase(MODEL_BUILD):  # no clock active: nothing to record into, no error
        pass
    clock = PhaseClock()
    with clock.active(), phase(MODEL_BUILD):
        time.sleep(0.01)
    with phase(MODEL_BUILD):  # deactivated again
        time.sleep(0.05)
    assert 0.01 <= clock.seconds[MODEL_BUILD] < 0.05


def test_model_build_of_a_real_env_is_its_own_row():
    """``LiteRobotEnv`` marks the MJCF compile and ``mjx.put_model``; the env row keeps the rest."""
    from bar_policy import envs

    timer = StartupTimer()
    t0 = time.monotonic()
    with timer.active(), timer.phase(sb.ENV_BUILD):
        env = envs.load("LiteReach")
    wall = time.monotonic() - t0
    assert env.mjx_model is not None
    assert timer.phases[MODEL_BUILD] > 0 and timer.phases[sb.ENV_BUILD] >= 0
    assert timer.phases[MODEL_BUILD] + timer.phases[sb.ENV_BUILD] <= wall + 1e-9


def test_record_names_every_phase_and_its_rows_add_up():
    timer = StartupTimer(origin=time.monotonic() - 10.0, origin_name="process start")
    timer.add(sb.BEFORE_RUN, 1.0)
    timer.add(sb.TRACE, 2.5)
    timer.add("a backend's own phase", 0.5)
    timer.programs["epoch"] = ProgramTimes(trace_s=2.5, lower_s=0.5, compile_s=3.0, cache_requests=1)
    timer.programs["evaluate"] = ProgramTimes(
        thread="worker", trace_s=1.0, compile_s=0.2, cache_requests=1, cache_hits=1, cache_load_s=0.15
    )
    rec = timer.finish(
        7.0,
        {"compiles": 2, "compile_s": 3.2, "cache_hits": 1, "cache_misses": 0, "cache_load_s": 0.15},
        total_s=9.0,
    )
    assert timer.report is rec and rec["until"] == sb.UNTIL_EVAL  # the default: ended by the evaluation
    assert set(PHASES) <= set(rec["phases"]) and "a backend's own phase" in rec["phases"]
    assert list(rec["phases"])[-1] == sb.OTHER
    # 9 s in all, 1 + 2.5 + 0.5 named: the other 5 s are the OTHER row.
    assert rec["phases"][sb.OTHER] == 5.0 and sum(rec["phases"].values()) == 9.0
    assert rec["programs"]["epoch"]["cache"] == "miss, not stored"
    assert rec["programs"]["evaluate"]["cache"] == "hit" and rec["programs"]["evaluate"]["thread"] == "worker"
    lines = StartupTimer.lines(rec)
    assert lines[0] == (
        "start-up: 9.0 s from process start to the first evaluation (first epoch done at 7.0 s)"
    )
    assert any(line.split()[-2:] == ["5.00", "s"] and sb.OTHER in line for line in lines)
    assert any(line.split()[:2] == ["evaluate", "worker"] and "hit (0.15 s load)" in line for line in lines)
    assert lines[-1].strip() == (
        "XLA compiles: 2 (3.2 s summed over threads); persistent cache 1 hits (0.15 s loading) / 0 misses"
    )
    assert json.loads(json.dumps(rec)) == rec


def test_a_start_up_without_an_evaluation_prints_no_evaluation_rows():
    # eval.initial=end or off, or a resume: the start-up ends with the first epoch.
    timer = StartupTimer(origin=time.monotonic() - 5.0, origin_name="process start")
    timer.add(sb.TRACE, 2.0)
    timer.add(sb.FIRST_EPOCH, 1.5)
    rec = timer.finish(4.5, total_s=5.0, until=sb.UNTIL_EPOCH)
    # The record keeps every phase (0.0 for the evaluation's two) and says where the start-up ended ...
    assert rec["until"] == sb.UNTIL_EPOCH and set(PHASES) <= set(rec["phases"])
    assert rec["phases"][sb.FIRST_EVAL] == rec["phases"][sb.MORE_EPOCHS] == 0.0
    # ... and the table leaves those two out instead of showing an evaluation that took 0 s; the rows
    # still add up to the total (2 + 1.5 named, 1.5 other).
    lines = StartupTimer.lines(rec)
    assert lines[0] == (
        "start-up: 5.0 s from process start to the end of the first epoch (done at 4.5 s; no evaluation "
        "before training)"
    )
    text = "\n".join(lines)
    assert sb.FIRST_EVAL not in text and sb.MORE_EPOCHS not in text and sb.FIRST_EPOCH in text
    assert any(sb.OTHER in line and line.split()[-2:] == ["1.50", "s"] for line in lines)
    # A record from before ``until`` existed ended at the first evaluation, rows and all.
    old = {k: v for k, v in StartupTimer().finish(1.0, total_s=2.0).items() if k != "until"}
    assert "to the first evaluation" in StartupTimer.lines(old)[0]
    assert any(sb.FIRST_EVAL in line for line in StartupTimer.lines(old))


@pytest.mark.parametrize(
    ("hits", "misses", "requests", "expected"),
    [(1, 0, 1, "hit"), (0, 1, 1, "miss"), (0, 0, 1, "miss, not stored"), (0, 0, 0, "off")],
)
def test_program_cache_outcome(hits, misses, requests, expected):
    assert ProgramTimes(cache_hits=hits, cache_misses=misses, cache_requests=requests).cache == expected


def test_a_run_records_its_startup_breakdown(brax_run, run_walls):
    _, summary = brax_run
    run_dir = Path(summary.run_dir)
    recs = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    (logged,) = [r for r in recs if r["kind"] == "startup"]
    rec = json.loads((run_dir / "final_eval.json").read_text())["startup"]
    assert {k: logged[k] for k in rec} == rec  # the same record in both files
    assert rec["origin"] == "run() call"
    phases = rec["phases"]
    assert set(PHASES) <= set(phases)
    assert all(v >= 0 for v in phases.values())
    # The stand-in env is handed to run(): no model to build. Everything else of a brax start happened
    # (the imports too, but in a test process they are done before, and may round to 0 ms).
    assert phases[MODEL_BUILD] == 0.0 and phases[sb.BEFORE_RUN] == 0.0
    for name in (sb.RUN_RECORD, sb.PROGRAMS, sb.TRACE, sb.LOWER, sb.FIRST_EPOCH):
        assert phases[name] > 0, name
    # eval.initial=end (the default): the start-up ends with the first epoch; no evaluation in it (with
    # start, tests/training/test_initial_eval.py).
    assert rec["until"] == sb.UNTIL_EPOCH and phases[sb.FIRST_EVAL] == phases[sb.MORE_EPOCHS] == 0.0
    # The rows add up to the total, which lies inside the wall time measured around run().
    assert sum(phases.values()) == pytest.approx(rec["total_s"], abs=ROUNDING_S)
    assert 0 < rec["first_epoch_end_s"] <= rec["total_s"] <= run_walls["brax"] + ROUNDING_S
    # Five programs: init, reset, rollout and update traced on the main thread, the evaluation on a worker;
    # the main thread's trace row is the sum of their traces.
    progs = rec["programs"]
    assert set(progs) == {"init", "reset", "rollout", "update", "evaluate"}
    assert [k for k, p in progs.items() if p["thread"] == "worker"] == ["evaluate"]
    main = [p for p in progs.values() if p["thread"] == "main"]
    assert sum(p["trace_s"] for p in main) == pytest.approx(phases[sb.TRACE], abs=ROUNDING_S)
    outcomes = ("hit", "miss", "miss, not stored")
    assert all(p["compile_s"] > 0 and p["cache"] in outcomes for p in progs.values())
    # Four programs, plus at most a few tiny ones jax needs (the pmap trainer compiled ~85 here).
    assert 4 <= rec["compiles"]["compiles"] <= 8
    # In the record: the first epoch, the report, the periodic evaluations, then the step-0 one.
    kinds = [r["kind"] for r in recs]
    assert kinds.index("train") < recs.index(logged) < kinds.index("eval")
    assert [r["step"] for r in recs if r["kind"] == "eval"][-1] == 0


def test_an_rsl_rl_run_records_its_startup_breakdown(rsl_run):
    _, summary = rsl_run
    run_dir = Path(summary.run_dir)
    recs = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    (logged,) = [r for r in recs if r["kind"] == "startup"]
    rec = json.loads((run_dir / "final_eval.json").read_text())["startup"]
    assert {k: logged[k] for k in rec} == rec
    phases = rec["phases"]
    assert set(PHASES) <= set(phases) and all(v >= 0 for v in phases.values())
    # Where an rsl-rl start goes: its jax programs (both envs' resets and steps and the evaluation's quality
    # reduction, traced and lowered on this thread: the TRACE and LOWER rows, taken out of the programs
    # row), then torch's imports (done before in a test process: the row is there, maybe 0 ms), the wait
    # for the training reset and its run, the runner and the first iteration (the FIRST_EPOCH row); the
    # step-0 evaluation runs after training (eval.initial=end), outside the start-up. No brax program is
    # built.
    for name in (sb.RSL_PROGRAMS, sb.RSL_RESET, sb.RSL_RUNNER, sb.TRACE, sb.LOWER, sb.FIRST_EPOCH):
        assert phases[name] > 0, name
    assert rec["until"] == sb.UNTIL_EPOCH and phases[sb.FIRST_EVAL] == phases[sb.MORE_EPOCHS] == 0.0
    assert sb.RSL_IMPORTS in phases and phases[sb.PROGRAMS] == 0.0
    progs = rec["programs"]
    assert set(progs) == {"train reset", "train step", "eval reset", "eval step", "eval quality"}
    assert all(p["thread"] == "main" for p in progs.values())
    # Finished once the evaluation's programs were ready: no row is a program still compiling on a worker.
    assert all(p["compile_s"] > 0 for p in progs.values()), progs
    assert sum(p["trace_s"] for p in progs.values()) == pytest.approx(phases[sb.TRACE], abs=ROUNDING_S)
    order = list(logged["phases"])  # metrics.jsonl keeps the print order (final_eval.json sorts its keys)
    happened = [sb.PROGRAMS, sb.RSL_PROGRAMS, sb.TRACE, sb.LOWER, sb.RSL_IMPORTS, sb.RSL_RESET, sb.RSL_RUNNER]
    assert [order.index(k) for k in happened] == sorted(order.index(k) for k in happened)
    assert order.index(sb.RSL_RUNNER) < order.index(sb.WAIT) and order[-1] == sb.OTHER
    # The rows add up to the total: each row is rounded to 1 ms (ROUNDING_S allows a few ms over all of
    # them). The report is finished after the first iteration where the evaluation's programs are ready.
    assert sum(phases.values()) == pytest.approx(rec["total_s"], abs=ROUNDING_S)
    assert 0 < rec["first_epoch_end_s"] <= rec["total_s"]
    # In the record: the first iteration, the report, the periodic evaluations, then the step-0 one.
    kinds = [r["kind"] for r in recs]
    assert kinds.index("train") < recs.index(logged) < kinds.index("eval")
    assert [r["step"] for r in recs if r["kind"] == "eval"][-1] == 0
