"""The held-out set with black keys, the random evaluation songs, and the gate's per-colour recall rows.

Black shares are counted from the notes' own times (independent of the bank's step tables); the gate's rows
and the report's recalls are worked out by hand from small counts (ratios of integers: exact to 1e-9 %).
"""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

import bar_policy.tasks.registry  # noqa: F401 - registers every task's gate
from bar_policy.quality.gate import check, excess, thresholds_text
from bar_policy.tasks.piano.heldout import (
    BLACK_HELDOUT,
    EVAL_HELDOUT,
    RANDOM_EVAL_SEED,
    heldout_song,
    random_eval_songs,
)
from bar_policy.tasks.piano.keyboard import compact_config, is_black
from bar_policy.tasks.piano.results import PianoEval, SongResult
from bar_policy.tasks.piano.song_library import HELDOUT, TRAIN
from bar_policy.tasks.piano.songs import playable

KB = compact_config()


def _black_share(name: str) -> float:
    notes = heldout_song(name).notes
    total = sum(n.end_s - n.start_s for n in notes)
    return sum(n.end_s - n.start_s for n in notes if is_black(n.key)) / total


def test_the_black_key_songs_are_held_out_playable_and_mostly_black() -> None:
    assert (*HELDOUT, *BLACK_HELDOUT) == EVAL_HELDOUT and not set(BLACK_HELDOUT) & set(TRAIN)
    for name in BLACK_HELDOUT:
        song = heldout_song(name)
        playable(song, KB)  # raises naming the note otherwise
        # Every hand on its side of middle C (the prior's split at 60).
        assert all((n.key < 60) == (n.hand == "left") for n in song.notes)
        assert _black_share(name) >= 0.20
    # Amazing Grace in F-sharp major is pentatonic: the right hand plays black keys only (C#4..C#5); the
    # left's B2 (3 of its 26 beats) is its one white key.
    grace = heldout_song("amazing_grace_f_sharp")
    assert {n.key for n in grace.notes if n.hand == "right"} == {61, 63, 66, 68, 70, 73}
    assert {n.key for n in grace.notes if not is_black(n.key)} == {47}
    # The library's held-out songs: one black key (F#) in g_major_scales_two_hands, none in the others.
    assert [round(_black_share(n), 3) > 0 for n in HELDOUT] == [False, False, True]


def test_random_eval_songs_are_the_banks_kind_from_another_seed() -> None:
    songs = random_eval_songs()
    assert len(songs) == 32 and RANDOM_EVAL_SEED == 2026
    assert songs[0].name == "random-2026-0000" and songs[-1].name == "random-2026-0031"
    assert all(max(n.end_s for n in s.notes) <= 9.5 + 1e-9 for s in songs)
    assert [s.notes for s in random_eval_songs(2, 2026)] == [s.notes for s in songs[:2]]  # deterministic
    assert random_eval_songs(1, 0)[0].notes != songs[0].notes  # seed 0 (the training bank's) differs


def _song(group: str, tp_b: int, fn_b: int, tp_w: int, fn_w: int, f1: float = 0.95) -> SongResult:
    q = {"name": "x", "ticks": 100, "faulted": False, "cap_ticks": 0, "chatter_mrad": 1.0, "limit_ticks": 0}
    q["action_rate_sum"] = 0.0
    return SongResult(
        song="x",
        ticks=100,
        scored=100,
        true_pos=tp_b + tp_w,
        false_pos=0,
        false_neg=fn_b + fn_w,
        precision=1.0,
        recall=0.9,
        f1=f1,
        faulted=False,
        end_reason="done",
        quality=q,
        true_pos_black=tp_b,
        false_neg_black=fn_b,
        true_pos_white=tp_w,
        false_neg_white=fn_w,
        group=group,
    )


def test_recall_rows_by_hand() -> None:
    # Held-out: black 30 of 40 (75 %), white 190 of 200 (95 %); random: black 9 of 10 (90 %), white 50 of 50.
    report = PianoEval(
        songs=[
            _song("held-out", 10, 10, 100, 10),
            _song("held-out", 20, 0, 90, 0),
            _song("random", 9, 1, 50, 0),
        ],
        policy="p",
        fingerprint="f",
    )
    rec = report.recall_pct()
    assert rec == pytest.approx(
        {
            "held-out black keys": 75.0,
            "held-out white keys": 95.0,
            "random black keys": 90.0,
            "random white keys": 100.0,
        },
        abs=1e-9,
    )
    gate = report.gate_report()
    assert gate["success_pct"] == pytest.approx(95.0, abs=1e-9)  # the held-out songs' F1 only
    assert len(gate["episodes"]) == 2  # safety and smoothness: the held-out songs
    misses = check("piano", gate)
    assert [m.text for m in misses] == ["recall of held-out black keys 75 % < 85 % (min_recall_pct)"]
    assert not misses[0].safety
    # Excess: 1 - 75 / 85 for the one row below its bound.
    assert excess("piano", gate) == pytest.approx(1 - 75 / 85, rel=1e-12)
    assert "min_recall_pct=85" in thresholds_text("piano")


def test_a_missing_recall_row_is_a_miss() -> None:
    """``--random-songs 0`` plays no random song: its rows are not measured, so the gate cannot pass."""
    report = PianoEval(songs=[_song("held-out", 40, 0, 200, 0)], policy="p", fingerprint="f")
    texts = [m.text for m in check("piano", report.gate_report())]
    assert texts == [
        "recall of random black keys: not measured (the report lacks it; min_recall_pct=85)",
        "recall of random white keys: not measured (the report lacks it; min_recall_pct=85)",
    ]


def test_the_mjx_evaluation_fills_the_recall_rows_for_the_best_iterate() -> None:
    """``training.best.held_out_report``: the MJX evaluation's pooled ``recall_black`` / ``recall_white`` (the
    training bank's songs) stand in for both song sets; an iterate at black recall 0.5 scores an excess of
    2 x (1 - 50 / 85) beyond one at 0.9 (both rows of each colour, the other figures equal)."""
    from bar_policy.training.best import held_out_report

    base = {"success_rate": 0.95, "quality/completion_pct": 100.0, "quality/cap_share_pct": 0.0}
    base["quality/chatter_max_mrad"] = 1.0
    low = held_out_report({**base, "recall_black": 0.5, "recall_white": 0.9})
    assert low["recall_pct"] == pytest.approx(
        {
            "held-out black keys": 50.0,
            "held-out white keys": 90.0,
            "random black keys": 50.0,
            "random white keys": 90.0,
        },
        abs=1e-9,
    )
    high = held_out_report({**base, "recall_black": 0.9, "recall_white": 0.9})
    assert excess("piano", high) == 0.0
    assert excess("piano", low) == pytest.approx(2 * (1 - 50 / 85), rel=1e-12)
    assert "recall_pct" not in held_out_report(base)  # another task's evaluation: no rows


def test_the_hand_load_read_by_hand() -> None:
    """Per song the compensation's estimate (left, right) and the arm's motion while fitting; the line: each
    hand's mean and range over the songs that had it, the largest motion; no line when none had it
    (``--hand-load off``)."""
    songs = [
        replace(_song("held-out", 1, 0, 1, 0), hand_load_kg=(0.30, 0.10), hand_load_motion_mrad=0.4),
        replace(_song("random", 1, 0, 1, 0), hand_load_kg=(0.50, -0.02), hand_load_motion_mrad=36.31),
        _song("random", 1, 0, 1, 0),
    ]
    report = PianoEval(songs=songs, policy="p", fingerprint="f")
    # left: (0.30 + 0.50) / 2 = 0.400, range 0.300..0.500; right: (0.10 - 0.02) / 2 = 0.040, -0.020..0.100
    line = (
        "hand load read (left / right, kg): mean 0.400 / 0.040, range 0.300..0.500 / -0.020..0.100 "
        "over 2 songs; the arm moved up to 36.3 mrad while fitting"
    )
    assert report.hand_load_line() == line and line in report.format()
    assert json.loads(json.dumps(report.to_dict()))["songs"][0]["hand_load_kg"] == [0.30, 0.10]
    assert PianoEval(songs=songs[2:], policy="p", fingerprint="f").hand_load_line() is None
