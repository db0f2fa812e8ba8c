"""The held-out evaluation songs: the library's ``HELDOUT`` and two melodies mostly on black keys.

The library's held-out songs hold 48 black goal key-ticks of 3,193 (1.5 %), so a policy that never presses a
black key still passes on them. The two songs here, written out note by note for evaluation only (never in a
training bank), put black keys at the centre of the held-out set:

- ``amazing_grace_f_sharp``: "Amazing Grace" (the tune "New Britain", American, printed 1829-1835: public
  domain), its first two lines, transposed to F-sharp major; the tune is pentatonic, so the right hand plays
  black keys only (C#4 to C#5), over a left bass of F#2, C#3 and B2.
- ``jingle_bells_e_flat``: the chorus of "Jingle Bells" (James Lord Pierpont, 1857: public domain) in E-flat
  major (its flats as sharps: D#, G#, A#), over a left bass of D#3, G#2 and A#2.

Each part is ``NAME[:beats]`` tokens at the song's tempo for one hand, every hand on its side of middle C
(the key-pose prior's hand split); ``generator.articulate`` ends each note early enough for the hand to
reach its next key. ``songs.playable`` accepts both, and each has at least 20 % black goal key-ticks
(tests/tasks/test_piano_heldout.py).

``random_eval_songs``: the random songs ``bar-deploy eval`` plays after the held-out ones (the gate's
``random`` rows), of the training bank's kind with a seed no bank was trained on. numpy only.
"""

from __future__ import annotations

from functools import cache

from bar_policy.tasks.piano.bank import random_songs
from bar_policy.tasks.piano.generator import TRAIN_TEMPO_BPM, articulate
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.song_library import HELDOUT, library_song, part
from bar_policy.tasks.piano.songs import Song

__all__ = [
    "BLACK_HELDOUT",
    "EVAL_HELDOUT",
    "RANDOM_EVAL_DURATION_S",
    "RANDOM_EVAL_SEED",
    "RANDOM_EVAL_SONGS",
    "heldout_song",
    "random_eval_songs",
]

_BLACK: dict[str, tuple[float, dict[str, str]]] = {
    # name: (bpm, {hand: tokens}); 3/4 after a one-beat pickup.
    "amazing_grace_f_sharp": (
        90,
        {
            "right": "C#4 F#4:2 A#4:0.5 F#4:0.5 A#4:2 G#4 F#4:2 D#4 C#4:2 C#4 "
            "F#4:2 A#4:0.5 F#4:0.5 A#4:2 G#4 C#5:3 C#5:2",
            "left": "r F#2:3 F#2:3 B2:3 F#2:3 F#2:3 F#2:3 C#3:3 C#3:2",
        },
    ),
    # 4/4, the chorus.
    "jingle_bells_e_flat": (
        100,
        {
            "right": "G4 G4 G4:2 G4 G4 G4:2 G4 A#4 D#4:1.5 F4:0.5 G4:4 "
            "G#4 G#4 G#4:1.5 G#4:0.5 G#4 G4 G4 G4:0.5 G4:0.5 G4 F4 F4 G4 F4:2 A#4:2",
            "left": "D#3:4 D#3:4 D#3:4 D#3:4 G#2:4 D#3:4 A#2:4 A#2:4",
        },
    ),
}

BLACK_HELDOUT: tuple[str, ...] = tuple(_BLACK)
"""The held-out songs mostly on black keys (this module's)."""
EVAL_HELDOUT: tuple[str, ...] = (*HELDOUT, *BLACK_HELDOUT)
"""Every held-out song, the order ``bar-deploy eval`` plays them in by default (the ship gate's)."""


RANDOM_EVAL_SONGS = 32
"""Random songs ``bar-deploy eval`` plays after the held-out ones by default (``--random-songs``)."""
RANDOM_EVAL_SEED = 2026
"""Their seed (``--random-seed``): never a training bank's (``PianoEnvConfig.song_seed`` is 0; the files
of docs/piano.md were trained on seed 0's bank)."""
RANDOM_EVAL_DURATION_S = 9.5
"""Each random song ends by this, s: the training bank's (a 10 s episode less the 0.5 s count-in)."""


def random_eval_songs(count: int = RANDOM_EVAL_SONGS, seed: int = RANDOM_EVAL_SEED) -> list[Song]:
    """``count`` random songs of the training bank's kind, drawn as the bank draws them.

    ``bank.random_songs`` on ``compact_config()``, tempos ~ U(``TRAIN_TEMPO_BPM``), ending by
    ``RANDOM_EVAL_DURATION_S``, named ``random-SEED-NNNN``; ``bench/piano_random_songs.py`` draws the same.
    """
    drawn = random_songs(compact_config(), count, RANDOM_EVAL_DURATION_S, TRAIN_TEMPO_BPM, seed)
    return [song for song, _ in drawn]


@cache
def heldout_song(name: str) -> Song:
    """The held-out song ``name`` (the library's or this module's); ``ValueError`` listing the names."""
    if name in HELDOUT:
        return library_song(name)
    if name not in _BLACK:
        raise ValueError(f"unknown held-out song {name!r}; held-out songs: {list(EVAL_HELDOUT)}")
    bpm, parts = _BLACK[name]
    notes = tuple(n for hand, text in parts.items() for n in part(hand, text, bpm))
    return Song(name, articulate(notes))
