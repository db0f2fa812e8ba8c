"""Builders shared by the bus, safety and target tests."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import can

from bar_policy.deploy.targets.real import RealTarget
from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.group import RobstrideGroup

from .bridge import PORT_ENV

TEST_TIMEOUT = 2.0
"""Reply deadline in tests, s: what a loaded 2-core CI host gives, not what the robot needs.

The emulator answers from its own thread, so a reply's latency is the host's scheduling delay: a thread was
seen stalled 490 ms in a full run, and a 200 ms deadline failed ("no reply within 200.0 ms") on a fresh
clone of a loaded 2-core machine. 2 s is four times the worst stall seen; only fault paths (a motor that
never answers) wait for it, and those tests set their own shorter deadline where the wait would add up."""


TEST_CAN_TIMEOUT = 1.0
"""The motors' CAN watchdog in tests, s (the robot's is 0.2): a test not about the watchdog must not trip it
when the loaded 2-core host stalls a thread (one did for 490 ms in a full run). The watchdog's own tests
set theirs."""


def make_group(
    robot, channels, *, calibration: Calibration | None = None, timeout: float = TEST_TIMEOUT, **kw
):
    kw.setdefault("can_timeout", TEST_CAN_TIMEOUT)
    buses = {i: can.Bus(interface="virtual", channel=ch) for i, ch in channels.items()}
    return RobstrideGroup.from_robot(robot, buses, calibration=calibration, reply_timeout=timeout, **kw)


def command_position(emu, robot, target) -> None:
    """Enable every joint motor of the emulator ``emu`` and latch a position command to ``target`` (rad,
    canonical order) at the robot's gains, as a type-1 frame would, without bus rounds (motor frame:
    ``raw = direction * q``; no homing offsets)."""
    for motor in emu.motors.values():
        j = motor.joint
        motor.enabled = True
        motor.cmd = (motor.direction * target[j], 0.0, robot.kp[j], robot.kd[j], 0.0)


def make_target(robot, channels, **kw) -> RealTarget:
    group = make_group(robot, channels, calibration=kw.pop("calibration", None), **kw.pop("group_kw", {}))
    kw.setdefault("refresh_on_read", False)
    kw.setdefault("damping_hold_s", 0.0)
    kw.setdefault("scan_ids", range(1, 33))
    return RealTarget(robot, group, **kw)


# ---------------------------------------------------------------------------------------------------
# a real subprocess whose virtual buses reach this process through ``bridge.SocketcandBridge``
# ---------------------------------------------------------------------------------------------------
_HERE = Path(__file__).resolve().parent
_REPO = _HERE.parents[1]


class Child:
    """``python bridged.py ARGS`` with its stdout read by a thread (``wait_for`` a line)."""

    def __init__(self, args: list[str], port: int) -> None:
        env = dict(os.environ)
        env[PORT_ENV] = str(port)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(_REPO), env.get("PYTHONPATH")]))
        env["PYTHONUNBUFFERED"] = "1"
        self.proc = subprocess.Popen(
            [sys.executable, str(_HERE / "bridged.py"), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.out: list[str] = []
        self._err: list[str] = []
        self._readers = [
            threading.Thread(target=self._read, args=(self.proc.stdout, self.out, True), daemon=True),
            threading.Thread(target=self._read, args=(self.proc.stderr, self._err, False), daemon=True),
        ]
        for t in self._readers:
            t.start()

    def _read(self, stream, sink: list[str], notify: bool) -> None:
        for line in stream:
            sink.append(line)
            if notify:
                self.lines.put(line)

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        """Block until a stdout line contains ``text``; fails with the child's stderr otherwise."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            try:
                if text in self.lines.get(timeout=min(left, 0.5)):
                    return
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
        self.kill()
        raise AssertionError(f"no line with {text!r}; stdout {self.out}; stderr {self.finish()[1]}")

    def finish(self, timeout: float = 60.0) -> tuple[int, str]:
        """Wait for the exit and the end of both streams; returns (status, stderr)."""
        self.proc.wait(timeout=timeout)
        for t in self._readers:
            t.join(timeout=5)
        return self.proc.returncode, "".join(self._err)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
