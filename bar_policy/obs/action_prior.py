"""The action prior: a fixed affine map from observation entries to the action a policy starts from.

A tracking policy's action is absolute (``q_cmd = default + scale * a``), so without help its MLP must
rebuild the reference pose from the observation to within the tracking tolerance: an identity map over the
whole motion box, learnt by PPO, whose error shows as a steady offset (a hold of the 2.5 Hz tracker sat
0.01-0.03 rad off on joints gravity barely loads, docs/tracking.md). With a prior, the policy's
pre-squash mean is ``mlp(obs) + atanh(prior(obs))`` and

    prior(obs) = clip(gain * obs[index] + offset, -bound, bound)        (action units, shape (..., A))

so a zero MLP output commands the reference itself and the network learns only the correction (gravity,
the filter's lag, the arm's dynamics). The reference prior reads one frame of ``motion_joint_pos``:
``a = (q_ref - default) / scale``, the action whose command is that frame's pose.

The prior has no parameters: it is part of the network's structure, written into the ONNX graph by
``bar_policy.export`` (Gather, Mul, Add, Clip, Atanh before the output Tanh), so a deployed file is still
``obs -> actions`` and the runtime never knows it is there. numpy only (the deploy side imports
``bar_policy.obs``); ``apply`` and ``pre_tanh`` also run on jax arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy.obs.manager import ObservationManager

__all__ = ["PRIOR_BOUND", "ActionPrior", "reference_prior"]

PRIOR_BOUND = 0.99
"""Bound of the prior, action units: atanh(0.99) = 2.65 keeps the squash's slope at 2 % rather than 0, so
the MLP can still move an action whose reference sits at the edge of the action box."""


@dataclass(frozen=True, kw_only=True)
class ActionPrior:
    """``prior(obs) = clip(gain * obs[..., index] + offset, -bound, bound)``, one entry per action."""

    index: tuple[int, ...]
    """Observation entries read, one per action (canonical joint order)."""
    gain: tuple[float, ...]
    """Multiplier per action, action units per observation unit."""
    offset: tuple[float, ...]
    """Added per action, action units."""
    bound: float = PRIOR_BOUND
    """Symmetric clip of the prior, action units, in (0, 1) (atanh of it must be finite)."""

    def __post_init__(self) -> None:
        n = len(self.index)
        if not n or len(self.gain) != n or len(self.offset) != n:
            raise ValueError(
                f"index, gain and offset need one entry per action (>= 1), got {n}, {len(self.gain)}, "
                f"{len(self.offset)}"
            )
        if any(int(i) != i or i < 0 for i in self.index):
            raise ValueError(f"index entries must be integers >= 0, got {self.index}")
        if not all(math.isfinite(v) for v in (*self.gain, *self.offset)):
            raise ValueError("gain and offset must be finite")
        if not 0.0 < self.bound < 1.0:
            raise ValueError(f"bound must be in (0, 1) action units, got {self.bound}")

    @property
    def action_size(self) -> int:
        """Number of actions A."""
        return len(self.index)

    def check_observation_size(self, obs_size: int) -> None:
        """``ValueError`` unless every index is inside an observation of ``obs_size`` entries."""
        if max(self.index) >= obs_size:
            raise ValueError(
                f"the prior reads observation entry {max(self.index)}, the observation has {obs_size}"
            )

    def apply(self, obs: Array) -> Array:
        """The prior action, shape ``(..., A)``, for observations of shape ``(..., obs)`` (numpy or jax)."""
        xp = array_namespace(obs)
        g = np.asarray(self.gain, np.float32)
        c = np.asarray(self.offset, np.float32)
        return xp.clip(obs[..., np.asarray(self.index)] * g + c, -self.bound, self.bound)

    def pre_tanh(self, obs: Array) -> Array:
        """``atanh(prior(obs))``: what is added to a tanh-squashed policy's mean, shape ``(..., A)``."""
        return array_namespace(obs).arctanh(self.apply(obs))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (run configs and reports)."""
        return {
            "index": list(self.index),
            "gain": list(self.gain),
            "offset": list(self.offset),
            "bound": self.bound,
        }


def reference_prior(
    manager: ObservationManager, default: np.ndarray, scale: np.ndarray, lead_steps: int
) -> ActionPrior:
    """The prior that commands the reference pose ``lead_steps`` control steps ahead.

    Args:
        manager: a tracking layout (with ``motion_joint_pos``: the reference at the next ``lookahead_steps``
            frames, frame-major).
        default: the layout's default pose, rad, shape (A,) (``q_cmd = default + scale * a``).
        scale: rad per action unit, shape (A,), > 0.
        lead_steps: which frame, 1 = the next one (the pose the command of this step reaches for), up to
            ``lookahead_steps``; more lead offsets the action filter's lag.

    Raises:
        ValueError: the layout has no ``motion_joint_pos``, or ``lead_steps`` is outside 1..lookahead_steps.
    """
    k = manager.schema.lookahead_steps
    if "motion_joint_pos" not in manager.term_names:
        raise ValueError(f"layout {manager.schema.name} has no motion_joint_pos term: no reference prior")
    if not 1 <= lead_steps <= k:
        raise ValueError(f"lead_steps must be in 1..{k} (the layout's lookahead frames), got {lead_steps}")
    n = len(manager.joint_names)
    default = np.asarray(default, np.float64).reshape(n)
    scale = np.asarray(scale, np.float64).reshape(n)
    if not np.all(scale > 0):
        raise ValueError("scale must be > 0 rad per action unit")
    term = next(t for t in manager.schema.terms if t.name == "motion_joint_pos")
    start = manager.term_slice("motion_joint_pos").start + (lead_steps - 1) * n
    # obs = term.scale * q_ref (no default offset on this term)  =>  a = (obs / term.scale - default) / scale
    return ActionPrior(
        index=tuple(range(start, start + n)),
        gain=tuple(float(v) for v in 1.0 / (term.scale * scale)),
        offset=tuple(float(v) for v in -default / scale),
    )
