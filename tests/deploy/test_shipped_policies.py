"""The policies in ``checkpoints/``: what their files declare, and what they do on the C MuJoCo sim target.

Figures come from ``bar-deploy eval`` on the sim target, the path a user runs; the thresholds are the
project's targets (reach: the shipped policy still reaches >= 95 % segment success; track: <= 2 cm
fingertip error, and a 0.05 rad joint error with 25 % room for the two gestures alone, whose mean the
shipped tracker holds at 0.056 rad: see docs/tracking.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import onnx
import pytest
from blocked_imports import BLOCK_HEAVY

from bar_policy.deploy.cli import main
from bar_policy.deploy.tasks import get_task
from bar_policy.motion import clip_set
from bar_policy.obs import ObservationManager
from bar_policy.obs.robot_layout import with_error_ema

CHECKPOINTS = Path(__file__).resolve().parents[2] / "checkpoints"
REACH, TRACK = CHECKPOINTS / "lite_reach_arms.onnx", CHECKPOINTS / "lite_track_arms.onnx"


def _eval(tmp_path: Path, *args: str) -> dict:
    out = tmp_path / "eval.json"
    assert main(["eval", *args, "--json", str(out)]) == 0
    return json.loads(out.read_text())


def _metadata(path: Path) -> dict[str, str]:
    return {p.key: p.value for p in onnx.load(str(path)).metadata_props}


def test_shipped_reach_policy_reaches_on_the_sim_target(tmp_path):
    res = _eval(tmp_path, "--policy", str(REACH), "--episodes", "20", "--seed", "1000")
    # The robust reach file carries the layout's opt-in next version: the golden plus joint_error_ema.
    v2 = ObservationManager(with_error_ema(ObservationManager.golden("lite_reach_arms").schema))
    assert res["obs_fingerprint"] == v2.fingerprint
    assert res["success_rate"] >= 0.95


def test_shipped_tracker_declares_its_task_for_humanoid_control():
    md = _metadata(TRACK)
    assert md["task_type"] == "track"
    assert md["body_names"].split(",") == ["left_elbow_pitch", "left_hand", "right_elbow_pitch", "right_hand"]
    assert int(md["lookahead_steps"]) == 5
    # The clip set it was trained on, rebuilt here from the library: the id pins every frame.
    assert md["dataset_repo_id"] == clip_set("train").id
    assert json.loads(md["bar.obs_fingerprint"]) == ObservationManager.golden("lite_track_arms").fingerprint


def test_shipped_tracker_follows_the_gestures_on_the_sim_target(tmp_path):
    res = _eval(tmp_path, "--policy", str(TRACK), "--clips", "wave,clap")
    (all_clips,) = [g for g in res["groups"] if g["group"] == "all"]
    assert all_clips["faults"] == 0 and all_clips["lost_steps"] == 0
    assert all_clips["joint_error_rad"] <= 1.25 * 0.05
    assert all_clips["fingertip_error_cm"] <= 2.0


@pytest.mark.parametrize("path", [REACH, TRACK])
def test_shipped_files_are_small(path):
    assert path.stat().st_size < 1_000_000


def test_every_shipped_policy_runs_on_the_mock_target_with_jax_and_torch_blocked(tmp_path):
    """The deploy side of every task (its command source, the runtime, the log) needs no training stack."""
    files = sorted(CHECKPOINTS.glob("*.onnx"))
    tasks = {str(p): json.loads(_metadata(p)["bar.task"]) for p in files}
    examples = {name: list(get_task(name).example_run) for name in set(tasks.values())}
    assert all(examples.values()), examples  # every shipped task names its demonstration run
    script = BLOCK_HEAVY + (
        "import json, sys\n"
        "from bar_policy.deploy.cli import main\n"
        "runs = json.loads(sys.argv[1])\n"
        "for i, (path, args) in enumerate(runs.items()):\n"
        "    argv = ['run', '--policy', path, '--target', 'mock', '--duration', '0.3',\n"
        "            '--ramp-time', '0.1', '--max-overruns', '0', '--log', f'{sys.argv[2]}/{i}', *args]\n"
        "    assert main(argv) == 0, path\n"
        "print('jax' in sys.modules, 'torch' in sys.modules)\n"
    )
    runs = {path: examples[task] for path, task in tasks.items()}
    out = subprocess.run(
        [sys.executable, "-c", script, json.dumps(runs), str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-4000:]
    assert out.stdout.split("\n")[-2] == "False False"
    assert len(list((tmp_path / "runs").glob("*/*/run.mcap"))) == len(files)  # one run log each
