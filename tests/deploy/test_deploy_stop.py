"""How ``bar-deploy`` ends, tested on a real child process: SIGINT / SIGTERM / SIGHUP on the sim target and
on the emulated real target (``--target real --can-interface virtual``, frames checked on the bus), SIGKILL.

Each signal must give DAMPING, then (real target) stop frames on every bus, then the log closed with the
reason, exit status 0; a second signal during the shutdown is counted and cannot skip the stop frames.
SIGKILL cannot be caught: what it leaves (``run.mcap``, flushed every 0.5 s) must hold the run up to at most
about 1 s before the kill, and ``load_log`` / ``plot_log`` must read it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.safety import Mode

CHILD = Path(__file__).parent / "deploy_child.py"
REPO = Path(__file__).resolve().parents[2]
DAMPING_TIME = 0.3
"""--damping-time of the runs, s: the DAMPING ticks between the stop request and the stop frames."""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return env


def _start(argv: list[str], log_dir: Path, frames: Path | None = None, ramp: float = 0.2) -> subprocess.Popen:
    common = [
        "--duration",
        "60",
        "--ramp-time",
        str(ramp),
        "--start",
        "hold",
        "--log",
        str(log_dir),
        "--damping-time",
        str(DAMPING_TIME),
        "--max-overruns",
        "0",
        "--stale-timeout",
        "2",
    ]
    if frames is None:
        cmd = [sys.executable, "-m", "bar_policy.deploy.cli", *argv, *common]
    else:
        cmd = [sys.executable, str(CHILD), str(frames), "can0,can1", "--", *argv, *common]
    return subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _run_dir(log_dir: Path) -> Path:
    (run,) = list(log_dir.iterdir())
    return run


def _wait_for_policy(proc: subprocess.Popen, log_dir: Path, *, extra_s: float = 0.0, timeout: float = 90.0):
    """Poll the child's live ``run.mcap`` until a tick in POLICY was flushed (then wait ``extra_s``)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"bar-deploy exited early ({proc.returncode}):\n{out}\n{err}")
        runs = list(log_dir.iterdir()) if log_dir.is_dir() else []
        if runs and (runs[0] / MCAP_FILE).is_file():
            try:
                mode = read_mcap_log(runs[0] / MCAP_FILE).arrays.get("mode")
            except ValueError:  # the header is not flushed yet
                mode = None
            if mode is not None and (mode == int(Mode.POLICY)).any():
                time.sleep(extra_s)
                return
        time.sleep(0.2)
    proc.kill()
    pytest.fail(f"no POLICY tick within {timeout} s:\n{proc.communicate()}")


def _stop_with(proc: subprocess.Popen, sig: signal.Signals) -> tuple[str, str, signal.Signals]:
    """Send ``sig``, then a second, different signal during the shutdown; wait for the exit."""
    second = signal.SIGTERM if sig == signal.SIGINT else signal.SIGINT
    proc.send_signal(sig)
    time.sleep(0.1)  # inside the 0.3 s of DAMPING before the stop frames
    proc.send_signal(second)
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"bar-deploy did not exit after {sig.name}: {proc.communicate()}")
    return out, err, second


def _assert_stopped_log(run: Path, sig: signal.Signals) -> dict[str, np.ndarray]:
    """The closed log of a run stopped by ``sig`` (then a second signal): reason, DAMPING to the end."""
    arrays, meta = load_log(run)
    assert meta["status"] == "closed" and (run / "log.npz").is_file()
    assert meta["end_reason"] == f"{sig.name} received" and meta["stop_reason"] == f"{sig.name} received"
    assert meta["stop_signal"] == sig.name and meta["stop_signals_received"] == 2
    assert meta["safe_stop"].startswith("stop confirmed") and meta["fault_count"] == 0
    last = meta["transitions"][-1]
    assert (last["from"], last["to"]) == ("POLICY", "DAMPING")
    assert last["reason"] == f"stop requested: {sig.name} received"
    k = last["tick"]
    assert (arrays["mode"][:k] == int(Mode.POLICY)).any()
    np.testing.assert_array_equal(arrays["mode"][k:], int(Mode.DAMPING))
    np.testing.assert_array_equal(arrays["kp"][k:], 0.0)  # damping: Kp = 0, Kd = 1
    np.testing.assert_array_equal(arrays["kd"][k:], 1.0)
    # DAMPING lasted --damping-time: the run ended at the first tick at least 0.3 s after the stop request
    # (on the wall clock for the real target, where a late tick on a loaded machine skips deadlines).
    damped = arrays["t"][k:] - arrays["t"][k]
    assert damped[-2] < DAMPING_TIME - 1e-9 <= damped[-1]
    # The MCAP beside it is complete and holds the same ticks.
    mcap = read_mcap_log(run / MCAP_FILE)
    assert mcap.complete and mcap.meta["end_reason"] == f"{sig.name} received"
    np.testing.assert_array_equal(mcap.arrays["q"], arrays["q"])
    assert [t["reason"] for t in mcap.transitions] == [t["reason"] for t in meta["transitions"]]
    return arrays


SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]


REAL_RAMP_S = 1.2
"""--ramp-time on the real target, s: at least the minimum it accepts for the test policy (Kp 50: 1.152 s,
``deploy.ramp_limit``)."""
WATCHDOG_S = 2.0
"""CAN watchdog armed by the emulated real target in these tests (generous: CI machines are loaded)."""


@pytest.mark.parametrize("sig", SIGNALS, ids=[s.name for s in SIGNALS])
def test_signal_on_sim_ends_in_damping_with_the_log_closed(sig, policy_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _start(["--policy", str(policy_path), "--target", "sim", "--realtime"], log_dir)
    _wait_for_policy(proc, log_dir)
    out, err, second = _stop_with(proc, sig)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert f"end: {sig.name} received" in out and "safe stop: stop confirmed" in out
    assert f"{second.name} received again (2 signals): ignored" in err
    _assert_stopped_log(_run_dir(log_dir), sig)


def _host_frames(frames_file: Path, channel: str) -> list[tuple[str, int, int | None]]:
    """Host -> motor frames on one channel as (type, motor id, raw Kp of MIT frames)."""
    from bar_policy.robstride import protocol as proto

    out = []
    for ch, arb_id, data, _ in json.loads(frames_file.read_text()):
        if ch != channel:
            continue
        try:
            req = proto.decode_request(arb_id, bytes.fromhex(data))
        except proto.FrameError:
            continue  # a motor's reply
        if isinstance(req, proto.MitRequest):
            out.append(("MIT", req.motor_id, req.raw[2]))
        else:
            out.append((req.comm_type.name, req.motor_id, None))
    return out


@pytest.mark.parametrize("sig", SIGNALS, ids=[s.name for s in SIGNALS])
def test_signal_on_emulated_real_target_sends_damping_then_stop_frames(sig, policy_path, tmp_path):
    pytest.importorskip("can")
    log_dir, frames = tmp_path / "runs", tmp_path / "frames.json"
    argv = ["--policy", str(policy_path), "--target", "real", "--can-interface", "virtual"]
    # Generous reply deadline and CAN watchdog: CI machines are loaded, and bus timing is not what this
    # test checks.
    proc = _start(
        [*argv, "--emulate", "lockstep", "--reply-timeout", "1", "--can-timeout", str(WATCHDOG_S)],
        log_dir,
        frames,
        ramp=REAL_RAMP_S,
    )
    _wait_for_policy(proc, log_dir)
    out, err, _ = _stop_with(proc, sig)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and f"end: {sig.name} received" in out
    arrays = _assert_stopped_log(_run_dir(log_dir), sig)
    assert load_log(_run_dir(log_dir))[1]["target_metadata"] == {"can_timeout": WATCHDOG_S}
    # On each bus, as the motors received them: policy frames (Kp > 0), then only damping frames (Kp = 0)
    # for every motor, then one stop frame (type 4) per motor, and nothing after the stop frames.
    for channel, ids in (("can0", range(11, 18)), ("can1", range(21, 28))):
        seq = _host_frames(frames, channel)
        last_policy = max(i for i, (kind, _, kp) in enumerate(seq) if kind == "MIT" and kp > 0)
        tail = seq[last_policy + 1 :]
        stops = [i for i, (kind, _, _) in enumerate(tail) if kind == "STOP"]
        assert stops, f"{channel}: no stop frame after the last policy frame"
        damping, after = tail[: stops[0]], tail[stops[0] :]
        assert all(kind == "MIT" and kp == 0 for kind, _, kp in damping), damping
        # At least the runtime's DAMPING ticks after the stop request: one frame per motor per tick.
        n_damping_ticks = int((arrays["mode"] == int(Mode.DAMPING)).sum())
        assert len(damping) >= 7 * (n_damping_ticks - 1)
        assert {mid for _, mid, _ in damping} == set(ids)
        assert [kind for kind, _, _ in after] == ["STOP"] * 7 and {m for _, m, _ in after} == set(ids)


def test_sigkill_leaves_a_readable_log_missing_at_most_one_second(policy_path, tmp_path):
    log_dir = tmp_path / "runs"
    proc = _start(["--policy", str(policy_path), "--target", "sim", "--realtime"], log_dir)
    _wait_for_policy(proc, log_dir, extra_s=1.5)
    killed_at = time.time()
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    run = _run_dir(log_dir)
    assert not (run / "log.npz").exists()
    arrays, meta = load_log(run)
    assert meta["status"] == "running" and meta["end_reason"].startswith("not closed")
    n = arrays["t"].size
    assert n > 50
    # Every tick up to the last flush, none missing in between.
    np.testing.assert_allclose(arrays["t"], np.arange(n) * 0.02, atol=1e-9)
    # The last recorded tick started at most ~1 s (flush every 0.5 s) before the kill, on the wall clock
    # (each tick's start is the publish time of its MCAP messages).
    published = read_mcap_log(run / MCAP_FILE).publish_unix
    assert published.size == n and np.all(np.diff(published) > 0)
    assert 0.0 < killed_at - published[-1] <= 1.0, killed_at - published[-1]
    from bar_policy.deploy.log.plot import plot_log

    files = plot_log(run, tmp_path / "png")
    assert [f.name for f in files] == ["joints.png", "torques.png", "timing.png"]
