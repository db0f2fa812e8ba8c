"""The goal keys' lead: ``PlaybackConfig.lead_steps``, its metadata key and ``SongCommands`` reading ahead.

Expected values by hand from the definition (``bank.PlaybackConfig``): with a lead of D steps the
``target_keys`` of step t are the song's rows t + D .. t + D + 10, while the tick's goal (what is scored)
stays row t. The env's side and its parity with ``SongCommands`` are
``tests/tasks/test_piano_env.py::test_env_and_song_commands_play_songs_alike``.
"""

from __future__ import annotations

import queue
from types import SimpleNamespace

import numpy as np
import pytest

from bar_policy.deploy.metadata import MetadataError, PolicyMetadata
from bar_policy.tasks.piano.bank import SONG_LEAD_STEPS, PlaybackConfig
from bar_policy.tasks.piano.env import LitePiano, default_config
from bar_policy.tasks.piano.key_input import MidiKeys
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.songs import Note, Song
from bar_policy.tasks.piano.source import SongCommands, policy_playback
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES
from tests.test_metadata import make

KB = compact_config()
DT = 0.02


def test_metadata_key_round_trip_and_refusals() -> None:
    props = make(song_lead_steps=2).to_props()
    assert props["bar.song_lead_steps"] == "2"
    assert PolicyMetadata.from_props(props).song_lead_steps == 2
    assert "bar.song_lead_steps" not in make().to_props()  # 0: no key, as in older files
    del props["bar.song_lead_steps"]
    assert PolicyMetadata.from_props(props).song_lead_steps == 0
    for bad in ('"2"', "true", "-1", "1.5", "[2]"):
        props["bar.song_lead_steps"] = bad
        with pytest.raises(MetadataError, match=r"'bar\.song_lead_steps' must be an integer >= 0"):
            PolicyMetadata.from_props(props)
    with pytest.raises(MetadataError, match="song lead must be an integer >= 0"):
        make(song_lead_steps=-1)


def test_playback_of_a_policy_and_refusals() -> None:
    """A file's lead reaches the playback; a file without the key (older ones) plays with none."""
    assert policy_playback(SimpleNamespace(metadata=make(song_lead_steps=3))) == PlaybackConfig(lead_steps=3)
    assert policy_playback(SimpleNamespace(metadata=make())).lead_steps == 0
    assert policy_playback(SimpleNamespace(metadata=SimpleNamespace())).lead_steps == 0
    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match=r"lead_steps = .* must be an integer >= 0"):
            PlaybackConfig(lead_steps=bad)  # type: ignore[arg-type]


def test_the_env_trains_with_the_lead_and_writes_it() -> None:
    """The env's playback reads the song 2 steps ahead and its metadata names it (``task_metadata``)."""
    cfg = default_config()
    assert cfg.playback == PlaybackConfig(lead_steps=SONG_LEAD_STEPS) and SONG_LEAD_STEPS == 2
    meta = LitePiano.task_metadata(SimpleNamespace(config=cfg))  # type: ignore[arg-type]
    assert meta["song_lead_steps"] == 2
    assert meta["dataset_repo_id"].startswith("bar_policy.piano:random256-seed0-countin0.5s-")


@pytest.mark.parametrize("lead", [0, 2])
def test_song_commands_read_the_song_ahead_and_score_its_own_time(lead: int) -> None:
    """One note, E4, from 0.6 s to 0.7 s: the song starts after the 0.5 s count-in, so it is not moved, and
    its rows are 30..34 (0.6 / 0.02 = 30 to 0.7 / 0.02 = 35, the end exclusive).

    - ``target_keys`` frame j at step t is row t + lead + j: E4 is on where 30 <= t + lead + j < 35; with
      lead 2, frame 0 holds it at steps 28..32 (rows 30..34), with lead 0 at steps 30..34;
    - ``goal_now`` (the score) is row t for both leads: on at steps 30..34 only."""
    k = 64 - KB.lowest
    song = Song("one_note", (Note(64, 0.6, 0.7, "right"),))
    src = SongCommands(song, KB, DT, MidiKeys(queue.Queue(), KB), PlaybackConfig(lead_steps=lead))
    src.begin(0.0)
    assert src.lead == lead and src.song_steps == 35

    def frames(t: int) -> tuple[np.ndarray, bool]:
        obs = src(t * DT)
        target = obs["target_keys"].reshape(TARGET_FRAMES, PIANO_KEYS)
        assert target.sum() == target[:, k].sum()  # E4 the only key
        return target[:, k], bool(src.goal_now()[k])

    for t in range(26, 40):
        column, goal = frames(t)
        want = [1.0 if 30 <= t + lead + j < 35 else 0.0 for j in range(TARGET_FRAMES)]
        np.testing.assert_array_equal(column, want, f"step {t}")
        assert goal == (30 <= t < 35), f"step {t}"
    first = 30 - lead  # frame 0 holds the note from this step (docstring)
    assert [frames(t)[0][0] for t in (first - 1, first, first + 4, first + 5)] == [0.0, 1.0, 1.0, 0.0]
