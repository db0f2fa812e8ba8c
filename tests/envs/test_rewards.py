"""Reward terms with hand-computed values, and pure actuator pieces."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.envs import rewards
from bar_policy.envs.actuator import ActuatorParams, apply_latency, implicit_damping, make_command
from bar_policy.robot.constants import load_robot


def test_reach_kernel_hand_values():
    # d = std -> 1 - tanh(1) = 0.238406; d = 0 -> 1; mean of the two hands.
    got = float(rewards.reach_kernel(jnp.float32(0.1), jnp.float32(0.0), 0.1))
    assert got == pytest.approx(0.5 * ((1 - math.tanh(1.0)) + 1.0), abs=1e-6)
    # far away -> ~0: 1 - tanh(10) = 4.1e-9.
    assert float(rewards.reach_kernel(jnp.float32(1.0), jnp.float32(1.0), 0.1)) < 1e-6


def test_success_needs_both_hands():
    assert float(rewards.success(jnp.float32(0.029), jnp.float32(0.0), 0.03)) == 1.0
    assert float(rewards.success(jnp.float32(0.029), jnp.float32(0.031), 0.03)) == 0.0
    assert float(rewards.success(jnp.float32(0.03), jnp.float32(0.0), 0.03)) == 0.0  # strict


def test_action_rate_hand_value():
    # (0.5 - 0)^2 + (-1 - 1)^2 + 0 = 0.25 + 4 = 4.25
    a = jnp.array([0.5, -1.0, 0.2])
    b = jnp.array([0.0, 1.0, 0.2])
    assert float(rewards.action_rate(a, b)) == pytest.approx(4.25)


def test_joint_limit_hand_value():
    # range [-1, 1], fraction 0.9 -> soft range [-0.9, 0.9]; q = 0.95 -> 0.05; q = -1.0 -> 0.1; q = 0 -> 0.
    lo, hi = jnp.array([-1.0, -1.0, -1.0]), jnp.array([1.0, 1.0, 1.0])
    q = jnp.array([0.95, -1.0, 0.0])
    assert float(rewards.joint_limit(q, lo, hi, 0.9)) == pytest.approx(0.15, abs=1e-6)
    # asymmetric range [-2.356, 0] (elbow), fraction 1.0: only beyond the hard limit counts.
    assert float(rewards.joint_limit(jnp.array([0.01]), jnp.array([-2.356]), jnp.array([0.0]), 1.0)) == (
        pytest.approx(0.01, abs=1e-6)
    )


def test_joint_deviation_hand_value():
    # |0.3 - 0| + |-0.2 - 0.1| + |0.5 - 0.5| = 0.6 rad (L1: an offset's sign does not count).
    q = jnp.array([0.3, -0.2, 0.5])
    ref = jnp.array([0.0, 0.1, 0.5])
    assert float(rewards.joint_deviation(q, ref)) == pytest.approx(0.6, abs=1e-6)
    assert float(rewards.joint_deviation(ref, ref)) == 0.0


def test_joint_vel_and_torque_hand_values():
    assert float(rewards.joint_vel(jnp.array([1.0, -2.0, 0.5]))) == pytest.approx(5.25)
    assert float(rewards.torque(jnp.float32(0.7))) == pytest.approx(0.7)


def test_latency_buffer():
    buf = jnp.zeros((3, 2))
    b1, out0 = apply_latency(buf, jnp.array([1.0, 1.0]), jnp.int32(0))
    np.testing.assert_array_equal(out0, [1.0, 1.0])  # no delay
    b2, out = apply_latency(b1, jnp.array([2.0, 2.0]), jnp.int32(1))
    np.testing.assert_array_equal(out, [1.0, 1.0])  # one step old
    _, out = apply_latency(b2, jnp.array([3.0, 3.0]), jnp.int32(2))
    np.testing.assert_array_equal(out, [1.0, 1.0])  # two steps old
    _, out = apply_latency(b2, jnp.array([3.0, 3.0]), jnp.int32(1))
    np.testing.assert_array_equal(out, [2.0, 2.0])


def test_command_quantisation_hand_values():
    robot = load_robot("arms")
    p = ActuatorParams.from_robot(robot, quantize_wire=True, torque_saturation=True)
    n = robot.num_joints
    cmd = make_command(jnp.zeros(n), jnp.full(n, 50.0), jnp.full(n, 2.0), p)
    # Kp range [0, 500]: floor(50 * 65535 / 500) = 6553 -> 6553 * 500 / 65535 = 49.99619
    np.testing.assert_allclose(cmd.kp, 6553 * 500 / 65535, rtol=1e-6)
    # Kd range [0, 5]: floor(2 * 65535 / 5) = 26214 -> 26214 * 5 / 65535 = 1.9999847
    np.testing.assert_allclose(cmd.kd, 26214 * 5 / 65535, rtol=1e-6)
    # q = 0 in [-4 pi, 4 pi]: floor(32767.5) = 32767 -> 32767 * 8 pi / 65535 - 4 pi = -1.9175e-4 rad
    np.testing.assert_allclose(cmd.q, 32767 * 8 * math.pi / 65535 - 4 * math.pi, atol=2e-6)
    off = make_command(
        jnp.zeros(n),
        jnp.full(n, 50.0),
        jnp.full(n, 2.0),
        ActuatorParams.from_robot(robot, quantize_wire=False, torque_saturation=False),
    )
    np.testing.assert_array_equal(off.kp, 50.0)
    assert np.all(
        np.isinf(ActuatorParams.from_robot(robot, quantize_wire=False, torque_saturation=False).tau_cap)
    )


class _FakeModel:
    def __init__(self, damping):
        self.dof_damping = damping

    def replace(self, **kw):
        return _FakeModel(kw["dof_damping"])


def test_implicit_damping_keeps_applied_torque():
    kd = jnp.array([2.0, 2.0, 2.0])
    tau = jnp.array([1.0, 4.0, -4.0])  # joints 1, 2 saturated at the cap 4
    cap = jnp.array([4.0, 4.0, 4.0])
    dq = jnp.array([0.5, 1.0, -1.0])
    m, qfrc = implicit_damping(_FakeModel(jnp.array([0.1, 0.0, 0.0])), kd, tau, dq, cap)
    # unsaturated: D = 2 -> qfrc = 1 + 2 * 0.5 = 2; passive -(0.1 + 2) * 0.5 brings the sum to 1 - 0.05.
    np.testing.assert_allclose(m.dof_damping, [2.1, 0.0, 0.0])
    np.testing.assert_allclose(qfrc, [2.0, 4.0, -4.0])


# ---------------------------------------------------------------------------------------------------
# Tracking terms
# ---------------------------------------------------------------------------------------------------
def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def test_joint_tracking_hand_value():
    # errors (0.1, -0.1, 0, 0): mean square 0.02 / 4 = 0.005; std 0.1 -> exp(-0.005 / 0.01) = exp(-0.5).
    q_ref = jnp.array([0.3, -1.0, 0.0, -1.7])
    q = q_ref + jnp.array([0.1, -0.1, 0.0, 0.0])
    assert float(rewards.joint_tracking(q, q_ref, 0.1)) == pytest.approx(math.exp(-0.5), rel=1e-5)
    assert float(rewards.joint_tracking(q_ref, q_ref, 0.1)) == 1.0


def test_body_pos_tracking_hand_value():
    # body 0 off by (0.03, 0.04, 0): 0.0025 m^2; body 1 exact: mean 0.00125; std 0.05 -> exp(-0.5).
    ref = jnp.array([[0.1, 0.2, 0.3], [0.0, -0.2, 0.2]])
    pos = ref + jnp.array([[0.03, 0.04, 0.0], [0.0, 0.0, 0.0]])
    assert float(rewards.body_pos_tracking(pos, ref, 0.05)) == pytest.approx(math.exp(-0.5), rel=1e-5)


def test_orientation_error_hand_values():
    eye = np.eye(3)
    assert float(rewards.orientation_error(jnp.asarray(_rot_x(0.3)), jnp.asarray(eye))) == pytest.approx(
        0.3, abs=1e-5
    )
    # 2.0 rad about (1, 1, 1) / sqrt(3) (Rodrigues), relative to a non-identity reference.
    k = np.ones(3) / math.sqrt(3)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    r = eye + math.sin(2.0) * kx + (1 - math.cos(2.0)) * kx @ kx
    ref = _rot_x(0.7)
    got = rewards.orientation_error(jnp.asarray(ref @ r), jnp.asarray(ref))
    assert float(got) == pytest.approx(2.0, abs=1e-5)
    assert float(rewards.orientation_error(jnp.asarray(eye), jnp.asarray(eye))) == 0.0  # no NaN at 0
    assert float(rewards.orientation_error(jnp.asarray(_rot_x(math.pi)), jnp.asarray(eye))) == pytest.approx(
        math.pi, abs=1e-3
    )


def test_rotation_from_6d_inverts_the_6d_form():
    r = _rot_x(0.4) @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    six = r[:, :2].reshape(6)  # (r00, r01, r10, r11, r20, r21)
    np.testing.assert_allclose(rewards.rotation_from_6d(jnp.asarray(six)), r, atol=1e-6)


def test_body_ori_tracking_hand_value():
    # body 0 rotated 0.3 rad from its reference, body 1 exact: mean theta^2 = 0.045; std 0.3 -> exp(-0.5).
    ref = np.stack([np.eye(3), _rot_x(1.0)])
    rot = np.stack([_rot_x(0.3), _rot_x(1.0)])
    six = ref[:, :, :2].reshape(2, 6)
    got = rewards.body_ori_tracking(jnp.asarray(rot), jnp.asarray(six), 0.3)
    assert float(got) == pytest.approx(math.exp(-0.5), rel=1e-4)


def test_action_accel_hand_value():
    # Second differences per joint: 0.3 - 2 * 0.1 + 0.0 = 0.1 and -0.2 - 2 * 0.0 + 0.4 = 0.2: 0.01 + 0.04.
    got = rewards.action_accel(jnp.array([0.3, -0.2]), jnp.array([0.1, 0.0]), jnp.array([0.0, 0.4]))
    assert float(got) == pytest.approx(0.05, rel=1e-6)
