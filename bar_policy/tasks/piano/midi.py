"""Songs from standard MIDI files, read with ``mido`` (a maintained MIDI library, not a parser of ours).

Every ``note_on`` (velocity > 0) starts a note and the next ``note_off`` or ``note_on`` with velocity 0 of
the same channel and key ends it; times come from ``mido``'s merged playback, which turns ticks into
seconds through the file's ``set_tempo`` messages (500000 us per beat, 120 bpm, before the first). Channel,
velocity and every other message are ignored. Hands are assigned by a split point: keys below ``split``
(default 60, middle C) go to the left hand, the rest to the right. The song is then checked with
``songs.playable`` (keyboard, reach, one key per hand, tempo), so a file the arms cannot play is refused
with the note named. ``mido`` comes with the ``deploy`` extra; it is imported when a file is read.
"""

from __future__ import annotations

import io
from pathlib import Path

from bar_policy.signals import check_stop
from bar_policy.tasks.piano.keyboard import HAND_SPLIT_MIDI, KeyboardConfig, note_name
from bar_policy.tasks.piano.songs import (
    Note,
    Song,
    SongError,
    TempoLimits,
    check_song_file,
    check_song_size,
    playable,
)

__all__ = ["load_midi", "midi_notes"]


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


def midi_notes(path: str | Path, split: int = HAND_SPLIT_MIDI) -> list[Note]:
    """The notes of a standard MIDI file, hands by ``split``, times in s; not checked against the arms.

    ``SongError`` for a file ``mido`` cannot read, a key pressed again while held, a key never released, or a
    file or song past ``songs``' limits (file size, note count, length: read no further than the first).
    """
    import mido

    path = Path(path)
    check_song_file(path)
    try:
        midi = mido.MidiFile(path, file=_StoppableBytes(path.read_bytes(), f"reading {path}"))
    except (OSError, EOFError, ValueError, KeyError, IndexError) as e:
        raise SongError(f"{path}: not a readable MIDI file ({e})") from None
    held: dict[tuple[int, int], float] = {}
    notes: list[Note] = []
    now = 0.0
    for k, msg in enumerate(midi):  # merged tracks; msg.time is the delta in seconds
        if k % 256 == 0:
            check_stop(f"reading {path}")  # a stop request acts within 256 messages
        now += msg.time
        if msg.type not in ("note_on", "note_off"):
            continue
        key = (msg.channel, msg.note)
        if msg.type == "note_on" and msg.velocity > 0:
            if key in held:
                raise SongError(f"{path}: {note_name(msg.note)} pressed again at {now:.3f} s while held")
            held[key] = now
        elif key in held:
            start = held.pop(key)
            notes.append(Note(msg.note, start, now, "left" if msg.note < split else "right"))
            check_song_size(str(path), len(notes), now)  # while reading: stop at the first note past a limit
    if held:
        (channel, key), start = next(iter(held.items()))
        raise SongError(
            f"{path}: {note_name(key)} on channel {channel} pressed at {start:.3f} s never released"
        )
    return notes


def load_midi(
    path: str | Path,
    config: KeyboardConfig | None = None,
    limits: TempoLimits | None = None,
    split: int = HAND_SPLIT_MIDI,
    name: str | None = None,
) -> Song:
    """A standard MIDI file as a checked song (``playable``); ``name`` defaults to the file's stem."""
    path = Path(path)
    song = Song(path.stem if name is None else name, tuple(midi_notes(path, split)))
    return playable(song, config, limits, split)
