"""The identification fit on synthetic data generated from its own model with known parameters.

The samples are random states (positions inside the limits, velocities and accelerations of either sign,
not a trajectory: every column independent), the torques the exact ones the joints would need given the
known strength, friction, damping, armature and a 0.4 kg payload at a known centre, computed with C MuJoCo
(``mj_inverse`` of the links, and of the links with a unit point mass at the centre for the payload). The fit
must give the parameters back to the float tolerance of a least-squares solve (the system is exact and
well conditioned: the residual is rounding only).
"""

from __future__ import annotations

import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.scene import load_model, robot_spec
from bar_policy.robot.sysid_fit import ArmSamples, PayloadRegressor, fit_arm

ROBOT = load_robot("arms")
LEFT = [j.index for j in ROBOT.joints if j.group == "left_arm"]


def _synthetic(n: int, com: np.ndarray, mass: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    lo, hi = ROBOT.lower + 0.2, ROBOT.upper - 0.2
    q = rng.uniform(lo, hi, size=(n, ROBOT.num_joints))
    dq = rng.uniform(0.2, 1.5, size=q.shape) * rng.choice([-1.0, 1.0], size=q.shape)
    qdd = rng.uniform(-6.0, 6.0, size=q.shape)
    truth = {
        "strength": np.array([0.9, 1.05, 0.95, 1.1, 0.85, 1.0, 0.92]),
        "friction": np.array([0.6, 0.45, 0.5, 0.55, 0.3, 0.35, 0.4]),
        "damping": np.array([0.05, 0.1, 0.0, 0.2, 0.02, 0.03, 0.01]),
        "armature": np.array([0.006, 0.003, 0.0025, 0.0031, 0.0022, 0.0018, 0.002]),
    }
    reg = PayloadRegressor(load_model("arms"), lambda: robot_spec("arms"), ROBOT.joint_names, "left_hand")
    s0 = ArmSamples(q, dq, qdd, np.zeros_like(q))
    id_base = reg.inverse(s0)
    unit = reg.columns(s0, id_base, com)[:, :, 0]  # the unit point mass at com: gravity and inertia
    need = id_base[:, LEFT] + mass * unit[:, LEFT]
    need += truth["friction"] * np.sign(dq[:, LEFT]) + truth["damping"] * dq[:, LEFT]
    need += truth["armature"] * qdd[:, LEFT]
    tau = np.zeros_like(q)
    tau[:, LEFT] = need / truth["strength"]  # the torque read is what the motor was told; it makes s times it
    return ArmSamples(q, dq, qdd, tau), reg, id_base, truth


def test_fit_recovers_known_parameters_exactly() -> None:
    com, mass = np.array([0.02, -0.11, 0.015]), 0.4
    samples, reg, id_base, truth = _synthetic(400, com, mass)
    fit = fit_arm(samples, LEFT, ROBOT.joint_names, reg, id_base=id_base, v_min=0.0, iterations=14)
    # exact data, 32 unknowns, 2800 rows: the solve's rounding (~1e-12 relative) and the fixed-point
    # iteration of the centre (measured: 8 passes leave 2e-6, each pass ~5x less: 14 leave < 1e-6)
    tol = 1e-6
    for key in ("strength", "friction", "damping", "armature"):
        np.testing.assert_allclose(getattr(fit, key), truth[key], rtol=0, atol=tol, err_msg=key)
    assert fit.mass == pytest.approx(mass, abs=tol)
    np.testing.assert_allclose(fit.com, com, atol=tol)
    assert fit.rms < 1e-8


def test_known_strength_is_held_and_the_rest_recovered() -> None:
    com, mass = np.array([0.0, -0.09, 0.0]), 0.35
    samples, reg, id_base, truth = _synthetic(300, com, mass, seed=1)
    fit = fit_arm(
        samples, LEFT, ROBOT.joint_names, reg, id_base=id_base, v_min=0.0, iterations=8,
        strength=truth["strength"],
    )  # fmt: skip
    np.testing.assert_array_equal(fit.strength, truth["strength"])
    np.testing.assert_allclose(fit.friction, truth["friction"], atol=1e-6)
    assert fit.mass == pytest.approx(mass, abs=1e-6)
