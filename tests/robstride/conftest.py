"""Fixtures: unique virtual channels, a lockstep emulator, listener buses that record every frame."""

from __future__ import annotations

import contextlib
import itertools
import threading
import time
from collections.abc import Iterator

import can
import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robstride import protocol as proto

_counter = itertools.count()


@pytest.fixture
def robot():
    return load_robot("arms")


@pytest.fixture
def channels() -> dict[str, str]:
    """Robot interface -> a virtual channel name unique to this test (virtual channels are process-global)."""
    k = next(_counter)
    return {"can0": f"rs-test{k}-can0", "can1": f"rs-test{k}-can1"}


class Listener:
    """A third node on a virtual channel: records every frame anybody sends."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[can.Message] = []

    def collect(self) -> list[can.Message]:
        while (msg := self.bus.recv(timeout=0)) is not None:
            self.frames.append(msg)
        return self.frames

    def host_frames(self, types: tuple[int, ...] = (1, 3, 4, 6, 18)) -> list[can.Message]:
        """Frames only the host sends (types 1, 3, 4, 6, 18 never come from a motor)."""
        return [m for m in self.collect() if m.is_extended_id and (m.arbitration_id >> 24) in types]


@pytest.fixture
def listeners(channels) -> Iterator[dict[str, Listener]]:
    ls = {iface: Listener(ch) for iface, ch in channels.items()}
    yield ls
    for lst in ls.values():
        lst.bus.shutdown()


@pytest.fixture
def make_emulator(robot, channels):
    from bar_policy.robstride.emulator import RobstrideEmulator

    made = []

    def make(**kw):
        kw.setdefault("mode", "lockstep")
        emu = RobstrideEmulator(kw.pop("robot", robot), channels, **kw).start()
        made.append(emu)
        return emu

    yield make
    for emu in made:
        emu.close()


def assert_ends_with_damping_then_stop(listener: Listener, ids: list[int], kd: float = 1.0) -> None:
    """The last host frames on a bus: one damping frame per motor (Kp = 0, Kd = kd, tau_ff = 0), then one
    stop frame (type 4, byte0 = 0) per motor, and nothing after them."""
    frames = listener.host_frames((1, 3, 4))
    n = len(ids)
    assert len(frames) >= 2 * n, f"only {len(frames)} host frames"
    damping, stops = frames[-2 * n : -n], frames[-n:]
    # stop: id = (4 << 24) | (0xFD << 8) | motor id, payload 00 * 8
    assert sorted(m.arbitration_id for m in stops) == sorted((4 << 24) | (0xFD << 8) | i for i in ids)
    assert all(bytes(m.data) == bytes(8) for m in stops)
    assert sorted(m.arbitration_id & 0xFF for m in damping) == sorted(ids)
    for m in damping:
        assert m.arbitration_id >> 24 == 1
        req = proto.decode_request(m.arbitration_id, bytes(m.data))
        _, dq, kp, kd_u, tau = req.raw
        assert kp == 0  # Kp = 0
        # Kd = 1.0 on a [0, 5] range: floor(1.0 * 65535 / 5) = 13107
        assert kd_u == int(kd * 65535 / 5)
        assert tau == 32767  # tau_ff = 0: floor(0.5 * 65535) = 32767
        assert dq == 32767  # dq_cmd = 0


@contextlib.contextmanager
def swept_emulator(robot, make_emulator, seed: int) -> Iterator[tuple[object, np.ndarray]]:
    """An emulator with random true offsets (uniform +-0.3 rad, ``seed``) whose joints a 'person' pushes
    from one stop to the other, resting 30 ms at each; yields ``(emulator, true offsets in joint order)``."""
    rng = np.random.default_rng(seed)
    true = {n: float(rng.uniform(-0.3, 0.3)) for n in robot.joint_names}
    emu = make_emulator(offsets=true)
    stop = threading.Event()

    def sweep() -> None:
        while not stop.is_set():
            for a in (0.0, 0.5, 1.0, 0.5):
                emu.set_joint_positions(robot.lower + a * (robot.upper - robot.lower))
                time.sleep(0.03)

    t = threading.Thread(target=sweep, daemon=True)
    t.start()
    try:
        yield emu, np.array([true[n] for n in robot.joint_names])
    finally:
        stop.set()
        t.join()
