"""Songs as played: the count-in, and the songs as one array, what the MJX env and ``SongCommands`` index.

``song_bank`` plays each song with the count-in of ``PlaybackConfig`` (``songs.count_in``: the whole song
delayed so that its first note starts no earlier than ``count_in_s``; a song file's times stay as written,
the count-in is playback) and turns it into ``down`` (S, T + D + L + 1, n_keys) of 0/1 (key ``k`` down at
control step ``t`` of song ``s``, ``songs.goal_keys``'s rounding) with the song's length in steps; the env
reads the window ``down[s, t + D : t + D + L + 1]`` as ``target_keys`` for ``t = 0..T`` (the state after
the last step included; ``D`` the playback's ``lead_steps``) and row ``t`` as the step's goal, and the
deploy side's ``SongCommands`` reads the same rows of a bank of its one song, so training and the robot
play every song with the same count-in and lead. A song is cut at T steps (its notes starting
at or after ``T * dt`` are dropped, counted in ``cut_notes``) and a shorter one is padded with silence (no
key down). numpy only: built once when the env is made.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.tasks.piano.generator import random_song
from bar_policy.tasks.piano.keyboard import KeyboardConfig
from bar_policy.tasks.piano.song_library import library_song
from bar_policy.tasks.piano.songs import Song, check_count_in, count_in, goal_keys

__all__ = ["SONG_LEAD_STEPS", "PlaybackConfig", "SongBank", "random_songs", "song_bank", "training_songs"]


SONG_LEAD_STEPS = 2
"""The env's ``PlaybackConfig.lead_steps``: the key-pose prior alone, sim target, 2-core CPU, scored
against the song's own time: held-out F1 0.906 at 0, 0.947 at 1, 0.951 at 2, 0.927 at 3; 32 random songs
of seed 2026: 0.869, 0.911, 0.929, 0.921 (docs/piano.md, "Song lead")."""


@dataclass(frozen=True, kw_only=True)
class PlaybackConfig:
    """How songs are played, in training (the env's bank) and on the robot (``SongCommands``) alike."""

    count_in_s: float = 0.5
    """Count-in, s: the first note of every song starts no earlier than this after the song's step 0 (the
    episode's start; POLICY's first tick on the robot), the whole song delayed by the difference
    (``songs.count_in``). The goal keys' lookahead (``TARGET_FRAMES - 1`` = 10 steps, 0.2 s) shows the first
    note in the count-in's last 0.2 s, so the hand reaches its first key in the air instead of travelling
    while pressing. Measured with the key-pose prior alone on the held-out songs, sim target
    (docs/piano.md, "Count-in"): without a count-in frere_jacques faults at 0.56 s (its first note at 0 s,
    85 mm from the resting hand); from 0.25 s to 1.5 s no song faults and the pooled F1 is flat (0.84-0.90
    per song). 0.5 s leaves 0.3 s before the first note comes into view and takes 5 % of a 10 s episode."""

    lead_steps: int = 0
    """Control steps the goal-key frames lead the song: at step ``t`` the policy's ``target_keys`` show the
    song's steps ``t + lead_steps .. t + lead_steps + TARGET_FRAMES - 1``, while the score (the reward's
    goal row, the evaluation's) stays at step ``t``. A key goes down some steps after the command that
    presses it (the action filter, the arm, the key's travel), and the song is known ahead, so the player
    reads it ahead by that lag, as a pianist does. 0: frame 0 is the step's own goal. The env trains with
    ``SONG_LEAD_STEPS``; a policy file records its value (``bar.song_lead_steps``) and ``SongCommands``
    plays with the file's (docs/piano.md, "Song lead")."""

    def __post_init__(self) -> None:
        """Refuse a negative or non-finite count-in (``songs.check_count_in``) or a negative lead."""
        check_count_in(self.count_in_s)
        d = self.lead_steps
        if isinstance(d, bool) or not (isinstance(d, int) and d >= 0):
            raise ValueError(f"lead_steps = {self.lead_steps!r} must be an integer >= 0 (control steps)")


@dataclass(frozen=True)
class SongBank:
    """Songs as arrays (see the module docstring)."""

    names: tuple[str, ...]
    """Song names, bank order."""
    down: np.ndarray
    """0/1 float32, shape (S, T + D + L + 1, n_keys): key down at each control step (silence from step T)."""
    hands: np.ndarray
    """0/1 uint8, shape (S, 2, T + D + L + 1, n_keys): ``down`` split by the hand that plays each note (left,
    right; the songs' hands resolved by ``songs.playable``), for the fingertip reward."""
    steps: np.ndarray
    """int32, shape (S,): each song's length in control steps, at most T (its last note's end)."""
    cut_notes: int
    """Notes dropped because they start at or after step T (counted, never silently)."""


def song_bank(
    songs: Sequence[Song],
    keyboard: KeyboardConfig,
    dt: float,
    steps: int,
    lookahead: int,
    playback: PlaybackConfig | None = None,
) -> SongBank:
    """The bank of ``songs`` for episodes of ``steps`` control steps of ``dt`` s and ``lookahead`` frames.

    Each song is played with ``playback``'s count-in (default ``PlaybackConfig()``): its rows, hands and
    length are those of ``songs.count_in(song, playback.count_in_s)``; ``playback.lead_steps`` more rows
    of silence at the end hold the lead's window at the last step. Raises ``ValueError`` for an empty
    list (the env needs a song to play).
    """
    if not songs:
        raise ValueError("a song bank needs at least one song")
    pb = PlaybackConfig() if playback is None else playback
    songs = [count_in(song, pb.count_in_s) for song in songs]
    rows = steps + pb.lead_steps + lookahead + 1
    down = np.zeros((len(songs), rows, keyboard.n_keys), np.float32)
    hands = np.zeros((len(songs), 2, rows, keyboard.n_keys), np.uint8)
    lengths = np.zeros(len(songs), np.int32)
    cut = 0
    for i, song in enumerate(songs):
        kept = tuple(n for n in song.notes if round(n.start_s / dt) < steps)
        cut += len(song.notes) - len(kept)
        if kept:
            down[i] = goal_keys(Song(song.name, kept), dt, rows, 0, keyboard)[:, 0]
            down[i, steps:] = 0.0  # the episode ends at T: nothing is asked after it
            for h, hand in enumerate(("left", "right")):
                mine = tuple(n for n in kept if n.hand == hand)
                if mine:
                    hands[i, h] = goal_keys(Song(song.name, mine), dt, rows, 0, keyboard)[:, 0] > 0.5
            hands[i, :, steps:] = 0
            lengths[i] = min(max(round(n.end_s / dt) for n in kept), steps)
    return SongBank(tuple(s.name for s in songs), down, hands, lengths, cut)


def training_songs(
    keyboard: KeyboardConfig,
    count: int,
    duration_s: float,
    tempo_bpm: tuple[float, float],
    seed: int,
    library: Sequence[str] = (),
) -> list[Song]:
    """``library`` songs (by name) then ``count`` random playable songs, tempos ~ U(``tempo_bpm``) bpm."""
    drawn = random_songs(keyboard, count, duration_s, tempo_bpm, seed)
    return [library_song(name) for name in library] + [song for song, _ in drawn]


def random_songs(
    keyboard: KeyboardConfig, count: int, duration_s: float, tempo_bpm: tuple[float, float], seed: int
) -> list[tuple[Song, float]]:
    """``training_songs``' random songs, each with its tempo in bpm.

    Per song a tempo ~ ``U(tempo_bpm)``, then ``generator.random_song``, both from one ``default_rng(seed)``;
    named ``random-SEED-NNNN``.
    """
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        tempo = float(rng.uniform(*tempo_bpm))
        out.append((random_song(rng, keyboard, duration_s, tempo, name=f"random-{seed}-{i:04d}"), tempo))
    return out
