"""Where the deploy side's ``key_pressed`` comes from: pluggable sources of the keys that are down now.

A ``KeySource`` answers ``read(t_s)`` with a bool array of shape (n_keys,) (keyboard order, lowest key
first: ``keyboard.key_table``) and counts what it could not use (``counts``). Four sources:

- ``SimKeys``: the keyboard scene simulated in C MuJoCo (sim2sim): each key's hinge angle, read by name
  from its ``piano_key{m}_angle`` sensor (or its joint's ``qpos``), against ``keyboard.pressed``.
- ``MidiKeys``: a MIDI keyboard, through ``mido``: ``note_on`` presses, ``note_off`` (or ``note_on`` with
  velocity 0) releases. Messages come from a mido input port (opened by name), any object with
  ``iter_pending()`` (a mido port), a ``queue.Queue`` or an iterable of ``mido.Message``; each ``read``
  drains what is pending (no thread: call it once per control tick).
- ``ScheduledKeys``: replays a list of ``(time_s, key, down)`` events (a recording, or a song's notes).
- ``SimMidiKeys``: the simulated keys' presses and releases sent through ``MidiKeys`` as ``mido`` note
  messages, in memory: the MIDI path end to end without a port (``bar-deploy eval --keys sim-midi``).

Event sources (``MidiKeys``, ``ScheduledKeys``) **latch** a press: a key pressed since the previous read
reads as down once even if it was released before it (a tap shorter than a control tick is not lost).
Keys off the keyboard are counted (``counts["off_keyboard"]``) and logged, never silently dropped.
numpy only (``mido`` is imported when a port is opened by name; no jax, no torch).
"""

from __future__ import annotations

import logging
import math
import queue
from abc import ABC, abstractmethod
from bisect import bisect_right
from collections import Counter
from collections.abc import Collection, Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.piano.keyboard import KeyboardConfig, default_config, note_name, pressed

if TYPE_CHECKING:
    import mujoco

    from bar_policy.tasks.piano.songs import Song

__all__ = ["KeySource", "MidiKeys", "ScheduledKeys", "SimKeys", "SimMidiKeys"]

log = logging.getLogger(__name__)


class KeySource(ABC):
    """A source of the keys that are down. Use as a context manager (``close`` on exit)."""

    def __init__(self, config: KeyboardConfig | None = None) -> None:
        """``config``: the keyboard (default: ``default_config()``)."""
        self.config = default_config() if config is None else config
        self.counts: Counter[str] = Counter()
        """What could not be used, by kind (``malformed``, ``off_keyboard``, ...)."""

    @property
    def n_keys(self) -> int:
        """Number of keys (the length of ``read``'s array)."""
        return self.config.n_keys

    @property
    def malformed(self) -> int:
        """Inputs that were not readable at all (a non-finite angle, an object that is not a message)."""
        return self.counts["malformed"]

    @abstractmethod
    def read(self, t_s: float) -> np.ndarray:
        """The keys down at time ``t_s`` (s, the caller's clock), bool, shape (n_keys,), keyboard order."""

    def close(self) -> None:  # noqa: B027 (a no-op by default, not abstract)
        """Release what the source holds (a MIDI port); a no-op by default."""

    def __enter__(self) -> KeySource:
        """The source itself."""
        return self

    def __exit__(self, *exc: object) -> None:
        """``close()``."""
        self.close()


class _Latch:
    """Keys down from press and release events, with presses since the last snapshot latched."""

    def __init__(self, source: KeySource) -> None:
        self.source = source
        self.down = np.zeros(source.n_keys, dtype=bool)
        self.latched = np.zeros(source.n_keys, dtype=bool)

    def event(self, midi: int, is_down: bool) -> None:
        """Press (``is_down``) or release MIDI note ``midi``; one off the keyboard is counted and logged."""
        cfg = self.source.config
        i = midi - cfg.lowest
        if not 0 <= i < self.source.n_keys:
            counts = self.source.counts
            counts["off_keyboard"] += 1
            level = logging.WARNING if counts[f"off_keyboard:{midi}"] == 0 else logging.DEBUG
            counts[f"off_keyboard:{midi}"] += 1
            span = f"{note_name(cfg.lowest)}..{note_name(cfg.highest)}"
            what = "press" if is_down else "release"
            log.log(
                level, "%s of %s (%d) is off the keyboard (%s); counted", what, note_name(midi), midi, span
            )
            return
        self.down[i] = is_down
        self.latched[i] |= is_down

    def snapshot(self) -> np.ndarray:
        """Keys down now or pressed since the previous snapshot; clears the latch."""
        out = self.down | self.latched
        self.latched[:] = False
        return out


class SimKeys(KeySource):
    """Keys of the keyboard scene in C MuJoCo, pressed past ``keyboard.pressed``'s threshold."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        config: KeyboardConfig | None = None,
        via: str = "sensor",
    ) -> None:
        """Find every key of ``config`` in a compiled ``keyboard_scene(config)``.

        Args:
            model: the compiled scene (``robot.scene.load_model(mode, keyboard_scene(config))``).
            data: its ``MjData``, read at each ``read``.
            config: the keyboard the scene was built with (default: ``default_config()``).
            via: ``"sensor"`` reads ``sensordata`` of ``piano_key{m}_angle`` (as a robot would: written by
                ``mj_forward`` / ``mj_step``); ``"qpos"`` reads joint ``piano_key{m}``'s ``qpos`` directly.
        """
        super().__init__(config)
        if via not in ("sensor", "qpos"):
            raise ValueError(f"via = {via!r}; expected 'sensor' or 'qpos'")
        self.data = data
        self.via = via
        cfg = self.config
        adr, missing = [], []
        for m in range(cfg.lowest, cfg.highest + 1):
            name = f"piano_key{m}" + ("_angle" if via == "sensor" else "")
            try:
                found = model.sensor(name).adr if via == "sensor" else model.joint(name).qposadr
            except KeyError:
                missing.append(name)
                continue
            adr.append(int(found[0]))
        if missing:
            raise ValueError(
                f"the model lacks {len(missing)} of the keyboard's {via} names, e.g. {missing[:3]}: "
                f"build it with keyboard_scene(config) for this config ({note_name(cfg.lowest)}.."
                f"{note_name(cfg.highest)})"
            )
        self._adr = np.array(adr, dtype=np.intp)

    def angles(self) -> np.ndarray:
        """Key hinge angles now, rad, shape (n_keys,) (a copy)."""
        src = self.data.sensordata if self.via == "sensor" else self.data.qpos
        return np.array(src[self._adr], dtype=float)

    def read(self, t_s: float) -> np.ndarray:
        """Keys at or past the press threshold now (``t_s`` unused: the data is the state now).

        A non-finite angle reads as not pressed and counts as ``malformed``.
        """
        a = self.angles()
        bad = ~np.isfinite(a)
        if bad.any():
            self.counts["malformed"] += int(bad.sum())
            a[bad] = 0.0
        return np.asarray(pressed(a, self.config))


class MidiKeys(KeySource):
    """Keys of a MIDI keyboard from its note messages (mido).

    Note numbers are MIDI's (60 = C4), as the keyboard's. Counted in ``counts``: ``off_keyboard`` (a note
    off this keyboard, also logged: a warning the first time per note), ``other_channel`` (filtered out by
    ``channels``), ``ignored`` (other message types: control change, clock, ...; the sustain pedal is not
    modelled) and ``malformed`` (an object that is not a note message).
    """

    def __init__(
        self,
        source: str | Any | Iterable[Any],
        config: KeyboardConfig | None = None,
        channels: Collection[int] | None = None,
    ) -> None:
        """Connect to ``source``.

        Args:
            source: a mido input port name (opened here with ``mido.open_input``), an object with
                ``iter_pending()`` (an open mido input port, e.g. ``mido.ports.EchoPort``), a
                ``queue.Queue`` of messages, or an iterable of ``mido.Message`` (read lazily: each ``read``
                takes what it yields, to its end).
            config: the keyboard (default: ``default_config()``).
            channels: MIDI channels to use, 0..15 (mido's numbering); ``None``: all.
        """
        super().__init__(config)
        if channels is not None and not all(isinstance(c, int) and 0 <= c <= 15 for c in channels):
            raise ValueError(f"channels = {channels!r}; expected MIDI channels 0..15 (mido's numbering)")
        self.channels = None if channels is None else frozenset(channels)
        self._owned = None
        if isinstance(source, str):
            import mido

            self._owned = source = mido.open_input(source)
        self._source = source
        self._iter = None
        if not (hasattr(source, "iter_pending") or isinstance(source, queue.Queue)):
            self._iter = iter(source)
        self._latch = _Latch(self)

    def _pending(self) -> Iterable[Any]:
        if isinstance(self._source, queue.Queue):
            while True:
                try:
                    yield self._source.get_nowait()
                except queue.Empty:
                    return
        elif self._iter is not None:
            yield from self._iter
        else:
            yield from self._source.iter_pending()

    def handle(self, msg: Any) -> None:
        """Apply one message (what ``read`` does with each pending one)."""
        kind = getattr(msg, "type", None)
        if kind not in ("note_on", "note_off"):
            self.counts["ignored" if isinstance(kind, str) else "malformed"] += 1
            return
        note, velocity, channel = (getattr(msg, a, None) for a in ("note", "velocity", "channel"))
        if not all(isinstance(v, int) and 0 <= v <= 127 for v in (note, velocity, channel)):
            self.counts["malformed"] += 1
            return
        if self.channels is not None and channel not in self.channels:
            self.counts["other_channel"] += 1
            return
        self._latch.event(note, kind == "note_on" and velocity > 0)

    def read(self, t_s: float) -> np.ndarray:
        """Drain the pending messages, then the keys down now or pressed since the previous read.

        ``t_s`` is unused: the messages are applied in their order of arrival.
        """
        for msg in self._pending():
            self.handle(msg)
        return self._latch.snapshot()

    def close(self) -> None:
        """Close the port this source opened by name (one passed in is the caller's to close)."""
        if self._owned is not None:
            self._owned.close()
            self._owned = None


class ScheduledKeys(KeySource):
    """Replays recorded key events: ``(time_s, key, down)``, ``key`` a MIDI note number, ``down`` a bool.

    ``read(t)`` applies every event at or before ``t`` not applied yet (events at one time in their order),
    latching presses as ``MidiKeys`` does. Reading an earlier time than the previous read replays from the
    start. Events off the keyboard are counted and logged when replayed.
    """

    def __init__(
        self, events: Iterable[tuple[float, int, bool]], config: KeyboardConfig | None = None
    ) -> None:
        """Sort ``events`` by time (stable); ``ValueError`` for a non-finite time or a key outside 0..127."""
        super().__init__(config)
        evs = sorted(((float(t), int(k), bool(d)) for t, k, d in events), key=lambda e: e[0])
        for t, k, _ in evs:
            if not math.isfinite(t) or not 0 <= k <= 127:
                raise ValueError(f"event at {t} s, key {k}: need a finite time and a MIDI note 0..127")
        self.events = tuple(evs)
        self._times = [e[0] for e in evs]
        self._latch = _Latch(self)
        self._next = 0
        self._last_t = -math.inf

    @classmethod
    def from_song(cls, song: Song, config: KeyboardConfig | None = None) -> ScheduledKeys:
        """Every note of ``song`` pressed at its start and released at its end.

        At one time, releases come before presses (a key released and pressed again at once reads as down).
        """
        ends = [(n.end_s, n.key, False) for n in song.notes]
        starts = [(n.start_s, n.key, True) for n in song.notes]
        return cls(sorted(ends + starts, key=lambda e: (e[0], e[2])), config)

    def read(self, t_s: float) -> np.ndarray:
        """Keys down at ``t_s`` (s, the events' clock) or pressed since the previous read."""
        if t_s < self._last_t:  # rewind: all keys up, replay from the start
            self._latch, self._next = _Latch(self), 0
        self._last_t = t_s
        end = bisect_right(self._times, t_s)
        for _, key, down in self.events[self._next : end]:
            self._latch.event(key, down)
        self._next = max(self._next, end)
        return self._latch.snapshot()


class SimMidiKeys(MidiKeys):
    """The simulated keys played into ``MidiKeys`` as ``mido`` note messages, in memory.

    Each ``read`` turns the simulated keys' changes since the previous read into ``note_on`` (velocity 64) and
    ``note_off`` messages, queues them and reads them back through ``MidiKeys``, so the notes' numbering, the
    latch and the message handling are those of a MIDI keyboard. A change is seen at a control tick: a tap
    shorter than a tick between two reads is not sent.
    """

    def __init__(self, sim: SimKeys, config: KeyboardConfig) -> None:
        """``sim``: the simulated keys of the sim target, on ``config``."""
        import mido  # a deploy extra, imported when this source is asked for

        self._queue: queue.Queue = queue.Queue()
        super().__init__(self._queue, config)
        self._message = mido.Message
        self._sim = sim
        self._was = np.zeros(self.n_keys, bool)

    def read(self, t_s: float) -> np.ndarray:
        """Send the simulated keys' presses and releases since the last read, then read them as MIDI."""
        now = self._sim.read(t_s)
        for i in np.flatnonzero(now != self._was):
            note = self.config.lowest + int(i)
            kind = "note_on" if now[i] else "note_off"
            self._queue.put(self._message(kind, note=note, velocity=64 if now[i] else 0))
        self._was = now
        return super().read(t_s)
