"""The piano's command source on the robot: the song's goal keys, the progress, and the keys down.

``SongCommands`` feeds the three piano terms each control tick, as the env builds them (``env.py``):

- ``target_keys``: rows ``s + D .. s + D + TARGET_FRAMES - 1`` of the song's goal keys (``bank.song_bank``,
  the env's count-in and rounding of note times to steps), ``s`` the control step since POLICY began (0
  before it), ``D`` the playback's lead (``PlaybackConfig.lead_steps``: the policy file's
  ``bar.song_lead_steps``, ``policy_playback``); the tick's goal, what is scored, is row ``s``;
- ``progress``: ``s / max(EPISODE_STEPS, song steps)``: the env's ``step / 500`` for a song of up to 10 s
  with its count-in (a longer song runs to 1 at its end instead of beyond it). Both count from the song's
  step 0, the count-in's start, as the env counts from the episode's start;
- ``key_pressed``: the key source's reading (``keys.py``: the simulated keys, a MIDI keyboard, or the
  fingertips' kinematics), named in the log.

The hand-load compensation's default here is ``tare`` (``CommandSource.hand_load``): fitted while the
count-in holds the hands still above the keys (``still_s``), kept for the song.

With a ``truth`` source (``bar-deploy eval --keys kinematic``), the keys that really went down are read at
the same instant as ``key_pressed`` (``scored_keys``): the policy sees the chosen source, the score counts
the simulated keys.

The song plays with the count-in of ``playback`` (``bank.PlaybackConfig``, the env's default): its first
note no earlier than ``count_in_s`` after POLICY's first tick. The run finishes ``END_HOLD_S`` after the
song's last note. The log records the goal keys of the step, the
keys down and the step, so a run can be drawn as a piano roll and scored (``step_counts``).

Score: ``tally`` (``tally.KeyTally``) holds each tick that ended in POLICY (``after_policy_tick``) and lies
in the song's window (``window``, ``metrics.song_window``: its first note's start to its last note's end,
so neither the start-up hold nor the count-in's silence nor the final hold counts); ``summary_lines`` gives
its precision, recall, F1 and per-colour recall, which ``bar-deploy`` prints after the run's ``end:`` line
(``tally.SongFigure``) and ``bar-deploy eval`` reports per song.

With a ``reference`` (``reference.KeyPoseReference``, which ``bar-deploy`` and ``bar-deploy eval`` give),
the source also keeps the song's joint-space reference: the key-pose prior's command for each tick's
``target_keys``, through the policy's action filter, one filter step per POLICY tick from ``begin`` on
(before it: the filter's start). ``target_q`` returns it, so the runtime measures chatter on ``q_cmd``
minus it, as the tracker's on ``q_cmd`` minus its clip (docs/piano.md, "Chatter against the key-pose
reference"), and the log records it as ``ref_q`` (``bar-deploy plot`` draws it). Without one, ``target_q``
is None: chatter of ``q_cmd`` itself.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import CommandSource
from bar_policy.tasks.piano.bank import PlaybackConfig, song_bank
from bar_policy.tasks.piano.key_input import KeySource, SimKeys
from bar_policy.tasks.piano.keyboard import KeyboardConfig, black_keys
from bar_policy.tasks.piano.metrics import song_window
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.songs import Song, check_table_size
from bar_policy.tasks.piano.tally import KeyTally
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

if TYPE_CHECKING:
    from bar_policy.robot.scene import SceneEdit
    from bar_policy.tasks.piano.arrange import Arrangement
    from bar_policy.tasks.piano.reference import KeyPoseReference

__all__ = ["END_HOLD_S", "EPISODE_STEPS", "SongCommands", "policy_playback", "sim_keys"]

log = logging.getLogger(__name__)

EPISODE_STEPS = 500
"""The env's episode, control steps (``PianoEnvConfig.episode_length_s`` 10 s at 50 Hz): progress's scale."""
END_HOLD_S = 0.5
"""The run goes on this long after the song's last note ends, s (the last key is released)."""


def policy_playback(policy: Any) -> PlaybackConfig:
    """How ``policy`` plays songs: the env's count-in and the goal keys' lead it trained with.

    The lead is its file's ``bar.song_lead_steps``: 0 for a file without the key, whose training read frame
    0 as the step's goal.
    """
    return PlaybackConfig(lead_steps=int(getattr(policy.metadata, "song_lead_steps", 0)))


class SongCommands(CommandSource):
    """A song's goal keys and progress, and a key source's keys down (see the module docstring)."""

    task = "piano"
    names = ("target_keys", "progress", "key_pressed")
    hand_load = "tare"
    """The hand-load fit runs during the count-in's still hands (``still_s``) and is kept for the song: a
    key's reaction at the fingertip reads as a lighter hand, and fitted during play it undid the presses
    (docs/robustness.md, "Hand-load compensation")."""
    load_inertia = True
    """The tare's masses' inertia is fed forward from a reference arm playing the same keys
    (``deploy.load_inertia``; docs/robustness.md, "The load's inertia")."""

    def __init__(
        self,
        song: Song,
        keyboard: KeyboardConfig,
        dt: float,
        keys: KeySource | None,
        playback: PlaybackConfig | None = None,
        reference: KeyPoseReference | None = None,
        truth: KeySource | None = None,
        arrangement: Arrangement | None = None,
    ) -> None:
        """Play ``song`` on ``keyboard`` at control period ``dt`` s, reading keys from ``keys``.

        ``keys`` None: the simulated keys of the target the runtime attaches (``attach``; the sim target
        in the keyboard's scene). ``playback``: the count-in and the goal keys' lead (default
        ``PlaybackConfig()``: the env's count-in, no lead; a policy's own: ``policy_playback``).
        ``reference``: the key-pose reference ``target_q`` returns (None: no reference; module docstring).
        ``truth``: the keys a tick is scored against (``scored_keys``), read just before ``keys`` so both
        see one state; None: ``keys`` itself (the simulated keys, where they feed the policy).
        ``arrangement``: what the loader changed to make ``song`` playable (``arrange.Arrangement``: tempo,
        hands, every note shortened or lengthened), in ``metadata`` (the run's log); None: as written.
        Raises ``ValueError`` for a keyboard of another size than the layout's.
        """
        if keyboard.n_keys != PIANO_KEYS:
            raise ValueError(f"the piano layout has {PIANO_KEYS} keys; the keyboard has {keyboard.n_keys}")
        self.song = song
        """The song as given (its file's times); ``down`` holds it as played, after the count-in."""
        self.arrangement = arrangement
        """What the loader changed to play the song (None: played as written)."""
        self.keyboard = keyboard
        self.dt = dt
        self.playback = PlaybackConfig() if playback is None else playback
        # Room for the song after any count-in: the bank plays it (count-in, rounding) and gives its length.
        room = math.ceil((song.duration_s + self.playback.count_in_s) / dt) + 1
        rows = room + self.playback.lead_steps + TARGET_FRAMES
        check_table_size(f"song {song.name!r}", rows, keyboard.n_keys)  # before allocating
        bank = song_bank([song], keyboard, dt, room, TARGET_FRAMES - 1, self.playback)
        self.song_steps = int(bank.steps[0])
        """The song's length as played, control steps: its last note's end, count-in included."""
        self.lead = self.playback.lead_steps
        """Control steps ``target_keys`` read ahead of the scored step (``PlaybackConfig.lead_steps``)."""
        self.down = bank.down[0, : self.song_steps + self.lead + TARGET_FRAMES]
        """Goal keys, 0/1 float32, shape (song steps + lead + TARGET_FRAMES, n_keys)."""
        self.window = song_window(self.down)
        """The scored steps ``[first, stop)``: the first note's start to the last note's end, as played."""
        self.tally = KeyTally(black_keys(keyboard), self.window)
        """The scored ticks (``after_policy_tick``) and their figures."""
        self.scale = max(EPISODE_STEPS, self.song_steps)
        self.keys = keys
        self._t0: float | None = None
        self._step = 0
        self._pressed = np.zeros(PIANO_KEYS, bool)
        self.truth = truth
        self._true = self._pressed
        self.reference = reference
        self._ref_state = None if reference is None else reference.start

    # -- the robot's side --------------------------------------------------------------------------
    def attach(self, target: Any) -> None:
        """With no key source given: the simulated keys of the target's scene.

        The sim target's, or the real target's in-process bus emulator's (each in the keyboard's scene).
        """
        if self.keys is None:
            self.keys = sim_keys(target, self.keyboard)

    def observe(self, q: np.ndarray, dq: np.ndarray) -> None:
        """Hand the measured q to a key source that estimates from it (``keys.KinematicKeys``)."""
        if hasattr(self.keys, "observe"):
            self.keys.observe(q)

    def begin(self, t: float) -> None:
        """The song's step 0 is POLICY's first tick; the reference's filter starts (as the runtime's)."""
        self._t0 = t
        if self.reference is not None:
            self._ref_state = self.reference.start

    @property
    def reference_scene(self) -> SceneEdit:
        """The keyboard's scene (``scene.keyboard_scene``): the reference arm plays its keys."""
        return keyboard_scene(self.keyboard)

    @property
    def still_s(self) -> float:
        """Time from POLICY's first tick before a goal key enters ``target_keys``, s.

        The count-in less the look-ahead (lead + ``TARGET_FRAMES`` - 1 steps), while the policy holds the
        held pose (a song of no note: all of it).
        """
        keyed = np.flatnonzero(self.down.any(axis=1))
        if keyed.size == 0:
            return self.song_steps * self.dt
        return max(int(keyed[0]) - self.lead - TARGET_FRAMES + 1, 0) * self.dt

    # -- each tick ---------------------------------------------------------------------------------
    def step_at(self, t: float) -> int:
        """Control steps since POLICY began (0 before it)."""
        return 0 if self._t0 is None else max(round((t - self._t0) / self.dt), 0)

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """The three piano terms at run time ``t`` (float32 arrays of the layout's sizes)."""
        s = min(self.step_at(t), self.song_steps)
        self._step = s
        assert self.keys is not None, "attach() gives the sim target's keys before the first tick"
        if self.truth is not None:  # the same state as the source's (no physics step between)
            self._true = np.asarray(self.truth.read(t), bool)
        self._pressed = np.asarray(self.keys.read(t), bool)
        if self.truth is None:
            self._true = self._pressed
        target = self.down[s + self.lead : s + self.lead + TARGET_FRAMES].reshape(-1).astype(np.float32)
        if self.reference is not None and self._t0 is not None:  # one filter step per POLICY tick
            self._ref_state = self.reference.filtered(self._ref_state, target, self._pressed)
        return {
            "target_keys": target,
            "progress": np.array([s / self.scale], np.float32),
            "key_pressed": self._pressed.astype(np.float32),
        }

    def goal_now(self) -> np.ndarray:
        """The goal keys of the last call's step, bool (n_keys,)."""
        return self.down[self._step] > 0.5

    def scored_keys(self) -> np.ndarray:
        """The keys down at the last call by ``truth`` (without one: ``key_pressed``'s), bool (n_keys,)."""
        return self._true.copy()

    def in_song(self) -> bool:
        """True when the last call's step lies in the song's window (a tick that is scored)."""
        return self.tally.in_window(self._step)

    def after_policy_tick(self) -> None:
        """Score the last call's tick (it ended in POLICY) if its step lies in the song's window."""
        self.tally.add(self._step, self._true, self.goal_now())

    def summary_lines(self) -> list[str]:
        """The song's precision, recall, F1 and per-colour recall over its window (``KeyTally.lines``)."""
        return self.tally.lines(self.song.name, self.dt)

    def target_q(self) -> np.ndarray | None:
        """The key-pose reference of the last call's tick, rad (canonical order); None without one."""
        if self.reference is None:
            return None
        return self.reference.q(self._ref_state)

    def finished(self, t: float) -> str | None:
        """``END_HOLD_S`` after the song's last note."""
        if self._t0 is not None and t - self._t0 >= self.song_steps * self.dt + END_HOLD_S - 1e-9:
            return f"song {self.song.name!r} finished"
        return None

    # -- logging -----------------------------------------------------------------------------------
    @property
    def log_fields(self) -> dict[str, tuple[tuple[int, ...], type]]:
        """The song step, its goal keys and the keys down (the piano roll); ``ref_q`` with a reference."""
        fields: dict[str, tuple[tuple[int, ...], type]] = {
            "song_step": ((), np.int64),
            "goal_keys": ((PIANO_KEYS,), np.bool_),
            "keys_down": ((PIANO_KEYS,), np.bool_),
        }
        if self.reference is not None:
            fields["ref_q"] = ((len(self.reference.default_joint_pos),), np.float64)
        return fields

    def record(self) -> dict[str, Any]:
        """The last call's step, goal keys and keys down, and its reference (``target_q``) as ``ref_q``."""
        rec: dict[str, Any] = {
            "song_step": self._step,
            "goal_keys": self.goal_now(),
            "keys_down": self._pressed.copy(),
        }
        if self.reference is not None:
            rec["ref_q"] = self.target_q()
        return rec

    def metadata(self) -> dict[str, Any]:
        """The song, its length and the key source."""
        keys = "sim (attached)" if self.keys is None else _describe(self.keys)
        return {
            **super().metadata(),
            "song": self.song.name,
            "song_steps": self.song_steps,
            "song_window_steps": list(self.window),
            "count_in_s": self.playback.count_in_s,
            "song_lead_steps": self.lead,
            "keys": keys,
            "reference": None if self.reference is None else self.reference.prior.label,
            "arrangement": None if self.arrangement is None else self.arrangement.to_dict(),
        }

    def describe(self) -> str:
        """One line for logs."""
        keys = "the sim's keys" if self.keys is None else _describe(self.keys)
        length, c = self.song_steps * self.dt, self.playback.count_in_s
        notes = len(self.song.notes)
        arranged = "" if self.arrangement is None else f", {self.arrangement.brief()}"
        return (
            f"song {self.song.name!r} ({notes} notes, {length:g} s with a {c:g} s count-in{arranged}), "
            f"keys {keys}"
        )

    def close(self) -> None:
        """Close the key source and log what it could not use (``KeySource.counts``)."""
        if self.keys is not None:
            if self.keys.counts:
                log.warning("key source %s: %s", _describe(self.keys), dict(self.keys.counts))
            self.keys.close()
        if self.truth is not None:
            self.truth.close()


def sim_keys(target: Any, keyboard: KeyboardConfig) -> SimKeys:
    """The simulated keys of ``target``'s scene: the sim target's, or its in-process bus emulator's.

    Read from the hinges' ``qpos`` (the keys now, not as the last step's sensors wrote them). Raises
    ``ValueError`` for a target with no simulated keys, naming the key sources to give instead.
    """
    sims = [target, *getattr(target, "companions", ())]
    sim = next((s for s in sims if hasattr(s, "model") and hasattr(s, "data")), None)
    model, data = (sim.model, sim.data) if sim is not None else (None, None)
    if model is None or data is None:
        raise ValueError(
            f"{type(target).__name__} has no simulated keys: give a key source (--keys midi[:PORT] or --keys "
            "kinematic)"
        )
    return SimKeys(model, data, keyboard, via="qpos")


def _describe(keys: KeySource) -> str:
    """``sim``, ``midi``, ``scheduled``, ``kinematic``: the source's kind, for the log."""
    return type(keys).__name__.removesuffix("Keys").lower()
