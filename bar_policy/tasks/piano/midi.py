"""Songs from standard MIDI files, read with ``mido`` (a maintained MIDI library, not a parser of ours).

Type 0 (one track) and type 1 (several tracks played together) files. Every ``note_on`` (velocity > 0)
starts a note and the next ``note_off`` or ``note_on`` with velocity 0 of the same channel and key ends it;
a key struck again while held ends the held note there (a legato export may put the next note-on before
the note-off of the same tick). Times come from ``mido``'s merged playback, which turns ticks into seconds
through the file's ``set_tempo`` messages wherever they are (500000 us per beat, 120 bpm, before the
first), so tempo changes are honoured. Channel, velocity and every other message are ignored.

The written notes (``read_midi``) have no hands and, from notation software, no gaps (each note-off at the
next note-on). ``arrange_midi`` / ``load_midi`` make them playable (``arrange.arrange``): hands by what
each arm reaches in time, the tempo (``--tempo``: a factor or ``auto``, the fastest the arms play, capped
at the written one), every note ended ``required_gap`` before its hand's next; a song no arrangement plays
is refused with the note named. ``mido`` comes with the ``deploy`` extra; it is imported when a file is
read.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

from bar_policy.signals import check_stop
from bar_policy.tasks.piano.arrange import Arrangement, arrange
from bar_policy.tasks.piano.keyboard import HAND_SPLIT_MIDI, KeyboardConfig, note_name
from bar_policy.tasks.piano.songs import (
    Note,
    Song,
    SongError,
    TempoLimits,
    check_song_file,
    check_song_size,
)

__all__ = ["WrittenMidi", "arrange_midi", "load_midi", "midi_notes", "read_midi"]


class _StoppableBytes(io.BytesIO):
    """A MIDI file's bytes for ``mido``, checking for a stop request (``check_stop``) as it is read.

    ``mido`` parses a byte at a time in Python (about 0.1 MB/s on the project's loaded 2-core CPU); every
    ``STOP_CHECK_READS`` reads this checks for a stop request.
    """

    STOP_CHECK_READS = 4096

    def __init__(self, data: bytes, what: str) -> None:
        super().__init__(data)
        self._what = what
        self._reads = 0

    def read(self, size: int | None = -1) -> bytes:
        """``BytesIO.read``, checking for a stop request every ``STOP_CHECK_READS`` calls."""
        self._reads += 1
        if self._reads % self.STOP_CHECK_READS == 0:
            check_stop(self._what)
        return super().read(size)


@dataclass(frozen=True)
class WrittenMidi:
    """A MIDI file's notes as written (hands ``either``, times in s at the file's tempo map)."""

    notes: tuple[Note, ...]
    """The notes, in file order of their ends."""
    bpm: float
    """The tempo at the file's start, bpm (its first ``set_tempo`` at tick 0, else 120)."""
    tempo_changes: int
    """``set_tempo`` messages after the start (mido's merged playback applies them to every track)."""
    midi_type: int
    """0 (one track) or 1 (several, played together)."""
    tracks: int
    """Number of tracks."""


def read_midi(path: str | Path) -> WrittenMidi:
    """A standard MIDI file's notes as written (module docstring); not checked against the arms.

    ``SongError`` for a file ``mido`` cannot read, a type 2 file (independent songs, not one), a key never
    released, or a file or song past ``songs``' limits (file size, note count, length: read no further than
    the first).
    """
    import mido

    path = Path(path)
    check_song_file(path)
    try:
        midi = mido.MidiFile(path, file=_StoppableBytes(path.read_bytes(), f"reading {path}"))
    except (OSError, EOFError, ValueError, KeyError, IndexError) as e:
        raise SongError(f"{path}: not a readable MIDI file ({e})") from None
    if midi.type not in (0, 1):
        raise SongError(
            f"{path}: a type {midi.type} MIDI file (independent sequences); give a type 0 or 1 file"
        )
    held: dict[tuple[int, int], float] = {}
    restruck: dict[tuple[int, int], float] = {}  # key -> when it was struck again while held
    notes: list[Note] = []
    bpm, changes, now = 120.0, 0, 0.0
    for k, msg in enumerate(midi):  # merged tracks; msg.time is the delta in seconds
        if k % 256 == 0:
            check_stop(f"reading {path}")  # a stop request acts within 256 messages
        now += msg.time
        if msg.type == "set_tempo":
            if now == 0.0 and not notes and not held:
                bpm = mido.tempo2bpm(msg.tempo)
            else:
                changes += 1
            continue
        if msg.type not in ("note_on", "note_off"):
            continue
        key = (msg.channel, msg.note)
        press = msg.type == "note_on" and msg.velocity > 0
        if not press and key in held and restruck.get(key) == now == held[key]:
            del restruck[key]  # the release of the note the strike at this tick ended, not of the new one
            continue
        if key in held and (not press or now > held[key]):
            start = held.pop(key)  # a release, or a key struck again while held: the held note ends here
            if press:
                restruck[key] = now
            if now > start:
                notes.append(Note(msg.note, start, now))
                check_song_size(str(path), len(notes), now)  # while reading: stop at the first past a limit
        if press:
            held[key] = now
    if held:
        (channel, key), start = next(iter(held.items()))
        raise SongError(
            f"{path}: {note_name(key)} on channel {channel} pressed at {start:.3f} s never released"
        )
    return WrittenMidi(tuple(notes), bpm, changes, midi.type, len(midi.tracks))


def midi_notes(path: str | Path) -> list[Note]:
    """The notes of a standard MIDI file as written, hands ``either``, times in s (``read_midi``)."""
    return list(read_midi(path).notes)


def arrange_midi(
    path: str | Path,
    tempo: float | str | None = None,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
    name: str | None = None,
) -> Arrangement:
    """A standard MIDI file arranged for the arms at ``tempo``, every change listed (``arrange.arrange``).

    ``name`` defaults to the file's stem; the written bpm is the file's at its start.
    """
    path = Path(path)
    written = read_midi(path)
    song = Song(path.stem if name is None else name, written.notes)
    return arrange(song, tempo, config, limits, split, written.bpm)


def load_midi(
    path: str | Path,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
    name: str | None = None,
    tempo: float | str | None = None,
) -> Song:
    """A standard MIDI file as a playable song (``arrange_midi``'s song)."""
    return arrange_midi(path, tempo, config, limits, split, name).song
