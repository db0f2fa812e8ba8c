"""Start-up of the real target: a stop request between steps enables nothing; missing replies are retried."""

from __future__ import annotations

import os
import signal

import pytest

from bar_policy.deploy.targets.base import TargetError
from bar_policy.deploy.targets.real import installed_stop_request
from bar_policy.robstride.errors import StopRequestedError, TimeoutError
from bar_policy.robstride.framing import PARAM_LIMIT_TORQUE, CommType
from bar_policy.robstride.startup import StartupControl
from bar_policy.signals import StopSignals

from .helpers import make_target

LEFT = [
    "left_shoulder_pitch",
    "left_shoulder_roll",
    "left_shoulder_yaw",
    "left_elbow_pitch",
    "left_wrist_yaw",
    "left_wrist_roll",
    "left_wrist_pitch",
]


def _cap_write_seen(listener) -> bool:
    """Whether the host has sent a torque-limit write (type 18, index 0x700B) on the listener's bus."""
    for m in listener.host_frames((18,)):
        if int.from_bytes(bytes(m.data[0:2]), "little") == PARAM_LIMIT_TORQUE:
            return True
    return False


def _assert_nothing_enabled(listeners, emu) -> None:
    for lst in listeners.values():
        assert lst.host_frames((3,)) == [], "an enable frame went out"
    assert not any(emu.enabled().values())


def test_stop_after_the_limits_write_enables_nothing(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    checks = []

    def stop_requested() -> bool:
        checks.append(1)
        return _cap_write_seen(listeners["can0"])

    target = make_target(robot, channels, stop_requested=stop_requested)
    with pytest.raises(TargetError, match=r"start-up stopped: .*nothing was enabled") as info:
        target.start()
    cause = info.value.__cause__
    assert isinstance(cause, StopRequestedError) and not cause.enabled
    assert "cap writes" in cause.step  # the request was seen at the next motor's cap writes
    assert len(checks) > 5  # checked between steps, not once
    _assert_nothing_enabled(listeners, emu)
    # the canTimeout was never armed on the other bus either: nothing after the stop request was written
    assert all(int(emu.motor(n).params[0x7028]) == 0 for n in robot.joint_names)
    assert target.stopped is False and target.enabled is False


def test_sigint_during_start_up_through_the_installed_stop_signals(robot, channels, listeners, make_emulator):
    """The CLI path: StopSignals installed, a real SIGINT after the limits write, the default check."""
    emu = make_emulator()
    fired = []

    def stop_requested() -> bool:
        if not fired and _cap_write_seen(listeners["can0"]):
            fired.append(1)
            os.kill(os.getpid(), signal.SIGINT)  # handled by StopSignals: sets the flag, raises nothing
        return installed_stop_request()

    with StopSignals() as stop:
        assert stop.installed and not installed_stop_request()
        target = make_target(robot, channels, stop_requested=stop_requested)
        with pytest.raises(TargetError, match="start-up stopped"):
            target.start()
        assert stop.requested and stop.signal_name == "SIGINT"
    assert not installed_stop_request()  # handlers restored
    _assert_nothing_enabled(listeners, emu)


def test_stop_before_the_start_sends_nothing(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    target = make_target(robot, channels, stop_requested=lambda: True)
    with pytest.raises(TargetError, match=r"before the start-up: nothing was enabled"):
        target.start()
    for lst in listeners.values():
        assert lst.host_frames((0, 1, 3, 4, 17, 18)) == []
    assert not any(emu.enabled().values())


def test_stop_after_the_enable_frames_damps_and_stops(robot, channels, listeners, make_emulator):
    from .conftest import assert_ends_with_damping_then_stop

    emu = make_emulator()
    target = make_target(robot, channels, stop_requested=lambda: bool(listeners["can1"].host_frames((3,))))
    with pytest.raises(TargetError, match=r"before the damping hold: the motors were enabled"):
        target.start()
    assert not any(emu.enabled().values())
    assert_ends_with_damping_then_stop(listeners["can0"], [11, 12, 13, 14, 15, 16, 17])
    assert_ends_with_damping_then_stop(listeners["can1"], [21, 22, 23, 24, 25, 26, 27])


@pytest.mark.parametrize("n", [1, 2])
def test_missing_joint_read_replies_are_retried(robot, channels, make_emulator, caplog, n):
    """All 7 motors of can0 miss their reply to the joint read (the reported failure), ``n`` times."""
    emu = make_emulator()
    for name in LEFT:
        emu.inject(name, drop_replies=n, drop_only=CommType.STOP)
    target = make_target(robot, channels, activation_retries=3, retry_backoff=0.001)
    with target:
        assert all(emu.enabled().values())
        assert target.startup.retries_used == {"joint read": n}
        meta = target.run_metadata()
        assert meta["activation_retries"] == n and meta["activation_retries_by_step"] == {"joint read": n}
    assert f"activation needed {n} retries of a missing reply" in caplog.text


@pytest.mark.slow
def test_too_many_missing_replies_refuse_with_the_tries(robot, channels, listeners, make_emulator):
    emu = make_emulator()
    for name in LEFT:
        emu.inject(name, drop_replies=3, drop_only=CommType.STOP)
    target = make_target(robot, channels, activation_retries=2, retry_backoff=0.001)
    with pytest.raises(TargetError, match=r"no reply within .* refusing after 3 tries \(2 retries"):
        target.start()
    _assert_nothing_enabled(listeners, emu)


def test_missing_scan_and_parameter_replies_are_retried(robot, channels, make_emulator):
    emu = make_emulator()
    emu.inject("right_wrist_roll", drop_replies=2, drop_only=CommType.GET_ID)
    emu.inject("left_elbow_pitch", drop_replies=1, drop_only=CommType.PARAM_READ)
    target = make_target(robot, channels, retry_backoff=0.001)
    with target:
        assert all(emu.enabled().values())
        assert target.startup.retries_used == {"scan of can1": 2, "can0 parameter exchange": 1}
        assert target.run_metadata()["activation_retries"] == 3


def test_scan_refusal_says_how_many_scans(robot, channels, make_emulator):
    make_emulator(absent=["right_wrist_roll"])
    target = make_target(robot, channels, activation_retries=1, retry_backoff=0.001)
    with pytest.raises(TargetError, match=r"scan mismatch.*right_wrist_roll.*\(after 2 scans\)"):
        target.start()


def test_no_retry_needed_leaves_the_run_metadata_as_it_was(robot, channels, make_emulator):
    make_emulator()
    with make_target(robot, channels) as target:
        assert target.startup.retries_used == {}
        assert target.run_metadata() == {"can_timeout": target.can_timeout}


def test_startup_control_retries_only_missing_replies():
    calls = []

    def flaky() -> str:
        calls.append(1)
        if len(calls) < 3:
            raise TimeoutError("no reply", missing=(5,), interface="can0")
        return "ok"

    ctl = StartupControl(retries=2, backoff=0.0)
    assert ctl.attempt("step", flaky) == "ok" and ctl.retries_used == {"step": 2} and ctl.total_retries == 2
    with pytest.raises(ValueError):
        StartupControl(retries=-1)

    def refused() -> None:
        raise StopRequestedError("x", step="y")

    with pytest.raises(StopRequestedError):
        StartupControl(retries=5, backoff=0.0).attempt("step", refused)


def test_bar_deploy_sigint_after_the_limits_write(robot, tmp_path, monkeypatch, capsys):
    """``bar-deploy --target real --can-interface virtual --emulate lockstep``: SIGINT after the first bus's
    cap writes ends the start-up there: nothing enabled, no policy tick, a clear message."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
    from policy_factory import make_policy_file

    from bar_policy.deploy import cli
    from bar_policy.robstride import group

    real_write_caps, fired = group.write_caps, []

    def write_caps(bus, **kw):
        out = real_write_caps(bus, **kw)
        if not fired:
            fired.append(bus.interface)
            os.kill(os.getpid(), signal.SIGINT)
        return out

    monkeypatch.setattr(group, "write_caps", write_caps)
    policy = make_policy_file(tmp_path / "zero.onnx")
    rc = cli.main(
        [
            "--policy",
            str(policy),
            "--target",
            "real",
            "--can-interface",
            "virtual",
            "--emulate",
            "lockstep",
            "--no-log",
            "--duration",
            "1",
            "--channels",
            f"can0=rs-cli{os.getpid()}-0,can1=rs-cli{os.getpid()}-1",
        ]
    )
    out = capsys.readouterr().out
    # A requested stop: status 0 at every moment, the start-up included (it ends the start-up there).
    assert fired == ["can0"] and rc == 0
    assert "start-up stopped: stop requested during start-up, before arming canTimeout on can0" in out
    assert "nothing was enabled" in out
