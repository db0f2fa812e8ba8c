"""Songs are bounded at load: file size, note count, length and playback tables, each named with its value.

A note held 4.5e9 s used to ask for 40 TiB (a traceback); a song of 10^5 notes or one note of 1e5 s was
accepted and took 1-2 GB. Expected values are worked out by hand next to each case.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import mido
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.signals import StopRequested, StopSignals
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.midi import load_midi
from bar_policy.tasks.piano.songs import (
    FORMAT,
    MAX_SONG_FILE_BYTES,
    MAX_SONG_NOTES,
    MAX_SONG_S,
    MAX_SONG_TABLE_BYTES,
    Note,
    Song,
    SongError,
    read_song,
)
from bar_policy.tasks.piano.source import SongCommands

KB = compact_config()


def _midi(path: Path, events: list[tuple[int, mido.Message | mido.MetaMessage]], tpb: int = 480) -> Path:
    mid = mido.MidiFile(type=0, ticks_per_beat=tpb)
    track = mido.MidiTrack()
    for delta, msg in events:
        track.append(msg.copy(time=delta))
    mid.tracks.append(track)
    mid.save(path)
    return path


def _json_song(path: Path, notes: list[dict]) -> Path:
    path.write_text(json.dumps({"format": FORMAT, "name": path.stem, "notes": notes}))
    return path


def test_note_held_4_5e9_s_is_refused_by_length(tmp_path):
    # The longest MIDI delta (2^28 - 1 = 268435455 ticks) at the slowest tempo (2^24 - 1 = 16777215 us per
    # beat) and 1 tick per beat: 268435455 * 16.777215 s = 4.5036e9 s.
    path = _midi(
        tmp_path / "held.mid",
        [
            (0, mido.MetaMessage("set_tempo", tempo=16777215)),
            (0, mido.Message("note_on", note=60, velocity=64)),
            (268435455, mido.Message("note_off", note=60)),
        ],
        tpb=1,
    )
    with pytest.raises(SongError) as err:
        load_midi(path, KB)
    msg = str(err.value)
    assert "a note ends at 4.504e+09 s; a song must end by 600 s" in msg and "MAX_SONG_S" in msg, msg
    assert MAX_SONG_S == 600.0


def test_note_held_1e5_s_is_refused(tmp_path):
    # 120 bpm (500000 us per beat), 480 ticks per beat: 1e5 s = 2e5 beats = 96e6 ticks.
    path = _midi(
        tmp_path / "long.mid",
        [(0, mido.Message("note_on", note=60, velocity=64)), (96_000_000, mido.Message("note_off", note=60))],
    )
    with pytest.raises(SongError, match=r"a note ends at 1e\+05 s; a song must end by 600 s"):
        load_midi(path, KB)
    path = _json_song(tmp_path / "long.json", [{"key": 60, "start_s": 0.0, "end_s": 1e5}])
    with pytest.raises(SongError, match=r"a note ends at 1e\+05 s; a song must end by 600 s"):
        read_song(path, KB)


def test_note_count_limit(tmp_path):
    # MAX_SONG_NOTES + 1 notes of C4, 0.1 s each, every 0.2 s: the last ends at 5000 * 0.2 + 0.1 = 1000.1 s,
    # past 600 s too; the count is checked first, as soon as the loader sees note MAX_SONG_NOTES + 1.
    n = MAX_SONG_NOTES + 1
    notes = [{"key": 60, "start_s": 0.2 * i, "end_s": 0.2 * i + 0.1} for i in range(n)]
    with pytest.raises(
        SongError, match=r"more than 5000 notes; a song may have at most 5000 .*MAX_SONG_NOTES"
    ):
        read_song(_json_song(tmp_path / "many.json", notes), KB)
    # MIDI: 5001 notes of 24 ticks (0.025 s at 120 bpm, 480 tpb) every 48 ticks: 240 s long, within 600 s.
    events = []
    for _ in range(n):
        events += [
            (24, mido.Message("note_on", note=60, velocity=64)),
            (24, mido.Message("note_off", note=60)),
        ]
    with pytest.raises(SongError, match="more than 5000 notes"):
        load_midi(_midi(tmp_path / "many.mid", events), KB)


def test_file_size_limit(tmp_path):
    path = tmp_path / "big.json"
    path.write_bytes(b" " * (MAX_SONG_FILE_BYTES + 1))  # read no further than its size
    with pytest.raises(
        SongError,
        match=f"has {MAX_SONG_FILE_BYTES + 1} bytes; a song file may have at most "
        f"{MAX_SONG_FILE_BYTES} .*MAX_SONG_FILE_BYTES",
    ):
        read_song(path, KB)
    mid = tmp_path / "big.mid"
    mid.write_bytes(b"MThd" + b"\0" * MAX_SONG_FILE_BYTES)
    with pytest.raises(SongError, match="MAX_SONG_FILE_BYTES"):
        load_midi(mid, KB)


def test_table_limit_names_the_size():
    # A 599 s song (within the length) at a 0.1 ms control period, no count-in: room = ceil(599 / 1e-4) + 1
    # = 5990001 steps, + TARGET_FRAMES rows; x 49 keys x 10 bytes = 2.8 GiB > 256 MiB.
    song = Song("long", (Note(60, 0.0, 599.0, "right"),))
    want = (
        r"song 'long': playing it needs 2.*MiB of goal-key tables .* the limit is 256 MiB \(.*MAX_SONG_TABLE"
    )
    with pytest.raises(SongError, match=want):
        SongCommands(song, KB, 1e-4, None, PlaybackConfig(count_in_s=0.0))
    assert MAX_SONG_TABLE_BYTES == 256 * 2**20
    # At the 20 ms control period the same song fits: 29951 + TARGET_FRAMES rows x 49 x 10 B = 14.7 MB.
    src = SongCommands(song, KB, 0.02, None, PlaybackConfig(count_in_s=0.0))
    assert src.song_steps == 29950  # round(599 / 0.02)


def test_cli_refuses_an_unbounded_song_in_one_line(tmp_path, capsys):
    policy = make_policy_file(
        tmp_path / "piano.onnx",
        metadata=dataclasses.replace(default_metadata(task="piano"), action_filter_hz=3.0),
    )
    song = _json_song(tmp_path / "long.json", [{"key": 60, "start_s": 0.0, "end_s": 1e5}])
    argv = ["--policy", str(policy), "--song", str(song), "--target", "mock", "--log", str(tmp_path / "runs")]
    try:
        status = main(argv)
    except SystemExit as e:
        status = e.code
    assert status == 2
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert "Traceback" not in cap.err and len(lines) == 1, cap.err
    assert "a song must end by 600 s" in lines[0] and "MAX_SONG_S" in lines[0]


def test_stop_request_ends_a_song_load(tmp_path):
    """A stop asked for before or while a song file is read ends the read (StopSignals entered)."""
    notes = [{"key": 60, "start_s": 0.5 * i, "end_s": 0.5 * i + 0.2} for i in range(300)]  # playable
    path = _json_song(tmp_path / "s.json", notes)
    events = []
    for _ in range(300):
        events += [
            (96, mido.Message("note_on", note=60, velocity=64)),
            (48, mido.Message("note_off", note=60)),
        ]
    mid = _midi(tmp_path / "s.mid", events)
    with StopSignals() as stop:
        stop.request("SIGTERM received")
        with pytest.raises(StopRequested, match=r"SIGTERM received: reading .*s\.json interrupted"):
            read_song(path, KB)
        with pytest.raises(StopRequested, match=r"SIGTERM received: reading .*s\.mid interrupted"):
            load_midi(mid, KB)
    assert len(read_song(path, KB).notes) == 300  # outside the context: read in full


def test_stop_request_during_the_midi_parse(tmp_path):
    """mido parses byte by byte: the bytes it reads check for a stop request every 4096 reads."""
    from bar_policy.tasks.piano import midi as midi_mod

    events = []
    for _ in range(2000):  # 4000 messages, 3 or more reads each: past 4096 reads
        events += [
            (96, mido.Message("note_on", note=60, velocity=64)),
            (48, mido.Message("note_off", note=60)),
        ]
    path = _midi(tmp_path / "long.mid", events)
    reads = []
    real_read = midi_mod._StoppableBytes.read

    def counting(self, size=-1):
        reads.append(size)
        if len(reads) == 5000:
            stop.request("SIGINT received")
        return real_read(self, size)

    with StopSignals() as stop:
        midi_mod._StoppableBytes.read = counting
        try:
            with pytest.raises(StopRequested, match=r"SIGINT received: reading .*long\.mid interrupted"):
                midi_mod.midi_notes(path)
        finally:
            midi_mod._StoppableBytes.read = real_read
    assert len(reads) == 8192  # the request at read 5000 acts at the next check, read 2 * 4096
