"""Raw CAN traffic recorded with python-can's writers: the BLF (or ASC) file holds exactly the frames that a
third node on the virtual bus saw, each with its direction and its bus's channel number."""

from __future__ import annotations

import can
import pytest

from bar_policy.robot.mit import MitCommand
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.can_record import CanRecorder
from bar_policy.robstride.framing import DEVICE_ID_REPLY_DEST

from .helpers import make_target


def _from_motor(msg: can.Message) -> bool:
    """A motor's frame: its destination (bits 0-7) is the host id, or 0xFE for a device-id reply (the host
    addresses a motor id there)."""
    return (msg.arbitration_id & 0xFF) in (proto.HOST_ID, DEVICE_ID_REPLY_DEST)


def _key(msg: can.Message) -> tuple[int, bytes]:
    return msg.arbitration_id, bytes(msg.data)


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_recorded_frames_equal_the_bus_traffic(robot, channels, listeners, make_emulator, tmp_path, suffix):
    make_emulator()
    target = make_target(robot, channels)
    path = target.record_can(tmp_path / f"run{suffix}")
    goal = robot.pose("piano_ready")
    with target:
        target.start()
        for _ in range(3):
            target.read_state()
            target.write_command(MitCommand.position(goal, robot.kp, robot.kd))
    assert target.can_recorder is not None and target.can_recorder.stopped
    with can.LogReader(str(path)) as reader:
        frames = list(reader)
    assert len(frames) == target.can_recorder.frames > 0
    # Channel numbers: the buses in the group's order, 1-based.
    order = {bus.interface: k for k, bus in enumerate(target.group.buses, start=1)}
    assert {m.channel for m in frames} == set(order.values()) == {1, 2}
    for iface, lst in listeners.items():
        on_bus = lst.collect()
        mine = [m for m in frames if m.channel == order[iface]]
        sent = [_key(m) for m in mine if not m.is_rx]
        got = [_key(m) for m in mine if m.is_rx]
        # Every frame the host sent, in order (scan, parameters, enable, MIT rounds, damping, stop) ...
        assert sent == [_key(m) for m in on_bus if not _from_motor(m)]
        assert all(not _from_motor(m) for m in mine if not m.is_rx)
        # ... and the motors' replies the host read, in the order they came (the bus's last replies may
        # come after the bus was closed: never read, never recorded).
        replies = [_key(m) for m in on_bus if _from_motor(m)]
        assert got == replies[: len(got)] and len(got) >= len(replies) - 7
        assert all(m.is_extended_id for m in mine)
    # MIT frames (type 1): one per motor per round (3 rounds, and the activation's damping hold).
    mit = [m for m in frames if not m.is_rx and m.arbitration_id >> 24 == 1]
    assert len(mit) >= 14 * 3


def test_recorder_refuses_other_formats(tmp_path):
    with pytest.raises(ValueError, match=r"\.blf or \.asc"):
        CanRecorder(tmp_path / "x.csv")
