"""The songs of a training run as one array: what the MJX env indexes per episode.

``song_bank`` turns songs into ``down`` (S, T + L + 1, n_keys) of 0/1 (key ``k`` down at control step ``t``
of song ``s``, ``songs.goal_keys``'s rounding) with the song's length in steps; the env reads the window
``down[s, t : t + L + 1]`` as ``target_keys`` for ``t = 0..T`` (the state after the last step included).
A song is cut at T steps (its notes starting at or after ``T * dt`` are dropped, counted in ``cut_notes``)
and a shorter one is padded with silence (no key down). numpy only: built once when the env is made.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.tasks.piano.generator import random_song
from bar_policy.tasks.piano.keyboard import KeyboardConfig
from bar_policy.tasks.piano.song_library import library_song
from bar_policy.tasks.piano.songs import Song, goal_keys

__all__ = ["SongBank", "song_bank", "training_songs"]


@dataclass(frozen=True)
class SongBank:
    """Songs as arrays (see the module docstring)."""

    names: tuple[str, ...]
    """Song names, bank order."""
    down: np.ndarray
    """0/1 float32, shape (S, T + L + 1, n_keys): key down at each control step (silence from step T)."""
    hands: np.ndarray
    """0/1 uint8, shape (S, 2, T + L + 1, n_keys): ``down`` split by the hand that plays each note (left,
    right; the songs' hands resolved by ``songs.playable``), for the fingertip reward."""
    steps: np.ndarray
    """int32, shape (S,): each song's length in control steps, at most T (its last note's end)."""
    cut_notes: int
    """Notes dropped because they start at or after step T (counted, never silently)."""


def song_bank(
    songs: Sequence[Song], keyboard: KeyboardConfig, dt: float, steps: int, lookahead: int
) -> SongBank:
    """The bank of ``songs`` for episodes of ``steps`` control steps of ``dt`` s and ``lookahead`` frames.

    Raises ``ValueError`` for an empty list (the env needs a song to play).
    """
    if not songs:
        raise ValueError("a song bank needs at least one song")
    rows = steps + lookahead + 1
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
    keyboard: KeyboardConfig, count: int, duration_s: float, tempo_bpm: tuple[float, float], seed: int,
    library: Sequence[str] = (),
) -> list[Song]:  # fmt: skip
    """``library`` songs (by name) then ``count`` random playable songs, tempos ~ U(``tempo_bpm``) bpm."""
    rng = np.random.default_rng(seed)
    songs = [library_song(name) for name in library]
    for i in range(count):
        tempo = float(rng.uniform(*tempo_bpm))
        songs.append(random_song(rng, keyboard, duration_s, tempo, name=f"random-{seed}-{i:04d}"))
    return songs
