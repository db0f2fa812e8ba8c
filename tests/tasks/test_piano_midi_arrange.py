"""MIDI files as musicians export them (bar_policy/tasks/piano/midi.py, arrange.py) and the melody set.

Expected values are worked by hand from the keyboard's geometry (white pitch 23.5 mm; white keys' aim points
share x and z, so two white keys n apart are 23.5 n mm apart) and the limits (0.5 m/s, 0.15 s shortest
note, 0.05 s shortest gap): ``required_gap`` of two white keys n apart is max(0.05, 0.047 n) s.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import mido
import pytest

from bar_policy.tasks.piano.arrange import arrange, assign_hands, fastest_tempo, parse_tempo
from bar_policy.tasks.piano.keyboard import compact_config, is_black
from bar_policy.tasks.piano.midi import arrange_midi, load_midi, read_midi
from bar_policy.tasks.piano.songs import Note, Song, SongError, required_gap

KB = compact_config()  # C2 (36) .. C6 (84)
MELODIES = Path(__file__).parents[1] / "data" / "piano_melodies"
EPS = 1e-9  # times are sums of a few float64 seconds of order 1-10 s: errors ~1e-15 s


def _legato(
    path: Path, parts: list[list[int]], midi_type: int = 0, tempi: list[tuple[int, int]] = ()
) -> Path:
    """A file of quarter notes (480 ticks), legato (note-off at the next note-on), one part per channel.

    Type 0: one track; type 1: the tempo map in track 0, each part in its own track after it. ``tempi``:
    (tick, us per beat) set_tempo messages (none: mido's 120 bpm).
    """
    events = [[(t, mido.MetaMessage("set_tempo", tempo=us)) for t, us in tempi]]
    for ch, keys in enumerate(parts):
        ev = []
        for i, k in enumerate(keys):
            ev += [(480 * i, mido.Message("note_on", note=k, velocity=80, channel=ch))]
            ev += [(480 * (i + 1), mido.Message("note_off", note=k, channel=ch))]
        events.append(ev)
    tracks = [[e for ev in events for e in ev]] if midi_type == 0 else events
    mid = mido.MidiFile(type=midi_type, ticks_per_beat=480)
    for evs in tracks:
        track, now = mido.MidiTrack(), 0
        order = {"set_tempo": 0, "note_off": 1, "note_on": 2}
        for tick, msg in sorted(evs, key=lambda e: (e[0], order[e[1].type])):
            track.append(msg.copy(time=tick - now))
            now = tick
        mid.tracks.append(track)
    mid.save(path)
    return path


def test_legato_file_is_articulated_to_the_required_gap(tmp_path):
    # C4 D4 G4 E4, quarter notes at 120 bpm (0.5 s), note-off at the next note-on: no gap anywhere. All the
    # right hand's (middle C and up: the split's side; it takes each note in time). Each note but the last
    # ends required_gap before the next starts:
    #   C4->D4: 1 white key, 23.5 mm / 0.5 m/s = 0.047 s -> the 0.05 s floor: ends 0.5 - 0.05 = 0.45 s
    #   D4->G4: 3 white keys, 70.5 mm -> 0.141 s: ends 1.0 - 0.141 = 0.859 s
    #   G4->E4: 2 white keys, 47 mm -> 0.094 s: ends 1.5 - 0.094 = 1.406 s
    #   E4 keeps its end, 2.0 s.
    path = _legato(tmp_path / "legato.mid", [[60, 62, 67, 64]])
    assert [(n.start_s, n.end_s) for n in read_midi(path).notes] == [
        (0.0, 0.5),
        (0.5, 1.0),
        (1.0, 1.5),
        (1.5, 2.0),
    ]
    a = arrange_midi(path, None, KB)
    got = [(n.key, n.start_s, n.end_s, n.hand) for n in a.song.notes]
    want = [
        (60, 0.0, 0.45, "right"),
        (62, 0.5, 0.859, "right"),
        (67, 1.0, 1.406, "right"),
        (64, 1.5, 2.0, "right"),
    ]
    for g, w in zip(got, want, strict=True):
        assert g[0] == w[0] and g[3] == w[3] and g[1] == pytest.approx(w[1], abs=EPS)
        assert g[2] == pytest.approx(w[2], abs=1e-6)  # the gaps' mm are 23.5 n to float precision
    notes = a.song.notes
    for x, y in itertools.pairwise(notes):  # the loader uses the library's own required_gap
        assert y.start_s - x.end_s == pytest.approx(required_gap(x.key, y.key, KB), abs=EPS)
    # Every change listed: three notes shortened, by 0.05, 0.141 and 0.094 s, each before its next key.
    assert [(c.key, round(c.played_s - c.written_s, 6), c.before) for c in a.changes] == [
        (60, -0.05, 62),
        (62, -0.141, 67),
        (67, -0.094, 64),
    ]
    assert a.to_dict()["changed"][1] == {
        "key": 62,
        "hand": "right",
        "start_s": 0.5,
        "written_s": 0.5,
        "played_s": 0.359,
        "before": 67,
    }
    # Fastest: the tightest pair, D4->G4: 0.5 s apart / (0.15 + 0.141) s = x1.7182 (C4->D4: 0.5 / 0.2 = x2.5).
    assert a.lines()[0] == (
        "song 'legato': tempo x1.000 (120 bpm, written 120), fastest playable x1.718; hands: 0 left, "
        "4 right (0 across the split at C4); 3 of 4 notes shortened, 0 lengthened"
    )


def test_hand_assignment_of_a_melody_crossing_middle_c(tmp_path):
    # E4 D4 C4 B3 A3 B3 C4 D4, legato quarter notes at 120 bpm (0.5 s). Both arms reach F#3..F#4, so each
    # note could be either's; each arm takes each note in time (0.5 s >= 0.15 + 0.05 s), so the split decides:
    # from middle C up the right, below it the left.
    path = _legato(tmp_path / "cross.mid", [[64, 62, 60, 59, 57, 59, 60, 62]])
    a = arrange_midi(path, None, KB)
    assert [n.hand for n in a.song.notes] == ["right"] * 3 + ["left"] * 3 + ["right"] * 2
    assert a.hands == {"left": 3, "right": 5} and a.against_split == ()
    # Each hand's own run is articulated; the hand's last note before the other hand takes over keeps its end
    # (C4 at 1.0-1.5 s: the right's next note is C4 at 3.0 s; B3 at 2.5-3.0 s: the left's last).
    ends = [round(n.end_s, 9) for n in a.song.notes]
    assert ends == [0.45, 0.95, 1.5, 1.95, 2.45, 3.0, 3.45, 4.0]


def test_a_note_the_split_s_hand_cannot_take_in_time_goes_to_the_other_arm(tmp_path):
    # Right: C6 at 0.0-0.5 s, then C4 at 0.5 s. C6 -> C4 is 14 white keys, 329 mm -> 0.658 s of move: the
    # right needs 0.15 + 0.658 = 0.808 s from C6's start and has 0.5 (x0.619). The left is free and reaches
    # C4: it takes it, across the split (listed: the key-pose prior would play it with the right arm).
    a = arrange(Song("s", (Note(84, 0.0, 0.5), Note(60, 0.5, 1.0))), None, KB)
    assert [n.hand for n in a.song.notes] == ["right", "left"]
    assert [n.key for n in a.against_split] == [60]
    # A chord of two goes to the two hands, lower left, higher right.
    got = assign_hands(Song("c", (Note(62, 0.0, 0.5), Note(64, 0.0, 0.5))), KB)
    assert [(n.key, n.hand) for n in got.notes] == [(62, "left"), (64, "right")]


def test_fastest_tempo_of_a_tiny_song_by_hand(tmp_path):
    # C5 G5 C5, eighth notes at 120 bpm (0.25 s apart), keys only the right arm reaches (the left's ends at
    # F#4). C5 <-> G5: 4 white keys, 94 mm -> 0.188 s of move, so each note needs 0.15 + 0.188 = 0.338 s from
    # the previous start: the fastest factor is 0.25 / 0.338 = 0.739645.
    song = Song("tiny", (Note(72, 0.0, 0.25), Note(79, 0.25, 0.5), Note(72, 0.5, 0.75)))
    assert fastest_tempo(assign_hands(song, KB), KB) == pytest.approx(0.25 / 0.338, abs=1e-6)
    a = arrange(song, "auto", KB, written_bpm=120.0)
    assert a.tempo == 0.739  # rounded down to 3 decimals: still playable
    # At x0.739 the notes start 0.25 / 0.739 = 0.338295 s apart; C5 and G5 end 0.188 s before the next:
    # 0.338295 - 0.188 = 0.150295 s long (>= 0.15), C5 last keeps its 0.338295 s.
    lengths = [n.end_s - n.start_s for n in a.song.notes]
    assert lengths == pytest.approx([0.150295, 0.150295, 0.338295], abs=1e-5)
    assert a.to_dict()["played_bpm"] == pytest.approx(120 * 0.739, abs=1e-9)


def test_refused_song_names_its_note_and_the_tempo_that_plays_it():
    # The tiny song at its written tempo: G5 starts 0.25 s after C5, 0.338 s needed (above); x0.739 plays it
    # (120 bpm x 0.739 = 88.68 bpm). One line.
    song = Song("tiny", (Note(72, 0.0, 0.25), Note(79, 0.25, 0.5), Note(72, 0.5, 0.75)))
    with pytest.raises(SongError) as e:
        arrange(song, None, KB, written_bpm=120.0)
    assert str(e.value) == (
        "song 'tiny', note 1 (G5 (79) at 0.250-0.500 s, right, as written): at x1 (120 bpm) it starts "
        "0.250 s after C5 (72) starts; the right hand needs 0.338 s (0.15 s of note, then 0.188 s to lift "
        "and move): a tempo beyond the arms; the song plays at x0.739 (88.68 bpm) at most: give --tempo "
        "0.739 or --tempo auto"
    )
    assert "\n" not in str(e.value)
    # At x0.8 (past x0.739) the same note, 0.25 / 0.8 = 0.3125 s after C5.
    with pytest.raises(SongError, match=r"at x0\.8 \(96 bpm\) it starts 0\.312 s after C5"):
        arrange(song, 0.8, KB, written_bpm=120.0)
    # x0.739 plays; a factor that is not one is refused with the choices.
    assert arrange(song, 0.739, KB).tempo == 0.739
    with pytest.raises(
        ValueError, match=r"--tempo 'fast': give a factor > 0 \(0\.5 plays at half speed\) or auto"
    ):
        parse_tempo("fast")
    assert parse_tempo("0.5") == 0.5 and parse_tempo("auto") == "auto" and parse_tempo(None) is None


def test_type_0_and_type_1_files_give_the_same_notes(tmp_path):
    # Melody E4 D4 C4 and bass C3 G2 C3, legato quarters at 120 bpm: one track with two channels (type 0), or
    # the tempo track and one track per part (type 1). mido's merged playback gives the same notes.
    parts = [[64, 62, 60], [48, 43, 48]]
    t0 = read_midi(_legato(tmp_path / "t0.mid", parts, 0, [(0, 500000)]))
    t1 = read_midi(_legato(tmp_path / "t1.mid", parts, 1, [(0, 500000)]))
    assert (t0.midi_type, t0.tracks, t1.midi_type, t1.tracks) == (0, 1, 1, 3)
    key = lambda n: (n.start_s, n.key)  # noqa: E731
    want = [(48, 0.0, 0.5), (64, 0.0, 0.5), (43, 0.5, 1.0), (62, 0.5, 1.0), (48, 1.0, 1.5), (60, 1.0, 1.5)]
    for w in (t0, t1):
        assert [(n.key, n.start_s, n.end_s) for n in sorted(w.notes, key=key)] == want
    a0, a1 = (arrange_midi(tmp_path / f"{n}.mid", None, KB).song for n in ("t0", "t1"))
    assert a0.notes == a1.notes and [n.hand for n in a0.notes] == ["left", "right"] * 3


def test_tempo_changes_are_honoured(tmp_path):
    # 120 bpm (500000 us per beat) then, at beat 2 (tick 960), 60 bpm (1000000 us): C4 D4 E4 F4 quarter notes
    # start at 0, 0.5, 1.0 and 1.0 + 1.0 = 2.0 s, the last ending at 3.0 s. Written tempo: the start's, 120.
    path = _legato(tmp_path / "rit.mid", [[60, 62, 64, 65]], 1, [(0, 500000), (960, 1000000)])
    w = read_midi(path)
    assert [(n.start_s, n.end_s) for n in w.notes] == [(0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.0)]
    assert (w.bpm, w.tempo_changes) == (120.0, 1)
    # --tempo 0.5: every time doubled (starts 0, 1, 2, 4 s), then articulated (C4->D4, D4->E4: 0.05 s; E4->F4
    # adjacent white keys, 0.05 s): ends 0.95, 1.95, 3.95, 6.0.
    song = load_midi(path, KB, tempo=0.5)
    assert [(n.start_s, round(n.end_s, 9)) for n in song.notes] == [(0, 0.95), (1, 1.95), (2, 3.95), (4, 6.0)]


def test_the_melody_set_plays_at_the_tempo_the_loader_chooses():
    files = sorted(MELODIES.glob("*.mid"))
    assert len(files) >= 10
    black_heavy, two_tracks = [], []
    for path in files:
        w = read_midi(path)
        # Legato as exported: most notes end exactly where a note begins (the rest end at a rest or the end).
        starts = {n.start_s for n in w.notes}
        assert sum(n.end_s in starts for n in w.notes) >= 0.8 * len(w.notes), path.stem
        a = arrange_midi(path, "auto", KB)  # no refusal
        assert 0.0 < a.tempo <= 1.0 and a.tempo <= a.fastest, path.stem
        if sum(is_black(n.key) for n in w.notes) >= 0.2 * len(w.notes):
            black_heavy.append(path.stem)
        if (w.midi_type, w.tracks) == (1, 2):
            two_tracks.append(path.stem)
        for n in a.song.notes:  # articulated notes stay at least the shortest note
            assert n.end_s - n.start_s >= 0.15 - 1e-9
    # Swan Lake: F#4 B3 C#4 D4 E4 F#4 D4 F#4 D4 F#4 B3 D4 B3 G3 D4 B3, twice: 5 black of 16 (31 %).
    # Greensleeves: 11 black (F#4 x 6, D#4 x 4, C#4) of 37 (30 %). Scarborough Fair: 7 (F#4 x 4, C#5 x 3)
    # of 34 (21 %).
    assert set(black_heavy) == {"swan_lake", "greensleeves", "scarborough_fair"}
    assert len(two_tracks) >= 3
    # Written beyond the arms, slowed: the Can-can's eighths at 140 bpm (0.214 s), C4 -> C5 (7 white keys,
    # 164.5 mm, 0.329 s of move): 0.2143 / (0.15 + 0.329) = x0.4473 -> x0.447.
    assert arrange_midi(MELODIES / "can_can.mid", "auto", KB).tempo == 0.447
    assert math.isclose(arrange_midi(MELODIES / "ode_to_joy.mid", "auto", KB).tempo, 1.0)


def test_auto_tempo_keeps_the_split_s_hands():
    # E4 0-0.25 s, F#4 0.25-0.5 s, E4 0.5-1.0 s, all in both arms' reach, on the right's side of the split.
    # E4 <-> F#4: 66.420 mm (the black key's aim point 55 mm back, 12 mm up, 35.25 mm across) -> 0.13284 s.
    # The right alone: each note 0.25 s after the last, needing 0.15 + 0.13284 = 0.28284 s: x0.88389.
    song = Song("s", (Note(64, 0.0, 0.25), Note(66, 0.25, 0.5), Note(64, 0.5, 1.0)))
    auto = arrange(song, "auto", KB)
    assert auto.tempo == 0.883 and auto.against_split == ()
    assert auto.fastest == pytest.approx(0.25 / (0.15 + 0.13284), abs=1e-5)
    # With F#4 on the left the right repeats E4 0.5 s apart, needing 0.15 + 0.05 s: x2.5, one note across.
    assert auto.fastest_across == (2.5, 1)
    # As written (x1) the right cannot take F#4 in time; the left can: it does, listed across the split.
    written = arrange(song, None, KB)
    assert written.tempo == 1.0 and [n.key for n in written.against_split] == [66]
    with pytest.raises(SongError) as e:
        arrange(song, 3.0, KB)
    assert str(e.value).endswith(
        "the song plays at x0.883 with the split's hands (--tempo 0.883 or --tempo auto), at x2.5 with 1 "
        "notes across the split"
    )


def test_a_key_struck_again_before_its_release_at_the_same_tick(tmp_path):
    # C4 C4 at 120 bpm, exported with the second note-on before the first note-off at tick 480 (0.5 s): two
    # notes, 0-0.5 s and 0.5-1.0 s; the off at 480 ends the first, not the second.
    mid, track = mido.MidiFile(type=0, ticks_per_beat=480), mido.MidiTrack()
    for delta, msg in [
        (0, mido.Message("note_on", note=60, velocity=80)),
        (480, mido.Message("note_on", note=60, velocity=80)),
        (0, mido.Message("note_off", note=60)),
        (480, mido.Message("note_off", note=60)),
    ]:
        track.append(msg.copy(time=delta))
    mid.tracks.append(track)
    mid.save(tmp_path / "again.mid")
    assert [(n.key, n.start_s, n.end_s) for n in read_midi(tmp_path / "again.mid").notes] == [
        (60, 0.0, 0.5),
        (60, 0.5, 1.0),
    ]
