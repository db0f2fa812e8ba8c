"""``bar-bus identify``'s excitation over the bus: the torque budget's supervisor and the supervised run.

``run_excitation`` sends the planned excitation (``robot.sysid_excitation``) on the enabled motors at the
robot's own Kp, Kd, with the nominal model's gravity torque at the target as feed-forward, one MIT round per
period. ``Supervisor``, every round: the torque the law will ask for (``Kp (q* - q) + Kd (dq* - dq) + ff``,
from the last reading) and the torque each motor reports stay within the budget (``budget`` x the joint's
cap, 50 % by default), every joint inside its limits; a motor fault, a missing reply, a stop request (a
signal) or any exception ends the run. Every end, normal or not, sends damping frames then stop frames
on every bus (``RobstrideGroup.damping_then_stop``). What it measured is a ``Recording``, which the fit
(``robstride.identify``) reads.

No jax, no torch.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand
from bar_policy.robot.scene import load_model
from bar_policy.robot.sysid_excitation import Excitation
from bar_policy.robstride.errors import RobstrideError
from bar_policy.robstride.group import RobstrideGroup

__all__ = ["BudgetError", "Recording", "Supervisor", "run_excitation"]


class BudgetError(RobstrideError):
    """The excitation would exceed (or a motor reported above) the torque budget, or left the joint limits."""


@dataclass
class Recording:
    """What the excitation measured, one row per round: shapes (N,) and (N, num_joints)."""

    t: list[float] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    dq: list[np.ndarray] = field(default_factory=list)
    tau: list[np.ndarray] = field(default_factory=list)
    q_cmd: list[np.ndarray] = field(default_factory=list)
    """Position target of each round's command (the state rows are the replies to it), rad."""
    dq_cmd: list[np.ndarray] = field(default_factory=list)
    ff: list[np.ndarray] = field(default_factory=list)
    """Feed-forward torque of each round's command, N*m."""
    peak_fraction: float = 0.0
    """Largest ``|tau| / cap`` reported or asked for over the run (the budget's use)."""
    pose_segments: list[tuple[float, float]] = field(default_factory=list)
    """``Excitation.pose_segments`` of the run: ``(t0, t1)`` of each held pose (its ramp in), s."""
    fast_segments: list[tuple[float, float, int]] = field(default_factory=list)
    """``Excitation.fast_segments`` of the run: ``(t0, t1, joint)``, s on the excitation's clock (command
    ``k`` at ``k * period``), where one joint moved alone and fast."""
    lever_segments: list[tuple[float, float, int]] = field(default_factory=list)
    """``Excitation.lever_segments`` of the run: ``(t0, t1, joint)``, s, where a wrist yaw swept alone in the
    lever pose (a known payload's gravity large about it); empty without the lever phase."""
    direction: np.ndarray | None = None
    """Each joint's motor direction (+-1, canonical order; None: the robot data's), as the bus used it."""
    homing_offset: np.ndarray | None = None
    """Each joint's homing offset, rad (canonical order; None: 0), as the bus used it: with ``direction``,
    the motor frame the wire's 16-bit fields are quantised in (``round_samples``)."""

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``t`` (N,), ``q``, ``dq``, ``tau`` (N, num_joints)."""
        return np.array(self.t), np.array(self.q), np.array(self.dq), np.array(self.tau)


class Supervisor:
    """The torque budget and the joint limits, checked before each command and on each reading."""

    def __init__(self, robot: RobotSpec, budget: float = 0.5, limit_margin: float = 0.05) -> None:
        if not 0 < budget <= 0.5:
            raise ValueError(f"torque budget {budget:g} of the cap: valid (0, 0.5]")
        self.cap = np.array([j.torque_cap for j in robot.joints])
        """Each joint's torque cap, N*m (the firmware's)."""
        self.limit = budget * self.cap
        self.lower = robot.lower - limit_margin
        self.upper = robot.upper + limit_margin
        self.names = robot.joint_names
        self.peak = 0.0

    def check(self, tau: np.ndarray, what: str, q: np.ndarray | None = None) -> None:
        """``BudgetError`` naming the joint when ``|tau|`` > budget (or ``q`` is outside the limits)."""
        frac = np.abs(tau) / self.cap
        self.peak = max(self.peak, float(np.nanmax(frac)))
        over = np.flatnonzero(~(np.abs(tau) <= self.limit))
        if over.size:
            i = int(over[0])
            raise BudgetError(
                f"{self.names[i]}: {what} torque {tau[i]:+.2f} N*m exceeds the budget "
                f"+-{self.limit[i]:.2f} N*m ({self.limit[i] / self.cap[i]:.0%} of the cap)"
            )
        if q is not None:
            out = np.flatnonzero(~((q >= self.lower) & (q <= self.upper)))
            if out.size:
                i = int(out[0])
                raise BudgetError(f"{self.names[i]}: q={q[i]:+.3f} rad left its limits")


def _gravity(model: mujoco.MjModel, index: RobotIndex) -> Callable[[np.ndarray], np.ndarray]:
    d = mujoco.MjData(model)

    def g(q: np.ndarray) -> np.ndarray:
        d.qpos[index.qpos] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(model, d)
        return d.qfrc_bias[index.dof].copy()

    return g


def run_excitation(
    group: RobstrideGroup,
    robot: RobotSpec,
    excitation: Excitation,
    supervisor: Supervisor,
    *,
    period: float,
    stop: Callable[[], bool] = lambda: False,
    realtime: bool = True,
    on_round: Callable[[int, np.ndarray], None] | None = None,
) -> Recording:
    """Run ``excitation`` on the (enabled) ``group`` one round per ``period`` s; damping then stop at the end.

    ``realtime``: pace the rounds on the wall clock (the real robot); False: back to back (the lockstep
    emulator, whose physics advances one period per round). ``on_round(k, q)``: called after each reading
    (tests inject faults there). Raises what ended the run, after damping then stop: ``BudgetError``, a
    ``RobstrideError`` (a fault, a missing reply), or ``KeyboardInterrupt`` when ``stop()`` turned true.
    """
    model = load_model(robot.mode)
    index = RobotIndex.from_model(model, robot.joint_names)
    gravity = _gravity(model, index)
    kp, kd = robot.kp, robot.kd
    rec = Recording(
        pose_segments=excitation.pose_segments(),
        fast_segments=excitation.fast_segments(),
        lever_segments=excitation.lever_segments(),
    )
    motors = {m.name: m for bus in group.buses for m in bus.motors}  # the frame the bus encodes in
    if all(n in motors for n in robot.joint_names):
        rec.direction = np.array([motors[n].direction for n in robot.joint_names], dtype=np.float64)
        rec.homing_offset = np.array([motors[n].homing_offset for n in robot.joint_names])
    n = round(excitation.duration / period)
    reading = group.last_reading
    q = reading.q.copy() if reading is not None else excitation.start.copy()
    dq = np.zeros_like(q)
    t0 = time.monotonic()
    rec.t.append(-period)  # the state before the first command
    rec.q.append(q.copy())
    rec.dq.append(dq.copy())
    rec.tau.append(reading.tau.copy() if reading is not None else np.zeros_like(q))
    try:
        for k in range(n + 1):
            if stop():
                raise KeyboardInterrupt("stop requested")
            t = k * period
            q_des, dq_des = excitation.at(t)
            ff = gravity(q_des)
            supervisor.check(kp * (q_des - q) + kd * (dq_des - dq) + ff, "commanded")
            if realtime:
                time.sleep(max(0.0, t0 + t - time.monotonic()))
            reading = group.exchange_mit(MitCommand(q_des, dq_des, kp, kd, ff))
            q, dq = reading.q, reading.dq
            if on_round is not None:
                on_round(k, q)
            supervisor.check(reading.tau, "reported", q)
            rec.t.append(t)
            rec.q.append(q.copy())
            rec.dq.append(dq.copy())
            rec.tau.append(reading.tau.copy())
            rec.q_cmd.append(q_des)
            rec.dq_cmd.append(dq_des)
            rec.ff.append(ff)
    finally:
        rec.peak_fraction = supervisor.peak
        group.damping_then_stop(hold_s=0.3 if realtime else 0.0)
    return rec
