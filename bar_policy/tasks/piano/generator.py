"""Random playable songs for training, and the articulation that makes written melodies playable.

``random_song`` writes, for each hand independently, one note per beat at ``tempo_bpm`` (a note lasts one
beat, or two with probability ``long_probability``; a beat is silent with probability
``rest_probability``), on keys drawn uniformly from the hand's range (``HAND_RANGES``: left C2..B3, right
C4..C6, so the hands never cross and both stay inside their reach) among those within ``max_interval``
semitones (7, a fifth) of the hand's previous key that the fingertip can get to in time. Each note is then
shortened (``articulate``) so that the hand leaves the key ``required_gap`` before its next note.
Tempos from 30 to ``max_tempo_bpm`` (300 bpm with the default limits: 0.15 s note + 0.05 s gap) are
accepted; training draws from ``TRAIN_TEMPO_BPM`` (60..120 bpm). One key per hand at a time, the two hands
at once. ``songs.playable`` accepts every song made here (tests/tasks/test_piano_songs.py). numpy only.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from bar_policy.tasks.piano.keyboard import KeyboardConfig, default_config
from bar_policy.tasks.piano.songs import Note, Song, TempoLimits, required_gap

__all__ = ["HAND_RANGES", "TRAIN_TEMPO_BPM", "articulate", "max_tempo_bpm", "random_song"]

HAND_RANGES: dict[str, tuple[int, int]] = {"left": (36, 59), "right": (60, 84)}
"""Keys each hand plays in random songs, MIDI (left C2..B3, right C4..C6)."""
TRAIN_TEMPO_BPM: tuple[float, float] = (60.0, 120.0)
"""Tempo range training draws from, beats per minute (one note per beat and hand)."""


def articulate(
    notes: tuple[Note, ...], config: KeyboardConfig | None = None, limits: TempoLimits | None = None
) -> tuple[Note, ...]:
    """Shorten each note so its hand can reach its next note in time (``required_gap`` before it starts).

    Notes of each hand (``left`` / ``right``; ``either`` counts as a hand of its own) are taken in start
    order; a note keeps its end when that leaves the gap already. Returns the notes in the same order. The
    result may still be refused by ``songs.playable`` (a note shortened below ``min_note_s``).
    """
    out = list(notes)
    for hand in {n.hand for n in notes}:
        idx = sorted((i for i, n in enumerate(notes) if n.hand == hand), key=lambda i: notes[i].start_s)
        for a, b in itertools.pairwise(idx):
            latest = notes[b].start_s - required_gap(notes[a].key, notes[b].key, config, limits)
            if out[a].end_s > latest:
                out[a] = replace(out[a], end_s=latest)
    return tuple(out)


def max_tempo_bpm(limits: TempoLimits | None = None) -> float:
    """Fastest tempo ``random_song`` accepts: a beat holds the shortest note and the shortest gap, bpm."""
    lim = TempoLimits() if limits is None else limits
    return 60.0 / (lim.min_note_s + lim.min_gap_s)


def random_song(
    rng: np.random.Generator,
    keyboard: KeyboardConfig | None = None,
    duration_s: float = 10.0,
    tempo_bpm: float = 90.0,
    limits: TempoLimits | None = None,
    rest_probability: float = 0.2,
    long_probability: float = 0.2,
    max_interval: int = 7,
    name: str = "random",
) -> Song:
    """A random playable two-hand song of about ``duration_s`` s at ``tempo_bpm`` (see the module).

    Every note ends by ``duration_s``. ``ValueError`` for a tempo outside 30..``max_tempo_bpm(limits)``.
    """
    cfg = default_config() if keyboard is None else keyboard
    lim = TempoLimits() if limits is None else limits
    if not 30.0 <= tempo_bpm <= max_tempo_bpm(lim):
        raise ValueError(f"tempo_bpm = {tempo_bpm} is outside 30..{max_tempo_bpm(lim):.0f} bpm")
    beat = 60.0 / tempo_bpm
    notes: list[Note] = []
    for hand, (lo, hi) in HAND_RANGES.items():
        keys = np.arange(max(lo, cfg.lowest), min(hi, cfg.highest) + 1)
        t, prev = 0.0, None
        while True:
            if rng.random() < rest_probability:
                t += beat
                continue
            length = beat * (2 if rng.random() < long_probability else 1)
            if t + length > duration_s + 1e-9:
                break
            if prev is None:
                key = int(rng.choice(keys))
            else:  # keys the fingertip reaches in time, leaving the previous note its shortest length
                room = t - prev.start_s - lim.min_note_s
                near = keys[np.abs(keys - prev.key) <= max_interval]
                ok = [int(k) for k in near if required_gap(prev.key, int(k), cfg, lim) <= room + 1e-9]
                key = int(rng.choice(ok))  # never empty: the same key needs only min_gap_s <= room
            prev = Note(key, t, t + length, hand)
            notes.append(prev)
            t += length
    return Song(name, articulate(tuple(notes), cfg, lim))
