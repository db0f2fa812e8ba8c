"""The piano task (issue 18): the Lite plays a keyboard. Definitions shared by training and deployment.

``keyboard`` (geometry, key table, press test), ``scene`` (the keys in the robot's ``MjSpec``), ``reach``
(which keys each fingertip reaches), ``songs`` (notes, validation, MIDI, goal keys, random songs) and
``song_library`` (the songs made here). numpy, mujoco and ``bar_policy.robot`` only: no jax, no torch.
See docs/piano.md.
"""

from bar_policy.tasks.piano.keyboard import (
    LEFT_REACH,
    RIGHT_REACH,
    Key,
    KeyboardConfig,
    default_config,
    key_table,
    pressed,
)
from bar_policy.tasks.piano.scene import FINGERTIP_BIT, FINGERTIP_GEOMS, keyboard_scene

__all__ = [
    "FINGERTIP_BIT",
    "FINGERTIP_GEOMS",
    "LEFT_REACH",
    "RIGHT_REACH",
    "Key",
    "KeyboardConfig",
    "default_config",
    "key_table",
    "keyboard_scene",
    "pressed",
]
