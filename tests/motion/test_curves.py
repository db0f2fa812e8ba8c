"""Minimum-jerk and B-spline curves: values by hand and the stated velocity/acceleration bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bar_policy.motion.curves import (
    MINJERK_PEAK_ACC,
    MINJERK_PEAK_VEL,
    bspline_frames,
    keyframe_frames,
    minimum_jerk,
)


def test_minimum_jerk_hand_values_and_peaks():
    # s(u) = 10u^3 - 15u^4 + 6u^5: s(0.5) = 1.25 - 0.9375 + 0.1875 = 0.5;
    # s(0.25) = 0.15625 - 0.05859375 + 0.005859375 = 0.103515625.
    np.testing.assert_allclose(
        minimum_jerk(np.array([0.0, 0.25, 0.5, 1.0, 1.5])), [0.0, 0.103515625, 0.5, 1.0, 1.0], atol=1e-12
    )
    # ds/du = 30u^2 (1-u)^2 peaks at u = 1/2: 30/16 = 1.875; d2s/du2 = 60u - 180u^2 + 120u^3 peaks at
    # u = 1/2 - sqrt(3)/6 with 10/sqrt(3).
    assert MINJERK_PEAK_VEL == 30 / 16
    u = 0.5 - math.sqrt(3) / 6
    assert 60 * u - 180 * u**2 + 120 * u**3 == pytest.approx(MINJERK_PEAK_ACC)
    fine = np.linspace(0, 1, 200_001)
    s = minimum_jerk(fine)
    h = fine[1]
    assert np.max(np.gradient(s, h)) == pytest.approx(MINJERK_PEAK_VEL, rel=1e-6)
    assert np.max(np.abs(np.gradient(np.gradient(s, h), h))) == pytest.approx(MINJERK_PEAK_ACC, rel=1e-3)


def test_keyframe_frames_hits_every_keyframe_at_rest():
    keys = np.array([[0.0, 1.0], [1.0, 1.0], [0.5, 0.0]])
    q = keyframe_frames(keys, np.array([0.2, 0.1]), 50.0)
    assert q.shape == (1 + 10 + 5, 2)
    np.testing.assert_allclose(q[[0, 10, 15]], keys, atol=1e-12)
    np.testing.assert_allclose(q[5, 0], 0.5, atol=1e-12)  # halfway in time = halfway in space
    with pytest.raises(ValueError, match="whole number of frames"):
        keyframe_frames(keys, np.array([0.2, 0.011]), 50.0)


def test_bspline_hand_values():
    # Uniform cubic B-spline: at a knot, q = (c0 + 4 c1 + c2) / 6; three equal points = start at rest.
    c = np.array([[0.0], [0.0], [0.0], [6.0], [12.0]])
    q = bspline_frames(c, knot_s=0.5, rate_hz=10.0)  # 2 spans of 0.5 s: frames at 0, 0.1, ..., 1.0 s
    assert q.shape == (11, 1)
    assert q[0, 0] == 0.0  # (0 + 0 + 0) / 6
    assert q[5, 0] == pytest.approx((0 + 4 * 0 + 6) / 6)  # knot 1
    assert q[10, 0] == pytest.approx((0 + 4 * 6 + 12) / 6)  # knot 2 = end
    # At the start: u = 0.2 -> (b2 * 0 + b3 * 6) / 6 with b3 = u^3 = 0.008 -> 0.008.
    assert q[1, 0] == pytest.approx(0.008)


def test_bspline_bounds_on_random_control_points():
    rng = np.random.default_rng(3)
    h, step = 0.4, 0.8
    c = np.cumsum(rng.uniform(-step, step, (40, 5)), axis=0)
    q = bspline_frames(c, h, 2000.0)  # fine sampling for finite differences
    dt = 1 / 2000.0
    v = np.abs(np.diff(q, axis=0)) / dt
    a = np.abs(np.diff(q, 2, axis=0)) / dt**2
    dc = np.abs(np.diff(c, axis=0)).max()
    d2c = np.abs(np.diff(c, 2, axis=0)).max()
    assert v.max() <= dc / h * (1 + 1e-6)
    assert a.max() <= d2c / h**2 * (1 + 1e-3) and d2c <= 2 * dc
    # Convex hull: inside the range of the control points.
    assert np.all(q >= c.min(0) - 1e-12) and np.all(q <= c.max(0) + 1e-12)
