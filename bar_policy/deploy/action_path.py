"""What a policy's raw output becomes before it is a joint target: the clip, then the action filter.

Per POLICY tick (the env's ``LiteRobotEnv.filtered_action``, in numpy):

1. the raw action is clipped to ``+-policy.action_clip`` (as the env clips to [-1, 1]); clipped entries are
   counted, and the first clip of a run is logged once;
2. with the file's ``bar.action_filter`` (``PolicyMetadata.action_filter_hz``), the first-order low-pass of
   ``bar_policy.robot.action_filter`` (the env's code) moves the applied action ``alpha`` of the way towards
   it; without it the clipped action is applied as it is (files made before the filter).

The applied action is the filter's state and the observation's ``actions`` term. ``start(q)`` sets it when
POLICY begins: the action of the pose ``q`` the robot was brought to (the HOLD ramp's target; an
evaluation's start frame) with the filter, 0 without it, as the env's reset does.

``check_action_scale`` (a pure function, in ``safety``: no import of the loader, so ``policy`` can call it
at load) checks the file's ``action_scale`` against the joint ranges: the
reach ``default +- action_scale * bound`` (bound = the action clip, else 1 action unit) must stay within
``[lower - margin, upper + margin]``. The runtime refuses a policy that fails it (``PolicyLoadError``).
"""

from __future__ import annotations

import logging

import numpy as np

from bar_policy.deploy.policy import OnnxPolicy
from bar_policy.deploy.safety import DEFAULT_REACH_MARGIN, check_action_scale
from bar_policy.robot.action_filter import filter_alpha, lowpass_step, pose_action

__all__ = ["DEFAULT_REACH_MARGIN", "ActionPath", "check_action_scale"]

log = logging.getLogger(__name__)


class ActionPath:
    """Clip and filter a policy's actions; holds the applied action (the filter state), float32 (n,)."""

    def __init__(self, policy: OnnxPolicy) -> None:
        """Read the clip bound, the filter cutoff, the default pose and the action scale of ``policy``."""
        self.policy = policy
        self.cutoff_hz = policy.metadata.action_filter_hz
        self.alpha = filter_alpha(self.cutoff_hz, policy.policy_dt)
        idx = policy.action_index
        self._default = np.asarray(policy.default_joint_pos, dtype=np.float64)[idx]
        self._scale = np.asarray(policy.action_scale, dtype=np.float64)
        self.last = np.zeros(policy.n_actions, dtype=np.float32)
        """The applied action of the last POLICY tick (the observation's ``actions``)."""
        self.clip_count = 0
        """Action entries clipped to ``+-policy.action_clip`` over the run."""
        self._warned = False
        self.count = 0
        """Raw action entries seen over the run (the clip count's denominator)."""

    @property
    def bound(self) -> float:
        """The action range, action units: ``policy.action_clip``, else 1 (training's range)."""
        c = self.policy.action_clip
        return 1.0 if c is None else float(c)

    def start(self, q: np.ndarray) -> None:
        """POLICY begins with the robot at pose ``q`` (rad, canonical order): set the filter state."""
        if self.cutoff_hz is None:
            self.last = np.zeros(self.policy.n_actions, dtype=np.float32)
        else:
            q_act = np.asarray(q, dtype=np.float64)[self.policy.action_index]
            self.last = pose_action(q_act, self._default, self._scale).astype(np.float32)

    def __call__(self, action: np.ndarray, t: float) -> tuple[np.ndarray, int]:
        """The applied action of raw ``action`` at run time ``t`` (s), and how many entries were clipped."""
        self.count += int(np.size(action))
        used = self._clip(action, t)
        n_clipped = int(np.count_nonzero(used != action))
        if self.cutoff_hz is not None:
            used = lowpass_step(self.last.astype(np.float64), used.astype(np.float64), self.alpha)
            used = used.astype(np.float32)
        self.last = used
        return used, n_clipped

    def _clip(self, action: np.ndarray, t: float) -> np.ndarray:
        """``clip(action, -c, c)`` with c = ``policy.action_clip`` (float32); clipped entries are counted."""
        c = self.policy.action_clip
        if c is None:
            return action
        used = np.minimum(np.maximum(action, np.float32(-c)), np.float32(c))
        if (used != action).any():
            self.clip_count += int(np.count_nonzero(used != action))
            if not self._warned:
                self._warned = True
                log.warning(
                    "policy action outside +-%g at t=%.3f s (indices %s); clipped as in training "
                    "(further ones counted)",
                    c,
                    t,
                    np.flatnonzero(used != action).tolist(),
                )
        return used
