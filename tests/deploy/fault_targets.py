"""Test targets: a stepped (synchronous, deterministic-clock) mock with fault injection."""

from __future__ import annotations

import time

import numpy as np

from bar_policy.deploy.targets.base import JointState, TargetError
from bar_policy.deploy.targets.mock import MockTarget
from bar_policy.robot.mit import mit_torque


class SteppedMock(MockTarget):
    """The mock echo, but synchronous: its clock is ``k * dt`` after k calls of ``advance(dt)``.

    Fault injection by read index (0-based, = control tick): ``nan_from`` (q[2] = NaN), ``freeze_from``
    (stamp stops advancing), ``offset_from`` (``offset`` added to the reported q; the reported torque is the
    firmware's at that q, as a motor whose own encoder reads it: capped MIT torque of the last command),
    ``faults_from`` (hardware fault strings), ``raise_at`` (read_state raises TargetError).
    """

    synchronous = True

    def __init__(
        self,
        *,
        nan_from: int | None = None,
        freeze_from: int | None = None,
        offset_from: int | None = None,
        offset: np.ndarray | None = None,
        faults_from: int | None = None,
        raise_at: int | None = None,
        initial_q: np.ndarray | None = None,
    ) -> None:
        super().__init__("arms", initial_q=initial_q)
        self.nan_from = nan_from
        self.freeze_from = freeze_from
        self.offset_from = offset_from
        self.offset = np.zeros(14) if offset is None else offset
        self.faults_from = faults_from
        self.raise_at = raise_at
        self.reads = 0
        self.steps = 0
        self.dt = 0.0
        self.commands: list = []

    def now(self) -> float:
        return self.steps * self.dt

    def advance(self, dt: float) -> None:
        self.dt = dt
        self.steps += 1

    def write_command(self, cmd) -> None:
        super().write_command(cmd)
        self.commands.append(self.last_command)

    def read_state(self) -> JointState:
        k = self.reads
        self.reads += 1
        if self.raise_at is not None and k >= self.raise_at:
            raise TargetError(f"injected bus failure at read {k}")
        s = super().read_state()
        q = s.q
        tau = s.tau
        if self.offset_from is not None and k >= self.offset_from:
            q = q + self.offset
            if self.last_command is not None:
                tau = np.asarray(mit_torque(self.last_command, q, s.dq, self._cap))
        if self.nan_from is not None and k >= self.nan_from:
            q = q.copy()
            q[2] = np.nan
        stamp = self.now()
        if self.freeze_from is not None and k >= self.freeze_from:
            stamp = self.freeze_from * self.dt
        faults = ("MOTOR_FAULT id 13",) if self.faults_from is not None and k >= self.faults_from else ()
        return JointState(q=q, dq=s.dq, tau=tau, stamp=stamp, faults=faults)


class SlowMock(MockTarget):
    """Asynchronous mock whose ``read_state`` sleeps ``delay`` seconds from read ``slow_from`` on."""

    def __init__(self, slow_from: int, delay: float) -> None:
        super().__init__("arms")
        self.slow_from = slow_from
        self.delay = delay
        self.reads = 0

    def read_state(self) -> JointState:
        if self.reads >= self.slow_from:
            time.sleep(self.delay)
        self.reads += 1
        return super().read_state()
