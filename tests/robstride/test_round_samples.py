"""``identify.round_samples`` pairs a round's mean acceleration with the law at the round's mean state.

The reference is a continuous robot: every joint alone a mass-spring-damper under the MIT law (inertia
``MU``, the robot's gains through the wire's 16-bit command), solved exactly by the matrix exponential and
sampled every 2 ms, as a firmware that runs the law far faster than the bus gives it. Over a round the
mean torque is ``MU (dq_k - dq_{k-1}) / dt``; the law at the mean of the round's end states is the
trapezoid of the law along the path, which differs from the mean by at most ``dt^2 / 12 max|tau''|``
(the law is affine in the state). The law at the round's start state differs by about ``dt / 2 |tau'|``:
the damping term's change, ``Kd dt qdd / 2``, is the armature a fit reads from it.
"""

from __future__ import annotations

import numpy as np

from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import U16_MAX, MitCommand, firmware_torque, wire_ranges
from bar_policy.robstride.excitation_run import Recording
from bar_policy.robstride.identify import round_samples

ROBOT = load_robot("arms")
MU = 0.05  # kg*m^2 on every joint: a shoulder-sized inertia, its mode (31.6 rad/s, damping ratio 0.63)
DT = 0.002  # s, one round
ROUNDS = 100


def _law(q_cmd: np.ndarray, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """The law as ``round_samples`` evaluates it (motor frame, 16-bit command, no offsets), joint frame."""
    d = np.asarray(ROBOT.direction, dtype=np.float64)
    zero = np.zeros_like(q)
    raw = MitCommand(d * q_cmd, zero, np.asarray(ROBOT.kp), np.asarray(ROBOT.kd), zero)
    return d * firmware_torque(raw, d * q, d * dq, wire_ranges(ROBOT.models), ROBOT.torque_cap)


def _continuous_robot() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per joint the exact solution from rest at piano_ready towards a 0.05 rad step, every ``DT``.

    Returns q, dq (ROUNDS + 1, joints), the command (joints,), and the law's second time derivative's
    largest magnitude and its first's, per joint (from the closed form sampled every 0.1 ms).
    """
    q0 = np.asarray(ROBOT.pose("piano_ready"), dtype=np.float64)
    q_cmd = q0 + 0.05  # 2.5 N*m at Kp 50: inside every cap (the wrists' 4 N*m), the law affine throughout
    zero = np.zeros_like(q0)
    # the law is affine in the state: its value at q0 and its slopes, as the 16-bit command makes them
    tau0 = _law(q_cmd, q0, zero)
    kp = (tau0 - _law(q_cmd, q0 + 1e-3, zero)) / 1e-3
    kd = (tau0 - _law(q_cmd, q0, zero + 1e-3)) / 1e-3
    fine = np.arange(0.0, ROUNDS * DT + 1e-12, 1e-4)
    q = np.empty((len(fine), len(q0)))
    dq = np.empty_like(q)
    for j in range(len(q0)):
        a = np.array([[0.0, 1.0], [-kp[j] / MU, -kd[j] / MU]])
        x_eq = np.array([q0[j] + tau0[j] / kp[j], 0.0])
        lam, v = np.linalg.eig(a)
        c = np.linalg.solve(v, np.array([q0[j], 0.0]) - x_eq)
        x = (v @ (c[:, None] * np.exp(lam[:, None] * fine[None, :]))).real + x_eq[:, None]
        q[:, j], dq[:, j] = x
    tau = tau0 - kp * (q - q0) - kd * dq
    tau_dot = -kp * dq - kd * tau / MU
    tau_ddot = -kp * tau / MU - kd * tau_dot / MU
    every = round(DT / 1e-4)
    return q[::every], dq[::every], q_cmd, np.abs(tau_ddot).max(axis=0), np.abs(tau_dot).max(axis=0)


def test_the_round_mean_state_reads_a_continuous_robot_to_second_order() -> None:
    q, dq, q_cmd, tau_ddot_max, tau_dot_max = _continuous_robot()
    rg = wire_ranges(ROBOT.models)
    d = np.asarray(ROBOT.direction, dtype=np.float64)
    # the readings as the firmware truncates them: half an LSB under the truth (round_samples adds it back)
    rec = Recording(
        t=[(k - 1) * DT for k in range(ROUNDS + 1)],
        q=list(q - d * rg.p_max / U16_MAX),
        dq=list(dq - d * rg.v_max / U16_MAX),
        tau=[np.zeros(ROBOT.num_joints)] * (ROUNDS + 1),
        q_cmd=[q_cmd] * ROUNDS,
        dq_cmd=[np.zeros(ROBOT.num_joints)] * ROUNDS,
        ff=[np.zeros(ROBOT.num_joints)] * ROUNDS,
    )
    s = round_samples(ROBOT, rec, DT)
    assert s.tau.shape == s.qdd.shape == (ROUNDS, ROBOT.num_joints)
    np.testing.assert_allclose(s.q, (q[1:] + q[:-1]) / 2, rtol=0, atol=1e-12)
    mean_torque = MU * s.qdd
    # the trapezoid's bound, plus the float rounding of the half-LSB round trip and the difference
    # quotient (1e-12 rad/s over 2 ms times MU: 3e-11 N*m; 1e-9 N*m is ample)
    bound = DT**2 / 12 * tau_ddot_max + 1e-9
    assert np.all(np.abs(s.tau - mean_torque) <= bound)
    # the start state's law misses by the torque's change over half a round: at least ten times more
    start = _law(q_cmd, q[:-1], dq[:-1])
    assert np.abs(start - mean_torque).max(axis=0).min() > 10 * bound.max()
    assert np.all(np.abs(start - mean_torque).max(axis=0) <= DT / 2 * tau_dot_max * 1.05)
