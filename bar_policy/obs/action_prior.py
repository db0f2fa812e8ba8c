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

**Integral term** (``error_index``, ``error_gain``; ``reference_prior(error_gain=...)``): the prior may add
``error_gain * obs[index of joint_error_ema]``, the moving average ``z`` of ``q_cmd - q``
(``robot.error_ema``). At gain 1 (``z / scale`` action units) it is integral action without a state of its
own: while the command is ``q_ref + z``, the average's step ``z + alpha (q_cmd - q - z)`` is
``z + alpha (q_ref - q)``, the tracking error integrated at ``1 / tau`` (tau 0.5 s); under a steady load
``tau_l`` the P-law's spring holds ``q_cmd - q = tau_l / Kp``, so ``z`` tends to it, the command to
``q_ref + tau_l / Kp`` and ``q`` to ``q_ref``, whatever the load (gravity, a payload, a weaker motor). The
MLP keeps the dynamic part. It winds up wherever ``q`` cannot follow the command: against a contact (a
piano key's stop: the piano's prior has none, docs/robust_training.md, "The integral prior") or a motor at
its torque cap, until the prior's clip at ``bound``; at a joint limit the command's clip bounds it.

The prior has no parameters: it is part of the network's structure, written into the ONNX graph by
``bar_policy.export`` (Gather, Mul, Add, Clip, Atanh before the output Tanh), so a deployed file is still
``obs -> actions`` and the runtime never knows it is there. numpy only (the deploy side imports
``bar_policy.obs``); ``apply`` and ``pre_tanh`` also run on jax arrays.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy.obs.manager import ObservationManager
from bar_policy.obs.robot_layout import ERROR_EMA_TERM

__all__ = ["PRIOR_BOUND", "ActionPrior", "BlendPrior", "Prior", "check_fits", "reference_prior"]

PRIOR_BOUND = 0.99
"""Bound of the prior, action units: atanh(0.99) = 2.65 keeps the squash's slope at 2 % rather than 0, so
the MLP can still move an action whose reference sits at the edge of the action box."""


@dataclass(frozen=True, kw_only=True)
class ActionPrior:
    """``prior(obs) = clip(gain * obs[..., index] + offset [+ integral term], -bound, bound)``, per action.

    The integral term (module docstring), for a prior that has one: ``error_gain * obs[..., error_index]``.
    """

    index: tuple[int, ...]
    """Observation entries read, one per action (canonical joint order)."""
    gain: tuple[float, ...]
    """Multiplier per action, action units per observation unit."""
    offset: tuple[float, ...]
    """Added per action, action units."""
    bound: float = PRIOR_BOUND
    """Symmetric clip of the prior, action units, in (0, 1) (atanh of it must be finite)."""
    error_index: tuple[int, ...] = ()
    """Observation entries of the integral term (``joint_error_ema``), one per action; () for none."""
    error_gain: tuple[float, ...] = ()
    """Multiplier per action on ``error_index``'s entries, action units per observation unit."""

    def __post_init__(self) -> None:
        n = len(self.index)
        if not n or len(self.gain) != n or len(self.offset) != n:
            raise ValueError(
                f"index, gain and offset need one entry per action (>= 1), got {n}, {len(self.gain)}, "
                f"{len(self.offset)}"
            )
        if len(self.error_index) != len(self.error_gain) or len(self.error_index) not in (0, n):
            raise ValueError(
                f"error_index and error_gain need one entry per action ({n}) or none, got "
                f"{len(self.error_index)}, {len(self.error_gain)}"
            )
        if any(int(i) != i or i < 0 for i in (*self.index, *self.error_index)):
            raise ValueError(f"index entries must be integers >= 0, got {self.index}, {self.error_index}")
        if not all(math.isfinite(v) for v in (*self.gain, *self.offset, *self.error_gain)):
            raise ValueError("gain, offset and error_gain must be finite")
        if not 0.0 < self.bound < 1.0:
            raise ValueError(f"bound must be in (0, 1) action units, got {self.bound}")

    @property
    def action_size(self) -> int:
        """Number of actions A."""
        return len(self.index)

    @property
    def has_error_term(self) -> bool:
        """Whether the prior adds the integral term."""
        return bool(self.error_index)

    def check_observation_size(self, obs_size: int) -> None:
        """``ValueError`` unless every index is inside an observation of ``obs_size`` entries."""
        last = max((*self.index, *self.error_index))
        if last >= obs_size:
            raise ValueError(f"the prior reads observation entry {last}, the observation has {obs_size}")

    def apply(self, obs: Array) -> Array:
        """The prior action, shape ``(..., A)``, for observations of shape ``(..., obs)`` (numpy or jax)."""
        xp = array_namespace(obs)
        g = np.asarray(self.gain, np.float32)
        c = np.asarray(self.offset, np.float32)
        a = obs[..., np.asarray(self.index)] * g + c
        if self.has_error_term:
            a = a + obs[..., np.asarray(self.error_index)] * np.asarray(self.error_gain, np.float32)
        return xp.clip(a, -self.bound, self.bound)

    def pre_tanh(self, obs: Array) -> Array:
        """``atanh(prior(obs))``: what is added to a tanh-squashed policy's mean, shape ``(..., A)``."""
        return array_namespace(obs).arctanh(self.apply(obs))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (run configs and reports)."""
        out: dict[str, Any] = {
            "index": list(self.index),
            "gain": list(self.gain),
            "offset": list(self.offset),
            "bound": self.bound,
        }
        if self.has_error_term:
            out.update(error_index=list(self.error_index), error_gain=list(self.error_gain))
        return out


@dataclass(frozen=True, kw_only=True, eq=False)
class BlendPrior:
    """Weighted means of poses that observation entries select (the piano's key-pose prior).

    With ``x = max(obs[..., start:start + n], 0)`` (shape ``(..., n)``: selector entries, e.g. goal keys)
    and ``m`` blends ``i`` (arrays stacked on a first axis)

        prior(obs) = clip(sum_i (x @ numer[i] + numer_bias[i]) / (x @ denom[i] + denom_bias[i]), -b, b)

    (``b`` = ``bound``). Column ``a`` of ``numer[i]`` holds ``w * pose[a]`` per entry and of ``denom[i]``
    its weight ``w >= 0``: each blend is the mean of the poses of the entries that are on, weighted, and of a
    rest pose ``numer_bias / denom_bias`` of weight ``denom_bias > 0``, which also keeps the division finite
    (``x`` is clipped at 0 for that reason: negative selectors still give a finite prior). Actions of
    different groups (a hand's joints) read different entries through their columns; blends add.
    """

    start: int
    """First observation entry read."""
    numer: np.ndarray
    """Weighted poses, action units, shape (m, n, A); float32, as all four arrays (converted once at
    construction: ``blend`` and the exported graph compute in float32, and a per-call conversion cost the
    piano's deploy tick 0.13 ms)."""
    denom: np.ndarray
    """Weights, >= 0, shape (m, n, A)."""
    numer_bias: np.ndarray
    """The rest poses times their weights, action units, shape (m, A)."""
    denom_bias: np.ndarray
    """The rest poses' weights, > 0, shape (m, A)."""
    bound: float = PRIOR_BOUND
    """Symmetric clip of the prior, action units, in (0, 1)."""
    label: str = ""
    """What it is and how it was built (run records)."""

    def __post_init__(self) -> None:
        for name in ("numer", "denom", "numer_bias", "denom_bias"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), np.float32))
        m, n, a = np.shape(self.numer)
        shapes = [np.shape(v) for v in (self.denom, self.numer_bias, self.denom_bias)]
        if shapes != [(m, n, a), (m, a), (m, a)]:
            raise ValueError(
                f"numer {np.shape(self.numer)}, denom, numer_bias and denom_bias {shapes} must be (m, n, A), "
                "(m, n, A), (m, A), (m, A)"
            )
        if self.start < 0:
            raise ValueError(f"start must be >= 0, got {self.start}")
        if np.any(np.asarray(self.denom) < 0) or not np.all(np.asarray(self.denom_bias) > 0):
            raise ValueError("denom must be >= 0 and denom_bias > 0 (weights)")
        if not all(
            np.all(np.isfinite(v)) for v in (self.numer, self.denom, self.numer_bias, self.denom_bias)
        ):
            raise ValueError("numer, denom and the biases must be finite")
        if not 0.0 < self.bound < 1.0:
            raise ValueError(f"bound must be in (0, 1) action units, got {self.bound}")

    @property
    def action_size(self) -> int:
        """Number of actions A."""
        return int(np.shape(self.numer)[2])

    @property
    def stop(self) -> int:
        """One past the last observation entry read."""
        return self.start + int(np.shape(self.numer)[1])

    def check_observation_size(self, obs_size: int) -> None:
        """``ValueError`` unless the entries read lie inside an observation of ``obs_size`` entries."""
        if self.stop > obs_size:
            raise ValueError(
                f"the prior reads observation entries up to {self.stop - 1}, the observation has {obs_size}"
            )

    def apply(self, obs: Array) -> Array:
        """The prior action, shape ``(..., A)``, for observations of shape ``(..., obs)`` (numpy or jax)."""
        return self.blend(obs[..., self.start : self.stop])

    def blend(self, entries: Array) -> Array:
        """The prior action, shape ``(..., A)``, of the entries it reads: ``obs[..., start:stop]``."""
        xp = array_namespace(entries)
        x = xp.maximum(entries, 0.0)
        total = 0.0
        for i in range(np.shape(self.numer)[0]):
            num = x @ self.numer[i] + self.numer_bias[i]
            den = x @ self.denom[i] + self.denom_bias[i]
            total = total + num / den
        return xp.clip(total, -self.bound, self.bound)

    def pre_tanh(self, obs: Array) -> Array:
        """``atanh(prior(obs))``: what is added to a tanh-squashed policy's mean, shape ``(..., A)``."""
        return array_namespace(obs).arctanh(self.apply(obs))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (run configs and reports): the label, the span read and the arrays' digest."""
        digest = hashlib.sha256()
        for v in (self.numer, self.denom, self.numer_bias, self.denom_bias):
            digest.update(np.ascontiguousarray(v, np.float32).tobytes())
        return {
            "kind": "blend",
            "label": self.label,
            "start": self.start,
            "stop": self.stop,
            "blends": int(np.shape(self.numer)[0]),
            "actions": self.action_size,
            "bound": self.bound,
            "sha256": digest.hexdigest(),
        }


Prior = ActionPrior | BlendPrior
"""Any action prior: what the learner adds before the squash and the exporter writes into the graph."""


def check_fits(prior: Prior, obs_size: int, action_size: int, holder: str = "the env") -> None:
    """``ValueError`` unless ``prior`` gives ``action_size`` actions and reads inside ``obs_size`` entries.

    ``holder`` names what has ``action_size`` actions in the message (the env, a network's last layer).
    """
    if prior.action_size != action_size:
        raise ValueError(f"the action prior has {prior.action_size} actions, {holder} {action_size}")
    prior.check_observation_size(obs_size)


def reference_prior(
    manager: ObservationManager,
    default: np.ndarray,
    scale: np.ndarray,
    lead_steps: int,
    error_gain: float = 0.0,
) -> ActionPrior:
    """The prior that commands the reference pose ``lead_steps`` control steps ahead (plus the integral term).

    Args:
        manager: a tracking layout (with ``motion_joint_pos``: the reference at the next ``lookahead_steps``
            frames, frame-major).
        default: the layout's default pose, rad, shape (A,) (``q_cmd = default + scale * a``).
        scale: rad per action unit, shape (A,), > 0.
        lead_steps: which frame, 1 = the next one (the pose the command of this step reaches for), up to
            ``lookahead_steps``; more lead offsets the action filter's lag.
        error_gain: the integral term's gain, >= 0 (module docstring): the command adds ``error_gain * z``
            rad, ``z`` the layout's ``joint_error_ema``; 1 cancels a steady load; 0: no term.

    Raises:
        ValueError: the layout has no ``motion_joint_pos``, ``lead_steps`` is outside 1..lookahead_steps,
            ``error_gain`` is negative or not finite, or it is > 0 and the layout has no ``joint_error_ema``.
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
    term = manager.term("motion_joint_pos")
    start = manager.term_slice("motion_joint_pos").start + (lead_steps - 1) * n
    if not (math.isfinite(error_gain) and error_gain >= 0.0):
        raise ValueError(f"error_gain must be a finite number >= 0, got {error_gain}")
    error_index: tuple[int, ...] = ()
    error_gains: tuple[float, ...] = ()
    if error_gain > 0.0:
        if ERROR_EMA_TERM not in manager.term_names:
            raise ValueError(
                f"error_gain {error_gain}: layout {manager.schema.name} v{manager.schema.version} has no "
                f"{ERROR_EMA_TERM} term (the robust layouts: RobotEnvConfig.joint_error_ema=true)"
            )
        ema = manager.term_slice(ERROR_EMA_TERM)
        error_index = tuple(range(ema.start, ema.stop))
        # obs = term.scale * z  =>  error_gain * z rad is error_gain / (term.scale * scale) per obs unit
        error_gains = tuple(float(v) for v in error_gain / (manager.term(ERROR_EMA_TERM).scale * scale))
    # obs = term.scale * q_ref (no default offset on this term)  =>  a = (obs / term.scale - default) / scale
    return ActionPrior(
        index=tuple(range(start, start + n)),
        gain=tuple(float(v) for v in 1.0 / (term.scale * scale)),
        offset=tuple(float(v) for v in -default / scale),
        error_index=error_index,
        error_gain=error_gains,
    )
