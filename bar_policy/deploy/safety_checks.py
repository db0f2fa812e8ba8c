"""Pure checks under the safety supervisor: the action scale's reach, the time at the torque cap, the ramp.

``check_action_scale`` refuses an ``action_scale`` that reaches beyond the joint ranges (the runtime's
construction); ``CapDwell`` times each joint at its cap (the saturation and ``action_out_of_range`` rules);
``_smoothstep`` shapes the HOLD ramp and its soft start of the gains.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["DEFAULT_REACH_MARGIN", "CapDwell", "check_action_scale"]


DEFAULT_REACH_MARGIN = 0.5
"""How far beyond a joint's range the action's reach may go, rad. The shipped policies reach up to 0.43 rad
beyond (``lite_reach_arms``: the wrist yaw, default -+1.2 rad + 0.8 rad vs the +-1.571 rad range): q_cmd is
clipped to the range, and the margin leaves them room while an ``action_scale`` typo (x10) is refused."""


def check_action_scale(
    default: np.ndarray,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    names: Sequence[str],
    *,
    bound: float = 1.0,
    margin: float = DEFAULT_REACH_MARGIN,
) -> list[str]:
    """Problems of an ``action_scale`` against the joint ranges (empty: none), one per action joint.

    Args:
        default: default pose of the action joints, rad, shape (n,).
        scale: ``action_scale``, rad per action unit, shape (n,).
        lower: lower joint limits of the action joints, rad, shape (n,).
        upper: upper joint limits of the action joints, rad, shape (n,).
        names: the action joints' names.
        bound: the action range, action units (the action clip; 1 without one).
        margin: allowed reach beyond the range, rad.

    Returns:
        ``"NAME: action_scale S rad x +-B reaches [LO, HI] rad, beyond its range [L, U] rad by more than
        M rad"`` (or a non-finite / negative scale) for every joint that fails.
    """
    d, s, lo, up = (np.asarray(x, dtype=np.float64) for x in (default, scale, lower, upper))
    problems = []
    for i, name in enumerate(names):
        if not (np.isfinite(s[i]) and s[i] >= 0):
            problems.append(
                f"{name}: action_scale {float(s[i])} is not a finite number >= 0 rad per action unit"
            )
            continue
        reach_lo, reach_hi = d[i] - s[i] * bound, d[i] + s[i] * bound
        if reach_lo < lo[i] - margin or reach_hi > up[i] + margin:
            problems.append(
                f"{name}: action_scale {s[i]:.4g} rad x +-{bound:.4g} from the default {d[i]:+.4g} rad "
                f"reaches [{reach_lo:+.4g}, {reach_hi:+.4g}] rad, beyond its range [{lo[i]:+.4g}, "
                f"{up[i]:+.4g}] rad by more than {margin:.4g} rad"
            )
    return problems


class CapDwell:
    """Time each joint's torque demand has stayed at its cap; the supervisor's saturation rule.

    A joint is at the cap when ``|demand| >= level`` (and, with ``reported_level``, while the torque its
    motor reports is ``>= reported_level``: ``quality.metrics.at_cap``). Its time grows by ``dt`` per tick
    at the cap and returns to 0 at its first tick below it, so only an unbroken run at the cap counts (a
    sign change at the cap does not break it: a 25 Hz bang-bang between +cap and -cap counts as at the
    cap). ``over()`` lists the joints past ``limit`` seconds. ``bench/track_fidelity.py`` applies the same
    rule to the MJX env's torques.
    """

    def __init__(self, level: np.ndarray, limit: float, reported_level: np.ndarray | None = None) -> None:
        """Per-joint levels and the time allowed at them.

        ``level``: per-joint cap, N*m, shape (n,); ``limit``: allowed time at it, s; ``reported_level``:
        per-joint level the reported torque must reach too, N*m, shape (n,) (None: the demand alone).
        """
        self.level = np.asarray(level, dtype=float)
        self.limit = float(limit)
        self.reported_level = None if reported_level is None else np.asarray(reported_level, dtype=float)
        self.time = np.zeros_like(self.level)

    def update(self, demand: np.ndarray, dt: float, reported: np.ndarray | None = None) -> np.ndarray:
        """Count one tick of ``dt`` s at signed torque ``demand`` (N*m, shape (n,)); returns ``over()``.

        ``reported``: the torque the motors report, N*m, shape (n,); with ``reported_level`` set a joint is
        at the cap only where it reaches that level too (None: the demand alone).
        """
        at_cap = np.abs(demand) >= self.level
        if self.reported_level is not None and reported is not None:
            at_cap &= np.abs(reported) >= self.reported_level
        self.time = np.where(at_cap, self.time + dt, 0.0)
        return self.over()

    def reset(self) -> None:
        """Clear every joint's time (a mode change starts a new count)."""
        self.time = np.zeros_like(self.level)

    def over(self) -> np.ndarray:
        """Indices of the joints at the cap for longer than ``limit``."""
        return np.flatnonzero(self.time > self.limit + 1e-12)


def _smoothstep(x: float) -> float:
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)
