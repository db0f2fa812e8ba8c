"""Every ``bar-deploy`` run ends with its task's figure: reach success and final distance, track errors.

The figures printed after the ``end:`` line are checked against the run log (the measured joints, the
commands and the reference frames the runtime recorded), recomputed here with the robot's kinematics;
the segment rule is checked by hand on a stand-in runtime.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.safety_config import Mode
from bar_policy.deploy.tasks import get_task
from bar_policy.robot.kinematics import Kinematics
from bar_policy.tasks.reach.run_figure import ReachRunFigure

REPO = Path(__file__).resolve().parents[2]
REACH = REPO / "checkpoints" / "lite_reach_arms.onnx"
TRACK = REPO / "checkpoints" / "lite_track_arms.onnx"


def _run(argv: list[str], tmp_path: Path, capsys) -> tuple[list[str], dict[str, np.ndarray]]:
    assert main([*argv, "--ramp-time", "1", "--log", str(tmp_path / "runs")]) == 0
    out = capsys.readouterr().out.splitlines()
    (run_dir,) = (tmp_path / "runs").iterdir()
    arrays, _ = load_log(run_dir)
    return out, arrays


def test_a_reach_run_ends_with_success_rate_and_final_distance(tmp_path, capsys):
    # 1 s ramp, then 7 s of policy: targets resampled every 1.5 s, each reached by a 1 s glide.
    out, a = _run(["--policy", str(REACH), "--duration", "8", "--commands", "sampled:1.5"], tmp_path, capsys)
    end = next(i for i, x in enumerate(out) if x.startswith("end: "))
    line = out[end + 1]  # the figure follows the end: line
    m = re.fullmatch(
        r"reach: (\d+)/(\d+) segment ends within 3 cm \(([\d.]+) %\); final distance left ([\d.]+) cm, "
        r"right ([\d.]+) cm",
        line,
    )
    assert m, line
    # From the log: the POLICY ticks' measured joints and targets; a segment is a stretch of one target
    # pair held 0.2 s (10 ticks) or longer, scored on its last tick.
    policy = a["mode"] == Mode.POLICY
    q, tl, tr = a["q"][policy], a["target_pos_left"][policy], a["target_pos_right"][policy]
    kin = Kinematics("arms")
    tips = np.array([kin.fingertips(x) for x in q])  # (ticks, 2, 3)
    dl = np.linalg.norm(tips[:, 0] - tl, axis=1)
    dr = np.linalg.norm(tips[:, 1] - tr, axis=1)
    targets = np.concatenate([tl, tr], axis=1)
    change = np.flatnonzero(np.any(targets[1:] != targets[:-1], axis=1)) + 1
    bounds = np.concatenate([[0], change, [len(targets)]])
    ends = [e - 1 for s, e in itertools.pairwise(bounds) if e - s >= 10]
    ok = sum(max(dl[i], dr[i]) < 0.03 for i in ends)
    assert (int(m[1]), int(m[2])) == (ok, len(ends))
    # 7 s of policy at a 1.5 s period: four whole periods, each a 1 s glide then a 0.5 s hold (scored), and a
    # last second that is all glide (not scored).
    assert len(ends) == 4
    assert float(m[3]) == pytest.approx(100 * ok / len(ends), abs=0.05)  # printed to 0.1 %
    assert float(m[4]) == pytest.approx(100 * dl[-1], abs=0.05)  # printed to 0.1 cm
    assert float(m[5]) == pytest.approx(100 * dr[-1], abs=0.05)
    assert ok == len(ends)  # the shipped reach policy reaches every held target (it passes its gate)


def test_a_track_run_ends_with_its_tracking_errors(tmp_path, capsys):
    out, a = _run(["--policy", str(TRACK), "--motion", "wave"], tmp_path, capsys)
    end = next(i for i, x in enumerate(out) if x.startswith("end: "))
    m = re.fullmatch(
        r"track \(wave\): mean joint error ([\d.]+) rad, tracked-body position error ([\d.]+) cm, fingertip "
        r"error ([\d.]+) cm, success ([\d.]+) % of (\d+) policy ticks",
        out[end + 1],
    )
    assert m, out[end + 1]
    # From the log: each POLICY tick's measured joints against the frame after the one it logged.
    from bar_policy.deploy.policy import load_policy
    from bar_policy.tasks.track.reference import load_motion, reference_for

    ref = reference_for(load_policy(TRACK), load_motion("wave"))
    policy = a["mode"] == Mode.POLICY
    frames = np.minimum(a["ref_frame"][policy].astype(int) + 1, ref.last)
    q = a["q"][policy]
    joint = np.mean(np.abs(q - ref.table.joint_pos[frames]), axis=1)
    kin = Kinematics("arms")
    tips = np.array([kin.fingertips(x) for x in q])
    tip = np.mean(np.linalg.norm(tips - ref.table.fingertip_pos[frames], axis=-1), axis=1)
    assert int(m[5]) == policy.sum() == 340  # the 6.8 s clip at 50 Hz: 341 frames, 340 policy ticks
    assert float(m[1]) == pytest.approx(joint.mean(), abs=5e-5 + 1e-9)  # printed to 1e-4 rad
    assert float(m[3]) == pytest.approx(100 * tip.mean(), abs=5e-3 + 1e-9)  # printed to 0.01 cm


class _Tips:
    """Stand-in kinematics: the left fingertip is q[0:3], the right q[3:6] (m)."""

    def fingertips(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return q[0:3], q[3:6]


def _tick(left_target, right_target, left_tip, right_tip, mode=Mode.POLICY):
    return SimpleNamespace(
        safety=SimpleNamespace(mode=mode),
        last_state=SimpleNamespace(q=np.array([*left_tip, *right_tip], float)),
        last_commands={
            "target_pos_left": np.array(left_target, float),
            "target_pos_right": np.array(right_target, float),
        },
    )


def test_the_reach_segment_rule_by_hand():
    # 0.1 s ticks: a segment counts from 2 ticks (0.2 s). Segment A (3 ticks) ends 1 and 2 cm away: a
    # success; a 1-tick glide is not scored; segment B (2 ticks) ends 5 cm away on the left: a miss.
    fig = ReachRunFigure(_Tips(), control_dt=0.1)  # type: ignore[arg-type]
    A, B, glide = (0, 0, 0), (1, 0, 0), (0.5, 0, 0)
    fig.on_tick(0, 0.0, _tick(A, A, (0.5, 0, 0), A, mode=Mode.HOLD))  # not the policy's: ignored
    for tip in ((0.2, 0, 0), (0.05, 0, 0), (0.01, 0, 0)):
        fig.on_tick(1, 0.1, _tick(A, A, tip, (0, 0.02, 0)))
    fig.on_tick(4, 0.4, _tick(glide, glide, A, A))
    fig.on_tick(5, 0.5, _tick(B, B, (0.9, 0, 0), B))
    fig.on_tick(6, 0.6, _tick(B, B, (1.05, 0, 0), (1, 0, 0.01)))
    assert (
        fig.line() == "reach: 1/2 segment ends within 3 cm (50.0 %); final distance left 5.0 cm, right 1.0 cm"
    )
    d = fig.to_dict()
    assert (d["segments"], d["successes"], d["policy_ticks"]) == (2, 1, 6)
    assert ReachRunFigure(_Tips(), control_dt=0.1).line() == "reach: no policy ticks"  # type: ignore[arg-type]


def test_the_figure_is_found_through_the_task_registry():
    from bar_policy.deploy.policy import load_policy
    from bar_policy.tasks.interfaces import RunFigure

    policy = load_policy(REACH)
    task = get_task(policy.task)
    fig = task.run_figure(policy, None, None)
    assert isinstance(fig, RunFigure) and type(fig).__name__ == "ReachRunFigure"
    assert get_task("state").run_figure(policy, None, None) is None  # a task without a figure: none


def test_a_failing_figure_stops_itself_not_the_run(caplog):
    fig = ReachRunFigure(_Tips(), control_dt=0.1)  # type: ignore[arg-type]
    broken = _tick((0, 0, 0), (0, 0, 0), (0, 0, 0), (0, 0, 0))
    broken.last_state.q = "not joints"  # np.asarray(..., float64) raises ValueError
    fig.tick(7, 0.7, broken)
    fig.tick(8, 0.8, _tick((0, 0, 0), (0, 0, 0), (0, 0, 0), (0, 0, 0)))  # stopped: not taken in
    assert fig.policy_ticks == 0 and fig.error.startswith("stopped at tick 7: ValueError")
    assert fig.final_line() == f"ReachRunFigure: no figure ({fig.error})"
    assert sum("task figure stopped at tick 7" in r.getMessage() for r in caplog.records) == 1
