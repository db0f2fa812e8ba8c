"""The loop on the mock target (rate, drift, echo), the run log (chunks, crash recovery), plots, sim2sim."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.log.files import log_fields
from bar_policy.deploy.log.plot import plot_log
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig, sleep_until
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.deploy.targets.mock import MockTarget
from bar_policy.tasks.reach.commands import SampledCommands
from bar_policy.tasks.reach.evaluate import EvalConfig, evaluate


def test_mock_echoes_commands_into_the_state():
    m = MockTarget("arms")
    q0 = m.read_state().q
    from bar_policy.robot.mit import MitCommand

    q_cmd = q0 + 0.1
    m.write_command(
        MitCommand(q_cmd, np.full(14, 0.5), np.full(14, 10.0), np.full(14, 1.0), np.full(14, 0.2))
    )
    s = m.read_state()
    np.testing.assert_array_equal(s.q, q_cmd)
    np.testing.assert_array_equal(s.dq, 0.5)
    # tau at the replaced state (q0, dq 0): 10 * 0.1 + 1 * (0.5 - 0) + 0.2 = 1.7 N*m (below every cap).
    np.testing.assert_allclose(s.tau, 1.7, atol=1e-12)


def test_mock_runs_at_500_hz_without_drift(make_policy, tmp_path):
    # A 500 Hz policy (dt 2 ms) on the asynchronous mock for 1.5 s: 750 ticks on the absolute grid.
    meta = default_metadata(policy_dt=0.002)
    pol = load_policy(make_policy(metadata=meta, bias=0.05), control_dt=0.002)
    mock = MockTarget("arms")
    cfg = RuntimeConfig(
        control_dt=0.002,
        duration=1.5,
        start_mode="policy",
        rt_priority=50,  # SCHED_FIFO where permitted (falls back with a warning elsewhere)
        safety=SafetyConfig(ramp_time=0.0, max_overruns=0),
    )
    rt = Runtime(pol, mock, SampledCommands(pol.obs_manager.command_names), cfg, log_dir=tmp_path)
    res = rt.run()
    # --duration is wall-clock time on a paced target: 750 deadlines, minus those skipped after late ticks.
    s = res.timing.summary()
    assert res.ticks == 750 - s["skipped"] and res.fault_count == 0
    assert mock.commands_written == res.ticks + 1  # + the safe_stop damping command
    a, meta_log = load_log(res.log_path)
    # Absolute deadlines: each tick's deadline (start - lateness) sits on the grid n * 2 ms from the start,
    # so errors never accumulate; an overrun skips grid slots but keeps the phase.
    deadline = a["wall"] - a["jitter"]
    slots = deadline / 0.002
    np.testing.assert_allclose(slots, np.round(slots), atol=1e-6)
    assert np.all(np.diff(np.round(slots)) >= 1)
    assert np.all(a["jitter"] >= 0)
    assert np.median(a["jitter"]) < 0.5e-3
    skipped = int(np.round(slots[-1])) - (res.ticks - 1)
    assert skipped == s["skipped"]  # the grid slots the log skipped are the pacer's skipped deadlines
    assert (s["overruns"] == 0) == (skipped == 0) and s["overruns"] <= skipped  # skipped only on overruns
    # Echo: the state read at tick k+1 is the q_cmd written at tick k.
    np.testing.assert_array_equal(a["q"][1:], a["q_cmd"][:-1])
    # Every tick in POLICY: q_cmd = default + 0.25 * 0.05.
    assert np.all(a["mode"] == int(Mode.POLICY))
    default = np.asarray(meta.default_joint_pos)
    np.testing.assert_allclose(a["q_cmd"][-1], default + 0.25 * np.float32(0.05), atol=1e-12)
    assert meta_log["timing"]["ticks"] == res.ticks


def test_sleep_until_is_not_early():
    import time

    for _ in range(20):
        d = time.perf_counter() + 0.001
        sleep_until(d)
        assert time.perf_counter() >= d


def test_runlog_is_durable_by_wall_time_without_close(tmp_path):
    fields = log_fields(2, 2, 3, ("target_pos_left",))
    log = RunLog(tmp_path / "runs", fields, {"x": 1}, name="t", chunk_ticks=10, flush_interval=0.2)
    for k in range(25):
        log.append({"t": k * 0.1, "q": [k, -k], "mode": 3})
    time.sleep(0.6)  # > the flush interval: the writer thread flushed and fsync-ed on its own
    # What a crash leaves: the run directory as it is now, never closed (copied while the writer runs).
    crashed = Path(shutil.copytree(log.path, tmp_path / "crashed"))
    log.close()
    assert not (crashed / "log.npz").exists()
    arrays, meta = load_log(crashed)
    np.testing.assert_array_equal(arrays["q"][:, 0], np.arange(25))  # every tick, not only full chunks
    np.testing.assert_allclose(arrays["t"], np.arange(25) * 0.1)
    assert meta["status"] == "running" and meta["x"] == 1 and meta["end_reason"].startswith("not closed")
    # An unwritten float field is NaN, not a silent 0.
    assert np.isnan(arrays["action"]).all()


def test_runlog_close_writes_everything(tmp_path):
    fields = log_fields(2, 2, 3, ())
    log = RunLog(tmp_path, fields, {}, chunk_ticks=10)
    for k in range(25):
        log.append({"t": k * 0.1, "q": [k, -k]})
    out = log.close(end_reason="done")
    assert log.close() == out  # idempotent
    arrays, meta = load_log(out)
    np.testing.assert_array_equal(arrays["q"][:, 1], -np.arange(25))
    assert meta["ticks"] == 25 and meta["end_reason"] == "done"
    assert json.loads((log.path / "run.json").read_text())["status"] == "closed"


def test_plot_writes_pngs(zero_policy, tmp_path):
    from fault_targets import SteppedMock

    rt = Runtime(
        zero_policy,
        SteppedMock(nan_from=20),
        SampledCommands(zero_policy.obs_manager.command_names),
        RuntimeConfig(duration=1.0, start_mode="hold", safety=SafetyConfig(ramp_time=0.2)),
        log_dir=tmp_path,
    )
    res = rt.run()
    files = plot_log(res.log_path.parent, tmp_path / "plots")
    assert [f.name for f in files] == ["joints.png", "torques.png", "timing.png"]
    for f in files:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        import imageio.v3 as iio

        h, w = iio.imread(f).shape[:2]
        assert h > 200 and w > 400


def test_plot_refuses_missing_log(tmp_path):
    with pytest.raises(FileNotFoundError, match="no run log"):
        plot_log(tmp_path / "nothing.npz")
    (tmp_path / "x.onnx").write_bytes(b"\x08\x07not an npz")
    with pytest.raises(ValueError, match="is not a run log"):
        load_log(tmp_path / "x.onnx")


def test_sim2sim_success_definition_and_seeds(zero_policy):
    # The zero policy holds the default pose; fingertips are then 0.05-0.25 m from sampled targets.
    runner = SimEpisodes(zero_policy)
    far = evaluate(zero_policy, EvalConfig(episodes=3, seed=11, episode_length=0.2), runner=runner)
    near = evaluate(
        zero_policy, EvalConfig(episodes=3, seed=11, episode_length=0.2, success_radius=1.0), runner=runner
    )
    assert far.success_rate == 0.0 and near.success_rate == 1.0
    assert [e.seed for e in far.episodes] == [11, 12, 13]
    # Same seeds, same episodes: distances reproduce exactly.
    assert [e.dist_left for e in far.episodes] == [e.dist_left for e in near.episodes]
    lo, hi = far.wilson_interval()
    assert lo == 0.0 and 0.5 < hi < 0.6  # Wilson 95 % upper bound for 0/3 is 0.5615
    assert "success rate 0.0 %" in far.format()


def test_sim2sim_scores_every_target_segment(zero_policy):
    # 0.2 s episodes resampled every 0.1 s: 2 segments per episode, scored at ticks 4 and 9.
    res = evaluate(
        zero_policy,
        EvalConfig(episodes=2, seed=0, episode_length=0.2, resample_period=0.1, success_radius=1.0),
        runner=SimEpisodes(zero_policy),
    )
    assert res.segments == 4 and res.success_rate == 1.0
    e = res.episodes[0]
    assert e.segments == 2 and len(e.dist_left) == 2
    # The two segments have different targets, so different distances.
    assert e.dist_left[0] != e.dist_left[1]


def test_deploy_never_imports_jax_torch_or_onnx():
    code = (
        "import sys\n"
        "import bar_policy.deploy.cli, bar_policy.deploy.runtime, bar_policy.deploy.policy\n"
        "import bar_policy.tasks.reach.evaluate, bar_policy.tasks.reach.commands\n"
        "import bar_policy.deploy.log.plot\n"
        "import bar_policy.deploy.targets.sim, bar_policy.deploy.targets.mock\n"
        "print(sorted(m for m in ('jax', 'torch', 'onnx') if m in sys.modules))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_make_policy_file_mlp_is_deterministic(tmp_path):
    a = load_policy(make_policy_file(tmp_path / "a.onnx", hidden=16, seed=3))
    b = load_policy(make_policy_file(tmp_path / "b.onnx", hidden=16, seed=3))
    x = np.linspace(-1, 1, 54).astype(np.float32)
    np.testing.assert_array_equal(a(x), b(x))
