"""LitePiano: the Lite plays the keyboard (a task on the robot env in the keyboard's scene).

Semantics (fixed; the exported policy and the deploy runtime rely on them). Action, control, latency, noise
and the initial-state noise are the robot env's (``bar_policy.envs.robot``); the task adds:

- **Scene**: the keyboard of ``config.keyboard`` (``keyboard_scene``: spring-loaded hinge keys that only the
  two fingertip spheres touch) on the robot's ``MjSpec``. The robot's joints are addressed by name; the keys'
  hinge angles are read from their own ``qpos`` addresses.
- **Songs**: a bank built once (``bank.song_bank``): the training library's songs and ``songs`` random
  playable ones (``generator.random_song``, tempos ~ U(``tempo_bpm``), written to end by
  ``episode_length_s - count_in_s``), each played with ``playback``'s count-in (the first note no earlier
  than ``count_in_s``; ``SongCommands`` plays songs on the robot with the same) and cut or padded to the
  episode. Each episode plays one song, drawn uniformly, from its start (the count-in's).
- **Observation**: ``ObservationManager.for_task("piano", mode)``: ``target_keys`` (the goal keys of
  ``TARGET_FRAMES`` control steps from the current one plus ``playback.lead_steps``: the song read ahead
  by the lead, ``bank.PlaybackConfig``), ``progress`` (steps / episode steps, from the
  episode's start: the count-in's ticks count, as on the robot),
  ``key_pressed`` (the keys past their press threshold now), then q, dq and the last action.
- **Step ``t``** (the ``t``-th control step of the episode, ``t = step - 1``): the goal is the bank's row
  ``t`` (the song's own time: ``target_keys`` showed it ``lead_steps`` steps before); it is compared with
  the keys down after the step. Rewards are the rows of the task's term table (``term_table.py``: functions of
  ``rewards`` and ``bar_policy.envs.rewards``) weighted by ``RewardScales``; metrics
  are the step's true positives, false positives and false negatives and its precision, recall and F1
  (``metrics``), so the evaluation reports RoboPianist's step means and the pooled F1 beside them; and the
  true positives and false negatives over the black keys and over the white keys (``colour_counts``), so
  it reports the pooled recall of each colour's goal key-ticks (``recall_black``, ``recall_white``).
- **Initial state**: the default pose as the robot holds it (``held.held_pose``: sagged under gravity at
  Kp, where the keyboard is placed) plus the robot env's noise, at rest; so no episode starts with the hands
  falling onto the keys.
- **Episodes**: the env ends an episode only when the physics turns non-finite; the wrappers truncate at
  ``episode_length_s``.
- **Reference** (``task_reference``: the chatter signal ``q_cmd - q_ref`` of the MJX evaluation,
  ``envs.quality_signals``): the key-pose reference of the deploy side (``reference.KeyPoseReference``,
  docs/piano.md "Chatter against the key-pose reference"), the key-pose prior (``KeyPosePriorConfig()``
  defaults, lead ``reference.LEAD_STEPS``, the config's keyboard; not ``config.prior``: a fixed yardstick)
  on the step's ``target_keys`` (the goal-key window the observation shows) and ``key_pressed`` (the keys
  down it shows, which the prior's release blend reads; kept as ``info["ref_keys"]``, 0 at a reset), through
  this env's action path: clip to [-1, 1], the action filter, ``q_ref = default + scale * f``. The filter
  state ``f`` is ``info["ref_act"]`` (n,); a reset sets it where it sets the policy's own filter
  (``initial_action`` of the held pose, not the deploy side's action 0: each side starts the reference where
  it starts the policy's filter), each step advances it once. It feeds nothing else: the observation,
  rewards and metrics are those of an env without it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from bar_policy.envs.device_arrays import to_device
from bar_policy.envs.robot import LiteRobotEnv
from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.envs.task import TaskStep, Transition
from bar_policy.envs.term_table import RewardTerm, TerminationTerm
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import BlendPrior
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.tasks.piano import metrics as piano_metrics
from bar_policy.tasks.piano import rewards, term_table
from bar_policy.tasks.piano.bank import SONG_LEAD_STEPS, PlaybackConfig, song_bank, training_songs
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.keyboard import (
    KeyboardConfig,
    black_keys,
    compact_config,
    key_table,
    press_thresholds,
)
from bar_policy.tasks.piano.prior import KeyPosePriorConfig, key_pose_prior
from bar_policy.tasks.piano.reference import LEAD_STEPS, prior_entries
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.song_library import TRAIN
from bar_policy.tasks.piano.term_table import RewardConfig, RewardScales
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

__all__ = ["LitePiano", "PianoEnvConfig", "RewardConfig", "RewardScales", "default_config", "nominal_config"]


@dataclass(frozen=True, kw_only=True)
class PianoEnvConfig(RobotEnvConfig):
    """Everything LitePiano needs. Build with ``default_config()``; derive with ``dataclasses.replace``."""

    episode_length_s: float = 10.0
    """Episode length, s (500 control steps): the random songs' length."""
    action_filter_hz: float | None = 3.0
    """Cutoff of the action low-pass, Hz (the tracker's and reach's; the deploy runtime applies the same)."""
    keyboard: KeyboardConfig = field(default_factory=compact_config)
    """The keyboard (must have ``PIANO_KEYS`` keys: the layout's sizes)."""
    songs: int = 256
    """Random songs in the bank (besides the training library's)."""
    library: tuple[str, ...] = TRAIN
    """Library songs in the bank (``song_library``; the held-out ones are never trained on)."""
    tempo_bpm: tuple[float, float] = (60.0, 120.0)
    """Tempo range of the random songs, beats per minute (a beat = one short note)."""
    song_seed: int = 0
    """Seed of the random songs."""
    playback: PlaybackConfig = field(default_factory=lambda: PlaybackConfig(lead_steps=SONG_LEAD_STEPS))
    """How the songs are played: the count-in before the first note and the goal keys' lead
    (``SongCommands`` plays with the policy file's lead, ``bar.song_lead_steps``, and the same count-in)."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """Reward terms and weights."""
    prior: KeyPosePriorConfig = field(default_factory=KeyPosePriorConfig)
    """The key-pose action prior (``network.action_prior=key_pose``; ``prior.py``)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.keyboard.n_keys != PIANO_KEYS:
            raise ValueError(
                f"keyboard has {self.keyboard.n_keys} keys; the piano layout is for {PIANO_KEYS} "
                "(keyboard.compact_config(): MIDI 36..84)"
            )
        if self.songs < 0 or (self.songs == 0 and not self.library):
            raise ValueError(f"the bank needs a song: songs = {self.songs}, library = {self.library}")
        if not self.playback.count_in_s < self.episode_length_s:
            raise ValueError(
                f"playback.count_in_s = {self.playback.count_in_s} s leaves no song in an episode of "
                f"{self.episode_length_s} s"
            )
        lo, hi = self.tempo_bpm
        if not 30.0 <= lo <= hi:
            raise ValueError(f"tempo_bpm must be (low, high) with 30 <= low <= high, got {self.tempo_bpm}")


def default_config() -> PianoEnvConfig:
    """The training configuration: every actuator effect and randomisation on."""
    return PianoEnvConfig()


def nominal_config(base: PianoEnvConfig | None = None) -> PianoEnvConfig:
    """``base`` (default: ``default_config()``) with every randomisation and noise off."""
    return nominal(base or default_config())


class LitePiano(LiteRobotEnv):
    """The Lite at the keyboard (see the module docstring for the exact semantics)."""

    task_name = "piano"

    def __init__(self, config: PianoEnvConfig | None = None) -> None:
        cfg = config or default_config()
        super().__init__(
            cfg, ObservationManager.for_task("piano", cfg.mode), scene=keyboard_scene(cfg.keyboard)
        )
        kb = cfg.keyboard
        m = self.mj_model
        keys = key_table(kb)
        self._key_qpos = np.array([m.jnt_qposadr[m.joint(f"piano_key{k.midi}").id] for k in keys])
        self._key_sites = np.array([m.site(f"piano_key{k.midi}_top").id for k in keys])
        self._tip_sites = np.array([m.site(s).id for s in FINGERTIP_SITES])
        self._threshold = to_device(press_thresholds(kb), np.float32)
        self._black = black_keys(kb)  # numpy: a static mask in the jitted step
        self._angle_max = to_device(rewards.angle_max(kb), np.float32)
        length_s = cfg.episode_length_s - cfg.playback.count_in_s  # the random songs fit after the count-in
        songs = training_songs(kb, cfg.songs, length_s, cfg.tempo_bpm, cfg.song_seed, cfg.library)
        self.songs = tuple(songs)
        """The bank's songs as written (the bank holds them as played)."""
        self.bank = song_bank(songs, kb, cfg.ctrl_dt, self.episode_length, TARGET_FRAMES - 1, cfg.playback)
        self._down = to_device(self.bank.down)
        self._hands = to_device(self.bank.hands)
        self._held = to_device(held_pose(np.asarray(self._default), cfg.mode, kp=self._kp), np.float32)

    def action_prior(self, lead_steps: int, error_gain: float = 0.0) -> BlendPrior:
        """The key-pose prior (``prior.py``): goal-key frames ``0..lead_steps`` press, later ones hover.

        Raises:
            ValueError: ``error_gain`` is not 0: the key-pose prior has no integral term (against a key's
                stop the error average winds up: docs/robust_training.md, "The integral prior").
        """
        if error_gain != 0.0:
            raise ValueError(
                f"network.prior_error_gain={error_gain}: LitePiano's key_pose prior has no integral term "
                "(against the keys' stops it winds up); valid: 0"
            )
        c = self.config
        return key_pose_prior(
            self.obs_manager, c.keyboard, self._default, self._scale, lead_steps, c.prior, kp=self._kp
        )

    @functools.cached_property
    def reference_prior(self) -> BlendPrior:
        """The reference's key-pose prior (``KeyPosePriorConfig()``, lead ``LEAD_STEPS``) on ``target_keys``.

        As ``KeyPoseReference.for_policy`` builds it (the deploy side), over this env's keyboard, default
        pose and action scale; built on first use (the key poses' IK takes ~2 s, cached per keyboard).
        """
        c = self.config
        return key_pose_prior(
            self.obs_manager,
            c.keyboard,
            self._default,
            self._scale,
            LEAD_STEPS,
            KeyPosePriorConfig(),
            kp=self._kp,
        )

    @functools.cached_property
    def _reference_terms(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``(scale, clip)`` of ``target_keys`` and of ``key_pressed`` (``reference.prior_entries``)."""
        tk, kp = self.obs_manager.term("target_keys"), self.obs_manager.term("key_pressed")
        return (float(tk.scale), float(tk.clip)), (float(kp.scale), float(kp.clip))

    def reference_action(self, target_keys: jax.Array, key_pressed: jax.Array | None = None) -> jax.Array:
        """The key-pose prior's action for one ``target_keys`` window and the keys down, float32.

        ``target_keys``: goal keys 0/1, frame-major; ``key_pressed``: keys down 0/1 (None: none), which the
        release blend reads. The terms as the observation carries them (``reference.prior_entries``, the
        deploy side's assembly), then the blend (``BlendPrior.blend``, jnp); not yet clipped to the action
        range.
        """
        prior = self.reference_prior
        target, keys = self._reference_terms
        x = prior_entries(jnp.asarray(target_keys), key_pressed, prior.stop - prior.start, target, keys)
        return prior.blend(x)

    def reference_state(self, info: dict) -> jax.Array:
        """The reference's filter state after the step of ``info``: one step of the env's action path.

        ``filtered_action(info["ref_act"], reference_action(window, info["ref_keys"]))`` with the window of
        ``info["step"]`` and the keys down (the observation's ``target_keys`` and ``key_pressed`` when the
        step's action was chosen), shape (n,).
        """
        window = self._target_window(info["song"], info["step"])
        return self.filtered_action(info["ref_act"], self.reference_action(window, info.get("ref_keys")))

    def _target_window(self, song: jax.Array, step: jax.Array) -> jax.Array:
        """The goal keys ``target_keys`` shows at ``step``, shape (TARGET_FRAMES, n_keys).

        ``TARGET_FRAMES`` rows of the bank from ``step`` plus the playback's lead.
        """
        start = step + self.config.playback.lead_steps
        return jax.lax.dynamic_slice_in_dim(self._down[song], start, TARGET_FRAMES, axis=0)

    def task_reference(self, info: dict) -> jax.Array:
        """The key-pose reference of the step of ``info``: ``default + scale * reference_state(info)``, rad.

        What the step's command targets (``envs.quality_signals``: the chatter signal is ``q_cmd`` minus it);
        not clipped to the joint limits (the deploy side's neither; the prior's poses are inside them).
        """
        return self._default + self._scale * self.reference_state(info)

    @property
    def metric_keys(self) -> tuple[str, ...]:
        """The step's key counts, precision, recall, F1, goal keys, keys down; TP and FN per key colour."""
        return (
            "true_pos",
            "false_pos",
            "false_neg",
            "precision",
            "recall",
            "f1",
            "goal_keys",
            "keys_down",
            "true_pos_black",
            "false_neg_black",
            "true_pos_white",
            "false_neg_white",
        )

    def eval_ratios(self, metrics: dict[str, jax.Array]) -> dict[str, tuple[jax.Array, jax.Array]]:
        """RoboPianist's step means (``f1``, ``precision``, ``recall``), pooled figures; success_rate = F1.

        Pooled (the evaluators sum numerators and denominators over steps and envs, then divide):
        ``f1_pooled``; ``recall_pooled`` (every goal key-tick), ``recall_black`` and ``recall_white`` (the
        goal key-ticks of one colour: ``TP / (TP + FN)`` of that colour's summed counts). The evaluators
        divide by ``max(denominator, 1)``, so an evaluation without a goal key of a colour reads 0 for it,
        never NaN (as every pooled ratio there).
        """
        one = jnp.ones_like(metrics["f1"])
        tp, fp, fn = metrics["true_pos"], metrics["false_pos"], metrics["false_neg"]
        tp_b, tp_w = metrics["true_pos_black"], metrics["true_pos_white"]
        f1 = (metrics["f1"], one)
        return {
            "success_rate": f1,
            "f1": f1,
            "precision": (metrics["precision"], one),
            "recall": (metrics["recall"], one),
            "f1_pooled": (2.0 * tp, 2.0 * tp + fp + fn),
            "recall_pooled": (tp, tp + fn),
            "recall_black": (tp_b, tp_b + metrics["false_neg_black"]),
            "recall_white": (tp_w, tp_w + metrics["false_neg_white"]),
        }

    def task_metadata(self) -> dict:
        """The song set's id and the goal keys' lead.

        ``dataset_repo_id``: the bank's recipe, count-in included; ``song_lead_steps``: ``SongCommands``
        must read the song as far ahead as training did.
        """
        c = self.config
        lib = "+".join(c.library) if c.library else "none"
        count_in = f"countin{c.playback.count_in_s:g}s"
        return {
            "dataset_repo_id": f"bar_policy.piano:random{c.songs}-seed{c.song_seed}-{count_in}-{lib}",
            "song_lead_steps": c.playback.lead_steps,
        }

    # -- hooks -------------------------------------------------------------------------------------
    def key_angles(self, data: mjx.Data) -> jax.Array:
        """The keys' hinge angles, rad, shape (n_keys,), keyboard order."""
        return data.qpos[self._key_qpos]

    def task_reset(self, model: mjx.Model, key: jax.Array) -> tuple[dict, jax.Array, jax.Array]:
        """A song from the bank, played from its start; the robot at rest in the held default pose.

        The reference's filter starts where the robot env starts the policy's: ``initial_action`` of the
        pose before the noise.
        """
        song = jax.random.randint(key, (), 0, self._down.shape[0])
        info = {
            "song": song,
            "ref_act": self.initial_action(self._held),
            "ref_keys": jnp.zeros(self.config.keyboard.n_keys, jnp.float32),  # the held pose presses none
        }
        return info, self._held, jnp.zeros(self.action_size)

    def reward_terms(self) -> tuple[RewardTerm, ...]:
        """The piano's reward table (``term_table.reward_terms``) for the current config."""
        return term_table.reward_terms(self.config.reward)

    def termination_terms(self) -> tuple[TerminationTerm, ...]:
        """The piano's terminations (``term_table.TERMINATIONS``): none of its own."""
        return term_table.TERMINATIONS

    def task_step(self, tr: Transition) -> TaskStep:
        """The key signals of the term table against the goal row of this step, and the key counts.

        The task's info: the reference's filter state advanced one step (``reference_state``).
        """
        data, info = tr.data, tr.info
        s = tr.step - 1
        goal = self._down[info["song"], s]
        angles = self.key_angles(data)
        down = angles >= self._threshold
        windows = jax.lax.dynamic_slice_in_dim(self._hands[info["song"]], s, TARGET_FRAMES, axis=1)
        ref_act = self.reference_state(info)
        signals = {
            "key_depression": rewards.key_depression(angles, self._angle_max),
            "keys_down": down,
            "goal_keys": goal,
            "black_goal_keys": goal * self._black,  # the static mask: 0/1 of goal's dtype
            "fingertips": data.site_xpos[self._tip_sites],
            "key_sites": data.site_xpos[self._key_sites],
            "hand_goal": rewards.next_goal(windows),
            "tau_applied": data.qfrc_applied[self.robot_index.dof],
            "reference_action": ref_act,
        }
        counts = piano_metrics.step_counts(down, goal)
        step = piano_metrics.scores(counts)
        colour = piano_metrics.colour_counts(down, goal, self._black)
        metrics = {
            "true_pos": counts.tp,
            "false_pos": counts.fp,
            "false_neg": counts.fn,
            "precision": step.precision,
            "recall": step.recall,
            "f1": step.f1,
            "goal_keys": jnp.sum(goal),
            "keys_down": jnp.sum(down.astype(jnp.float32)),
            "true_pos_black": colour.black.tp,
            "false_neg_black": colour.black.fn,
            "true_pos_white": colour.white.tp,
            "false_neg_white": colour.white.fn,
        }
        f32 = {
            k: jnp.asarray(v).astype(jnp.float32) for k, v in metrics.items()
        }  # strong float32, as reset's
        return TaskStep(
            signals=signals,
            info={"ref_act": ref_act, "ref_keys": down.astype(jnp.float32)},
            metrics=f32,
        )

    def task_obs(self, model: mjx.Model, data: mjx.Data, q_meas: jax.Array, info: dict) -> dict:
        """Goal keys of ``TARGET_FRAMES`` steps from ``step + lead_steps``, progress, the keys down now."""
        step = info["step"]
        window = self._target_window(info["song"], step)
        down = (self.key_angles(data) >= self._threshold).astype(jnp.float32)
        return {
            "target_keys": window.reshape(-1),
            "progress": jnp.reshape(step / self.episode_length, (1,)).astype(jnp.float32),
            "key_pressed": down,
        }
