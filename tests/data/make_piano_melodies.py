"""Writes tests/data/piano_melodies/*.mid: public-domain melodies as notation software exports them.

Each melody is written from note lists here, at a usual written tempo, as a standard MIDI file (mido, 480
ticks per beat) the way notation software exports a score: legato (each note-off at the next note-on of its
part, no gap), no hands, velocity 80. Parts are ``NAME[:beats]`` tokens (``r`` a rest; one beat if no
length), one part per voice. ``type 0`` files merge the parts into one track (each part on its own
channel); ``type 1`` files give each part its own track, the tempo map in the first. Tempo changes are
``(beat, bpm)`` pairs.

All public domain: "Ode to Joy" (Beethoven, 1824), "Frere Jacques", "Twinkle, Twinkle, Little Star",
"Greensleeves", "Scarborough Fair", "When the Saints Go Marching In" (traditional), "Amazing Grace"
(Newton, 1779; the tune "New Britain", 1829), "Minuet in G" (Petzold, c. 1725), "Fur Elise" (Beethoven,
1810, its opening), the "Swan Lake" theme (Tchaikovsky, 1876), the "Can-can" (Offenbach, 1858). Each is
written out here from the well-known tune, one or two voices, not copied from any edition.

Run ``python tests/data/make_piano_melodies.py`` to rewrite them (the files are committed; the tests read
them). Needs ``mido`` (the ``deploy`` extra).
"""

from __future__ import annotations

from pathlib import Path

import mido

from bar_policy.tasks.piano.keyboard import note_number

OUT = Path(__file__).parent / "piano_melodies"
TPB = 480

# name: (midi type, bpm, tempo changes [(beat, bpm)], parts)
MELODIES: dict[str, tuple[int, float, list[tuple[float, float]], list[str]]] = {
    "ode_to_joy": (
        1,
        120,
        [],
        [
            "E4 E4 F4 G4 G4 F4 E4 D4 C4 C4 D4 E4 E4:1.5 D4:0.5 D4:2 "
            "E4 E4 F4 G4 G4 F4 E4 D4 C4 C4 D4 E4 D4:1.5 C4:0.5 C4:2",
            "C3:4 G2:4 C3:4 G2:2 G2:2 C3:4 G2:4 C3:4 G2:2 C3:2",
        ],
    ),
    "frere_jacques": (
        0,
        110,
        [],
        [
            "F4 G4 A4 F4 F4 G4 A4 F4 A4 A#4 C5:2 A4 A#4 C5:2 "
            "C5:0.5 D5:0.5 C5:0.5 A#4:0.5 A4 F4 C5:0.5 D5:0.5 C5:0.5 A#4:0.5 A4 F4 F4 C4 F4:2 F4 C4 F4:2"
        ],
    ),
    "twinkle_twinkle": (
        1,
        100,
        [],
        [
            "C4 C4 G4 G4 A4 A4 G4:2 F4 F4 E4 E4 D4 D4 C4:2 "
            "G4 G4 F4 F4 E4 E4 D4:2 G4 G4 F4 F4 E4 E4 D4:2 "
            "C4 C4 G4 G4 A4 A4 G4:2 F4 F4 E4 E4 D4 D4 C4:2",
            "C3:4 F3:2 C3:2 G2:2 C3:2 G2:2 C3:2 C3:2 G2:2 C3:2 G2:2 C3:2 G2:2 C3:2 G2:2 "
            "C3:4 F3:2 C3:2 G2:2 C3:2 G2:2 C3:2",
        ],
    ),
    "greensleeves": (
        0,
        120,
        [],
        [
            "E4 G4:2 A4 B4:1.5 C5:0.5 B4 A4:2 F#4 D4:1.5 E4:0.5 F#4 G4:2 E4 E4:1.5 D#4:0.5 E4 F#4:2 D#4 "
            "B3:2 E4 G4:2 A4 B4:1.5 C5:0.5 B4 A4:2 F#4 D4:1.5 E4:0.5 F#4 G4:1.5 F#4:0.5 E4 "
            "D#4:1.5 C#4:0.5 D#4 E4:3"
        ],
    ),
    "amazing_grace": (
        1,
        90,
        [(37.0, 80), (43.0, 66)],  # a ritardando over the last line
        [
            "D4 G4:2 B4:0.5 G4:0.5 B4:2 A4 G4:2 E4 D4:2 D4 G4:2 B4:0.5 G4:0.5 B4:2 A4 D5:3 r:2 B4 "
            "D5:1.5 B4:0.5 D5:0.5 B4:0.5 G4:2 D4 E4:1.5 G4:0.5 G4:0.5 E4:0.5 D4:2 D4 G4:2 B4:0.5 G4:0.5 "
            "B4:2 A4 G4:3",
            "r G2:3 G2:3 C3:3 G2:3 G2:3 G2:3 D3:3 D3:3 G2:3 G2:3 C3:3 G2:3 G2:3 D3:3 G2:3",
        ],
    ),
    "scarborough_fair": (
        0,
        100,
        [],
        [
            "E4:2 E4 B4:2 B4 F#4:1.5 G4:0.5 F#4 E4:3 r B4 C#5 D5:2 C#5 B4 C#5 A4 B4:3 r:2 E5 E5:2 E5 "
            "D5:2 B4 B4 A4 G4 F#4 D4:2 E4 B4:2 A4 G4:2 F#4 E4 D4 E4:3"
        ],
    ),
    "minuet_in_g": (
        1,
        120,
        [],
        [
            "D5 G4:0.5 A4:0.5 B4:0.5 C5:0.5 D5 G4 G4 E5 C5:0.5 D5:0.5 E5:0.5 F#5:0.5 G5 G4 G4 "
            "C5 D5:0.5 C5:0.5 B4:0.5 A4:0.5 B4 C5:0.5 B4:0.5 A4:0.5 G4:0.5 F#4 G4:0.5 A4:0.5 B4:0.5 "
            "G4:0.5 A4:3",
            "G3:2 A3 B3:3 C3:3 B2:3 A2:3 G2:3 D3:3 D3:3",
        ],
    ),
    "fur_elise": (
        0,
        140,  # the eighth as the beat: the sixteenths are 0.214 s
        [],
        [
            "E5:.5 D#5:.5 E5:.5 D#5:.5 E5:.5 B4:.5 D5:.5 C5:.5 A4:1 r:.5 C4:.5 E4:.5 A4:.5 B4:1 r:.5 "
            "E4:.5 G#4:.5 B4:.5 C5:1 r:.5 E4:.5 E5:.5 D#5:.5 E5:.5 D#5:.5 E5:.5 B4:.5 D5:.5 C5:.5 A4:1 "
            "r:.5 C4:.5 E4:.5 A4:.5 B4:1 r:.5 E4:.5 C5:.5 B4:.5 A4:2"
        ],
    ),
    "swan_lake": (
        0,
        76,
        [],
        [
            "F#4:4 B3:0.5 C#4:0.5 D4:0.5 E4:0.5 F#4:1.5 D4:0.5 F#4:1.5 D4:0.5 "
            "F#4:1.5 B3:0.5 D4:0.5 B3:0.5 G3:0.5 D4:0.5 B3:4 "
            "F#4:4 B3:0.5 C#4:0.5 D4:0.5 E4:0.5 F#4:1.5 D4:0.5 F#4:1.5 D4:0.5 "
            "F#4:1.5 B3:0.5 D4:0.5 B3:0.5 G3:0.5 D4:0.5 B3:4"
        ],
    ),
    "can_can": (
        1,
        140,
        [],
        [
            "C4:2 D4:0.5 F4:0.5 E4:0.5 D4:0.5 G4 G4 G4:0.5 A4:0.5 E4:0.5 F4:0.5 "
            "D4 D4 D4:0.5 F4:0.5 E4:0.5 D4:0.5 C4:0.5 C5:0.5 B4:0.5 A4:0.5 G4:0.5 F4:0.5 E4:0.5 D4:0.5 "
            "C4:2 D4:0.5 F4:0.5 E4:0.5 D4:0.5 G4 G4 G4:0.5 A4:0.5 E4:0.5 F4:0.5 "
            "D4 G4:0.5 A4:0.5 G4:0.5 F4:0.5 E4:0.5 D4:0.5 C4:2",
            "C3 G2 C3 G2 C3 G2 C3 G2 G2 D3 G2 D3 C3 G2 C3 G2 C3 G2 C3 G2 C3 G2 C3 G2 G2 D3 C3:2",
        ],
    ),
    "when_the_saints": (
        1,
        120,
        [],
        [
            "r C4 E4 F4 G4:4 r C4 E4 F4 G4:4 r C4 E4 F4 G4:2 E4:2 C4:2 E4:2 D4:4 "
            "r E4 E4 D4 C4:3 C4 E4:2 G4:2 G4 F4:3 r E4 F4 G4 E4:2 C4:2 D4:2 D4:2 C4:4",
            "C3:4 C3:4 C3:4 C3:4 C3:4 C3:4 C3:4 G2:4 G2:4 C3:4 C3:4 F2:4 C3:4 C3:4 G2:4 C3:4",
        ],
    ),
}


def _events(part: str, channel: int) -> list[tuple[int, mido.Message]]:
    """(absolute tick, message) of one part, legato: each note-off at the next note-on."""
    out, tick = [], 0
    for token in part.split():
        name, _, beats = token.partition(":")
        length = round(TPB * float(beats or 1))
        if name != "r":
            key = note_number(name)
            out.append((tick, mido.Message("note_on", note=key, velocity=80, channel=channel)))
            out.append((tick + length, mido.Message("note_off", note=key, velocity=0, channel=channel)))
        tick += length
    return out


def _track(events: list[tuple[int, mido.Message | mido.MetaMessage]]) -> mido.MidiTrack:
    """A track from absolute-tick events: at one tick, note-offs before note-ons (as exporters write)."""
    order = {"set_tempo": 0, "note_off": 1, "note_on": 2}
    track, now = mido.MidiTrack(), 0
    for tick, msg in sorted(events, key=lambda e: (e[0], order.get(e[1].type, 3))):
        track.append(msg.copy(time=tick - now))
        now = tick
    return track


def write(name: str) -> Path:
    """Write the melody ``name`` under ``OUT``; returns its path."""
    midi_type, bpm, changes, parts = MELODIES[name]
    tempo = [(0, mido.MetaMessage("set_tempo", tempo=mido.bpm2tempo(bpm)))]
    tempo += [(round(TPB * b), mido.MetaMessage("set_tempo", tempo=mido.bpm2tempo(v))) for b, v in changes]
    voices = [_events(p, ch) for ch, p in enumerate(parts)]
    mid = mido.MidiFile(type=midi_type, ticks_per_beat=TPB)
    if midi_type == 0:
        mid.tracks.append(_track(tempo + [e for v in voices for e in v]))
    else:
        mid.tracks.append(_track(tempo + voices[0]))
        mid.tracks.extend(_track(v) for v in voices[1:])
    path = OUT / f"{name}.mid"
    mid.save(path)
    return path


if __name__ == "__main__":
    OUT.mkdir(exist_ok=True)
    for melody in MELODIES:
        print(write(melody))
