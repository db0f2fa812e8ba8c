"""F1 over the song only (``metrics.song_window``, ``tally.KeyTally``): the window and the scores worked out
by hand, the same ticks scored by the song source (the run summary), the piano roll and ``bar-deploy
--song``'s printed summary on the sim target. Every figure is a ratio of small integers: compared exactly or
to 1e-12.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "deploy"))
from policy_factory import default_metadata, make_policy_file

from bar_policy.deploy.cli import main
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.key_input import ScheduledKeys
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.metrics import song_window
from bar_policy.tasks.piano.plot import roll_tally
from bar_policy.tasks.piano.songs import Note, Song, write_song
from bar_policy.tasks.piano.source import SongCommands

KB = compact_config()
DT = 0.02


def test_song_window_by_hand() -> None:
    goal = np.zeros((12, 5), bool)
    assert song_window(goal) == (0, 0)  # no goal key: nothing to score
    goal[3, 1] = goal[4, 1] = True  # a note on steps 3..4
    goal[8, 4] = True  # a note on step 8 (its end, exclusive: step 9)
    assert song_window(goal) == (3, 9)  # first note's start to last note's end; the rest 5..7 inside
    assert song_window(goal.astype(np.float32)) == (3, 9)  # 0/1 rows, as the bank writes them


def _song_source() -> SongCommands:
    """C4 0.10-0.30 s and C#4 0.40-0.60 s; with the 0.5 s count-in they sound at 0.50-0.70 s (steps 25..34)
    and 0.80-1.00 s (steps 40..49): the window is steps [25, 50). The keys (events half a step before a tick,
    so each read is unambiguous): C3 down 0-0.29 s (the start-up's settling: steps 0..14, before the song),
    C4 0.51-0.69 s (read down at steps 26..34: step 25 missed), C#4 0.79-0.89 s (steps 40..44: 45..49
    missed), C5 1.09-1.19 s (steps 55..59: after the song's last note)."""
    song = Song("two", (Note(60, 0.10, 0.30, "right"), Note(61, 0.40, 0.60, "right")))
    events = [
        (0.0, 48, True),
        (0.29, 48, False),
        (0.51, 60, True),
        (0.69, 60, False),
        (0.79, 61, True),
        (0.89, 61, False),
        (1.09, 72, True),
        (1.19, 72, False),
    ]
    return SongCommands(song, KB, DT, ScheduledKeys(events, KB), PlaybackConfig())


def _play(src: SongCommands, ticks: int, policy_from: int) -> dict[str, np.ndarray]:
    """Tick ``src`` as the runtime does (POLICY from tick ``policy_from``); the log's arrays."""
    rows: dict[str, list] = {"t": [], "mode": [], "song_step": [], "goal_keys": [], "keys_down": []}
    for k in range(ticks):
        t = k * DT
        if k == policy_from:
            src.begin(t)
        src(t)
        policy = k >= policy_from
        if policy:
            src.after_policy_tick()
        rec = src.record()
        for name, v in (("t", t), ("mode", 3 if policy else 2), *((n, rec[n]) for n in rec if n in rows)):
            rows[name].append(v)
    return {k: np.asarray(v) for k, v in rows.items()}


def test_the_song_source_scores_the_song_window_by_hand() -> None:
    src = _song_source()
    assert src.window == (25, 50) and src.song_steps == 50
    _play(src, 75, policy_from=0)
    tally = src.tally
    # Scored: steps 25..49 only (25 ticks); C3's and C5's presses lie outside and count nowhere.
    assert tally.ticks == 25 and tally.steps.tolist() == list(range(25, 50))
    # Per tick (TP FP FN -> P R F1): 25: 0 0 1 -> 1 0 0; 26..34 (9): 1 0 0 -> 1 1 1; 35..39 (5, a rest
    # played as a rest): 1 1 1; 40..44 (5): 1 1 1; 45..49 (5): 0 0 1 -> 1 0 0.
    # Means: P 25/25 = 1, R = F1 = (9 + 5 + 5) / 25 = 0.76. Pooled: TP 14, FP 0, FN 6: F1 28/34.
    assert tuple(tally.counts()) == (14, 0, 6)
    p, r, f1 = tally.means()
    assert p == 1.0 and r == pytest.approx(19 / 25, rel=1e-12) and f1 == pytest.approx(19 / 25, rel=1e-12)
    # Colours: C4 white, 9 of 10 pressed; C#4 black, 5 of 10.
    colour = {"true_pos_black": 5, "false_neg_black": 5, "true_pos_white": 9, "false_neg_white": 1}
    assert tally.colour() == colour
    assert src.summary_lines() == [
        "song 'two' from its first note to its last note's end (0.50-1.00 s): precision 1.000 recall 0.760 "
        "F1 0.760 (step means over 25 ticks; pooled F1 0.824)",
        "  recall of goal key-ticks (pooled): black 0.500 of 10, white 0.900 of 10",
    ]


def test_ticks_outside_policy_are_not_scored() -> None:
    # POLICY from tick 30 (a start-up of 0.6 s): song step 0 is tick 30, so the song's window is ticks 55..79.
    # C4 then sounds at steps 25..34 = ticks 55..64 while its key was down at ticks 26..34 (before it): all 10
    # missed; C#4's at ticks 70..79, its key down at 40..44: all 10 missed; C5 down at 55..59 is a wrong key.
    src = _song_source()
    _play(src, 100, policy_from=30)
    tally = src.tally
    assert tally.ticks == 25 and tuple(tally.counts()) == (0, 5, 20)
    # Per tick: steps 25..29 (C5 down, C4 the goal): 0 1 1 -> P 0, R 0, F1 0; 30..34: 0 0 1 -> 1 0 0;
    # 35..39 rest: 1 1 1; 40..49: 0 0 1 -> 1 0 0. P = 20/25, R = 5/25, F1 = 5/25.
    p, r, f1 = tally.means()
    assert p == pytest.approx(0.8, rel=1e-12)
    assert r == pytest.approx(0.2, rel=1e-12) and f1 == pytest.approx(0.2, rel=1e-12)


def test_the_piano_roll_scores_the_same_ticks() -> None:
    """``plot.roll_tally`` on the run's log (with and without the metadata's window) equals the source's."""
    src = _song_source()
    arrays = _play(src, 100, policy_from=30)
    meta = {"mode_names": {"HOLD": 2, "POLICY": 3}, "command_source": src.metadata()}
    assert meta["command_source"]["song_window_steps"] == [25, 50]
    for m in (meta, {"mode_names": meta["mode_names"]}):  # the second: an older log, window from the rows
        roll = roll_tally(arrays, m)
        assert roll.window == (25, 50) and roll.steps.tolist() == src.tally.steps.tolist()
        assert tuple(roll.counts()) == tuple(src.tally.counts()) and roll.means() == src.tally.means()
        assert roll.colour() == src.tally.colour()


@pytest.fixture(scope="module")
def piano_policy(tmp_path_factory) -> Path:
    meta = dataclasses.replace(default_metadata(task="piano"), action_filter_hz=3.0)
    return make_policy_file(tmp_path_factory.mktemp("piano") / "piano.onnx", metadata=meta)


def test_the_run_summary_prints_the_song_figures_on_the_sim_target(piano_policy, tmp_path, capsys) -> None:
    """``bar-deploy --song`` on the sim target prints the song's precision, recall, F1 and per-colour recall
    after its ``end:`` line. The zero policy holds the held pose above the keys; the sim target starts at the
    exact pose, whose 19.7 mm sag drops the fingertips onto C3 and C5 for a few ticks of the start-up
    (test_piano_deploy's run): not the song's ticks, so not scored. Scored: C4's 15 ticks (0.5-0.8 s after
    POLICY's start, the count-in), none pressed: P 1, R 0, F1 0 each tick; white recall 0 of 15."""
    song = tmp_path / "one.json"
    write_song(song, Song("one", (Note(60, 0.0, 0.3, "right"),)))
    rc = main(
        [
            "--policy",
            str(piano_policy),
            "--target",
            "sim",
            "--song",
            str(song),
            "--ramp-time",
            "0.5",
            "--log",
            str(tmp_path / "runs"),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out.splitlines()
    end = next(i for i, line in enumerate(out) if line.startswith("end: "))
    assert out[end + 1 : end + 3] == [
        "piano: song 'one' from its first note to its last note's end (0.50-0.80 s): precision 1.000 "
        "recall 0.000 F1 0.000 (step means over 15 ticks; pooled F1 0.000)",
        "  recall of goal key-ticks (pooled): black - of 0, white 0.000 of 15",
    ]
