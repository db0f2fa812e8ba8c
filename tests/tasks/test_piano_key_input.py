"""Key sources of the deploy side (bar_policy/tasks/piano/key_input.py): MIDI messages, schedules, the sim;
and the fingertip estimate's geometry (bar_policy/tasks/piano/keys.py, ``kinematic_pressed``).

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
from bar_policy.tasks.piano.keyboard import KeyboardConfig, compact_config, default_config, key_table
from bar_policy.tasks.piano.keys import kinematic_pressed
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


# The fingertip estimate (keys.kinematic_pressed), worked by hand on the default keyboard's C4 (MIDI 60) and
# D4 (62): white keys centred on y = 0 and y = -0.0235, 22.5 mm wide (edges at +-0.01125 and -0.01225 ..
# -0.03475: the gap is y in [-0.01225, -0.01125]), tops at z = 0.180, hinges at x = 0.336 + 0.150 = 0.486.
# Threshold t = 0.5 * 0.010 / 0.150 = 1/30 rad: sin t = 0.0333272, cos t = 0.9994445. Sphere radius
# r = 0.006. At the aim point, u = 0.125 m in front of the hinge (x = 0.361), the key top at threshold is
# u sin t = 4.1659 mm below rest, and a centre dz above the rest top is p_z = u sin t + dz cos t above it.
DEFAULT = default_config()
X_AIM = 0.486 - 0.125
SIN_T, COS_T = 0.0333272, 0.9994445


def _pressed_midi(*centres: tuple[float, float, float]) -> list[int]:
    return _down(kinematic_pressed(np.array(centres), DEFAULT), 23)


def test_kinematic_threshold_at_the_finger_x_by_hand() -> None:
    """Over C4 at the aim point, the sphere touches the key top at threshold when p_z = r:
    dz = (r - u sin t) / cos t = (0.006 - 0.0041659) / 0.9994445 = 0.0018351 m, the sphere's bottom 4.165 mm
    below the rest top. The old rule needed the front edge's 5 mm (a bottom at 0.175, centre at 0.181).
    """
    dz = (0.006 - 0.125 * SIN_T) / COS_T
    assert dz == pytest.approx(0.0018351, abs=1e-7)
    assert _pressed_midi((X_AIM, 0.0, 0.180 + dz - 1e-5)) == [60]  # 10 um past the boundary
    assert _pressed_midi((X_AIM, 0.0, 0.180 + dz + 1e-5)) == []  # 10 um short of it
    assert _pressed_midi((X_AIM, 0.0, 0.1815)) == [60]  # 4.5 mm down: pressed here, not at the front edge
    # At the front edge (u = 0.150) the threshold is the full 5 mm: dz = (0.006 - 0.150 sin t) / cos t
    # = (0.006 - 0.0049991) / 0.9994445 = 0.0010015 m; there 4.5 mm down is not enough.
    x_front = 0.336 + 1e-4
    dz_front = (0.006 - (0.150 - 1e-4) * SIN_T) / COS_T
    assert _pressed_midi((x_front, 0.0, 0.180 + dz_front - 1e-5)) == [60]
    assert _pressed_midi((x_front, 0.0, 0.1815)) == []


def test_kinematic_sphere_over_the_gap_presses_both_neighbours() -> None:
    """Centre over the middle of the C4 / D4 gap (y = -0.01175): 0.5 mm past each key's edge in y, so the
    sphere overlaps both tops at threshold while p_z <= sqrt(r^2 - 0.5^2 mm^2) = 5.979 mm, and touches them
    from above while p_z >= 0.5 mm. p_z = 3 mm: dz = (0.003 - 0.0041659) / 0.9994445 = -1.1666 mm (the
    centre below the rest top, the sphere's rim holding both keys 2 mm past their threshold): both pressed.
    The old rule (the centre over a key's footprint) pressed neither.
    """
    y_gap = -0.01175
    dz = (0.003 - 0.125 * SIN_T) / COS_T
    assert _pressed_midi((X_AIM, y_gap, 0.180 + dz)) == [60, 62]
    dz_far = (0.00599 - 0.125 * SIN_T) / COS_T  # p_z = 5.99 mm > 5.979: the rims miss both
    assert _pressed_midi((X_AIM, y_gap, 0.180 + dz_far)) == []
    # In x: centre 3 mm in front of C4's front edge, u = 0.153. p_z = 4 mm: dz = (0.004 - 0.153 sin t) / cos t
    # = -1.0997 mm; p_x = -0.153 cos t + dz sin t = -0.15295, e_x = 2.95 mm: overlap (8.7 + 16 <= 36 mm^2),
    # from above (4 >= 2.95 mm): pressed by the rim over the front edge.
    x_ahead = 0.336 - 0.003
    dz = (0.004 - 0.153 * SIN_T) / COS_T
    assert _pressed_midi((x_ahead, 0.0, 0.180 + dz)) == [60]


def test_kinematic_a_resting_or_sidelong_finger_presses_nothing() -> None:
    """A resting finger: the held piano_ready pose's spheres (docs: left (0.357, 0.157, 0.191), right
    (0.357, -0.157, 0.191), bottoms 5 mm above the white tops) press nothing; nor does a sphere just resting
    on C4's top (bottom at 0.180: at threshold the top is 4.17 mm lower, p_z = r + 4.17 mm > r).

    Sidelong: centre 5 mm past C4's edge toward D4 (y = -0.01625), 3 mm below the rest top: for C4,
    p_z = 0.0041659 - 0.003 * 0.9994445 = 1.1676 mm; e_y = 5 mm, overlap (25 + 1.36 <= 36 mm^2) but the
    contact normal is 77 degrees off the key's (1.17 mm up for 5 mm across: it pushes C4 sideways, not down):
    not pressed. D4, under the centre (p_z = 1.17 mm <= r), is.
    """
    assert _pressed_midi((0.357, 0.157, 0.191), (0.357, -0.157, 0.191)) == []
    assert _pressed_midi((X_AIM, 0.0, 0.180 + 0.006)) == []
    assert _pressed_midi((X_AIM, -0.01625, 0.177)) == [62]


def test_kinematic_geometry_is_the_scene_s(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    """The hand-worked boundary point over C4 is r from C4's box in the compiled scene with the key at its
    threshold (MuJoCo's hinge, axis and box, not the estimate's own formulas).
    """
    model, data = scene
    mujoco.mj_resetData(model, data)
    c4 = next(k for k in key_table(DEFAULT) if k.midi == 60)
    data.qpos[model.joint("piano_key60").qposadr[0]] = 0.5 * c4.angle_max
    mujoco.mj_kinematics(model, data)
    geom = model.geom("piano_key60")
    for x, dz in ((X_AIM, (0.006 - 0.125 * SIN_T) / COS_T), (0.3361, (0.006 - 0.1499 * SIN_T) / COS_T)):
        local = data.geom_xmat[geom.id].reshape(3, 3).T @ (
            np.array([x, 0.0, 0.180 + dz]) - data.geom_xpos[geom.id]
        )
        gap = np.maximum(np.abs(local) - model.geom_size[geom.id], 0.0)
        assert np.linalg.norm(gap) == pytest.approx(0.006, abs=1e-6)
