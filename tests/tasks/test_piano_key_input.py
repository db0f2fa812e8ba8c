"""Key sources of the deploy side (bar_policy/tasks/piano/key_input.py): MIDI messages, schedules, the sim.

MIDI messages are fed in memory (``mido.Message`` through mido's in-memory ``EchoPort``, a ``queue.Queue``
or a list); no real port is opened. Expected key sets are read off the messages by hand. The compact
keyboard is C2..C6 (MIDI 36..84); the default one B0..C7 (23..96), whose thresholds (docs/piano.md) are
half of 0.010 / 0.150 = 0.0333 rad for a white key and half of 0.010 / 0.095 = 0.0526 rad for a black one.
"""

from __future__ import annotations

import logging
import queue

import mido
import mujoco
import numpy as np
import pytest
from mido.ports import EchoPort

from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.key_input import MidiKeys, ScheduledKeys, SimKeys
from bar_policy.tasks.piano.keyboard import KeyboardConfig, compact_config, default_config
from bar_policy.tasks.piano.metrics import episode_scores
from bar_policy.tasks.piano.songs import Note, Song, goal_keys

COMPACT = compact_config()


def _down(keys: np.ndarray, lowest: int = 36) -> list[int]:
    """MIDI numbers of the keys down."""
    assert keys.dtype == bool
    return [int(i) + lowest for i in np.flatnonzero(keys)]


def on(note: int, velocity: int = 64, channel: int = 0) -> mido.Message:
    return mido.Message("note_on", note=note, velocity=velocity, channel=channel)


def off(note: int, channel: int = 0) -> mido.Message:
    return mido.Message("note_off", note=note, channel=channel)


def test_midi_keys_over_time_from_a_port() -> None:
    port = EchoPort()
    keys = MidiKeys(port, COMPACT)
    assert keys.read(0.0).shape == (49,) and _down(keys.read(0.0)) == []
    port.send(on(60))
    assert _down(keys.read(0.02)) == [60]
    assert _down(keys.read(0.04)) == [60]  # held: still down with no new message
    port.send(on(64, velocity=70))
    port.send(on(60, velocity=0))  # note_on with velocity 0 releases
    assert _down(keys.read(0.06)) == [64]
    port.send(off(64))
    assert _down(keys.read(0.08)) == []
    # Both ends of the compact keyboard are on it.
    port.send(on(36))
    port.send(on(84))
    assert _down(keys.read(0.10)) == [36, 84]
    assert keys.counts.total() == 0 and keys.malformed == 0


def test_a_tap_between_reads_is_latched_once() -> None:
    port = EchoPort()
    keys = MidiKeys(port, COMPACT)
    port.send(on(62))
    port.send(off(62))  # pressed and released within one tick
    assert _down(keys.read(0.02)) == [62]  # reported down once
    assert _down(keys.read(0.04)) == []


def test_off_keyboard_notes_are_counted_and_logged(caplog: pytest.LogCaptureFixture) -> None:
    q: queue.Queue = queue.Queue()
    keys = MidiKeys(q, COMPACT)
    with caplog.at_level(logging.DEBUG, logger="bar_policy.tasks.piano.key_input"):
        for msg in (on(30), on(100), off(30), on(30), on(60)):
            q.put(msg)
        assert _down(keys.read(0.0)) == [60]
    # 30 pressed, 100 pressed, 30 released, 30 pressed again: four off the keyboard.
    assert keys.counts["off_keyboard"] == 4
    assert keys.counts["off_keyboard:30"] == 3 and keys.counts["off_keyboard:100"] == 1
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    # A warning the first time per note (F#1 = 30, E7 = 100), the repeats at debug level.
    assert len(warnings) == 2
    assert "F#1 (30) is off the keyboard (C2..C6)" in warnings[0] and "E7 (100)" in warnings[1]
    assert sum(r.levelno == logging.DEBUG for r in caplog.records) == 2


def test_channels_other_messages_and_malformed_items() -> None:
    msgs = [
        on(60, channel=0),
        on(62, channel=3),  # filtered out
        mido.Message("control_change", control=64, value=127),  # sustain pedal: not modelled
        mido.Message("clock"),
        object(),  # not a message at all
        on(64, channel=1),
    ]
    keys = MidiKeys(iter(msgs), COMPACT, channels=[0, 1])
    assert _down(keys.read(0.0)) == [60, 64]
    assert keys.counts["other_channel"] == 1
    assert keys.counts["ignored"] == 2
    assert keys.malformed == 1
    assert _down(keys.read(0.02)) == [60, 64]  # the iterable is exhausted; the state holds
    with pytest.raises(ValueError, match="channels"):
        MidiKeys([], COMPACT, channels=[16])


def test_scheduled_keys_replay_and_rewind() -> None:
    events = [
        (0.0, 60, True),
        (0.5, 60, False),
        (0.5, 62, True),
        (0.6, 62, False),
        (0.7, 20, True),  # off the compact keyboard
        (1.0, 70, True),
        (1.01, 70, False),  # a 10 ms tap
    ]
    keys = ScheduledKeys(events, COMPACT)
    assert _down(keys.read(0.0)) == [60]  # events at t are applied at t
    assert _down(keys.read(0.25)) == [60]
    assert _down(keys.read(0.5)) == [62]
    assert _down(keys.read(0.75)) == []
    assert keys.counts["off_keyboard"] == 1
    assert _down(keys.read(0.98)) == []
    assert _down(keys.read(1.02)) == [70]  # the tap, latched
    assert _down(keys.read(1.04)) == []
    assert _down(keys.read(0.25)) == [60]  # an earlier time replays from the start
    with pytest.raises(ValueError, match="finite time"):
        ScheduledKeys([(float("nan"), 60, True)], COMPACT)


def test_scheduled_song_matches_its_goal_keys() -> None:
    # Times on multiples of dt = 0.05 s (exact in binary): 60 held 0-0.5 s and again 0.5-0.75 s (release
    # and press at once), 64 over 0.25-1.0 s.
    song = Song("t", (Note(60, 0.0, 0.5), Note(60, 0.5, 0.75), Note(64, 0.25, 1.0)))
    dt, steps = 0.05, 25
    goal = goal_keys(song, dt, steps, 0, COMPACT)[:, 0]
    keys = ScheduledKeys.from_song(song, COMPACT)
    played = np.stack([keys.read(t * dt) for t in range(steps)])
    assert _down(played[9]) == [60, 64] and _down(played[10]) == [60, 64]  # 0.45 s and 0.5 s
    assert _down(played[15]) == [64] and _down(played[20]) == []
    np.testing.assert_array_equal(played, goal > 0.5)
    assert episode_scores(played, goal).f1 == 1.0


@pytest.fixture(scope="module")
def scene() -> tuple[mujoco.MjModel, mujoco.MjData]:
    from bar_policy.tasks.piano.scene import keyboard_scene

    model = load_model("arms", keyboard_scene(default_config()))
    return model, mujoco.MjData(model)


def test_sim_keys_threshold_by_name(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    model, data = scene
    mujoco.mj_resetData(model, data)
    angles = {60: 0.0340, 61: 0.0500, 62: 0.0330, 63: 0.0600}  # C4 past, C#4 below, D4 below, D#4 past
    for midi, angle in angles.items():
        data.qpos[model.joint(f"piano_key{midi}").qposadr[0]] = angle
    by_qpos = SimKeys(model, data, via="qpos")
    assert _down(by_qpos.read(0.0), 23) == [60, 63]
    by_sensor = SimKeys(model, data)
    assert _down(by_sensor.read(0.0), 23) == []  # sensordata is written by mj_forward / mj_step
    mujoco.mj_forward(model, data)
    assert _down(by_sensor.read(0.0), 23) == [60, 63]
    np.testing.assert_allclose(by_sensor.angles()[60 - 23], 0.034)
    data.qpos[model.joint("piano_key72").qposadr[0]] = np.nan
    assert _down(by_qpos.read(0.0), 23) == [60, 63] and by_qpos.malformed == 1


def test_sim_keys_refuse_a_model_without_the_keys(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    model, data = scene
    with pytest.raises(ValueError, match="lacks 74 of the keyboard's sensor names"):
        SimKeys(load_model("arms"), data)
    # The default scene (23..96) holds every compact key (36..84): fine; a wider keyboard is not.
    assert SimKeys(model, data, COMPACT).n_keys == 49
    with pytest.raises(ValueError, match=r"lacks 2 of the keyboard's qpos names, e\.g\. \['piano_key21'"):
        SimKeys(model, data, KeyboardConfig(lowest=21), via="qpos")
    with pytest.raises(ValueError, match="via"):
        SimKeys(model, data, via="ctrl")
