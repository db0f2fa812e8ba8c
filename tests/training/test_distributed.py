"""Two processes through ``jax.distributed`` on this machine (coordinator 127.0.0.1, 2 CPU devices each).

One shared run (``dist_worker.py`` x 2, gloo collectives across the processes) feeds every check: identical
parameters on both processes, a global step count, one set of logs, no torch in a brax run, a start-up
record counted from the process start, and clean output (no gRPC errors at exit, no Warp notice at start).

The workers train on the stand-in env (``toy_env.ToyReach``), not LiteReach: each process compiles its own
programs, and two concurrent MJX compiles (epoch and evaluation, about 200 s of CPU each per process) take
well over the 3 minutes this test may use on a 2-core CI machine.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

WORKER = Path(__file__).parent / "dist_worker.py"
REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _launch(out: Path, cache: Path, run_name: str) -> Path:
    """Both workers of one 2-process run into ``out`` (asserts they exit 0); their output is kept there."""
    env = {
        **os.environ,
        "JAX_PLATFORMS": "cpu",
        "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
        # The executable cache, off on a CPU by default: its multi-process path is what runs on GPUs.
        "BAR_POLICY_EXECUTABLE_CACHE_ON_CPU": "1",
        # This checkout's bar_policy, whichever one is installed.
        "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
    }
    port = str(_free_port())
    # Three evaluation periods (the tiny preset has one): a progress line per 2 iterations, evaluations at
    # 1,024 and 2,048 env steps, as the assertions below count them.
    args = [
        "export_onnx=False",
        "eval.num_evals=3",
        f"compile_cache_dir={cache}",
        f"run_name={run_name}",
        "--toy",
    ]
    procs = [
        subprocess.Popen(
            [sys.executable, str(WORKER), port, str(pid), str(out), *args],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for pid in (0, 1)
    ]
    logs = []
    try:
        for p in procs:
            logs.append(p.communicate(timeout=600))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for pid, (p, (stdout, stderr)) in enumerate(zip(procs, logs, strict=True)):
        assert p.returncode == 0, f"process {pid} failed:\n{stdout[-2000:]}\n{stderr[-4000:]}"
        (out / f"process{pid}.out").write_text(stdout)
        (out / f"process{pid}.err").write_text(stderr)
    return out


@pytest.fixture(scope="module")
def dist_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("dist_cache")


@pytest.fixture(scope="module")
def dist_run(tmp_path_factory: pytest.TempPathFactory, dist_cache: Path) -> Path:
    """The cold run: every program compiled by each process and stored in the executable cache."""
    return _launch(tmp_path_factory.mktemp("dist"), dist_cache, "dist")


@pytest.fixture(scope="module")
def dist_warm(
    tmp_path_factory: pytest.TempPathFactory, dist_cache: Path, dist_run: Path
) -> tuple[Path, float]:
    """The same run again on the same cache (another run name and coordinator port); its start time."""
    started = time.time()
    return _launch(tmp_path_factory.mktemp("dist_warm"), dist_cache, "dist_warm"), started


def _result(out: Path, pid: int) -> dict:
    with np.load(out / f"result_{pid}.npz") as f:
        return {k: f[k] for k in f.files}


def test_both_processes_end_with_identical_parameters(dist_run):
    r0, r1 = _result(dist_run, 0), _result(dist_run, 1)
    leaves = sorted(k for k in r0 if k.startswith("arr_"))
    assert leaves == sorted(k for k in r1 if k.startswith("arr_")) and len(leaves) > 10
    for k in leaves:
        assert np.array_equal(r0[k], r1[k]), k
    # Trained, not the initial params: the normaliser has seen observations.
    assert float(r0["normalizer_count"]) > 0


def test_step_count_counts_both_processes(dist_run):
    r0, r1 = _result(dist_run, 0), _result(dist_run, 1)
    assert int(r0["global_devices"]) == 4 and int(r0["local_devices"]) == 2
    # tiny preset: 16 segments x 4 minibatches x 8 steps = 512 env steps per iteration, 4 iterations.
    assert int(r0["env_steps"]) == int(r1["env_steps"]) == 4 * 512
    # The observation normaliser counts every observation of every device once (psum over the mesh):
    # 2,048, where a process that saw only its own envs would count 1,024.
    assert float(r0["normalizer_count"]) == float(r1["normalizer_count"]) == 2048.0


def test_only_process_zero_writes_logs(dist_run):
    lines = [json.loads(x) for x in (dist_run / "dist" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines if r["kind"] == "train"] == [512, 1024, 1536, 2048]
    assert len([r for r in lines if r["kind"] == "final"]) == 1
    # Both processes ran every evaluation (collectives), the step-0 one after training (eval.initial=end).
    assert [r["step"] for r in lines if r["kind"] == "eval"] == [1024, 2048, 0]


def test_brax_run_never_imports_torch(dist_run):
    for pid in (0, 1):
        assert not bool(_result(dist_run, pid)["torch_imported"])


def test_processes_start_and_shut_down_without_error_output(dist_run):
    """No gRPC errors from a process that outlives the coordinator (``shutdown_distributed``), and no
    notice that the optional Warp backend of MJX is missing (``bar_policy._mjx_quiet``), on either stream."""
    for pid in (0, 1):
        for stream in ("out", "err"):
            text = (dist_run / f"process{pid}.{stream}").read_text()
            for needle in ("Failed to connect", "CANCELLED", "Failed to import warp"):
                assert needle not in text, f"process {pid} std{stream}: {needle!r}\n{text[-3000:]}"


def test_startup_record_counts_from_the_process_start(dist_run):
    from bar_policy._phases import MODEL_BUILD
    from bar_policy.training.startup import breakdown as sb

    rec = json.loads((dist_run / "dist" / "final_eval.json").read_text())["startup"]
    assert rec["origin"] == "process start"
    phases = rec["phases"]
    assert set(sb.PHASES) <= set(phases) and all(v >= 0 for v in phases.values())
    # The interpreter started before run() (imports of the worker), the processes met at the coordinator,
    # and the stand-in env builds no MuJoCo model.
    assert phases[sb.BEFORE_RUN] > 0 and phases[sb.DISTRIBUTED] > 0 and phases[MODEL_BUILD] == 0.0
    assert sum(phases.values()) == pytest.approx(rec["total_s"], abs=0.02)


def test_warm_run_loads_every_program_on_both_processes_and_trains_the_same(dist_run, dist_warm, dist_cache):
    """Under two processes the executable cache serves the second run: each process stored its own five
    programs (reset, rollout, update, init, evaluate) in the cold run, loaded all of them in the warm one
    (each load touches its entry), compiled none, and both runs end with the same parameters."""
    warm, started = dist_warm
    entries = sorted((dist_cache / "executables").glob("*.bin"))
    sidecars = [json.loads(p.with_suffix(".json").read_text()) for p in entries]
    assert len(entries) == 10, [p.name for p in entries]  # 5 programs x 2 processes, nothing added warm
    assert sorted(s["platform"]["process_index"] for s in sidecars) == [0] * 5 + [1] * 5
    assert all(p.stat().st_mtime >= started for p in entries)  # every entry loaded by the warm run
    record = json.loads((warm / "dist_warm" / "final_eval.json").read_text())["startup"]["programs"]
    assert {name: r["executable"] for name, r in record.items()} == dict.fromkeys(
        ("evaluate", "init", "reset", "rollout", "update"), "hit"
    )
    for pid in (0, 1):
        cold, again = _result(dist_run, pid), _result(warm, pid)
        leaves = sorted(k for k in cold if k.startswith("arr_"))
        assert len(leaves) > 10 and all(np.array_equal(cold[k], again[k]) for k in leaves)
        assert int(again["env_steps"]) == 4 * 512
    # The warm run's output is as clean as the cold run's.
    for pid in (0, 1):
        text = (warm / f"process{pid}.err").read_text()
        for needle in ("Failed to connect", "CANCELLED", "unusable"):
            assert needle not in text, f"process {pid}: {needle!r}\n{text[-3000:]}"
