"""The piano task (issue 18): the Lite plays a keyboard. Definitions shared by training and deployment.

``keyboard`` (geometry, key table, press test), ``scene`` (the keys in the robot's ``MjSpec``), ``reach``
(which keys each fingertip reaches), ``songs`` (notes, the song format, playability, goal keys), ``midi``
(standard MIDI files, through mido), ``generator`` (random playable songs) and ``song_library`` (the songs
made here). numpy, mujoco and ``bar_policy.robot`` only: no jax, no torch. See docs/piano.md.
"""

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
from bar_policy.tasks.piano.songs import Note, Song, SongError, TempoLimits, goal_keys, playable, read_song

__all__ = [
    "FINGERTIP_BIT",
    "FINGERTIP_GEOMS",
    "HELDOUT",
    "LEFT_REACH",
    "RIGHT_REACH",
    "TRAIN",
    "TRAIN_TEMPO_BPM",
    "Key",
    "KeyboardConfig",
    "Note",
    "Song",
    "SongError",
    "TempoLimits",
    "compact_config",
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
