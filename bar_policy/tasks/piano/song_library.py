"""The songs made here: scales, arpeggios, two-hand exercises and public-domain melodies, note by note.

Each part is written as ``NAME[:beats]`` tokens (``r`` a rest; one beat if no length), at the song's tempo,
for one hand; ``articulate`` then ends every note just early enough for the hand to reach its next key
(``songs.required_gap``). Every song is checked by ``songs.playable`` (tests/tasks/test_piano_songs.py).
Melodies: "Ode to Joy" (Beethoven, Symphony No. 9, 1824), "Twinkle, Twinkle, Little Star", "Mary Had a
Little Lamb", "Frere Jacques" and "Au clair de la lune" (traditional): all public domain, written out here
from the well-known tunes in C major. "London Bridge Is Falling Down" (traditional English nursery rhyme,
printed since the 18th century: public domain), written out here from the well-known tune transposed to
F major, its B-flats as A#4 (the note names have sharps only).
Black keys (2026-11-27: no training song had one): the D major and E major scales, the B-flat and E-flat
major arpeggios and London Bridge.

``TRAIN`` songs are for training; ``HELDOUT`` songs are never trained on (evaluation only); ``RETIRED``
songs are no longer trained on but stay defined for the files that were. numpy only.
"""

from __future__ import annotations

from functools import cache

from bar_policy.tasks.piano.generator import articulate
from bar_policy.tasks.piano.keyboard import note_number
from bar_policy.tasks.piano.songs import Note, Song

__all__ = ["HELDOUT", "RETIRED", "SONG_NAMES", "TRAIN", "library_bpm", "library_song", "part"]


def part(hand: str, text: str, bpm: float) -> list[Note]:
    """One hand's notes from ``NAME[:beats]`` tokens at ``bpm`` (``r`` a rest), each spanning its beats.

    Not articulated. The songs of ``heldout`` are written the same way.
    """
    beat, t, out = 60.0 / bpm, 0.0, []
    for token in text.split():
        name, _, beats = token.partition(":")
        length = beat * float(beats or 1)
        if name != "r":
            out.append(Note(note_number(name), round(t, 6), round(t + length, 6), hand))
        t += length
    return out


_SCALE_UP = "C{o} D{o} E{o} F{o} G{o} A{o} B{o} C{p}"
_SCALE_DOWN = "B{o} A{o} G{o} F{o} E{o} D{o} C{o}:2"


def _scale(o: int) -> str:
    return f"{_SCALE_UP} {_SCALE_DOWN}".format(o=o, p=o + 1)


def _up_and_down(up: str) -> str:
    """A scale as ``_scale`` plays it from its 8 notes up: up, back down, the last note two beats."""
    notes = up.split()
    return " ".join([*notes, *notes[-2:0:-1], f"{notes[0]}:2"])


_SONGS: dict[str, tuple[float, dict[str, str]]] = {
    # name: (bpm, {hand: tokens})
    "c_major_scale_right": (100, {"right": _scale(4)}),
    "c_major_scale_left": (100, {"left": _scale(3)}),
    "c_major_arpeggio_right": (90, {"right": "C4 E4 G4 C5 G4 E4 C4:2"}),
    "c_major_arpeggio_left": (90, {"left": "C3 E3 G3 C4 G3 E3 C3:2"}),
    # Retired (RETIRED): its left part climbs to C4, which the prior's hand split at middle C gives the
    # right arm together with the right part's C6: a torque-cap fault (docs/piano.md "Count-in"). Kept, as
    # written, for the files trained on it (checkpoints/lite_piano_arms.onnx: its dataset_repo_id names it).
    "c_major_scales_two_hands": (90, {"left": _scale(3), "right": _scale(5)}),
    # Its successor: the left part from C2 to C3, below the split.
    "c_major_scales_two_octaves": (90, {"left": _scale(2), "right": _scale(5)}),
    "twinkle_twinkle": (
        100,
        {
            "right": "C4 C4 G4 G4 A4 A4 G4:2 F4 F4 E4 E4 D4 D4 C4:2",
            "left": "C3:4 F3:2 C3:2 G3:2 C3:2 G3:2 C3:2",
        },
    ),
    "mary_had_a_little_lamb": (
        110,
        {"right": "E4 D4 C4 D4 E4 E4 E4:2 D4 D4 D4:2 E4 G4 G4:2 E4 D4 C4 D4 E4 E4 E4 E4 D4 D4 E4 D4 C4:4"},
    ),
    "au_clair_de_la_lune": (100, {"right": "C4 C4 C4 D4 E4:2 D4:2 C4 E4 D4 D4 C4:4"}),
    # Black keys (the sharps of D and E major, B-flat and E-flat as A# and D#); each hand on its own side
    # of middle C (the prior's hand split).
    "d_major_scale_right": (100, {"right": _up_and_down("D4 E4 F#4 G4 A4 B4 C#5 D5")}),
    "e_major_scale_left": (100, {"left": _up_and_down("E2 F#2 G#2 A2 B2 C#3 D#3 E3")}),
    # B-flat major's arpeggio, then E-flat major's, in octaves: the left from A#2 (B-flat 2), the right
    # from A#4.
    "b_flat_e_flat_arpeggios_two_hands": (
        90,
        {
            "left": "A#2 D3 F3 A#3 F3 D3 A#2:2 D#3 G3 A#3 G3 D#3:2",
            "right": "A#4 D5 F5 A#5 F5 D5 A#4:2 D#5 G5 A#5 G5 D#5:2",
        },
    ),
    "london_bridge": (
        100,
        {
            "right": "C5:1.5 D5:0.5 C5 A#4 A4 A#4 C5:2 G4 A4 A#4:2 A4 A#4 C5:2 "
            "C5:1.5 D5:0.5 C5 A#4 A4 A#4 C5:2 G4:2 C5:2 A4 F4:3"
        },
    ),
    # held out
    "ode_to_joy": (
        100,
        {
            "right": "E4 E4 F4 G4 G4 F4 E4 D4 C4 C4 D4 E4 E4:1.5 D4:0.5 D4:2 "
            "E4 E4 F4 G4 G4 F4 E4 D4 C4 C4 D4 E4 D4:1.5 C4:0.5 C4:2",
            "left": "C3:4 G3:4 C3:4 G3:2 G3:2 C3:4 G3:4 C3:4 G3:2 C3:2",
        },
    ),
    "frere_jacques": (
        90,
        {
            "right": "C4 D4 E4 C4 C4 D4 E4 C4 E4 F4 G4:2 E4 F4 G4:2 "
            "G4:0.5 A4:0.5 G4:0.5 F4:0.5 E4 C4 G4:0.5 A4:0.5 G4:0.5 F4:0.5 E4 C4 C4 G3 C4:2 C4 G3 C4:2"
        },
    ),
    "g_major_scales_two_hands": (
        100,
        {"left": "G2 A2 B2 C3 D3 E3 F#3 G3:2", "right": "G4 A4 B4 C5 D5 E5 F#5 G5:2"},
    ),
}

HELDOUT: tuple[str, ...] = ("ode_to_joy", "frere_jacques", "g_major_scales_two_hands")
"""Songs kept out of training."""
RETIRED: tuple[str, ...] = ("c_major_scales_two_hands",)
"""Songs no longer trained on, kept so that the song sets of files trained on them still resolve."""
TRAIN: tuple[str, ...] = tuple(n for n in _SONGS if n not in HELDOUT and n not in RETIRED)
"""Songs to train on."""
SONG_NAMES: tuple[str, ...] = tuple(_SONGS)
"""Every song of the library."""


def library_bpm(name: str) -> float:
    """The written tempo of the library's song ``name``, bpm; ``ValueError`` listing the names."""
    if name not in _SONGS:
        raise ValueError(f"unknown song {name!r}; songs: {list(_SONGS)}")
    return float(_SONGS[name][0])


@cache
def library_song(name: str) -> Song:
    """The library's song ``name`` (hands given, notes articulated); ``ValueError`` listing the names."""
    if name not in _SONGS:
        raise ValueError(f"unknown song {name!r}; songs: {list(_SONGS)}")
    bpm, parts = _SONGS[name]
    notes = tuple(n for hand, text in parts.items() for n in part(hand, text, bpm))
    return Song(name, articulate(notes))
