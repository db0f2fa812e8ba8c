"""train/ship.py judges the file to ship by the ship gate on held-out data and refuses one that misses.

Tiny runs: a ``final_eval.json`` recording the env name and a policy file from ``tests/deploy``'s factory
(zero weights: the arms hold the default pose, so reach scores 0 % and tracking errs by decimetres). The
held-out evaluations are ``bar-deploy eval``'s, cut short through ``main``'s test-only ``eval_options``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

import bar_policy.tasks.registry  # noqa: F401 - registers every task's gate
from bar_policy.quality.gate import check, thresholds_text

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "deploy"))

from policy_factory import default_metadata, make_policy_file  # noqa: E402
from script_modules import load_script  # noqa: E402

ship = load_script(ROOT / "train" / "ship.py", "ship_script")

SHORT = {
    "reach": {"episodes": 2, "episode_length": 1.0},
    "track": {"clips": "wave", "hold_s": 0.0},
}
"""Held-out evaluations cut short (the defaults are 100 episodes / the heldout clip set)."""


def _run(tmp_path: Path, env_name: str, file_task: str) -> Path:
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    make_policy_file(run_dir / "policy.onnx", metadata=default_metadata(task=file_task))
    final = {
        "config": {"train": {"env_name": env_name}, "env": {"mode": "arms"}},
        "final_eval": {"success_rate": 0.0, "episode_reward": 0.0},
        "env_steps": 0,
    }
    (run_dir / "final_eval.json").write_text(json.dumps(final))
    return run_dir


def _args(tmp_path: Path, run_dir: Path, *more: str) -> list[str]:
    return [
        "--from-run",
        str(run_dir),
        "--checkpoints-dir",
        str(tmp_path / "ck"),
        "--docs-dir",
        str(tmp_path / "docs"),
        "--raw-throughput",
        "0",
        *more,
    ]


@pytest.mark.parametrize(
    ("env_name", "task", "metric", "threshold"),
    [
        ("LiteReach", "reach", "min_success_pct", "< 95 %"),
        ("LiteTrack", "track", "max_fingertip_error_cm", "> 1 cm"),
    ],
)
def test_a_file_that_misses_the_gate_is_refused_and_nothing_is_written(
    tmp_path, monkeypatch, capsys, env_name, task, metric, threshold
):
    monkeypatch.chdir(tmp_path)  # relative defaults would land here, never in the repo
    run_dir = _run(tmp_path, env_name, task)
    rc = ship.main(_args(tmp_path, run_dir), eval_options=SHORT[task])
    out = capsys.readouterr().out
    assert rc == ship.REFUSED == 3
    assert thresholds_text(task) in out
    (line,) = [x for x in out.splitlines() if x.startswith("gate: MISS") and f"({metric})" in x]
    assert threshold in line  # "gate: MISS mean fingertip error 29.68 cm > 1 cm (max_fingertip_error_cm)"
    assert "ship: refused" in out and "gate: PASS" not in out
    assert not (tmp_path / "ck").exists() and not (tmp_path / "docs").exists()
    assert not (tmp_path / "checkpoints").exists()


class _Passing:
    """An evaluation result whose gate report passes the track gate."""

    def __init__(self, report: dict) -> None:
        self.report = report

    def gate_report(self) -> dict:
        return self.report

    def gate_lines(self) -> list[str]:
        return ["(the eval's own gate lines)"]

    def format(self) -> str:
        return "tracking (SimTarget) policy x\n(the eval's own gate lines)"


def _passing_track_report() -> dict:
    quality = {"completion_pct": 100.0, "cap_share_pct": 0.1, "chatter_max_mrad": 1.0}
    episodes = [{"name": "wave", "faulted": False, "chatter_mrad": 1.0}]
    return {
        "task": "track",
        "quality": quality,
        "episodes": episodes,
        "joint_error_rad": 0.015,
        "fingertip_error_cm": 0.8,
    }


def test_a_passing_file_is_published_with_the_gate_record(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    run_dir = _run(tmp_path, "LiteTrack", "track")
    seen = {}

    def fake_eval(onnx, task, options=None):
        seen.update(onnx=Path(onnx), task=task, options=options)
        return _Passing(_passing_track_report())

    monkeypatch.setattr(ship, "held_out_evaluation", fake_eval)
    rc = ship.main(_args(tmp_path, run_dir, "--name", "lite_track_arms", "--robustness", "none"))
    out = capsys.readouterr().out
    assert rc == ship.SHIPPED == 0
    assert "robustness tier: not run (--robustness none): published on the nominal gate alone" in out
    assert seen == {"onnx": run_dir / "policy.onnx", "task": "track", "options": None}  # the eval's defaults
    assert thresholds_text("track") in out and "gate: PASS" in out
    assert "(the eval's own gate lines)" not in out  # printed once, by ship
    ck = tmp_path / "ck"
    assert sorted(p.name for p in ck.iterdir()) == ["lite_track_arms.json", "lite_track_arms.onnx"]
    assert not (tmp_path / "docs").exists()  # the docs' results block is the reach policy's
    rec = json.loads((ck / "lite_track_arms.json").read_text())["ship_gate"]
    assert rec["verdict"] == "pass" and rec["misses"] == [] and rec["task"] == "track"
    assert rec["thresholds"]["max_fingertip_error_cm"] == 1.0 and "min_success_pct" not in rec["thresholds"]
    assert rec["report"]["fingertip_error_cm"] == 0.8 and rec["episodes"] == 1
    assert rec["robustness"] == {"verdict": "not run", "rows": []}  # said, not left out
    assert check("track", rec["report"]) == []  # the recorded figures pass again


def test_default_name_comes_from_the_runs_task_and_mode(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run_dir = _run(tmp_path, "LiteTrack", "track")
    monkeypatch.setattr(ship, "held_out_evaluation", lambda *a, **k: _Passing(_passing_track_report()))
    assert ship.main(_args(tmp_path, run_dir, "--robustness", "none")) == 0
    assert (tmp_path / "ck" / "lite_track_arms.onnx").exists()


def test_gate_record_of_hand_made_reports():
    quality = {"completion_pct": 100.0, "cap_share_pct": 0.0, "chatter_max_mrad": 0.5}
    ok = {"task": "reach", "quality": quality, "success_pct": 97.0, "median_end_cm": 0.3}
    assert check("reach", ok) == []
    assert ship.gate_record("reach", ok, [])["verdict"] == "pass"
    bad = {**ok, "success_pct": 90.0}
    misses = check("reach", bad)
    rec = ship.gate_record("reach", bad, misses)
    assert rec["verdict"] == "miss"
    assert rec["misses"] == ["success 90 % < 95 % (min_success_pct)"]
    # Success hides accuracy (a 3 cm radius): the median end distance is its own threshold.
    far = {**ok, "median_end_cm": 0.8}
    assert [m.text for m in check("reach", far)] == [
        "median segment-end distance 0.8 cm > 0.6 cm (max_median_end_cm)"
    ]
    assert [m.text for m in check("reach", {**ok, "median_end_cm": None})] == [
        "median segment-end distance: not measured (the report lacks it; max_median_end_cm=0.6)"
    ]
    assert rec["thresholds"] == {
        "min_completion_pct": 100.0,
        "max_cap_share_pct": 0.5,
        "max_chatter_mrad": 5.0,
        "min_success_pct": 95.0,
        "max_median_end_cm": 0.6,
    }


def test_a_file_of_another_task_than_the_run_is_not_evaluated(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    run_dir = _run(tmp_path, "LiteTrack", "reach")
    assert ship.main(_args(tmp_path, run_dir), eval_options=SHORT["reach"]) == ship.NOT_EVALUATED == 2
    assert "task mismatch" in capsys.readouterr().err
    assert not (tmp_path / "ck").exists()


def test_run_task_reads_the_env_name_and_matches_the_envs():
    from bar_policy import envs

    for name in envs.ALL_ENVS:
        assert ship.ENV_TASKS[name] == envs._entry(name)[0].task_name


def test_a_run_without_an_env_name_has_no_task(tmp_path):
    (tmp_path / "final_eval.json").write_text(json.dumps({"config": {"train": {}}}))
    with pytest.raises(ValueError, match="env_name None"):
        ship.run_task(tmp_path)


def test_robustness_tier_refuses_a_file_that_misses_a_gated_row_and_records_a_pass(
    tmp_path, monkeypatch, capsys
):
    # The nominal gate passes (a faked held-out evaluation); the tier runs its rows for real on the perturbed
    # sim target with the zero-weight tracker (the arms hold the default pose: decimetres of fingertip
    # error): the gated friction row misses the 1 cm threshold, the offset row is reported only.
    monkeypatch.chdir(tmp_path)
    run_dir = _run(tmp_path, "LiteTrack", "track")
    monkeypatch.setattr(
        ship, "held_out_evaluation", lambda onnx, task, options=None: _Passing(_passing_track_report())
    )
    rows = "friction +1.0 N*m,offset 0.01 rad"
    rc = ship.main(_args(tmp_path, run_dir, "--name", "t", "--robustness", rows), eval_options=SHORT["track"])
    out = capsys.readouterr().out
    assert rc == ship.REFUSED == 3  # a missed gated row refuses the file, naming the row
    assert "suite: MISS on 1 of 1 gated rows: friction +1.0 N*m" in out
    assert "misses the robustness tier on 1 row(s): friction +1.0 N*m" in out
    assert not (tmp_path / "ck").exists()
    # The reported row alone: nothing gated misses, so the file ships with every row's record.
    args = _args(tmp_path, run_dir, "--name", "t", "--robustness", "offset 0.01 rad")
    rc = ship.main(args, eval_options=SHORT["track"])
    assert rc == ship.SHIPPED
    rec = json.loads((tmp_path / "ck" / "t.json").read_text())["ship_gate"]
    assert rec["verdict"] == "pass" and rec["robustness"]["verdict"] == "pass"
    assert [(r["name"], r["spec"], r["gating"], r["verdict"]) for r in rec["robustness"]["rows"]] == [
        ("offset 0.01 rad", "offset_rad=0.01", "none", "report"),
    ]
    assert any("max_fingertip_error_cm" in m for m in rec["robustness"]["rows"][0]["misses"])  # reported
    # By default the tier runs on the sim target, then on the emulated bus, each recorded with its target.
    assert rec["robustness"]["target"] == "C MuJoCo sim target"
    bus = rec["robustness_bus"]
    assert bus["target"] == "emulated CAN bus (lockstep)" and bus["verdict"] == "pass"
    assert [(r["name"], r["verdict"]) for r in bus["rows"]] == [("offset 0.01 rad", "report")]
    out = capsys.readouterr().out
    assert "each the held-out evaluation on a perturbed sim target" in out
    assert "each the held-out evaluation on the emulated bus" in out
    assert "robustness suite: policy " in out and "(track), emulated CAN bus (lockstep)" in out


def test_robustness_rows_are_named_or_refused(capsys):
    assert [r.name for r in ship.robustness_rows("push 10 N, mass x0.8")] == ["push 10 N", "mass x0.8"]
    assert "nominal" not in [r.name for r in ship.robustness_rows("suite")]
    assert len(ship.robustness_rows("suite")) == 12
    with pytest.raises(
        ValueError, match=r"unknown suite row\(s\) \['mass x9'\]; valid: 'suite', 'none' or any of"
    ):
        ship.robustness_rows("mass x9")
    assert ship.robustness_rows("none") == ()  # the nominal gate alone
    assert ship.main(["--robustness", "mass x9", "--from-run", "x"]) == ship.NOT_EVALUATED
    assert "valid: 'suite', 'none' or any of" in capsys.readouterr().err
    assert ship.robustness_targets("bus, sim") == ("bus", "sim")
    assert ship.robustness_targets("sim") == ("sim",)
    for bad in ("sim,sim", "gpu", ""):
        assert ship.main(["--robustness-targets", bad, "--from-run", "x"]) == ship.NOT_EVALUATED
        assert "give each of sim, bus at most once, comma-separated" in capsys.readouterr().err
    # A flag ship does not know is not dropped with --from-run (it would only apply to a training run).
    assert ship.main(["--from-run", "x", "--robustness-enforce"]) == ship.NOT_EVALUATED
    assert "['--robustness-enforce'] are not ship options" in capsys.readouterr().err


def test_rejudge_replaces_a_published_record_on_a_pass_and_keeps_it_on_a_miss(tmp_path, monkeypatch, capsys):
    # A published tracker (the zero-weight file, its JSON an older record): re-judged with a faked passing
    # held-out evaluation and the reported offset row, its ship_gate is replaced (the rest of the JSON kept,
    # the re-judging stamped); with the real evaluation (decimetres of error) it misses and nothing changes.
    monkeypatch.chdir(tmp_path)
    ck = tmp_path / "ck"
    ck.mkdir()
    make_policy_file(ck / "t.onnx", metadata=default_metadata(task="track"))
    old = {"env_steps": 7, "ship_gate": {"task": "track", "verdict": "pass", "robustness": "absent"}}
    (ck / "t.json").write_text(json.dumps(old))
    args = ["--rejudge", "t", "--checkpoints-dir", str(ck), "--robustness", "offset 0.01 rad"]
    rc = ship.main(args, eval_options=SHORT["track"])  # the real evaluation: a miss
    out = capsys.readouterr().out
    assert rc == ship.REFUSED and "gate: MISS" in out and "ship: refused" in out
    assert json.loads((ck / "t.json").read_text()) == old
    monkeypatch.setattr(
        ship, "held_out_evaluation", lambda onnx, task, options=None: _Passing(_passing_track_report())
    )
    assert ship.main(args, eval_options=SHORT["track"]) == ship.SHIPPED
    new = json.loads((ck / "t.json").read_text())
    assert new["env_steps"] == 7 and new["ship_gate"]["verdict"] == "pass"
    assert [r["name"] for r in new["ship_gate"]["robustness"]["rows"]] == ["offset 0.01 rad"]
    assert "git_commit" in new["ship_gate"]["rejudged"]
    assert ship.main(["--rejudge", "t", "--from-run", "x"]) == ship.NOT_EVALUATED
    assert "--rejudge judges a published file" in capsys.readouterr().err
    assert ship.main(["--rejudge", "nope", "--checkpoints-dir", str(ck)]) == ship.NOT_EVALUATED


def test_help_is_ships_own_and_points_to_the_training_flags(capsys):
    """``--help`` prints ship's options (not the training CLI's, which the other flags pass through to),
    then where the training flags are; exit 0, nothing run."""
    assert ship.main(["--help"]) == ship.SHIPPED == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: python train/ship.py")
    for flag in ("--from-run", "--rejudge", "--robustness", "--robustness-targets", "--iterate"):
        assert flag in out
    assert "python train/ppo.py --help" in out and "--preset" not in out
    assert ship.main(["--preset", "track", "-h"]) == 0 and "--rejudge" in capsys.readouterr().out
