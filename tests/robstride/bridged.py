"""Subprocess entry of the bridge tests; its ``virtual`` buses reach the test process through ``bridge``.

    python bridged.py bar-bus ARGS...          # bar-bus, unchanged
    python bridged.py drive CAN_TIMEOUT_S      # activate both arms, hold 0.1 rad off the start pose at 50 Hz

``drive`` prints ``RUNNING`` after a few ticks and then ticks until it is killed; it installs no signal
handler and never sends a stop frame of its own.
"""

from __future__ import annotations

import itertools
import sys
import time

import bridge


def drive(can_timeout: float) -> int:
    import can

    from bar_policy.robot.constants import load_robot
    from bar_policy.robot.mit import MitCommand
    from bar_policy.robstride.group import RobstrideGroup

    robot = load_robot("arms")
    interfaces = dict.fromkeys(j.can_interface for j in robot.joints)
    buses = {i: can.Bus(interface="virtual", channel=i) for i in interfaces}
    # 2 s deadlines: the replies cross a TCP bridge between two processes on a possibly loaded host.
    group = RobstrideGroup.from_robot(robot, buses, reply_timeout=2.0, can_timeout=can_timeout)
    reading = group.activate(lower=robot.lower, upper=robot.upper, scan_ids=range(1, 33), scan_timeout=2.0)
    cmd = MitCommand.position(reading.q + 0.1, robot.kp, robot.kd)  # 0.1 rad off: a visible holding torque
    for k in itertools.count():
        group.exchange_mit(cmd)
        if k == 5:
            print("RUNNING", flush=True)
        time.sleep(0.02)
    return 0


if __name__ == "__main__":
    bridge.install_client()
    if sys.argv[1] == "bar-bus":
        from bar_policy.robstride.tools import main

        sys.exit(main(sys.argv[2:]))
    sys.exit(drive(float(sys.argv[2])))
