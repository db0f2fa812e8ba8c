"""The piano's joint-space reference: the key-pose prior's command for the song, what chatter is measured on.

The tracker's chatter is the high-passed ``q_cmd - q_ref`` (``bar_policy.quality.metrics``): what the
policy adds on top of the motion it tracks. The piano has no motion clip, and chatter of ``q_cmd`` itself
counts the keystrokes: the key-pose prior alone (a scripted player, no network) scores 6-10 mrad above
5 Hz on the held-out songs, 70 % of it at 5-8 Hz (harmonics of the note rate), against the gate's 5 mrad.
So the piano's reference is the command of that scripted player for the song (docs/piano.md, "Chatter
against the key-pose reference"):

    a_ref[k] = clip(prior(target_keys[k], key_pressed[k]), -c, c)     (action units, the prior's blend)
    f[k]     = f[k-1] + alpha * (a_ref[k] - f[k-1]),  f[-1] = the action the runtime starts its filter at
    q_ref[k] = default + scale * f[k]                                 (rad, the joints the policy drives)

with ``prior`` the key-pose prior (``prior.key_pose_prior``: ``KeyPosePriorConfig()`` defaults, the preset's
``network.prior_lead_steps``) over the policy's layout, evaluated in numpy (``BlendPrior.blend`` of
``prior_entries``) on the tick's ``target_keys`` and ``key_pressed`` observation terms (the prior's
release blend lifts a key held down off its goal: the reference reads the keys the policy reads), ``c``
the policy's action clip, ``alpha`` the policy file's action filter (``robot.action_filter``, cutoff
``bar.action_filter``; 1 without one),
``default`` and ``scale`` its ``default_joint_pos`` and ``action_scale``: the path a policy's action takes
(``deploy.action_path``, ``OnnxPolicy.q_command``), the applied action kept in float32 as there. The runtime
starts its filter at the action of its HOLD target, the command source's ``hold_pose`` or else the policy's
(``q_command(0)``: action 0); the song source names none, so ``f[-1] = 0``. Joints the policy does not drive
are at 0, as ``q_command`` pins them. Not clipped to the joint limits (the supervisor clips ``q_cmd``; the
prior's poses are inside them).

The reference is the same for every policy of a layout, whatever prior a policy was trained with: a
fixed yardstick, not the file's own prior. A zero-MLP policy (``bench/piano_prior.py``) commands it exactly,
tick by tick, so its chatter against it is ~0; a policy that oscillates on top of it keeps its chatter.
numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from bar_policy._array import Array, array_namespace
from bar_policy.robot.action_filter import filter_alpha, lowpass_step
from bar_policy.tasks.piano.keyboard import KeyboardConfig, compact_config
from bar_policy.tasks.piano.preset import PIANO
from bar_policy.tasks.piano.prior import KeyPosePriorConfig, key_pose_prior

if TYPE_CHECKING:
    from bar_policy.obs.action_prior import BlendPrior
    from bar_policy.tasks.episodes import Policy

__all__ = ["LEAD_STEPS", "KeyPoseReference", "prior_entries"]

LEAD_STEPS = int(PIANO["network.prior_lead_steps"])  # type: ignore[call-overload]
"""Goal-key frames ``0..LEAD_STEPS`` press in the reference: the preset's ``network.prior_lead_steps``."""


def prior_entries(
    target_keys: Array,
    key_pressed: Array | None,
    n_entries: int,
    target_term: tuple[float, float],
    keys_term: tuple[float, float],
) -> Array:
    """The observation entries the key-pose prior reads (``obs[prior.start:prior.stop]``), float32.

    ``target_keys`` (goal keys 0/1, frame-major) first, as the observation carries it
    (``clip(scale * goal, -clip, clip)``, ``target_term`` = its ``(scale, clip)``); when the prior reads
    more (``n_entries`` beyond it: the release blend), zeros for the terms between (``progress``, not read)
    and ``key_pressed`` (keys down 0/1, ``keys_term`` its ``(scale, clip)``; None: none down) last.
    numpy or jax, shape ``(n_entries,)``: the one assembly for the deploy side (``KeyPoseReference``) and
    the env (``LitePiano.reference_action``).
    """
    xp = array_namespace(target_keys) if key_pressed is None else array_namespace(target_keys, key_pressed)
    scale, clip = target_term
    x = xp.clip(xp.reshape(xp.asarray(target_keys, dtype=xp.float32), (-1,)) * scale, -clip, clip)
    if n_entries == x.shape[0]:
        return x
    if key_pressed is None:
        return xp.concatenate([x, xp.zeros(n_entries - x.shape[0], xp.float32)])
    k_scale, k_clip = keys_term
    k = xp.clip(xp.reshape(xp.asarray(key_pressed, dtype=xp.float32), (-1,)) * k_scale, -k_clip, k_clip)
    gap = xp.zeros(n_entries - x.shape[0] - k.shape[0], xp.float32)
    return xp.concatenate([x, gap, k])


@dataclass(frozen=True)
class KeyPoseReference:
    """The key-pose prior's command as a policy's action path makes it (see the module docstring).

    Stateless: ``filtered`` advances a filter state the caller keeps (``SongCommands``: one step per
    POLICY tick, as the runtime's filter), ``q`` turns a state into joint positions.
    """

    prior: BlendPrior
    """The key-pose prior over the policy's layout (reads ``target_keys``)."""
    term_scale: float
    """``target_keys``' observation scale (obs = clip(scale * goal, -term_clip, term_clip))."""
    term_clip: float
    """``target_keys``' observation clip."""
    default_joint_pos: np.ndarray
    """The policy's default pose, rad, canonical order, float64 (num_joints,)."""
    action_index: np.ndarray
    """Canonical index of each action joint, int (n_actions,)."""
    action_scale: np.ndarray
    """rad per action unit, float64 (n_actions,)."""
    alpha: float
    """The action filter's factor (``filter_alpha`` of the file's cutoff; 1: no filter)."""
    action_clip: float | None
    """The raw action's clip (the policy's ``action_clip``; None: not clipped)."""
    keys_scale: float = 1.0
    """``key_pressed``' observation scale."""
    keys_clip: float = 1.0
    """``key_pressed``' observation clip."""

    @classmethod
    def for_policy(
        cls, policy: Policy, keyboard: KeyboardConfig | None = None, config: KeyPosePriorConfig | None = None
    ) -> KeyPoseReference:
        """The reference of ``policy``'s layout and action path, from its metadata.

        ``keyboard``: the trained one (default ``compact_config()``); ``config``: the prior's settings
        (default ``KeyPosePriorConfig()``). Raises ``ValueError`` for a layout without ``target_keys``.
        """
        meta = policy.metadata
        joints = tuple(policy.robot.joint_names)
        index = np.array([joints.index(n) for n in meta.action_joint_names], dtype=int)
        default = np.asarray(policy.default_joint_pos, dtype=np.float64)
        scale = np.asarray(meta.action_scale, dtype=np.float64)
        manager = policy.obs_manager
        kp = np.asarray(meta.joint_stiffness, dtype=np.float64)  # the file's gains: its prior's springs
        prior = key_pose_prior(
            manager, keyboard or compact_config(), default[index], scale, LEAD_STEPS, config, kp=kp
        )
        term = manager.term("target_keys")
        keys = manager.term("key_pressed")
        clip = getattr(policy, "action_clip", None)
        return cls(
            prior=prior,
            term_scale=float(term.scale),
            term_clip=float(term.clip),
            default_joint_pos=default,
            action_index=index,
            action_scale=scale,
            alpha=filter_alpha(meta.action_filter_hz, policy.policy_dt),
            action_clip=None if clip is None else float(clip),
            keys_scale=float(keys.scale),
            keys_clip=float(keys.clip),
        )

    @property
    def start(self) -> np.ndarray:
        """The filter's state when POLICY begins: action 0 (the policy's hold pose), float32 (n_actions,)."""
        return np.zeros(len(self.action_index), np.float32)

    def action(self, target_keys: np.ndarray, key_pressed: np.ndarray | None = None) -> np.ndarray:
        """The prior's action for one ``target_keys`` term and the tick's ``key_pressed``, clipped, float32.

        ``target_keys``: goal keys, frame-major; ``key_pressed``: keys down, 0/1 (None: none), which the
        release blend reads.
        """
        x = prior_entries(
            np.asarray(target_keys),
            None if key_pressed is None else np.asarray(key_pressed),
            self.prior.stop - self.prior.start,
            (self.term_scale, self.term_clip),
            (self.keys_scale, self.keys_clip),
        )
        a = np.asarray(self.prior.blend(x), np.float32)
        if self.action_clip is not None:
            a = np.minimum(np.maximum(a, np.float32(-self.action_clip)), np.float32(self.action_clip))
        return a

    def filtered(
        self, state: np.ndarray, target_keys: np.ndarray, key_pressed: np.ndarray | None = None
    ) -> np.ndarray:
        """One filter step from ``state`` towards ``action(target_keys, key_pressed)`` (as ``ActionPath``)."""
        a = self.action(target_keys, key_pressed)
        if self.alpha == 1.0:
            return a
        return lowpass_step(state.astype(np.float64), a.astype(np.float64), self.alpha).astype(np.float32)

    def q(self, state: np.ndarray) -> np.ndarray:
        """Joint positions of filter state ``state``: ``default + scale * state``, rad, (num_joints,)."""
        q = np.zeros_like(self.default_joint_pos)
        idx = self.action_index
        q[idx] = self.default_joint_pos[idx] + self.action_scale * np.asarray(state, dtype=np.float64)
        return q
