"""How a run on the real target stops, on the emulated bus (python-can ``virtual`` channels, in process):
one damping-then-stop sequence whatever ends the run, the stop report's matching of replies to joints,
wall-clock duration on paced targets, the refusal of a step start, and the exit status of a stop at every
moment (during the start-up, during the imports).

The runs use the real target as ``bar-deploy --target real --can-interface virtual`` builds it
(``targets.real_cli.make_target``: ``RealTarget`` + the realtime ``RobstrideEmulator``), with reply
deadlines and CAN watchdogs far above what a loaded 2-core host needs (``REPLY_S``, ``WATCHDOG_S``):
only the injected faults make replies go missing.
"""

from __future__ import annotations

import argparse
import itertools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fault_targets import SlowMock, SteppedMock

from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.run_config import EXIT_FAULT, EXIT_OK, EXIT_STOP_UNCONFIRMED
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands

can = pytest.importorskip("can")

from bar_policy.robstride import motor_side  # noqa: E402
from bar_policy.robstride.errors import FrameError  # noqa: E402
from bar_policy.robstride.framing import CommType  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DT = 0.02
DAMPING_S = 0.3
"""--damping-time of these runs, s."""
REPLY_S = 0.25
"""Reply deadline on the virtual bus, s: a loaded 2-core host hands frames between threads well within it."""
WATCHDOG_S = 2.0
"""The motors' CAN watchdog, s (tests not about the watchdog must never trip it)."""
_ids = itertools.count()


def _args(**kw) -> argparse.Namespace:
    k = next(_ids)
    base = dict(
        can_interface="virtual",
        channels=f"can0=stopseq{os.getpid()}-{k}-0,can1=stopseq{os.getpid()}-{k}-1",
        calibration=None,
        dry_run=False,
        emulate="realtime",
        emulate_dt=None,
        reply_timeout=REPLY_S,
        can_timeout=WATCHDOG_S,
        damping_kd=1.0,
        scan_to=32,
        activation_retries=2,
        control_dt=DT,
        damping_time=DAMPING_S,
    )
    return argparse.Namespace(**(base | kw))


class Recorder:
    """A third node on both virtual channels: every frame anybody sends, with its arrival time."""

    def __init__(self, args: argparse.Namespace) -> None:
        pairs = dict(s.split("=") for s in args.channels.split(","))
        self.buses = {iface: can.Bus(interface="virtual", channel=ch) for iface, ch in pairs.items()}
        self.frames: dict[str, list[can.Message]] = {iface: [] for iface in pairs}

    def collect(self) -> None:
        for iface, bus in self.buses.items():
            while (msg := bus.recv(timeout=0)) is not None:
                self.frames[iface].append(msg)

    def host_frames(self, iface: str, motor_id: int) -> list[tuple[str, int, float]]:
        """Host -> ``motor_id`` frames as (kind, raw Kp of MIT frames else -1, timestamp), in order."""
        out = []
        for m in self.frames[iface]:
            try:
                req = motor_side.decode_request(m.arbitration_id, bytes(m.data))
            except FrameError:
                continue  # a motor's reply
            if req.motor_id != motor_id:
                continue
            if isinstance(req, motor_side.MitRequest):
                out.append(("MIT", req.raw[2], m.timestamp))
            else:
                out.append((CommType(req.comm_type).name, -1, m.timestamp))
        return out

    def close(self) -> None:
        for bus in self.buses.values():
            bus.shutdown()


def _real(args: argparse.Namespace):
    from bar_policy.deploy.targets.real_cli import make_target

    return make_target(args, "arms")


def _runtime(policy, target, *, duration=5.0, on_tick=None, log_dir=None, **safety) -> Runtime:
    cfg = RuntimeConfig(
        duration=duration,
        start_mode="policy",
        damping_after_fault=DAMPING_S,
        handle_signals=False,
        safety=SafetyConfig(**({"ramp_time": 0.0, "max_overruns": 0, "stale_timeout": 2.0} | safety)),
    )
    return Runtime(
        policy,
        target,
        SampledCommands(policy.obs_manager.command_names, seed=0),
        cfg,
        on_tick=on_tick,
        log_dir=log_dir,
    )


def _tail_after_policy(frames: list[tuple[str, int, float]]) -> list[tuple[str, int, float]]:
    """The frames after the last POLICY frame (MIT with Kp > 0)."""
    last = max(i for i, (kind, kp, _) in enumerate(frames) if kind == "MIT" and kp > 0)
    return frames[last + 1 :]


def _assert_one_sequence(rec: Recorder, iface: str, motor_id: int) -> float:
    """Damping frames (Kp = 0), then exactly one stop frame, nothing after; returns the damping's span, s."""
    tail = _tail_after_policy(rec.host_frames(iface, motor_id))
    kinds = [kind for kind, _, _ in tail]
    assert kinds.count("STOP") == 1, kinds
    assert kinds[-1] == "STOP" and all(k == "MIT" for k in kinds[:-1]), kinds
    assert all(kp == 0 for kind, kp, _ in tail[:-1]), tail
    assert len(tail) >= 2, "no damping frame before the stop frame"
    return tail[-1][2] - tail[0][2]


# -- one damping-then-stop sequence per run, whatever ends it ---------------------------------------------
FAULTS = ["fault bits", "missed replies", "watchdog trip", "duration", "stop request", "exception"]


@pytest.mark.parametrize("end", FAULTS)
def test_every_end_gives_one_damping_then_stop_of_the_damping_time(end, zero_policy, tmp_path):
    # Before: a driver error ran the target's own stop (0.2 s of damping, stop) and then the runtime's
    # (damping, a second stop 0.2 s later); the end reason was "exception TargetError: ..." with no end line.
    args = _args(can_timeout=0.1 if end == "watchdog trip" else WATCHDOG_S)
    target = _real(args)
    emu = target.companions[0]
    rec = Recorder(args)
    victim, victim_id = "right_wrist_roll", 26

    def on_tick(k, t, rt):
        if k != 10:
            return
        if end == "fault bits":
            emu.inject(victim, fault_bits=0b000100)  # overtemperature, from the next reply on
        elif end == "missed replies":
            emu.inject(victim, drop_replies=-1)
        elif end == "watchdog trip":
            time.sleep(0.5)  # 5x the 0.1 s watchdog: every motor leaves run mode
        elif end == "stop request":
            rt.request_stop("test stop")
        elif end == "exception":
            raise RuntimeError("policy blew up")

    duration = 0.6 if end == "duration" else 10.0
    rt = _runtime(zero_policy, target, duration=duration, on_tick=on_tick, log_dir=tmp_path)
    try:
        rt.open_log()  # as bar-deploy: nothing slow between the activation and the first tick
        target.start()
        if end == "exception":
            with pytest.raises(RuntimeError, match="policy blew up"):
                rt.run()
        else:
            rt.run()
    finally:
        target.close()
        time.sleep(0.05)
        rec.collect()
        rec.close()
    res = rt.result
    assert res is not None
    for iface, ids in (("can0", range(11, 18)), ("can1", range(21, 28))):
        for motor_id in ids:
            span = _assert_one_sequence(rec, iface, motor_id)
            # The damping lasted --damping-time (0.3 s): from the first damping frame to the stop frame; the
            # frames come every 10 ms (the target's hold) or every tick (20 ms, the loop's DAMPING ticks).
            assert span >= DAMPING_S - 0.021, (iface, motor_id, span)
    line = res.end_line()
    assert line.startswith("end: ")
    if end == "fault bits":
        assert res.end_reason.startswith(
            f"fault target: can1: motor fault: {victim} (id {victim_id}): overtemp"
        )
    elif end == "missed replies":
        assert res.end_reason.startswith(
            f"fault target: can1: no reply within {REPLY_S * 1e3:.1f} ms from [(26,"
        )
    elif end == "watchdog trip":
        assert res.end_reason.startswith("fault target: motors left run mode while commanded: ")
        assert "the CAN watchdog tripped" in res.end_reason
    elif end == "duration":
        assert res.end_reason == "duration reached" and res.exit_status == EXIT_OK
    elif end == "stop request":
        assert res.end_reason == "test stop" and res.exit_status == EXIT_OK
    else:
        assert res.end_reason == "exception RuntimeError: policy blew up"
    if end in ("fault bits", "missed replies", "watchdog trip"):
        assert res.exit_status in (EXIT_FAULT, EXIT_STOP_UNCONFIRMED)
    _, meta = load_log(rt.log_path.parent)
    assert meta["end_reason"] == res.end_reason


def test_the_first_fault_is_the_end_reason_and_later_ones_are_listed(zero_policy, tmp_path):
    # The target reports a hardware fault from read 10 (DAMPING from tick 10), then its bus fails at read 15:
    # the end reason stays the first fault, the bus failure is listed after it (end line and run record).
    first = "fault target: target reports faults ['MOTOR_FAULT id 13']"
    rt = _runtime(zero_policy, SteppedMock(faults_from=10, raise_at=15), log_dir=tmp_path)
    res = rt.run()
    assert res.end_reason == first and res.ticks == 15
    assert res.later_faults == ("fault target: injected bus failure at read 15",)
    assert res.end_line().endswith("; later faults: fault target: injected bus failure at read 15")
    _, meta = load_log(rt.log_path.parent)
    assert meta["end_reason"] == first
    assert meta["later_faults"] == ["fault target: injected bus failure at read 15"]
    assert meta["faults"] == [first, "fault target: injected bus failure at read 15"]


# -- the stop report: a joint answers with its own id, after its own stop frame ----------------------------
def test_a_silent_motor_is_not_confirmed_by_another_answering_with_its_id():
    args = _args()
    target = _real(args)
    emu = target.companions[0]
    try:
        target.start()
        target.read_state()
        # left_shoulder_pitch (id 11) falls silent; left_shoulder_roll (id 12) answers everything as id 11.
        emu.inject("left_shoulder_pitch", drop_replies=-1)
        emu.inject("left_shoulder_roll", reply_as=11)
        report = target.safe_stop(hold_s=0.0)
    finally:
        target.close()
    # Before: the stop round took id 11's (impostor) reply as left_shoulder_pitch's answer and reported only
    # left_shoulder_roll. Now neither counts: 11 said nothing after its own stop frame, and the frame carrying
    # 11 that came after 12's stop frame is not 12's.
    assert report.no_stop_reply == ("left_shoulder_pitch", "left_shoulder_roll")
    assert not report.confirmed and report.unconfirmed[:2] == ("left_shoulder_pitch", "left_shoulder_roll")
    assert set(report.unconfirmed) == {"left_shoulder_pitch", "left_shoulder_roll"}


def test_every_answering_motor_confirms_its_own_stop():
    target = _real(_args())
    try:
        target.start()
        target.read_state()
        report = target.safe_stop(hold_s=0.0)
        again = target.safe_stop(hold_s=1.0)  # already stopped: the same report, nothing sent
    finally:
        target.close()
    assert report.confirmed and again is report


# -- --duration is wall-clock time on a paced target ------------------------------------------------------
class SlowStepped(SteppedMock):
    """A synchronous target whose every read takes ``delay`` s (a loaded host, a slow viewer)."""

    def __init__(self, delay: float) -> None:
        super().__init__()
        self.delay = delay

    def read_state(self):
        time.sleep(self.delay)
        return super().read_state()


@pytest.mark.parametrize("which", ["async", "sim paced", "sim unpaced"])
def test_duration_is_wall_clock_time_when_paced(which, zero_policy):
    # Every read takes 30 ms > the 20 ms period: every tick ends after the next deadline. Duration 0.5 s =
    # 25 deadlines. Paced, each tick uses up >= 2 deadlines (it ran late, the one it overran is skipped), so
    # at most ceil(25 / 2) = 13 ticks run and the loop ends at the first deadline at or after 0.5 s of wall
    # clock. Before: 25 ticks, >= 0.75 s ("duration reached" after 1.5x the duration). Unpaced (a headless
    # sim), the duration is target time: 25 ticks.
    delay = 0.03
    if which == "async":
        target, realtime = SlowMock(slow_from=0, delay=delay), False
    else:
        target, realtime = SlowStepped(delay), which == "sim paced"
    cfg = RuntimeConfig(
        duration=0.5,
        start_mode="policy",
        realtime=realtime,
        handle_signals=False,
        safety=SafetyConfig(ramp_time=0.0, max_overruns=0, stale_timeout=10.0),
    )
    res = Runtime(zero_policy, target, SampledCommands(zero_policy.obs_manager.command_names), cfg).run()
    s = res.timing.summary()
    assert res.end_reason == "duration reached"
    if which == "sim unpaced":
        assert res.ticks == 25 and s["overruns"] == 0
        return
    assert res.ticks <= 13 and s["overruns"] == res.ticks  # every tick ran late
    assert res.ticks + s["skipped"] >= 25  # the deadlines passed: run or skipped
    # The last tick started before the 0.5 s deadline and took >= 30 ms; the loop stops at the next
    # deadline check, so the wall time is at least 0.5 s minus one tick's start slack and at most 0.5 s
    # plus the longest tick (compute holds the read) plus one period.
    assert res.timing.wall >= 0.5 - DT
    assert res.timing.wall <= 0.5 + float(res.timing.compute.max()) + DT
    text = res.timing.format()
    assert f"late ticks {res.ticks} (ended after the next deadline; {s['skipped']} deadlines skipped)" in text


# -- the real target refuses a step start unless told loudly -----------------------------------------------
def test_ramp_limit_matches_the_hand_derivation(zero_policy):
    from bar_policy.deploy.ramp_limit import min_ramp_time

    # Wrist yaw: range [-pi/2, pi/2], hold -1.2 (the factory's default pose), Kp 20 (policy_factory), cap
    # 4 N*m, dt 0.02 s: E = pi/2 + 0.3 + 1.2; T = 1.5 E Kp dt / cap.
    lim = min_ramp_time(zero_policy)
    kp = float(zero_policy.kp[4])
    e = np.pi / 2 + 0.3 + 1.2
    assert lim.joint in ("left_wrist_yaw", "right_wrist_yaw")
    assert lim.error == pytest.approx(e, abs=1e-6)  # the pose is float32: 1e-7 rad rounding
    assert lim.seconds == pytest.approx(1.5 * e * kp * 0.02 / 4.0, rel=1e-6)


def _cli(argv: list[str], timeout: float = 120.0) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return subprocess.run(
        [sys.executable, "-m", "bar_policy.entry", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


SHIPPED = str(REPO / "checkpoints" / "lite_reach_arms.onnx")
"""Kp 50 on every joint: the minimum ramp is 1.152 s (the wrist yaw; ``ramp_limit``'s docstring)."""


@pytest.mark.parametrize("start", [["--ramp-time", "0"], ["--ramp-time", "1.1"], ["--start", "policy"]])
def test_real_target_refuses_a_step_start(start, tmp_path):
    p = _cli(["--policy", SHIPPED, "--target", "real", "--can-interface", "virtual", *start, "--no-log"])
    assert p.returncode == 2, p.stderr
    (line,) = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert line.startswith("bar-deploy: error: ") and "is refused on the real target" in line
    assert "safe minimum ramp of 1.16 s" in line and "--unsafe-allow-step-start" in line
    assert "real target started" not in p.stderr  # nothing was enabled


def test_real_target_takes_a_step_start_with_the_override_and_warns(tmp_path):
    argv = ["--policy", SHIPPED, "--target", "real", "--can-interface", "virtual", "--start", "policy"]
    argv += ["--unsafe-allow-step-start", "--duration", "0.2", "--no-log", "--reply-timeout", str(REPLY_S)]
    argv += ["--can-timeout", str(WATCHDOG_S), "--max-overruns", "0", "--stale-timeout", "2"]
    p = _cli(argv)
    assert p.returncode == 0, p.stderr
    assert "WARNING: --unsafe-allow-step-start: --start policy (no ramp) on the real target" in p.stderr
    assert "end: duration reached" in p.stdout


def test_sim_target_keeps_the_step_start(tmp_path):
    p = _cli(["--policy", SHIPPED, "--target", "sim", "--ramp-time", "0", "--duration", "0.1", "--no-log"])
    assert p.returncode == 0, p.stderr
    p = _cli(["--policy", SHIPPED, "--target", "sim", "--start", "policy", "--duration", "0.1", "--no-log"])
    assert p.returncode == 0 and "WARNING" not in p.stderr


# -- exit statuses of a stop at every moment ----------------------------------------------------------------
def test_stop_during_the_real_start_up_exits_0(tmp_path, monkeypatch, capsys):
    # SIGINT arrives while the real target activates (after the stop handlers are installed): the start-up
    # ends, nothing stays enabled, and bar-deploy exits 0 as for any requested stop. Before: exit 2,
    # "error: ... start-up stopped".
    from bar_policy.deploy.cli import main
    from bar_policy.robstride.group import RobstrideGroup

    original = RobstrideGroup.activate

    def interrupted(self, *a, **kw):
        os.kill(os.getpid(), signal.SIGINT)
        return original(self, *a, **kw)

    monkeypatch.setattr(RobstrideGroup, "activate", interrupted)
    k = next(_ids)
    status = main(
        [
            "--policy",
            SHIPPED,
            "--target",
            "real",
            "--can-interface",
            "virtual",
            "--log",
            str(tmp_path),
            "--channels",
            f"can0=su{os.getpid()}-{k}-0,can1=su{os.getpid()}-{k}-1",
        ]
    )
    out = capsys.readouterr().out
    assert status == 0
    assert "SIGINT received during the start-up: start-up stopped" in out
    assert "end: SIGINT received during the start-up; nothing left enabled" in out
    (run,) = list(tmp_path.iterdir())
    _, meta = load_log(run)
    assert meta["end_reason"] == "stopped during the start-up: SIGINT received"


_EARLY_CHILD = """
import os, signal, sys, importlib.abc
from bar_policy import entry
assert "numpy" not in sys.modules  # the entry point is in place before the heavy imports
class SignalAtNumpy(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.{sig})
        return None
sys.meta_path.insert(0, SignalAtNumpy())
sys.exit(entry.deploy(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_during_the_imports_ends_quietly_with_status_0(sig, policy_path):
    # The signal lands exactly when numpy starts to be imported (inside ``bar_policy.deploy.cli``'s import,
    # where the issue saw a traceback for SIGINT and SIGTERM killed the process with -15).
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    p = subprocess.run(
        [sys.executable, "-c", _EARLY_CHILD.format(sig=sig), "--policy", str(policy_path), "--no-log"],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr
    assert p.stdout.strip() == f"{sig} received before the start: nothing was started"


def test_a_signal_during_the_imports_of_eval_exits_130(policy_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    p = subprocess.run(
        [sys.executable, "-c", _EARLY_CHILD.format(sig="SIGINT"), "eval", "--policy", str(policy_path)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert p.returncode == 130 and "Traceback" not in p.stderr
    assert p.stderr.strip() == "bar-deploy eval: interrupted (SIGINT)"


# -- damping that holds the arms: gravity compensation for the fault and end stops -------------------------
def test_gravity_torque_equals_inverse_dynamics_at_rest():
    # Independent reference: mj_inverse with qvel = 0 and qacc = 0 gives the generalized force that holds the
    # pose, M 0 + bias - passive - constraint = gravity (no joint springs: passive = damping x 0 = 0; the
    # constraints are disabled in the reference: a random pose may put two links in contact).
    import mujoco

    from bar_policy.deploy.gravity import GravityTorque
    from bar_policy.robot.constants import load_robot
    from bar_policy.robot.scene import load_model

    g = GravityTorque("arms")
    model = load_model("arms")
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    robot = load_robot("arms")
    for _ in range(5):
        q = rng.uniform(robot.lower, robot.upper)
        data.qpos[:14], data.qvel[:], data.qacc[:] = q, 0.0, 0.0
        mujoco.mj_inverse(model, data)
        # Same floating-point operations up to ordering: 1e-9 N*m on torques of at most a few N*m.
        np.testing.assert_allclose(g.raw(q), data.qfrc_inverse[:14], atol=1e-9)
        np.testing.assert_allclose(g(q), np.clip(data.qfrc_inverse[:14], -robot.torque_cap, robot.torque_cap))
    assert g.clip_count == 0 and g.calls == 5


def test_gravity_torque_beyond_a_cap_is_clipped_and_counted():
    from bar_policy.deploy.gravity import GravityTorque

    g = GravityTorque("arms")
    g.cap = g.cap * 0.0 + 0.01  # every joint whose gravity torque exceeds 0.01 N*m is clipped
    q = np.zeros(14)
    raw = g.raw(q)
    tau = g(q)
    over = np.abs(raw) > 0.01
    np.testing.assert_array_equal(tau, np.clip(raw, -0.01, 0.01))
    assert g.clip_count == int(over.sum()) > 0


def _sag(target_name: str, kind: str, zero_policy, tmp_path) -> tuple[float, dict, np.ndarray, np.ndarray]:
    """The sag (rad, worst joint) over 1 s of damping after a stop at 1 s; the log's record, tau_ff, caps."""
    from bar_policy.deploy.safety import Mode

    policy = zero_policy
    if target_name == "sim":
        from bar_policy.deploy.targets.sim import SimTarget

        target = SimTarget("arms")
    else:
        from bar_policy.deploy.targets.emulated import EmulatedBusTarget

        target = EmulatedBusTarget("arms", DT, reply_timeout=0.5)
    target.reset(policy.hold_pose)
    qs: list[np.ndarray] = []

    def on_tick(k, t, rt):
        if k == 50:
            rt.request_stop("measurement")
        if rt.safety.mode == Mode.DAMPING:
            qs.append(rt.last_state.q.copy())

    cfg = RuntimeConfig(
        duration=3.0,
        start_mode="policy",
        damping_after_fault=1.0,
        stop_damping=kind,
        handle_signals=False,
        safety=SafetyConfig(ramp_time=0.0, max_overruns=0),
    )
    rt = Runtime(
        policy,
        target,
        SampledCommands(policy.obs_manager.command_names),
        cfg,
        on_tick=on_tick,
        log_dir=tmp_path,
    )
    try:
        res = rt.run()
    finally:
        target.close()
    assert res.end_reason == "measurement" and res.exit_status == EXIT_OK
    q = np.asarray(qs)
    assert len(q) == 51  # tick 51 .. 101: 1 s of DAMPING at 50 Hz
    arrays, meta = load_log(rt.log_path.parent)
    damping = arrays["mode"] == int(Mode.DAMPING)
    if kind == "gravity":  # each DAMPING tick's tau_ff is the gravity torque at that tick's measured q
        from bar_policy.deploy.gravity import GravityTorque

        g = GravityTorque("arms")
        expected = np.array([g(q) for q in arrays["q"][damping]])
        np.testing.assert_allclose(arrays["tau_ff"][damping], expected, rtol=0, atol=1e-12)
    return (
        float(np.abs(q - q[0]).max()),
        meta["stop_damping"],
        arrays["tau_ff"][damping],
        policy.robot.torque_cap,
    )


@pytest.mark.parametrize("target_name", ["sim", "emulated"])
def test_damping_alone_sags_and_gravity_damping_holds_the_arms(target_name, zero_policy, tmp_path):
    # The policy's rest pose (elbows at -1.7 rad, the upper arms forward): 1 s of damping alone lets the
    # elbows fall about 1 rad (measured: bench/stop_sag.py); the gravity torque as tau_ff holds the pose
    # within 0.1 rad, with every tau_ff within its cap (no cap raised) and no clip.
    plain, rec_plain, ff_plain, _ = _sag(target_name, "plain", zero_policy, tmp_path / "plain")
    held, rec, ff, cap = _sag(target_name, "gravity", zero_policy, tmp_path / "gravity")
    assert plain > 0.5, plain
    assert held < 0.1, held
    assert rec_plain["kind"] == "plain" and "gravity" not in rec_plain
    np.testing.assert_array_equal(ff_plain, 0.0)
    assert rec["kind"] == "gravity" and rec["gravity"]["clipped_joint_evaluations"] == 0
    assert np.all(np.abs(ff) <= cap) and np.abs(ff).max() > 0.5  # the elbows' gravity torque, N*m


def test_the_real_targets_own_stop_damps_with_the_gravity_torque():
    # After a driver error the real target stops by itself: its damping frames carry tau_ff = the gravity
    # torque at the measured q (in the motor's frame: direction x tau), to the wire's 16-bit step.
    from bar_policy.deploy.gravity import GravityTorque
    from bar_policy.robot.mit import wire_ranges

    args = _args()
    target = _real(args)
    rec = Recorder(args)
    g = GravityTorque("arms")
    try:
        target.start()
        q = target.read_state().q
        rec.collect()
        rec.frames = {k: [] for k in rec.frames}
        target.use_stop_torque(g)
        target.safe_stop(hold_s=0.0)  # one damping round at the last reading's q, then the stops
    finally:
        target.close()
        time.sleep(0.05)
        rec.collect()
        rec.close()
    expected = g(q)
    index = {n: i for i, n in enumerate(target.joint_names)}
    for bus in target.group.buses:
        ranges = wire_ranges([m.model for m in bus.motors])
        for k, motor in enumerate(bus.motors):
            (mit,) = [
                req
                for m in rec.frames[bus.interface]
                for req in [_request(m)]
                if isinstance(req, motor_side.MitRequest) and req.motor_id == motor.can_id
            ]
            tau = mit.setpoint(motor.model).tau
            step = 2 * ranges.t_max[k] / 65535  # one 16-bit step of the torque field
            assert tau == pytest.approx(motor.direction * expected[index[motor.name]], abs=step), motor.name


def _request(m):
    try:
        return motor_side.decode_request(m.arbitration_id, bytes(m.data))
    except FrameError:
        return None


class ClosedViewer(SteppedMock):
    """A synchronous target whose ``advance`` fails from step ``at`` on (a sim whose viewer was closed)."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def advance(self, dt: float) -> None:
        if self.steps >= self.at:
            from bar_policy.deploy.targets.base import TargetError

            raise TargetError("the viewer window was closed")
        super().advance(dt)


def test_a_synchronous_target_that_cannot_advance_ends_the_run_as_a_fault(zero_policy, tmp_path):
    # advance fails after tick 5 ran (ticks 0..5 are in the log): the fault "target", no exception, status 1.
    rt = _runtime(zero_policy, ClosedViewer(5), log_dir=tmp_path)
    res = rt.run()
    assert res.ticks == 6 and res.end_reason == "fault target: the viewer window was closed"
    assert res.exit_status == EXIT_FAULT and res.end_line().startswith("end: fault target: the viewer")
    arrays, _ = load_log(rt.log_path.parent)
    assert arrays["t"].size == 6


def test_a_fault_that_repeats_with_other_numbers_is_listed_once_and_counted(zero_policy, tmp_path):
    # The stamp freezes at read 5: from tick 8 (age 0.06 s > 0.05 s) every tick is stale, each with its own
    # age in the text ("state is 60.0 ms old", "80.0 ms", ...): one fault in the record, counted per tick.
    rt = _runtime(zero_policy, SteppedMock(freeze_from=5), log_dir=tmp_path, stale_timeout=0.05)
    res = rt.run()
    assert res.end_reason == "fault stale_state: state is 60.0 ms old (timeout 50 ms)"
    assert rt.faults == [res.end_reason] and rt.fault_repeats == [res.fault_count] and res.fault_count > 1
    assert res.later_faults == () and "later faults" not in res.end_line()
    _, meta = load_log(rt.log_path.parent)
    assert meta["faults"] == [res.end_reason] and meta["fault_repeats"] == [res.fault_count]
