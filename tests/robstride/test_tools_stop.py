"""``bar-bus calibrate``'s stop path: SIGINT, SIGTERM and SIGHUP to a real subprocess, a second signal during
shutdown, and an exception, all end with damping then stop frames on both buses (seen by listener nodes)."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.errors import OperationError
from bar_policy.robstride.group import RobstrideGroup
from bar_policy.robstride.tools import main

from .bridge import SocketcandBridge
from .conftest import assert_ends_with_damping_then_stop, swept_emulator
from .helpers import TEST_TIMEOUT, Child

LEFT = [11, 12, 13, 14, 15, 16, 17]
RIGHT = [21, 22, 23, 24, 25, 26, 27]
LSB = 8 * np.pi / 65535  # one step of the 16-bit position field


@pytest.fixture
def sweeping(robot, make_emulator):
    """An emulator with random true offsets whose joints a 'person' sweeps stop to stop (30 ms rests)."""
    with swept_emulator(robot, make_emulator, seed=3) as swept:
        yield swept


def _calibrate_child(bridge, out, *extra):
    return Child(
        [
            "bar-bus",
            "calibrate",
            "--can-interface",
            "virtual",
            "--calibration",
            str(out),
            "--reply-timeout",
            str(TEST_TIMEOUT),
            "--rate",
            "100",
            *extra,
        ],
        bridge.port,
    )


@pytest.mark.parametrize(
    "sig",
    [
        signal.SIGINT,
        pytest.param(signal.SIGTERM, marks=pytest.mark.slow),
        pytest.param(signal.SIGHUP, marks=pytest.mark.slow),
    ],
)
def test_stop_signal_damps_stops_then_writes(sig, tmp_path, robot, channels, listeners, sweeping):
    emu, true = sweeping
    out = tmp_path / "cal.json"
    with SocketcandBridge(channels) as bridge:
        child = _calibrate_child(bridge, out)
        try:
            child.wait_for("Move each joint")
            time.sleep(1.0)  # several sweeps recorded
            os.kill(child.proc.pid, sig)
            code, err = child.finish()
        finally:
            child.kill()
    assert code == 0, err
    assert f"stopping: {sig.name} received; damping and stop frames sent" in "".join(child.out)
    assert "Traceback" not in err
    for iface, ids in (("can0", LEFT), ("can1", RIGHT)):
        assert_ends_with_damping_then_stop(listeners[iface], ids)
    np.testing.assert_allclose(Calibration.load(out).offsets(robot), true, atol=2 * LSB)
    assert not any(emu.enabled().values())


@pytest.mark.slow
def test_second_signal_during_shutdown_cannot_skip_the_stop_frames(tmp_path, channels, listeners, sweeping):
    """SIGINT and SIGHUP land while the damping round waits for replies (can1 silenced: 0.5 s deadline)."""
    emu, _ = sweeping
    out = tmp_path / "cal.json"
    with SocketcandBridge(channels) as bridge:
        child = _calibrate_child(bridge, out)
        try:
            child.wait_for("Move each joint")
            time.sleep(0.5)
            emu.silence("can1")  # from now on every round waits its 0.5 s deadline for can1
            listeners["can0"].collect()
            os.kill(child.proc.pid, signal.SIGTERM)
            end = time.monotonic() + 30
            while not listeners["can0"].host_frames((1,)) and time.monotonic() < end:  # damping began
                time.sleep(0.002)
            os.kill(child.proc.pid, signal.SIGINT)
            os.kill(child.proc.pid, signal.SIGHUP)
            code, err = child.finish()
        finally:
            child.kill()
    assert code == 0, err
    assert "stopping: SIGTERM received" in "".join(child.out)
    assert "received again (2 signals): ignored" in err and "received again (3 signals): ignored" in err
    assert "SIGINT received again" in err and "SIGHUP received again" in err  # in either order
    for iface, ids in (("can0", LEFT), ("can1", RIGHT)):
        assert_ends_with_damping_then_stop(listeners[iface], ids)
    assert out.exists()


def test_exception_damps_stops_and_discards(tmp_path, channels, listeners, sweeping, monkeypatch, capsys):
    """A bus failure mid-sweep: damping then stop frames on both buses, nothing written, one line, exit 1."""
    out = tmp_path / "cal.json"
    out.write_text("previous calibration\n")
    real_poll, calls = RobstrideGroup.poll_disabled, []

    def failing_poll(self, **kw):
        calls.append(1)
        if len(calls) == 20:
            raise OperationError("can1: cannot send: CAN interface can1 is down")
        return real_poll(self, **kw)

    monkeypatch.setattr(RobstrideGroup, "poll_disabled", failing_poll)
    chans = f"{channels['can0']},{channels['can1']}"
    code = main(
        [
            "calibrate",
            "--can-interface",
            "virtual",
            "--channels",
            chans,
            "--calibration",
            str(out),
            "--reply-timeout",
            str(TEST_TIMEOUT),
            "--rate",
            "200",
        ]
    )
    err = capsys.readouterr().err
    assert code == 1
    assert err == "bar-bus: error: can1: cannot send: CAN interface can1 is down\n"
    assert out.read_text() == "previous calibration\n"  # discarded: the old file is untouched
    for iface, ids in (("can0", LEFT), ("can1", RIGHT)):
        assert_ends_with_damping_then_stop(listeners[iface], ids)


def test_nothing_swept_writes_nothing(tmp_path, channels, make_emulator, capsys):
    make_emulator()  # nobody moves the joints
    out = tmp_path / "cal.json"
    chans = f"{channels['can0']},{channels['can1']}"
    code = main(
        [
            "calibrate",
            "--can-interface",
            "virtual",
            "--channels",
            chans,
            "--calibration",
            str(out),
            "--reply-timeout",
            str(TEST_TIMEOUT),
            "--duration",
            "0.2",
        ]
    )
    assert code == 1 and not out.exists()
    assert "no joint was swept by 0.5 rad or more" in capsys.readouterr().err


def test_watchdog_probe_stopped_by_sigterm_damps_then_stops(channels, listeners, make_emulator):
    emu = make_emulator()
    with SocketcandBridge(channels) as bridge:
        child = Child(
            [
                "bar-bus",
                "watchdog",
                "--can-interface",
                "virtual",
                "--channel",
                "can0",
                "--id",
                "11",
                "--reply-timeout",
                "0.5",
                "--silences",
                "0.3,0.3,0.3,0.3",
            ],
            bridge.port,
        )
        try:
            child.wait_for("probing silences")
            time.sleep(0.2)
            os.kill(child.proc.pid, signal.SIGTERM)
            code, err = child.finish()
        finally:
            child.kill()
    assert code == 128 + signal.SIGTERM, err  # cut short: not the documented finish
    assert "stopped by SIGTERM received before the end; damping and stop frames sent" in "".join(child.out)
    assert_ends_with_damping_then_stop(listeners["can0"], [11])
    assert listeners["can1"].host_frames() == []
    assert not any(emu.enabled().values())
