"""The piano keyboard scene (bar_policy/tasks/piano/keyboard.py): geometry, springs, presses, contacts, reach.

Expected numbers are worked out by hand in the comments from the stated geometry: white pitch 23.5 mm,
white lever 150 mm, black lever 95 mm, travel 10 mm, 1.0 N at the front edge for full travel.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.keyboard import (
    LEFT_REACH,
    RIGHT_REACH,
    KeyboardConfig,
    default_config,
    key_table,
    note_name,
    press_thresholds,
    pressed,
)
from bar_policy.tasks.piano.reach import ReachChecker, sweep
from bar_policy.tasks.piano.scene import FINGERTIP_BIT, FINGERTIP_GEOMS, keyboard_scene

CFG = default_config()
ROBOT = load_robot("arms")


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_model("arms", keyboard_scene(CFG))


def _key(midi: int):
    return next(k for k in key_table(CFG) if k.midi == midi)


def test_key_table_by_hand():
    keys = key_table(CFG)
    # B0 (23) .. C7 (96): 74 keys; white: B0, 6 full octaves C1..B6 (42), C7 -> 44; black 30.
    assert len(keys) == CFG.n_keys == 74
    assert [k.midi for k in keys] == list(range(23, 97))
    assert sum(not k.black for k in keys) == 44
    assert [note_name(m) for m in (21, 23, 60, 61, 69, 98)] == ["A0", "B0", "C4", "C#4", "A4", "D7"]
    # Middle C on the midline; higher notes to the right (-y), one white key every 23.5 mm.
    assert _key(60).y == 0.0
    assert _key(62).y == pytest.approx(-0.0235)
    assert _key(72).y == pytest.approx(-7 * 0.0235)  # C5: one octave = 164.5 mm
    assert _key(48).y == pytest.approx(7 * 0.0235)
    assert _key(61).y == pytest.approx(-0.01175)  # C#4 on the C4 | D4 boundary
    assert _key(66).y == pytest.approx(-3.5 * 0.0235)  # F#4 between F4 (3) and G4 (4)
    whites = [k.y for k in keys if not k.black]
    np.testing.assert_allclose(np.diff(whites), -0.0235, atol=1e-12)
    # Levers, travel angles and springs: angle_max = 0.010 / L; k = 1.0 N * L / angle_max.
    white, black = _key(60), _key(61)
    assert (white.lever, black.lever) == (0.150, 0.095)
    assert white.angle_max == pytest.approx(0.0666667, rel=1e-6)
    assert black.angle_max == pytest.approx(0.1052632, rel=1e-6)
    assert white.stiffness == pytest.approx(2.25)  # 1.0 * 0.150**2 / 0.010
    assert black.stiffness == pytest.approx(0.9025)  # 1.0 * 0.095**2 / 0.010
    assert black.top_z - white.top_z == pytest.approx(0.012)
    assert black.front_x - white.front_x == pytest.approx(0.055)  # 150 - 95 mm, back edges flush


def test_config_refuses_black_end_keys():
    with pytest.raises(ValueError, match="lowest = 22 must be a white key"):
        KeyboardConfig(lowest=22)
    with pytest.raises(ValueError, match="press_fraction"):
        KeyboardConfig(press_fraction=1.0)


def test_robot_unchanged(model):
    alone = load_model("arms")
    index = RobotIndex.from_model(model, ROBOT.joint_names)
    # Keys hang from the world after the chest: the robot keeps qpos 0..13; 74 key hinges follow.
    np.testing.assert_array_equal(index.qpos, np.arange(14))
    assert (model.nq, model.nv, model.nsensor) == (88, 88, 74)
    # Robot bodies: same masses and inertias (the fingertip spheres are massless, inertia is explicit).
    for b in range(alone.nbody):
        other = model.body(alone.body(b).name).id
        assert model.body_mass[other] == alone.body_mass[b]
        np.testing.assert_array_equal(model.body_inertia[other], alone.body_inertia[b])
    # The robot's geoms keep their collision bits, in order; the scene's geoms are the task's.
    names = [model.geom(g).name for g in range(model.ngeom)]
    robot_geoms = [g for g, n in enumerate(names) if not n.startswith("piano_")]
    assert len(robot_geoms) == alone.ngeom
    np.testing.assert_array_equal(model.geom_contype[robot_geoms], alone.geom_contype)
    np.testing.assert_array_equal(model.geom_conaffinity[robot_geoms], alone.geom_conaffinity)
    np.testing.assert_array_equal(model.geom_size[robot_geoms], alone.geom_size)
    # Fingertip kinematics equal to the robot alone's at random poses.
    rng = np.random.default_rng(0)
    d, da = mujoco.MjData(model), mujoco.MjData(alone)
    for _ in range(20):
        q = rng.uniform(ROBOT.lower, ROBOT.upper)
        d.qpos[index.qpos], da.qpos[:] = q, q
        mujoco.mj_kinematics(model, d)
        mujoco.mj_kinematics(alone, da)
        for s in ("left_finger2_tip", "right_finger2_tip"):
            np.testing.assert_array_equal(d.site(s).xpos, da.site(s).xpos)


def test_contact_bits(model):
    # Keys: contype 0, conaffinity 8; fingertip spheres: contype 8, conaffinity 0. A key therefore
    # touches a fingertip (8 & 8) and nothing else: not the robot (bits 1, 2, 4), not another key (0 & 8).
    tips = [model.geom(n).id for n in FINGERTIP_GEOMS]
    keys = [model.geom(f"piano_key{m}").id for m in range(23, 97)]
    assert FINGERTIP_BIT == 8
    assert set(model.geom_contype[tips]) == {8} and set(model.geom_conaffinity[tips]) == {0}
    assert set(model.geom_contype[keys]) == {0} and set(model.geom_conaffinity[keys]) == {8}
    robot = [g for g in range(model.ngeom) if not model.geom(g).name.startswith("piano_")]
    assert not any(model.geom_contype[robot] & 8) and not any(model.geom_conaffinity[robot] & 8)
    assert model.geom_size[tips[0], 0] == 0.006
    assert model.body(model.geom_bodyid[tips[0]]).name == "left_hand"


def test_placement_at_piano_ready(model):
    d = mujoco.MjData(model)
    d.qpos[:14] = ROBOT.pose("piano_ready")
    mujoco.mj_forward(model, d)
    assert d.ncon == 0  # nothing touches at rest
    for site, midi in (("left_finger2_tip", 48), ("right_finger2_tip", 72)):
        tip, key = d.site(site).xpos, _key(midi)
        # The exact pose: 5 mm plus the 19.7 mm the held pose sags (next test) above the keys.
        assert tip[2] - 0.006 - key.top_z == pytest.approx(0.0247, abs=0.001)
        assert tip[0] - key.front_x == pytest.approx(0.025, abs=0.001)  # ~25 mm behind the front
        assert abs(tip[1] - key.y) < (0.0235 - 0.001) / 2  # over C3 / C5


def test_the_held_pose_presses_nothing():
    """The robot holds piano_ready at its gains on the sim target (gravity on): its fingertip spheres settle
    ~5 mm above C3 and C5 (the sag is what the placement allows for) and no key goes down."""
    from bar_policy.deploy.targets.sim import SimConfig, SimTarget
    from bar_policy.robot.mit import MitCommand
    from bar_policy.tasks.piano.held import held_pose

    sim = SimTarget("arms", SimConfig(), scene=keyboard_scene(CFG))
    q0 = ROBOT.pose("piano_ready")
    sim.reset(q0)
    z = np.zeros(14)
    sim.write_command(MitCommand(q0, z, np.asarray(ROBOT.kp, float), np.asarray(ROBOT.kd, float), z))
    sim.advance(2.0)
    for site, midi in (("left_finger2_tip", 48), ("right_finger2_tip", 72)):
        gap = sim.data.site(site).xpos[2] - 0.006 - _key(midi).top_z
        assert gap == pytest.approx(0.005, abs=0.0015), site
    assert not pressed(sim.data.sensordata[: CFG.n_keys], CFG).any()
    # held_pose solves the same balance statically: within the 2 mrad of play that joint friction
    # (0.1 N m / Kp 50) leaves around it.
    np.testing.assert_allclose(sim.read_state().q, held_pose(q0), atol=2e-3)


def _settle(model, midi: int, force: float, seconds: float = 1.0) -> float:
    """Push key ``midi`` with ``force`` N normal to its top at its front edge; return its final angle."""
    d = mujoco.MjData(model)
    key = _key(midi)
    body = model.body(f"piano_key{midi}").id
    jnt = model.joint(f"piano_key{midi}")
    hang = ROBOT.pose("arms_hanging")  # hands by the hips, far from the keys
    for _ in range(int(seconds / model.opt.timestep)):
        d.qpos[:14], d.qvel[:14] = hang, 0.0
        mujoco.mj_kinematics(model, d)
        rot = d.xmat[body].reshape(3, 3)
        front = d.xpos[body] + rot @ np.array([-key.lever, 0.0, 0.0])
        d.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(model, d, -force * rot[:, 2], np.zeros(3), front, body, d.qfrc_applied)
        mujoco.mj_step(model, d)
    return float(d.qpos[jnt.qposadr[0]])


def test_key_settles_where_spring_balances_force(model):
    # Balanced lever (centre of mass on the hinge): gravity adds no torque, so a force F normal to the key
    # top at the front edge settles where k * angle = F * L.
    # White C4: 0.6 N * 0.150 m / 2.25 N*m/rad = 0.040 rad (0.6 of 0.0667: pressed).
    # White C4: 0.4 N -> 0.02667 rad (0.4 of travel: not pressed).
    # Black C#4: 0.3 N * 0.095 m / 0.9025 N*m/rad = 0.031579 rad (0.3 of 0.10526: not pressed).
    assert _settle(model, 60, 0.0) == pytest.approx(0.0, abs=1e-9)
    assert _settle(model, 60, 0.6) == pytest.approx(0.040, rel=1e-4)
    assert _settle(model, 60, 0.4) == pytest.approx(0.026667, rel=1e-4)
    assert _settle(model, 61, 0.3) == pytest.approx(0.031579, rel=1e-4)
    angles = np.zeros(CFG.n_keys)
    angles[60 - 23], angles[61 - 23] = 0.040, 0.031579
    got = pressed(angles, CFG)
    assert got[60 - 23] and not got[61 - 23] and got.sum() == 1


def test_pressed_threshold():
    # Half of the travel angle: white 0.03333 rad, black 0.05263 rad.
    angles = np.zeros((2, CFG.n_keys))
    angles[0, 60 - 23], angles[0, 61 - 23] = 0.0334, 0.0527  # just past
    angles[1, 60 - 23], angles[1, 61 - 23] = 0.0333, 0.0526  # just short
    got = pressed(angles, CFG)
    assert got.shape == (2, 74)
    assert got[0].sum() == 2 and got[0, 60 - 23] and got[0, 61 - 23]
    assert not got[1].any()
    with pytest.raises(ValueError, match="expected"):
        pressed(np.zeros(5), CFG)
    thresholds = press_thresholds(CFG)
    assert thresholds[60 - 23] == pytest.approx(0.01 / 0.15 / 2) and thresholds[61 - 23] == pytest.approx(
        0.01 / 0.095 / 2
    )
    assert pressed(list(angles[0]), CFG).sum() == 2  # a plain list works too


def test_fingertip_presses_key(model):
    # The right fingertip is put by IK 5 mm above C5's aim point, then driven (joint positions prescribed,
    # mj_step) 12 mm down over 0.3 s and held 0.2 s. The sphere's bottom ends 7 mm below the key's rest
    # top at the aim point, 125 mm from the hinge: the key turns ~asin(0.007 / 0.125) = 0.056 rad, past
    # the threshold (0.0333) and short of the stop (0.0667), less the contact's small penetration.
    checker = ReachChecker(CFG)
    key = _key(72)
    x, y, z = key.site
    q_up, e_up = checker.solve("right", np.array([x, y, z + 0.006 + 0.005]), ROBOT.pose("piano_ready"))
    q_dn, e_dn = checker.solve("right", np.array([x, y, z + 0.006 - 0.007]), q_up)
    assert max(e_up, e_dn) < 1e-4
    d = mujoco.MjData(model)
    dt = model.opt.timestep
    n_move, n_hold = int(0.3 / dt), int(0.2 / dt)
    tip = model.geom(FINGERTIP_GEOMS[1]).id
    touched = set()
    for i in range(n_move + n_hold):
        s = min(i / n_move, 1.0)
        d.qpos[:14] = (1 - s) * q_up + s * q_dn
        d.qvel[:14] = (q_dn - q_up) / (n_move * dt) if i < n_move else 0.0
        mujoco.mj_step(model, d)
        touched |= {model.geom(c.geom2 if c.geom1 == tip else c.geom1).name for c in d.contact[: d.ncon]}
    angles = d.sensordata[:74]
    assert touched == {"piano_key72"}
    assert 0.045 < angles[72 - 23] <= key.angle_max * 1.02
    assert pressed(angles, CFG)[72 - 23]
    assert pressed(angles, CFG).sum() == 1
    np.testing.assert_allclose(np.delete(angles, 72 - 23), 0.0, atol=1e-6)


@pytest.mark.slow
def test_reach_sweep_sets_the_span():
    # The sweep over a full 88-key keyboard stops inside it, at the stated reaches; the default keyboard
    # is their union.
    got = sweep(KeyboardConfig(lowest=21, highest=108))
    assert got == {"left": LEFT_REACH, "right": RIGHT_REACH}
    assert (CFG.lowest, CFG.highest) == (LEFT_REACH[0], RIGHT_REACH[1])
    assert LEFT_REACH[1] >= RIGHT_REACH[0]  # the hands' ranges overlap: every key is reachable


def test_compact_config_holds_every_song():
    from bar_policy.tasks.piano.generator import HAND_RANGES
    from bar_policy.tasks.piano.keyboard import compact_config
    from bar_policy.tasks.piano.song_library import SONG_NAMES, library_song

    small = compact_config()
    assert (small.lowest, small.highest, small.n_keys) == (36, 84, 49)  # C2..C6
    assert small.front_x == CFG.front_x and small.top_z == CFG.top_z
    # Same placement: a key keeps its position whatever the keyboard's ends.
    assert next(k for k in key_table(small) if k.midi == 60) == _key(60)._replace(index=60 - 36)
    keys = {n.key for name in SONG_NAMES for n in library_song(name).notes}
    assert small.lowest <= min(keys) and max(keys) <= small.highest
    assert HAND_RANGES["left"][0] >= small.lowest and HAND_RANGES["right"][1] <= small.highest


PROBE = r"""
import sys
import bar_policy.tasks.piano as piano
from bar_policy.tasks.piano import generator, keyboard, midi, reach, scene, song_library, songs
piano.load_midi  # mido is imported only when a file is read
HEAVY = ("jax", "jaxlib", "torch", "brax", "flax", "mujoco.mjx", "mido")
print(sorted(m for m in HEAVY if m in sys.modules))
"""


def test_piano_imports_without_jax_or_torch():
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.split()[-1] == "[]", out.stdout + out.stderr
