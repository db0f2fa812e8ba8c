"""Builders shared by the bus, safety and target tests."""

from __future__ import annotations

import can

from bar_policy.deploy.robstride.calibration import Calibration
from bar_policy.deploy.robstride.group import RobstrideGroup
from bar_policy.deploy.targets.real import RealTarget

TEST_TIMEOUT = 0.2
"""Reply deadline in tests, s: generous (threads on a loaded 2-core host); only fault paths wait for it."""


def make_group(robot, channels, *, calibration: Calibration | None = None, timeout: float = TEST_TIMEOUT):
    buses = {i: can.Bus(interface="virtual", channel=ch) for i, ch in channels.items()}
    return RobstrideGroup.from_robot(robot, buses, calibration=calibration, reply_timeout=timeout)


def make_target(robot, channels, **kw) -> RealTarget:
    group = make_group(robot, channels, calibration=kw.pop("calibration", None))
    kw.setdefault("refresh_on_read", False)
    kw.setdefault("damping_hold_s", 0.0)
    kw.setdefault("scan_ids", range(1, 33))
    return RealTarget(robot, group, **kw)
