"""The low-pass filter between a policy's output and the MIT command, once for the env and the robot.

A first-order low-pass (exponential moving average) on the action, per joint, at the control rate:

    a_applied[t] = a_applied[t-1] + alpha * (a_policy[t] - a_applied[t-1]),   alpha = 1 - exp(-2 pi f_c dt)

``f_c`` is the cutoff (-3 dB) frequency and ``dt`` the control period; ``alpha = 1`` passes the action
through unchanged. The filter's state is the last applied action, which is also the observation's
``actions`` term: the policy sees what was applied, so the filtered system stays Markov. At the start of an
episode (the env's reset, the first POLICY tick after the HOLD ramp on the robot) the state is the action
that commands the pose the robot starts from (``pose_action``), so the first command continues from the
pose instead of jumping towards the default.

The MJX env (jax) and the deploy runtime (numpy) call these same functions; the ONNX metadata key
``bar.action_filter`` carries the cutoff (absent or null: no filter, as in files made before the filter).
"""

from __future__ import annotations

import math

from bar_policy._array import Array, array_namespace

__all__ = ["filter_alpha", "lowpass_step", "pose_action"]


def filter_alpha(cutoff_hz: float | None, dt: float) -> float:
    """The smoothing factor of a first-order low-pass at ``cutoff_hz`` sampled every ``dt`` s.

    ``None`` (no filter) gives 1.0. Raises ``ValueError`` unless the cutoff is > 0 Hz and below Nyquist.
    """
    if cutoff_hz is None:
        return 1.0
    if not (0.0 < cutoff_hz < 0.5 / dt):
        raise ValueError(
            f"action filter cutoff must be > 0 Hz and below the Nyquist frequency {0.5 / dt:g} Hz, "
            f"got {cutoff_hz}"
        )
    return 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt)


def lowpass_step(state: Array, action: Array, alpha: float) -> Array:
    """One filter step: ``state + alpha * (action - state)``, shape ``(..., n)`` (numpy or jax)."""
    return state + alpha * (action - state)


def pose_action(q: Array, default: Array, scale: Array) -> Array:
    """The action that commands pose ``q``: ``clip((q - default) / scale, -1, 1)``, shape ``(..., n)``.

    ``default`` (rad) and ``scale`` (rad per unit action) are the policy's ``default_joint_pos`` and
    ``action_scale``; the inverse of ``q_cmd = default + scale * a`` inside the action range.
    """
    xp = array_namespace(q, default, scale)
    return xp.clip((q - default) / scale, -1.0, 1.0)
