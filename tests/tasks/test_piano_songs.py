"""Songs for the piano task (bar_policy/tasks/piano/songs.py, midi.py, generator.py, song_library.py).

Expected values are worked by hand from the keyboard's geometry (white pitch 23.5 mm; a black key's aim
point 55 mm further back and 12 mm higher than a white key's) and the limits (0.5 m/s, 0.15 s shortest
note, 0.05 s shortest gap).
"""

from __future__ import annotations

import itertools

import mido
import numpy as np
import pytest

from bar_policy.tasks.piano.generator import (
    HAND_RANGES,
    TRAIN_TEMPO_BPM,
    articulate,
    max_tempo_bpm,
    random_song,
)
from bar_policy.tasks.piano.keyboard import HAND_SPLIT_MIDI, default_config, is_black, note_number
from bar_policy.tasks.piano.midi import load_midi
from bar_policy.tasks.piano.song_library import (
    HELDOUT,
    RETIRED,
    SONG_NAMES,
    TRAIN,
    _scale,
    library_song,
    part,
)
from bar_policy.tasks.piano.songs import (
    Note,
    Song,
    SongError,
    TempoLimits,
    count_in,
    goal_keys,
    playable,
    read_song,
    required_gap,
    song_from_json,
    song_to_json,
    write_song,
)

CFG = default_config()  # B0 (23) .. C7 (96): key index = MIDI - 23


def test_goal_keys_two_notes():
    # C4 0.00-0.10 s, E4 0.10-0.16 s at dt = 0.02: C4 is down at steps 0..4 (round(0.10 / 0.02) = 5 is
    # its first step up), E4 at steps 5..7 (round(0.16 / 0.02) = 8).
    song = Song("two", (Note(60, 0.0, 0.1, "right"), Note(64, 0.1, 0.16, "right")))
    g = goal_keys(song, dt=0.02, steps=10, lookahead=2, config=CFG)
    assert g.shape == (10, 3, 74)
    c4, e4 = 60 - 23, 64 - 23
    assert [t for t in range(10) if g[t, 0, c4]] == [0, 1, 2, 3, 4]
    assert [t for t in range(10) if g[t, 0, e4]] == [5, 6, 7]
    assert g[:, 0].sum() == 8  # nothing else down
    # Lookahead j looks at step t + j: at step 3, j = 2 is step 5 (E4, not C4).
    assert g[3, 2, e4] == 1 and g[3, 2, c4] == 0 and g[3, 1, c4] == 1
    assert g[9].sum() == 0  # steps 9..11: after the song
    np.testing.assert_array_equal(g[1:, 0], g[:-1, 1])  # row t+1's now is row t's next


def test_count_in_shifts_the_whole_song():
    # First note at 0.10 s, count-in 0.5 s: every note moves by 0.5 - 0.1 = 0.4 s, keeping its key, hand
    # and length (C4 0.10-0.30 -> 0.50-0.70, G2 0.20-1.00 -> 0.60-1.40).
    song = Song("s", (Note(60, 0.10, 0.30, "right"), Note(43, 0.20, 1.00, "left")))
    got = count_in(song, 0.5)
    assert [(n.key, n.hand) for n in got.notes] == [(60, "right"), (43, "left")]
    np.testing.assert_allclose([(n.start_s, n.end_s) for n in got.notes], [(0.5, 0.7), (0.6, 1.4)])
    assert got.name == "s" and song.notes[0].start_s == 0.10  # the song itself keeps its times
    # A song already starting at or after the count-in, or empty, comes back as it is: applying the
    # count-in twice is applying it once.
    assert count_in(got, 0.5) is got and count_in(got, 0.3) is got
    assert count_in(Song("empty"), 0.5).notes == ()
    with pytest.raises(ValueError, match=r"count_in_s = -0\.1"):
        count_in(song, -0.1)


def test_required_gap_by_hand():
    # C4 -> D4: 23.5 mm / 0.5 m/s = 0.047 s < 0.05 s floor.
    assert required_gap(60, 62, CFG) == pytest.approx(0.05)
    # C4 -> G4: 4 white keys = 94 mm -> 0.188 s.
    assert required_gap(60, 67, CFG) == pytest.approx(0.188)
    # E4 -> F#4: dy = 3.5 * 23.5 - 2 * 23.5 = 35.25 mm, dx = 55 mm, dz = 12 mm:
    # sqrt(35.25^2 + 55^2 + 12^2) = 66.420 mm -> 0.13284 s.
    assert required_gap(64, 66, CFG) == pytest.approx(0.13284, abs=1e-5)


def _refusal(*notes: Note) -> str:
    with pytest.raises(SongError) as e:
        playable(Song("s", notes), CFG)
    return str(e.value)


def test_refusals_name_the_note():
    msg = _refusal(Note(60, 0.0, 0.5, "right"), Note(108, 1.0, 1.5, "right"))
    assert msg == "song 's', note 1 (C8 (108) at 1.000-1.500 s, right): off the keyboard (B0..C7)"
    msg = _refusal(Note(60, 0.0, 1.0, "right"), Note(62, 0.5, 1.5, "right"))
    assert msg == (
        "song 's', note 1 (D4 (62) at 0.500-1.500 s, right): it overlaps C4 (60) at 0.000-1.000 s, "
        "right: one key per hand at a time"
    )
    msg = _refusal(Note(60, 0.0, 0.5, "right"), Note(67, 0.6, 1.0, "right"))
    # A 0.100 s gap of the 0.188 s needed: at x(0.1 / 0.188) = x0.5319 it is 0.188 s; printed rounded down.
    assert msg == (
        "song 's', note 1 (G4 (67) at 0.600-1.000 s, right): it starts 0.100 s after C4 (60) at "
        "0.000-0.500 s, right ends; the right fingertip needs 0.188 s (94 mm at 0.5 m/s, at least "
        "0.05 s): a tempo beyond the arms (x0.531 of it leaves the gap)"
    )
    msg = _refusal(Note(60, 0.0, 0.1, "right"))
    assert msg == (  # 0.1 s / 0.15 s = x0.6667, rounded down
        "song 's', note 0 (C4 (60) at 0.000-0.100 s, right): shorter than 0.15 s, a tempo beyond the arms "
        "(x0.666 of it plays it)"
    )
    # Legato (C4 ends as D4 starts): no tempo opens the 0.05 s gap; the message blames the gap.
    msg = _refusal(Note(60, 0.0, 0.5, "right"), Note(62, 0.5, 1.0, "right"))
    assert msg == (
        "song 's', note 1 (D4 (62) at 0.500-1.000 s, right): it starts as C4 (60) at 0.000-0.500 s, right "
        "ends, with no gap; the right fingertip needs 0.050 s (24 mm at 0.5 m/s, at least 0.05 s) to lift "
        "and move: a missing gap, not a tempo (end the note before it sooner; bar-deploy --tempo 1 has the "
        "loader do it)"
    )
    msg = _refusal(Note(84, 0.0, 0.5, "left"))
    assert msg.endswith("the left fingertip reaches B0..F#4 only")
    with pytest.raises(SongError, match="ends before it starts"):
        Song("s", (Note(60, 1.0, 0.5),))
    with pytest.raises(SongError, match="hand 'both'"):
        Song("s", (Note(60, 0.0, 0.5, "both"),))
    with pytest.raises(ValueError, match=r"max_speed = 0\.0 must be positive"):
        TempoLimits(max_speed=0.0)


def test_either_hand_assignment():
    # Both hands free: the split (60) decides; right busy: the left takes it; out of the left's reach and
    # right busy: refused, both reasons given.
    got = playable(Song("s", (Note(60, 0.0, 0.5), Note(59, 1.0, 1.5))), CFG)
    assert [n.hand for n in got.notes] == ["right", "left"]
    got = playable(Song("s", (Note(64, 0.0, 1.0, "right"), Note(62, 0.2, 0.6))), CFG)
    assert [n.hand for n in got.notes] == ["right", "left"]
    msg = _refusal(Note(72, 0.0, 1.0, "right"), Note(74, 0.2, 0.6))
    assert "the left fingertip reaches B0..F#4 only; it overlaps C5 (72)" in msg


def test_json_round_trip(tmp_path):
    song = Song("s", (Note(60, 0.0, 0.5, "right"), Note(48, 0.25, 0.75, "left"), Note(62, 0.6, 1.0)))
    text = song_to_json(song)
    assert '"format": "bar_policy.piano.song/1"' in text
    assert song_from_json(text) == song
    write_song(tmp_path / "s.json", song)
    got = read_song(tmp_path / "s.json", CFG)
    assert [n.hand for n in got.notes] == ["right", "left", "right"]  # either -> right (62 >= 60)
    with pytest.raises(SongError, match="note 0: start_s and end_s must be numbers"):
        song_from_json(
            '{"format": "bar_policy.piano.song/1", "name": "x", "notes": [{"key": 60, '
            '"start_s": "0", "end_s": 1}]}'
        )
    with pytest.raises(SongError, match="not a song file"):
        song_from_json('{"name": "x", "notes": []}')


def _write_midi(path, events: list[tuple[int, mido.Message | mido.MetaMessage]]) -> None:
    """A type-0 file at 480 ticks per beat from (delta ticks, message) pairs."""
    mid = mido.MidiFile(type=0, ticks_per_beat=480)
    track = mido.MidiTrack()
    for delta, msg in events:
        track.append(msg.copy(time=delta))
    mid.tracks.append(track)
    mid.save(path)


def test_midi_times_from_ticks_and_tempo(tmp_path):
    # 480 ticks per beat. Tempo 600000 us/beat (100 bpm): 480 ticks = 0.6 s, 240 = 0.3 s.
    # C4 on 0, off +480 -> 0.0-0.6 s; D4 on +240, off +480 -> 0.9-1.5 s.
    # Then 300000 us/beat (200 bpm): 480 ticks = 0.3 s, 960 = 0.6 s.
    # C3 on +480, off (note_on velocity 0) +960 -> 1.8-2.4 s, below the split: left.
    _write_midi(
        tmp_path / "t.mid",
        [
            (0, mido.MetaMessage("set_tempo", tempo=600000)),
            (0, mido.Message("note_on", note=60, velocity=64)),
            (480, mido.Message("note_off", note=60)),
            (240, mido.Message("note_on", note=62, velocity=64)),
            (480, mido.Message("note_off", note=62)),
            (0, mido.MetaMessage("set_tempo", tempo=300000)),
            (480, mido.Message("note_on", note=48, velocity=64)),
            (960, mido.Message("note_on", note=48, velocity=0)),
        ],
    )
    song = load_midi(tmp_path / "t.mid", CFG)
    assert song.name == "t"
    got = [(n.key, round(n.start_s, 9), round(n.end_s, 9), n.hand) for n in song.notes]
    assert got == [(60, 0.0, 0.6, "right"), (62, 0.9, 1.5, "right"), (48, 1.8, 2.4, "left")]


def test_midi_refusals(tmp_path):
    # Default tempo 120 bpm: 480 ticks = 0.5 s. C4 0.0-1.0 s, then D4 0.5-1.5 s while C4 is held (an
    # overlap, as a performance's export may have). Both arms reach both keys and each takes D4 in time
    # (0.5 s >= 0.15 s of C4 + 0.05 s), so the split decides: both the right's, C4 ended 0.05 s before D4.
    _write_midi(
        tmp_path / "o.mid",
        [
            (0, mido.Message("note_on", note=60, velocity=64)),
            (480, mido.Message("note_on", note=62, velocity=64)),
            (480, mido.Message("note_off", note=60)),
            (480, mido.Message("note_off", note=62)),
        ],
    )
    got = [(n.key, n.start_s, n.end_s, n.hand) for n in load_midi(tmp_path / "o.mid", CFG).notes]
    assert got == [(60, 0.0, 0.45, "right"), (62, 0.5, 1.5, "right")]
    # C4, E4 and G4 struck together: three keys, two fingertips.
    _write_midi(
        tmp_path / "c.mid",
        [
            *[(0, mido.Message("note_on", note=k, velocity=64)) for k in (60, 64, 67)],
            (480, mido.Message("note_off", note=60)),
            *[(0, mido.Message("note_off", note=k)) for k in (64, 67)],
        ],
    )
    with pytest.raises(SongError, match=r"note 0 \(C4 .*: a chord of 3 notes \(C4, E4, G4\); the arms play"):
        load_midi(tmp_path / "c.mid", CFG)
    _write_midi(tmp_path / "h.mid", [(0, mido.Message("note_on", note=60, velocity=64))])
    with pytest.raises(SongError, match=r"C4 on channel 0 pressed at 0\.000 s never released"):
        load_midi(tmp_path / "h.mid", CFG)
    (tmp_path / "bad.mid").write_bytes(b"not midi")
    with pytest.raises(SongError, match="not a readable MIDI file"):
        load_midi(tmp_path / "bad.mid", CFG)


@pytest.mark.parametrize("seed", range(40))
def test_random_songs_are_playable(seed):
    rng = np.random.default_rng(seed)
    for tempo in (TRAIN_TEMPO_BPM[0], float(rng.uniform(*TRAIN_TEMPO_BPM)), TRAIN_TEMPO_BPM[1], 300.0):
        song = random_song(rng, CFG, duration_s=8.0, tempo_bpm=tempo)
        got = playable(song, CFG)
        assert len(got.notes) > 0 and song.duration_s <= 8.0 + 1e-9
        for hand in ("left", "right"):
            lo, hi = HAND_RANGES[hand]
            mine = [n for n in got.notes if n.hand == hand]
            assert all(lo <= n.key <= hi for n in mine)
            assert all(a.end_s <= b.start_s for a, b in itertools.pairwise(mine))  # one key at a time


def split_clashes(song: Song, split: int = HAND_SPLIT_MIDI) -> list[tuple[Note, Note]]:
    """Pairs of notes sounding at once that the key-pose prior's hand split (``prior.py``) puts on one arm."""
    return [
        (a, b)
        for a, b in itertools.combinations(song.notes, 2)
        if (a.key >= split) == (b.key >= split) and a.start_s < b.end_s and b.start_s < a.end_s
    ]


def test_library_keeps_to_the_prior_hand_split():
    # The prior drives one arm per key (left below middle C, right from it), whatever the song's hand says:
    # two notes at once on one arm blend two key poses into a pose over neither.
    for name in set(SONG_NAMES) - set(RETIRED):
        assert split_clashes(library_song(name)) == [], name
    # The retired two-hand scales (left from C3, right from C5, 90 bpm: a beat is 2/3 s): the left's
    # C4 (beat 7) and the right's C6 (beat 7) both go to the right arm, from 7 * 2/3 = 4.667 s to the next
    # note's start less the 0.05 s gap (23.5 mm to B3 / B5 at 0.5 m/s is 0.047 s): 5.333 - 0.05 = 5.283 s.
    notes = part("left", _scale(3), 90) + part("right", _scale(5), 90)
    old = playable(Song("old", articulate(tuple(notes))), CFG)
    assert old.notes == library_song("c_major_scales_two_hands").notes  # kept as it was
    [(a, b)] = split_clashes(old)
    assert (a.key, a.hand, b.key, b.hand) == (60, "left", 84, "right")
    assert a.start_s == b.start_s == pytest.approx(4.666667) and a.end_s == b.end_s == pytest.approx(5.283333)
    # Its successor: the left from C2 (36) to C3 (48), the right unchanged (C5 72 .. C6 84).
    new = library_song("c_major_scales_two_octaves").notes
    assert {n.key for n in new if n.hand == "left"} == {36, 38, 40, 41, 43, 45, 47, 48}
    assert [n.key for n in new if n.hand == "right"] == [n.key for n in notes if n.hand == "right"]


def test_random_song_tempo_limits():
    assert max_tempo_bpm() == pytest.approx(300.0)  # 60 / (0.15 + 0.05)
    with pytest.raises(ValueError, match="tempo_bpm = 301"):
        random_song(np.random.default_rng(0), CFG, 4.0, 301.0)
    a = random_song(np.random.default_rng(7), CFG, 6.0, 90.0)
    assert a == random_song(np.random.default_rng(7), CFG, 6.0, 90.0)  # seeded: reproducible


def test_library():
    assert set(TRAIN).isdisjoint(HELDOUT) and set(TRAIN).isdisjoint(RETIRED)
    assert set(TRAIN) | set(HELDOUT) | set(RETIRED) == set(SONG_NAMES)
    assert len(SONG_NAMES) == 16 and "c_major_scales_two_octaves" in TRAIN
    assert {"ode_to_joy", "frere_jacques"} <= set(HELDOUT)
    for name in SONG_NAMES:
        song = library_song(name)
        assert playable(song, CFG) == song  # hands given, every note playable
    # The right-hand C major scale at 100 bpm: a beat is 0.6 s; C4 ends 0.05 s before D4 (required gap).
    scale = library_song("c_major_scale_right").notes
    assert [n.key for n in scale[:8]] == [60, 62, 64, 65, 67, 69, 71, 72]  # C4 D4 E4 F4 G4 A4 B4 C5
    assert [note_number(x) for x in ("C4", "F#3", "A0", "C8")] == [60, 54, 21, 108]
    assert (scale[0].start_s, scale[0].end_s, scale[1].start_s) == (0.0, pytest.approx(0.55), 0.6)
    assert scale[-1].end_s == pytest.approx(15 * 0.6 + 0.6)  # 14 one-beat notes, a two-beat C4
    with pytest.raises(ValueError, match="unknown song 'x'; songs: \\['c_major_scale_right'"):
        library_song("x")


NEW_BLACK = (
    "d_major_scale_right",
    "e_major_scale_left",
    "b_flat_e_flat_arpeggios_two_hands",
    "london_bridge",
)


def test_library_trains_on_black_keys_in_both_hands():
    # 2026-11-27: no training song had a black key. The four songs added then hold black keys in each
    # hand, every one of the five (C#, D#, F#, G#, A#), each hand on its side of the split.
    assert set(NEW_BLACK) <= set(TRAIN)
    notes = [n for name in TRAIN for n in library_song(name).notes]
    assert {n.key for n in notes if is_black(n.key) and n.hand == "left"}
    assert {n.key for n in notes if is_black(n.key) and n.hand == "right"}
    assert {n.key % 12 for n in notes if is_black(n.key)} == {1, 3, 6, 8, 10}
    old = [n for name in TRAIN if name not in NEW_BLACK for n in library_song(name).notes]
    assert not [n for n in old if is_black(n.key)]  # before: none
    for name in NEW_BLACK:
        song = library_song(name).notes
        assert all((n.key >= HAND_SPLIT_MIDI) == (n.hand == "right") for n in song), name
    # The D major scale, right hand, 100 bpm (a beat is 0.6 s): D4 E4 F#4 G4 = 62 64 66 67. D4 -> E4 needs
    # the 0.05 s floor: D4 ends at 0.55 s. E4 -> F#4 needs 0.13284 s (test_required_gap_by_hand): E4 ends
    # at 1.2 - 0.13284 = 1.06716 s. F#4 -> G4: dy = 4 * 23.5 - 3.5 * 23.5 = 11.75 mm, dx = 55, dz = 12:
    # sqrt(11.75^2 + 55^2 + 12^2) = 57.507 mm -> 0.11501 s, F#4 ends at 1.8 - 0.11501 = 1.68499 s.
    # G4 -> A4: the floor, 2.35 s.
    d = library_song("d_major_scale_right").notes
    assert [n.key for n in d[:8]] == [62, 64, 66, 67, 69, 71, 73, 74]  # ... A4 B4 C#5 D5
    np.testing.assert_allclose(
        [(n.start_s, n.end_s) for n in d[:4]],
        [(0.0, 0.55), (0.6, 1.06716), (1.2, 1.68499), (1.8, 2.35)],
        atol=1e-5,
    )
    assert len(d) == 15 and d[-1].key == 62 and d[-1].end_s == pytest.approx(14 * 0.6 + 1.2)
    # The two-hand arpeggios, 90 bpm (a beat is 2/3 s): A#2 (46) and A#4 (70) together at 0 s, then D3
    # (50) and D5 (74) at 0.667 s. A#4 -> D5: dy = 8 * 23.5 - 5.5 * 23.5 = 58.75 mm, dx = 55, dz = 12:
    # 81.367 mm -> 0.16273 s; both end at 0.66667 - 0.16273 = 0.50393 s (the left's octave below alike).
    arp = sorted(library_song("b_flat_e_flat_arpeggios_two_hands").notes, key=lambda n: (n.start_s, n.key))
    assert [(n.key, n.hand) for n in arp[:4]] == [(46, "left"), (70, "right"), (50, "left"), (74, "right")]
    np.testing.assert_allclose([n.start_s for n in arp[:4]], [0.0, 0.0, 2 / 3, 2 / 3], atol=1e-6)
    np.testing.assert_allclose([n.end_s for n in arp[:2]], [0.50393, 0.50393], atol=1e-5)
