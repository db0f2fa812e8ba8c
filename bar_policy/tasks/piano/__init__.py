"""The piano task: the Lite plays a keyboard. Definitions shared by training and deployment.

``keyboard`` (geometry, key table, press test), ``scene`` (the keys in the robot's ``MjSpec``), ``reach``
(which keys each fingertip reaches), ``songs`` (notes, the song format, playability, goal keys), ``midi``
(standard MIDI files, through mido), ``generator`` (random playable songs), ``song_library`` (the songs
made here) and ``bank`` (songs as played: the count-in, the goal keys per control step). numpy, mujoco and
``bar_policy.robot`` only: no jax, no torch. See docs/piano.md.
"""

from bar_policy.task_records import EnvEntry, TaskRecord
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.generator import TRAIN_TEMPO_BPM, random_song
from bar_policy.tasks.piano.keyboard import (
    LEFT_REACH,
    RIGHT_REACH,
    Key,
    KeyboardConfig,
    compact_config,
    default_config,
    key_table,
    press_thresholds,
    pressed,
)
from bar_policy.tasks.piano.midi import load_midi
from bar_policy.tasks.piano.scene import FINGERTIP_BIT, FINGERTIP_GEOMS, keyboard_scene
from bar_policy.tasks.piano.song_library import HELDOUT, TRAIN, library_song
from bar_policy.tasks.piano.songs import (
    Note,
    Song,
    SongError,
    TempoLimits,
    count_in,
    goal_keys,
    playable,
    read_song,
)

__all__ = [
    "FINGERTIP_BIT",
    "FINGERTIP_GEOMS",
    "HELDOUT",
    "LEFT_REACH",
    "RECORD",
    "RIGHT_REACH",
    "TRAIN",
    "TRAIN_TEMPO_BPM",
    "Key",
    "KeyboardConfig",
    "Note",
    "PlaybackConfig",
    "Song",
    "SongError",
    "TempoLimits",
    "compact_config",
    "count_in",
    "default_config",
    "goal_keys",
    "key_table",
    "keyboard_scene",
    "library_song",
    "load_midi",
    "playable",
    "press_thresholds",
    "pressed",
    "random_song",
    "read_song",
]

_HERE = "bar_policy.tasks.piano"

RECORD = TaskRecord(
    name="piano",
    summary="play the keyboard",
    envs=(
        EnvEntry(
            name="LitePiano",
            env=f"{_HERE}.env:LitePiano",
            config=f"{_HERE}.env:default_config",
            action_prior="key_pose",
        ),
    ),
    layout=f"{_HERE}.layout:schema",
    terms=f"{_HERE}.terms:TERMS",
    shipped_layouts=(("lite_piano_arms", "arms"),),
    command_terms=("target_keys", "progress", "key_pressed"),
    implied_by=("target_keys", "key_pressed"),
    hc_only=False,
    metadata_keys=("dataset_repo_id", "song_lead_steps"),
    metric="key-press precision, recall and F1 over the song's steps (RoboPianist's)",
    presets=(("piano", f"{_HERE}.preset:PIANO"), ("piano-robust", f"{_HERE}.preset:PIANO_ROBUST")),
    gate=f"{_HERE}.gate:GATE",
    deploy=f"{_HERE}.deploy",
)
"""The piano task's registration (``bar_policy.tasks.registry``)."""
