"""Smooth joint curves with known bounds: minimum-jerk segments and uniform cubic B-splines (numpy).

Minimum-jerk (rest to rest, Flash and Hogan 1985): ``q(t) = q0 + (q1 - q0) s(t / T)`` with
``s(u) = 10 u^3 - 15 u^4 + 6 u^5``. Velocity and acceleration are zero at both ends; the peaks are
``|dq| <= 1.875 |q1 - q0| / T`` (at u = 1/2) and ``|ddq| <= 5.7735 |q1 - q0| / T^2`` (10 / sqrt(3), at
u = 1/2 -+ sqrt(3)/6).

Uniform cubic B-spline with knot spacing ``h`` and control points ``c_0 .. c_{K-1}``: the curve stays in
the convex hull of its control points (so inside any box holding them), and since its derivatives are
B-splines of the differences, ``|dq| <= max|c_{i+1} - c_i| / h`` and ``|ddq| <= max|c_{i+2} - 2 c_{i+1}
+ c_i| / h^2 <= 2 max|c_{i+1} - c_i| / h^2``. Three equal control points at an end make the curve start
(or stop) there at rest (zero velocity and acceleration).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MINJERK_PEAK_ACC",
    "MINJERK_PEAK_VEL",
    "bspline_frames",
    "keyframe_frames",
    "minimum_jerk",
]

MINJERK_PEAK_VEL = 1.875
"""Peak of ``ds/du`` of the minimum-jerk profile: peak speed = 1.875 * distance / duration."""
MINJERK_PEAK_ACC = 10.0 / math.sqrt(3.0)
"""Peak of ``|d2s/du2|`` (5.7735): peak acceleration = 5.7735 * distance / duration^2."""


def minimum_jerk(u: np.ndarray) -> np.ndarray:
    """The minimum-jerk profile ``s(u) = 10 u^3 - 15 u^4 + 6 u^5`` for ``u`` in [0, 1] (clipped)."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def keyframe_frames(keyframes: np.ndarray, durations: np.ndarray, rate_hz: float) -> np.ndarray:
    """Frames through ``keyframes`` with rest-to-rest minimum-jerk segments.

    Args:
        keyframes: poses, shape (K, n), rad.
        durations: time from keyframe k to k + 1, s, shape (K - 1,); each a whole number of frames.
        rate_hz: frame rate, Hz.

    Returns:
        Frames, shape (1 + sum(durations) * rate, n), rad: the first frame is ``keyframes[0]``, the last
        ``keyframes[-1]``.
    """
    keyframes = np.asarray(keyframes, dtype=np.float64)
    durations = np.asarray(durations, dtype=np.float64)
    if keyframes.ndim != 2 or durations.shape != (keyframes.shape[0] - 1,):
        raise ValueError(
            f"need keyframes (K, n) and durations (K - 1,), got {keyframes.shape}, {durations.shape}"
        )
    out = [keyframes[:1]]
    for q0, q1, dur in zip(keyframes[:-1], keyframes[1:], durations, strict=True):
        steps = dur * rate_hz
        if not (dur > 0 and abs(steps - round(steps)) < 1e-9):
            raise ValueError(
                f"segment duration {dur} s must be a positive whole number of frames at {rate_hz} Hz"
            )
        u = np.arange(1, round(steps) + 1) / round(steps)
        out.append(q0 + (q1 - q0) * minimum_jerk(u)[:, None])
    return np.concatenate(out, axis=0)


def bspline_frames(control: np.ndarray, knot_s: float, rate_hz: float) -> np.ndarray:
    """Sample a uniform cubic B-spline at ``rate_hz`` from its first to its last span end.

    Args:
        control: control points, shape (K >= 4, n).
        knot_s: knot spacing h, s.
        rate_hz: frame rate, Hz.

    Returns:
        Frames at t = 0, 1/rate, ... <= (K - 3) h, shape (T, n).
    """
    c = np.asarray(control, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] < 4:
        raise ValueError(f"need control points of shape (K >= 4, n), got {c.shape}")
    spans = c.shape[0] - 3
    t = np.arange(math.floor(spans * knot_s * rate_hz + 1e-9) + 1) / rate_hz
    x = t / knot_s
    j = np.minimum(np.floor(x).astype(int), spans - 1)
    u = (x - j)[:, None]
    b0 = (1 - u) ** 3
    b1 = 3 * u**3 - 6 * u**2 + 4
    b2 = -3 * u**3 + 3 * u**2 + 3 * u + 1
    b3 = u**3
    return (b0 * c[j] + b1 * c[j + 1] + b2 * c[j + 2] + b3 * c[j + 3]) / 6.0
