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
        samples,
        LEFT,
        ROBOT.joint_names,
        reg,
        id_base=id_base,
        v_min=0.0,
        iterations=8,
        strength=truth["strength"],
    )
    np.testing.assert_array_equal(fit.strength, truth["strength"])
    np.testing.assert_allclose(fit.friction, truth["friction"], atol=1e-6)
    assert fit.mass == pytest.approx(mass, abs=1e-6)


# -- the fast single-joint fit and its intervals ---------------------------------------------------------

ELBOW = LEFT[3]
FAST_TRUTH = {"friction": 0.6, "damping": 0.05, "armature": 0.002}
RHO = 0.9
"""AR(1) coefficient of the synthetic torque noise: correlated over ~10 samples, as a smoothed reading is."""


def _elbow_alone(n: int = 1500, dt: float = 0.002):
    """The elbow alone on a two-sine (1.3 and 3.1 Hz, 0.05 rad each) at the fast phase's pose, others held.

    Returns samples with the exact torque (no noise) and ``id_base``: the links' ``mj_inverse`` (C MuJoCo).
    The torque read is what the motor was told: ``tau = (ID + f sign(dq) + b dq + a qdd)`` at strength 1.
    """
    t = np.arange(n) * dt
    w = 2 * np.pi * np.array([1.3, 3.1])
    q = np.tile(np.array([-0.5, -1.1, 0.0, -1.0, 0.0, 0.0, 0.0] + [0.0] * 7), (n, 1))
    q[:, ELBOW] += 0.05 * np.sin(np.outer(t, w)).sum(axis=1)
    dq, qdd = np.zeros_like(q), np.zeros_like(q)
    dq[:, ELBOW] = 0.05 * (w * np.cos(np.outer(t, w))).sum(axis=1)
    qdd[:, ELBOW] = -0.05 * (w**2 * np.sin(np.outer(t, w))).sum(axis=1)
    reg = PayloadRegressor(load_model("arms"), lambda: robot_spec("arms"), ROBOT.joint_names, "left_hand")
    id_base = reg.inverse(ArmSamples(q, dq, qdd, np.zeros_like(q)))
    tau = id_base.copy()
    tau[:, ELBOW] += FAST_TRUTH["friction"] * np.sign(dq[:, ELBOW]) + FAST_TRUTH["damping"] * dq[:, ELBOW]
    tau[:, ELBOW] += FAST_TRUTH["armature"] * qdd[:, ELBOW]
    return ArmSamples(q, dq, qdd, tau), id_base


def _ar1(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Stationary AR(1) noise of standard deviation ``sigma`` and coefficient ``RHO``."""
    e = rng.normal(0.0, sigma * np.sqrt(1 - RHO**2), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sigma)
    for k in range(1, n):
        x[k] = RHO * x[k - 1] + e[k]
    return x


def _fit_noisy(samples, id_base, noise, hac_lag):
    from bar_policy.robot.sysid_fast import fit_fast

    tau = samples.tau.copy()
    tau[:, ELBOW] += noise
    s = ArmSamples(samples.q, samples.dq, samples.qdd, tau)
    # the friction constraint's unclamped force: opposing the motion, far above f (always sliding)
    sliding = -np.sign(samples.dq) * 1e3
    return fit_fast(
        s, [(slice(0, len(tau)), ELBOW)], ROBOT.joint_names, id_base, sliding, np.ones(1), hac_lag=hac_lag
    )


def test_fast_fit_recovers_armature_and_friction_within_the_noise() -> None:
    samples, id_base = _elbow_alone()
    sigma = 0.01  # N*m, AR(1) at RHO
    noise = _ar1(np.random.default_rng(3), len(samples.q), sigma)
    fit = _fit_noisy(samples, id_base, noise, hac_lag=50)
    # the tolerance from the noise, worked out apart from the fit: least squares on the columns
    # (sign(dq), dq, qdd) with AR(1) noise has the covariance (A^T A)^-1 times the noise's long-run
    # variance sigma^2 (1 + rho) / (1 - rho) (the sum of its autocovariances); 4 standard deviations
    a = np.column_stack([np.sign(samples.dq[:, ELBOW]), samples.dq[:, ELBOW], samples.qdd[:, ELBOW]])
    sd = np.sqrt(np.diag(np.linalg.inv(a.T @ a)) * sigma**2 * (1 + RHO) / (1 - RHO))
    for i, key in enumerate(("friction", "damping", "armature")):
        assert getattr(fit, key)[0] == pytest.approx(FAST_TRUTH[key], abs=4 * sd[i]), key
    assert 4 * sd[2] < 0.25 * FAST_TRUTH["armature"]  # the check is meaningful: the tolerance is < 25 %


def test_fast_fit_intervals_cover_the_truth_with_correlated_noise() -> None:
    """Over 40 noise seeds the stated 95 % interval holds the truth in most (>= 34: a 95 % interval covers
    38 on average, binomial sd 1.4); the ordinary least-squares one, which takes the 1500 correlated samples
    as independent (~sqrt(19) too narrow at RHO 0.9), in far fewer."""
    samples, id_base = _elbow_alone()
    hac, ols = {"armature": 0, "friction": 0}, {"armature": 0, "friction": 0}
    for seed in range(40):
        noise = _ar1(np.random.default_rng(100 + seed), len(samples.q), 0.02)
        for counts, lag in ((hac, 50), (ols, None)):
            fit = _fit_noisy(samples, id_base, noise, hac_lag=lag)
            for key in counts:
                counts[key] += abs(getattr(fit, key)[0] - FAST_TRUTH[key]) <= fit.half95[key][0]
    assert min(hac.values()) >= 34, hac
    assert max(ols.values()) <= 28, ols


def test_fast_fit_holds_a_given_armature_and_fits_the_rest_around_it() -> None:
    """Noise-free elbow: holding the true armature gives friction and damping exactly; holding one 0.001
    kg*m^2 too high leaves ``0.001 qdd`` in the equation, which the fit's other columns (sign(dq), dq) absorb
    as far as they can: the estimates move by the least-squares projection of it on them, worked out here
    apart with numpy."""
    from bar_policy.robot.sysid_fast import fit_fast

    samples, id_base = _elbow_alone()
    sliding = -np.sign(samples.dq) * 1e3
    seg = [(slice(0, len(samples.q)), ELBOW)]
    exact = fit_fast(
        samples,
        seg,
        ROBOT.joint_names,
        id_base,
        sliding,
        np.ones(1),
        armature=np.array([FAST_TRUTH["armature"]]),
    )
    assert exact.armature[0] == FAST_TRUTH["armature"] and exact.half95["armature"][0] == 0.0
    for key in ("friction", "damping"):  # float64 least squares on exact data: to 1e-9 of the value
        assert getattr(exact, key)[0] == pytest.approx(FAST_TRUTH[key], rel=1e-9, abs=1e-12), key
    off = fit_fast(
        samples,
        seg,
        ROBOT.joint_names,
        id_base,
        sliding,
        np.ones(1),
        armature=np.array([FAST_TRUTH["armature"] + 1e-3]),
    )
    a = np.column_stack([np.sign(samples.dq[:, ELBOW]), samples.dq[:, ELBOW]])
    delta, *_ = np.linalg.lstsq(a, -1e-3 * samples.qdd[:, ELBOW], rcond=None)
    assert off.armature[0] == FAST_TRUTH["armature"] + 1e-3
    assert off.friction[0] == pytest.approx(FAST_TRUTH["friction"] + delta[0], rel=1e-9, abs=1e-12)
    assert off.damping[0] == pytest.approx(FAST_TRUTH["damping"] + delta[1], rel=1e-9, abs=1e-12)
