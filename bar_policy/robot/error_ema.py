"""The integral-like observation input ``joint_error_ema``: a low-passed joint tracking error, one function.

``z_t = z_{t-1} + alpha * ((q_cmd_{t-1} - q_t) - z_{t-1})``: the exponential moving average of the error
between the joint command the policy side issued for the last control step (``q_cmd``, after the clip to
the joint limits, before any latency the motors add) and the measured position now (``q_t``, what the
observation's ``joint_pos`` reads), with ``alpha = ctrl_dt / ERROR_EMA_TAU_S``. ``z`` is 0 when a policy
starts (an env reset; the runtime's first POLICY tick). Under a steady load (a payload's sag) ``z`` tends to
the steady error, and ``Kp * z`` to the load torque the P-law carries: what a memoryless policy needs to
cancel it. One body for numpy (the deploy runtime, ``deploy.inputs``) and jax (the MJX env), so both sides
compute the same number from the same states.
"""

from __future__ import annotations

from bar_policy._array import Array

__all__ = ["ERROR_EMA_SCALE", "ERROR_EMA_TAU_S", "error_ema_alpha", "error_ema_step"]

ERROR_EMA_TAU_S = 0.5
"""Time constant of the average, s: long against the 20 ms control period (the average is the steady part
of the error), short against an episode (it settles within one)."""

ERROR_EMA_SCALE = 10.0
"""The observation term's scale, 1/rad: a 0.05 rad sag reads 0.5."""


def error_ema_alpha(ctrl_dt: float, tau: float = ERROR_EMA_TAU_S) -> float:
    """``ctrl_dt / tau`` (both s); ``ValueError`` unless ``0 < ctrl_dt < tau``."""
    if not 0 < ctrl_dt < tau:
        raise ValueError(f"joint_error_ema needs 0 < control period ({ctrl_dt} s) < tau ({tau} s)")
    return ctrl_dt / tau


def error_ema_step(z: Array, q_cmd: Array, q: Array, alpha: float) -> Array:
    """The next average: ``z + alpha * ((q_cmd - q) - z)``, rad, any matching shapes (numpy or jax)."""
    return z + alpha * ((q_cmd - q) - z)
