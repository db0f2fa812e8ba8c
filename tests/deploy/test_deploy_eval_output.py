"""``bar-deploy eval``'s output: a progress line per episode, repeated warnings counted once, ``--quiet``."""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pytest
from policy_factory import default_metadata

from bar_policy.deploy.cli import main
from bar_policy.deploy.warning_tally import WarningTally
from bar_policy.robot.constants import load_robot

PROGRESS = re.compile(
    r"^eval episode (\d+)/(\d+): seed (\d+), (\d+)/(\d+) segments reached, farthest segment end "
    r"([\d.]+|inf) cm(, faulted)? \(([\d.]+) s\)$"
)


def test_a_progress_line_per_episode_with_its_figure(policy_path, tmp_path, capsys):
    out_json = tmp_path / "eval.json"
    argv = ["eval", "--policy", str(policy_path), "--episodes", "3", "--seed", "5", "--episode-length", "0.2"]
    assert main([*argv, "--json", str(out_json)]) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("eval episode")]
    data = json.loads(out_json.read_text())["episodes"]
    assert len(lines) == 3
    elapsed = []
    for i, (line, ep) in enumerate(zip(lines, data, strict=True)):
        m = PROGRESS.match(line)
        assert m, line
        assert (int(m[1]), int(m[2]), int(m[3])) == (i + 1, 3, 5 + i)
        # The figure is the episode's own, as the result file has it.
        assert (int(m[4]), int(m[5])) == (ep["successes"], ep["segments"])
        farthest = 100 * max(max(ep["dist_left"]), max(ep["dist_right"]))
        assert abs(float(m[6]) - farthest) <= 0.05 + 1e-9  # printed to 0.1 cm
        elapsed.append(float(m[8]))
    assert elapsed == sorted(elapsed)  # time since the start, growing


def test_quiet_prints_no_progress_but_the_result(policy_path, capsys):
    argv = ["eval", "--policy", str(policy_path), "--episodes", "2", "--episode-length", "0.2", "--quiet"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "eval episode" not in out and "success rate 0.0 %" in out


def test_clip_warnings_are_counted_into_one_line(make_policy, tmp_path, capsys):
    # A constant action of +-1 toward each joint's nearer limit, scaled to pass it by 0.3 rad (the loader
    # allows 0.5): every q_cmd is past its limit, so the supervisor clips all 14 joints from the first tick
    # and warns once per joint and episode: 14 x 2 episodes = 28 warnings of one kind.
    robot = load_robot("arms")
    n = robot.num_joints
    default = np.asarray(default_metadata().default_joint_pos)
    up, down = robot.upper - default, default - robot.lower
    scale = tuple(float(x) for x in np.minimum(up, down) + 0.3)
    bias = np.where(up <= down, 1.0, -1.0).astype(np.float32)
    path = make_policy(metadata=default_metadata(action_scale=scale), bias=bias)
    out_json = tmp_path / "eval.json"
    argv = ["eval", "--policy", str(path), "--episodes", "2", "--episode-length", "0.1"]
    assert main([*argv, "--json", str(out_json)]) == 0
    captured = capsys.readouterr()
    text = captured.out + captured.err
    # Not one line per warning: one summary line with the count at its end.
    assert text.count("clipped to its limit") == 1
    line = next(x for x in text.splitlines() if "clipped to its limit" in x).strip()
    assert line.startswith("WARNING bar_policy.deploy.safety: q_cmd of ") and line.endswith(f"[x{2 * n}]")
    kinds = json.loads(out_json.read_text())["warnings"]
    clip = next(k for k in kinds if k["template"].startswith("q_cmd of %s clipped to its limit"))
    assert clip["count"] == 2 * n and clip["logger"] == "bar_policy.deploy.safety"
    total = sum(k["count"] for k in kinds)
    assert f"warnings: {total} in {len(kinds)} kind(s)" in text


def test_the_tally_counts_each_record_once_and_passes_the_rest():
    logger = logging.getLogger("bar_policy.test_tally")
    root = logging.getLogger()
    seen: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage())

    handlers = [Keep(), Keep()]  # a record goes to both: still counted once
    for h in handlers:
        root.addHandler(h)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    try:
        with WarningTally() as tally:
            for i in range(64):
                logger.warning("joint %d clipped", i)
            logger.error("bus down")
            logger.info("episode done")
        logger.warning("after")  # the tally is gone: passes
    finally:
        logger.setLevel(old_level)
        for h in handlers:
            root.removeHandler(h)
    assert seen == ["episode done", "episode done", "after", "after"]
    assert tally.total == 65
    assert tally.lines() == [
        "WARNING bar_policy.test_tally: joint 0 clipped [x64]",
        "ERROR bar_policy.test_tally: bus down [x1]",
    ]
    assert [k["count"] for k in tally.to_dict()] == [64, 1]


def test_reach_gate_report_holds_the_median_end_distance_over_both_hands():
    """Worked by hand: segment ends at 0.1, 0.5 cm (left) and 0.2, 0.9 cm (right) in one episode, 0.3 and
    0.4 cm in another: six distances, median (0.3 + 0.4) / 2 = 0.35 cm."""
    from bar_policy.tasks.reach.evaluate import EpisodeResult, EvalConfig, EvalResult

    def ep(left: list[float], right: list[float]) -> EpisodeResult:
        return EpisodeResult(0, len(left), len(left), left, right, False, "duration reached")

    res = EvalResult(EvalConfig(), [ep([0.001, 0.005], [0.002, 0.009]), ep([0.003], [0.004])], "x.onnx", "f")
    assert res.gate_report()["median_end_cm"] == pytest.approx(0.35, abs=1e-12)
    assert EvalResult(EvalConfig(), [ep([], [])], "x.onnx", "f").median_end_cm() is None
