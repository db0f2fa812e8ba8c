"""``mock`` target: no physics, commands echoed into the state (ros2_control's ``mock_components``).

After ``write_command(cmd)`` the state reads ``q = cmd.q``, ``dq = cmd.dq`` and ``tau`` = the MIT torque
that ``cmd`` demanded at the state it replaced (clipped to the torque cap). It lives in wall-clock time
(asynchronous): every reading is stamped with ``time.monotonic()``, so the runtime's deadline scheduler sets
the rate. Use it to test wiring, rates and safety without a simulator.
"""

from __future__ import annotations

import time

import numpy as np

from bar_policy.deploy.targets.base import JointState, Target, TargetError
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand, mit_torque

__all__ = ["MockTarget"]


class MockTarget(Target):
    """Echoes MIT commands into the joint state."""

    synchronous = False
    measures_torque = False  # its torque is the law's at the echoed state, not a physical one

    def __init__(self, mode: str = "arms", *, initial_q: np.ndarray | None = None) -> None:
        """Create the mock for a joint set.

        Args:
            mode: ``arms`` or ``arms_neck``.
            initial_q: starting positions, rad, shape (num_joints,); the ``piano_ready`` pose by default.
        """
        robot = load_robot(mode)
        super().__init__(robot.joint_names)
        self._cap = robot.torque_cap
        q0 = robot.pose("piano_ready") if initial_q is None else np.asarray(initial_q, dtype=np.float64)
        if q0.shape != (self.num_joints,):
            raise ValueError(f"initial_q has shape {q0.shape}, expected ({self.num_joints},)")
        self._q = q0.copy()
        self._dq = np.zeros(self.num_joints)
        self._tau = np.zeros(self.num_joints)
        self.commands_written = 0
        """Number of ``write_command`` calls."""
        self.last_command: MitCommand | None = None
        """The last command written."""

    def read_state(self) -> JointState:
        """The echoed state, stamped now (monotonic clock)."""
        return JointState(q=self._q.copy(), dq=self._dq.copy(), tau=self._tau.copy(), stamp=time.monotonic())

    def write_command(self, cmd: MitCommand) -> None:
        """Echo ``cmd``: q <- q_cmd, dq <- dq_cmd, tau <- MIT torque at the previous state (capped)."""
        fields = [np.asarray(f, dtype=np.float64) for f in cmd]
        for name, f in zip(MitCommand._fields, fields, strict=True):
            if f.shape != (self.num_joints,):
                raise TargetError(f"command field {name} has shape {f.shape}, expected ({self.num_joints},)")
        c = MitCommand(*fields)
        self._tau = np.asarray(mit_torque(c, self._q, self._dq, self._cap))
        self._q = c.q.copy()
        self._dq = c.dq.copy()
        self.last_command = c
        self.commands_written += 1
