"""The MIT law and the 16-bit wire quantiser, with hand-computed numbers; numpy and jax give the same."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.robot import MitCommand, load_robot, mit_torque, quantize_command
from bar_policy.robot.mit import decode_u16, encode_u16, firmware_torque, wire_ranges

P = 4 * math.pi


def cmd(q=0.0, dq=0.0, kp=0.0, kd=0.0, tau=0.0) -> MitCommand:
    return MitCommand(*(np.array([x], dtype=np.float64) for x in (q, dq, kp, kd, tau)))


def test_impedance_mode() -> None:
    # 50*(0.5-0.3) + 2*(0-0.1) + 0 = 10 - 0.2 = 9.8
    tau = mit_torque(cmd(q=0.5, kp=50, kd=2), np.array([0.3]), np.array([0.1]))
    assert tau[0] == pytest.approx(9.8)


def test_computed_torque_mode() -> None:
    # 10*(1.0-0.8) + 0.5*(2.0-1.0) + 1.5 = 2 + 0.5 + 1.5 = 4.0
    tau = mit_torque(cmd(q=1.0, dq=2.0, kp=10, kd=0.5, tau=1.5), np.array([0.8]), np.array([1.0]))
    assert tau[0] == pytest.approx(4.0)


def test_damping_only_mode() -> None:
    # Kp=0, Kd=1, q_cmd = captured q: tau = -Kd*dq = -0.5 whatever q does.
    c = MitCommand.damping(np.array([0.2]), 1.0)
    assert c.kp[0] == 0 and c.q[0] == 0.2
    assert mit_torque(c, np.array([0.7]), np.array([0.5]))[0] == pytest.approx(-0.5)


def test_pure_torque_and_zero_torque_modes() -> None:
    assert mit_torque(cmd(tau=1.25), np.array([3.0]), np.array([-7.0]))[0] == 1.25
    z = MitCommand.zero_torque(3)
    np.testing.assert_array_equal(mit_torque(z, np.ones(3), np.ones(3)), np.zeros(3))


def test_clip_to_joint_caps() -> None:
    robot = load_robot("arms")
    # A 1 rad error at Kp=50 asks for 50 N*m: the shoulders clip at 17/14, the wrists at their 4 N*m cap.
    c = MitCommand.position(np.ones(14), robot.kp, robot.kd)
    tau = mit_torque(c, np.zeros(14), np.zeros(14), robot.torque_cap)
    assert tau.tolist() == [17, 14, 14, 14, 4, 4, 4] * 2
    tau = mit_torque(c._replace(q=-np.ones(14)), np.zeros(14), np.zeros(14), robot.torque_cap)
    assert tau.tolist() == [-17, -14, -14, -14, -4, -4, -4] * 2


def test_encode_matches_worked_example() -> None:
    # robstride-protocol.md 2: RS02, q=1, dq=0, Kp=10, Kd=0.5, tau=1 with P_max = 4*pi.
    assert encode_u16(1.0, -P, P) == 0x8A2F  # (1+4pi)/(8pi)*65535 = 35375.4 -> 35375
    assert encode_u16(0.0, -44.0, 44.0) == 0x7FFF  # 44*65535/88 = 32767.5 -> 32767
    assert encode_u16(10.0, 0.0, 500.0) == 0x051E  # 10*131.07 = 1310.7 -> 1310
    assert encode_u16(0.5, 0.0, 5.0) == 0x1999  # 0.5*13107 = 6553.5 -> 6553
    assert encode_u16(1.0, -17.0, 17.0) == 0x8787  # 18*65535/34 = 34695 exactly


def test_encode_clamps_and_decode_inverts() -> None:
    assert encode_u16(99.0, -14.0, 14.0) == 65535 and encode_u16(-99.0, -14.0, 14.0) == 0
    assert decode_u16(65535, -14.0, 14.0) == 14.0 and decode_u16(0, -14.0, 14.0) == -14.0
    # Zero torque is not exactly zero on the wire: 32767 decodes to -14/65535 N*m.
    assert decode_u16(encode_u16(0.0, -14.0, 14.0), -14.0, 14.0) == pytest.approx(-14 / 65535)


def test_quantize_command_per_model() -> None:
    robot = load_robot("arms")
    ranges = wire_ranges(robot.models)
    c = MitCommand(np.full(14, 1.0), np.zeros(14), robot.kp, robot.kd, np.zeros(14))
    qc = quantize_command(c, ranges)
    # Position: 35375 * 8pi/65535 - 4pi for every model (same P range).
    assert qc.q[0] == pytest.approx(35375 * 8 * math.pi / 65535 - 4 * math.pi)
    # Kp 50 of 500: 50*131.07 = 6553.5 -> 6553 -> 6553*500/65535 = 49.99618...
    assert qc.kp[0] == pytest.approx(6553 * 500 / 65535)
    # Kd 2 of 5: 2*13107 = 26214 exactly -> 2.0
    assert qc.kd[0] == pytest.approx(2.0)
    # Velocity zero: rs-02 range 44 -> -44/65535; rs-00 range 33 -> -33/65535; rs-05 range 50 -> -50/65535.
    assert qc.dq[[0, 1, 4]] == pytest.approx([-44 / 65535, -33 / 65535, -50 / 65535])
    # Every field moves by at most one quantisation step.
    for field, span in (("q", 2 * ranges.p_max), ("dq", 2 * ranges.v_max), ("kp", ranges.kp_max)):
        assert np.all(np.abs(getattr(qc, field) - getattr(c, field)) <= span / 65535 + 1e-12)


@pytest.mark.numerics
def test_numpy_and_jax_give_the_same_torque() -> None:
    robot = load_robot("arms")
    ranges = wire_ranges(robot.models)
    rng = np.random.default_rng(1)
    b = 8
    c = MitCommand(
        rng.uniform(-1, 1, (b, 14)),
        rng.uniform(-1, 1, (b, 14)),
        np.broadcast_to(robot.kp, (b, 14)),
        np.broadcast_to(robot.kd, (b, 14)),
        rng.uniform(-1, 1, (b, 14)),
    )
    q, dq = rng.uniform(-1, 1, (b, 14)), rng.uniform(-3, 3, (b, 14))
    want = firmware_torque(c, q, dq, ranges, robot.torque_cap)
    assert isinstance(want, np.ndarray)

    @jax.jit
    def f(c: MitCommand, q: jax.Array, dq: jax.Array) -> jax.Array:
        return firmware_torque(c, q, dq, ranges, robot.torque_cap)

    cj = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), c)
    got = jax.vmap(f)(cj, jnp.asarray(q, jnp.float32), jnp.asarray(dq, jnp.float32))
    assert isinstance(got, jax.Array) and got.shape == (b, 14)
    # float32 vs float64: the 16-bit grid can flip by one step at a boundary; bound = Kp * LSB + rounding.
    np.testing.assert_allclose(np.asarray(got), want, atol=50 * 8 * math.pi / 65535 + 1e-4)
    frac = np.mean(np.abs(np.asarray(got) - want) < 1e-4)
    assert frac > 0.95
