"""Where ``key_pressed`` comes from on the robot: pluggable key sources (numpy, mujoco, mido; no jax).

A ``KeySource`` answers, each control tick, which keys of the keyboard are down (bool, shape (n_keys,),
keyboard order). Three kinds:

- ``SimKeys``: the simulated keys of the sim target's scene (``keyboard_scene``): a key is down when its hinge
  angle is past its press threshold, the env's own test (``keyboard.pressed``).
- ``MidiKeys``: a MIDI keyboard, through mido: ``note_on`` (velocity > 0) puts a key down, ``note_off`` or
  ``note_on`` with velocity 0 lifts it. Messages come from an input port (read by a background thread) or
  are fed in memory (``feed``: tests, replays). Notes off the keyboard are counted and logged once, never
  silently dropped.
- ``KinematicKeys``: an estimate when no keyboard is connected: a key is down when a fingertip sphere's
  bottom is inside the key's footprint and below the key top by more than the press threshold's travel
  (the fingertips by forward kinematics of the measured q).

Each names itself (``describe``) for the run log.
"""

from __future__ import annotations

import abc
import logging
import queue
import threading
from collections.abc import Iterable
from typing import Any

import mujoco
import numpy as np

from bar_policy.tasks.piano.keyboard import KeyboardConfig, key_table, press_thresholds

__all__ = ["KEY_SOURCES", "KeySource", "KinematicKeys", "MidiKeys", "SimKeys"]

log = logging.getLogger(__name__)

KEY_SOURCES = ("sim", "midi", "midi:PORT", "kinematic")
"""The ``--keys`` choices (``deploy.py``)."""


class KeySource(abc.ABC):
    """Which keys are down now (see the module docstring)."""

    name: str = ""
    """Kind, for logs: ``sim``, ``midi``, ``kinematic``."""

    def __init__(self, config: KeyboardConfig) -> None:
        self.config = config
        self.n_keys = config.n_keys

    @abc.abstractmethod
    def read(self, q: np.ndarray | None) -> np.ndarray:
        """Keys down now, bool (n_keys,); ``q``: the measured joint positions (rad, canonical), if known."""

    def describe(self) -> str:
        """One line for logs."""
        return self.name

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release ports and threads."""


class SimKeys(KeySource):
    """The simulated keys of a C MuJoCo model and data (the sim target's ``model`` / ``data``)."""

    name = "sim"

    def __init__(self, config: KeyboardConfig, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        super().__init__(config)
        try:
            self._qpos = np.array(
                [model.jnt_qposadr[model.joint(f"piano_key{k.midi}").id] for k in key_table(config)]
            )
        except KeyError as e:
            raise ValueError(
                f"the sim target's scene has no piano key joint ({e}): build it with keyboard_scene"
            ) from None
        self._data = data
        self._threshold = press_thresholds(config)

    def angles(self) -> np.ndarray:
        """The keys' hinge angles, rad, shape (n_keys,)."""
        return np.asarray(self._data.qpos[self._qpos])

    def read(self, q: np.ndarray | None) -> np.ndarray:
        """Hinge angle at or past the press threshold."""
        return self.angles() >= self._threshold


class MidiKeys(KeySource):
    """A MIDI keyboard (mido messages from a port, or fed in memory)."""

    name = "midi"

    def __init__(self, config: KeyboardConfig, port: str | None = None) -> None:
        """Open input port ``port`` (None: no port; messages come through ``feed``)."""
        super().__init__(config)
        self._down = np.zeros(self.n_keys, bool)
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.off_keyboard = 0
        """Note messages for keys the keyboard does not have (counted, logged once)."""
        self.messages = 0
        """Note messages applied."""
        self.port_name = port
        self._port = None
        self._stop = threading.Event()
        if port is not None:
            import mido  # only when a port is opened: mido is a deploy extra

            try:
                self._port = mido.open_input(port)
            except (OSError, ValueError) as e:
                names = mido.get_input_names()
                raise ValueError(f"cannot open MIDI input {port!r} ({e}); inputs: {names}") from None
            threading.Thread(target=self._reader, name="bar-deploy-midi", daemon=True).start()

    def _reader(self) -> None:
        assert self._port is not None
        while not self._stop.is_set():
            for msg in self._port.iter_pending():
                self._queue.put(msg)
            self._stop.wait(0.001)

    def feed(self, messages: Iterable[Any]) -> None:
        """Queue mido messages (``mido.Message``) as if they came from the port."""
        for msg in messages:
            self._queue.put(msg)

    def _apply(self, msg: Any) -> None:
        kind = getattr(msg, "type", None)
        if kind not in ("note_on", "note_off"):
            return  # control changes, clock, sustain: not key presses
        k = msg.note - self.config.lowest
        if not 0 <= k < self.n_keys:
            self.off_keyboard += 1
            if self.off_keyboard == 1:
                log.warning(
                    "MIDI note %d is off the keyboard (%d..%d); ignored, further ones counted",
                    msg.note,
                    self.config.lowest,
                    self.config.highest,
                )
            return
        self._down[k] = kind == "note_on" and msg.velocity > 0
        self.messages += 1

    def read(self, q: np.ndarray | None) -> np.ndarray:
        """The keys down after every message received so far."""
        while True:
            try:
                self._apply(self._queue.get_nowait())
            except queue.Empty:
                break
        return self._down.copy()

    def describe(self) -> str:
        """One line for logs."""
        return f"midi({self.port_name})" if self.port_name else "midi(in memory)"

    def close(self) -> None:
        """Stop the reader and close the port."""
        self._stop.set()
        if self._port is not None:
            self._port.close()
            self._port = None


class KinematicKeys(KeySource):
    """Keys estimated from the fingertips' forward kinematics (no keyboard connected)."""

    name = "kinematic"

    def __init__(self, config: KeyboardConfig, fingertips: Any) -> None:
        """``fingertips(q) -> (left, right)`` positions, m (``robot.kinematics.Kinematics.fingertips``)."""
        super().__init__(config)
        keys = key_table(config)
        self._fingertips = fingertips
        half = np.array(
            [(config.black_width if k.black else config.white_pitch - config.white_gap) / 2 for k in keys]
        )
        self._y_lo = np.array([k.y for k in keys]) - half
        self._y_hi = np.array([k.y for k in keys]) + half
        self._x_lo = np.array([k.front_x for k in keys])
        self._x_hi = self._x_lo + np.array([k.lever for k in keys])
        # Depth of the press threshold under the key top at the fingertip's x is at most the front edge's
        # travel; the front edge's (press_fraction * travel) is used: a conservative (shallower) test.
        self._press_z = np.array([k.top_z for k in keys]) - config.press_fraction * config.travel
        self._black = np.array([k.black for k in keys])
        self._radius = config.fingertip_radius

    def read(self, q: np.ndarray | None) -> np.ndarray:
        """A fingertip sphere inside a key's footprint with its bottom below the press depth."""
        if q is None:
            return np.zeros(self.n_keys, bool)
        down = np.zeros(self.n_keys, bool)
        for tip in self._fingertips(np.asarray(q)):
            x, y, z = (float(v) for v in tip)
            inside = (self._x_lo <= x) & (x <= self._x_hi) & (self._y_lo <= y) & (y <= self._y_hi)
            # Where a black key covers a white one, the black key (higher, in front) takes the press.
            if (inside & self._black).any():
                inside &= self._black
            down |= inside & (z - self._radius <= self._press_z)
        return down
