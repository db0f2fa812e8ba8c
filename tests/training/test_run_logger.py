"""RunLogger's per-epoch and per-evaluation calls: what each records, prints and answers.

The trainers yield one ``Epoch`` record per epoch (``epoch_end``: the train record, the budget check, the
progress line) and one ``Evaluated`` per evaluation (kept, and offered to the best keeper, by
``Evaluations``); these tests hold the lines and records they write against values worked out by hand.
"""

from __future__ import annotations

import io
import json
import time
from pathlib import Path

from bar_policy.training.evaluations import Evaluations
from bar_policy.training.progress import RunLogger


def _logger(tmp_path: Path, elapsed_s: float) -> tuple[RunLogger, io.StringIO]:
    """A logger 1000 env steps long, no scalar writer, started ``elapsed_s`` ago."""
    out = io.StringIO()
    logger = RunLogger(tmp_path, 1000, stream=out, logger="none")
    logger.t0 = time.monotonic() - elapsed_s
    return logger, out


def _records(tmp_path: Path) -> list[dict]:
    return [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]


def test_epoch_end_records_the_epoch_prints_its_line_and_answers_the_budget(tmp_path: Path) -> None:
    # 30.2 s in: format_duration rounds to 30 s as long as the test takes under 0.3 s between here and the
    # line. 250 of 1000 steps at 50 steps/s: 25 %, ETA (1000 - 250) / 50 = 15 s.
    logger, out = _logger(tmp_path, 30.2)
    over = logger.epoch_end(250, {"sps": 50.0, "episode_reward": 1.5}, next_s=20.0, budget_s=60.0)
    assert over is False  # 30.2 + 20 = 50.2 s <= 60 s
    assert out.getvalue() == "[ 25%] 250/1k steps | 50 steps/s | reward 1.50 | 30s, ETA 15s\n"
    (rec,) = _records(tmp_path)
    assert (rec["kind"], rec["step"], rec["sps"], rec["episode_reward"]) == ("train", 250, 50.0, 1.5)
    # 30.2 + 40 = 70.2 s > 60 s: the next epoch would end past the budget.
    assert logger.epoch_end(500, {"sps": 50.0}, next_s=40.0, budget_s=60.0) is True
    # No budget (0) never stops.
    assert logger.epoch_end(750, {"sps": 50.0}, next_s=1e9, budget_s=0.0) is False


def test_epoch_end_prints_a_line_only_when_due_or_at_the_budget(tmp_path: Path) -> None:
    logger, out = _logger(tmp_path, 10.2)
    calls: list[int] = []

    def line() -> tuple[float, dict[str, float]]:
        calls.append(1)
        return 100.0, {"success_rate": 0.5}

    # Not due, inside the budget (10.2 + 1 <= 60): recorded, no line, the line's window left untouched.
    assert not logger.epoch_end(100, {"sps": 80.0}, next_s=1.0, budget_s=60.0, line=line, line_due=False)
    assert out.getvalue() == "" and calls == [] and len(_records(tmp_path)) == 1
    # Not due, but the budget is reached (10.2 + 55 > 60): the last line is printed, from ``line``
    # (100 steps/s over its window, not the record's 80): ETA (1000 - 200) / 100 = 8 s; the notes first.
    over = logger.epoch_end(
        200, {"sps": 80.0}, next_s=55.0, budget_s=60.0, line=line, line_due=False, notes=["  a note"]
    )
    assert over and calls == [1]
    assert out.getvalue() == "  a note\n[ 20%] 200/1k steps | 100 steps/s | success 50.0% | 10s, ETA 8s\n"


def test_an_evaluation_is_recorded_then_offered_and_the_keepers_line_printed(tmp_path: Path) -> None:
    logger, out = _logger(tmp_path, 5.0)
    offered: list[dict[str, float]] = []
    evaluations = Evaluations(0, None, 0.9)

    def offer(step: int, m: dict[str, float], snapshot: object) -> bool:
        offered.append(dict(m))
        return m["success_rate"] > 0.5

    evaluations.keeper.offer = offer  # type: ignore[method-assign]
    for step, m in (
        (100, {"success_rate": 0.25, "episode_reward": 2.0}),
        (200, {"success_rate": 0.75, "episode_reward": 3.0}),
    ):
        logger.follow(evaluations.record(step, m, lambda: None, "  best so far"))
    assert out.getvalue() == (
        "  eval @ 100 steps: success 25.0%, episode reward 2.00\n"
        "  eval @ 200 steps: success 75.0%, episode reward 3.00\n"
        "  best so far\n"
    )
    # The keeper sees the record as logged, its time included.
    assert [sorted(m) for m in offered] == [["episode_reward", "success_rate", "time_s"]] * 2
    assert [e["step"] for e in evaluations.records] == [100, 200] and evaluations.time_to_threshold_s is None


def test_resumed_names_the_checkpoint_and_each_changed_setting(tmp_path: Path) -> None:
    logger, out = _logger(tmp_path, 0.0)
    logger.resumed(tmp_path / "step_1.msgpack", 512, 4, ["resume: 1 settings differ", "  train seed: 0 -> 1"])
    assert out.getvalue() == (
        f"resumed {tmp_path / 'step_1.msgpack'} at 512 env steps (iteration 4)\n"
        "resume: 1 settings differ\n  train seed: 0 -> 1\n"
    )
