"""The perturbation spec and its model edits, checked on the compiled C MuJoCo model by hand-worked values."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import load_robot
from bar_policy.robot.perturb import (
    ARM_BODIES,
    PUSH_DURATION_S,
    MotorPerturbation,
    Pusher,
    payload_body_name,
    perturbed_scene,
)
from bar_policy.robot.perturb_spec import KEYS, Perturbation, PerturbationError, parse_perturbation
from bar_policy.robot.perturb_suite import SUITE
from bar_policy.robot.scene import load_model

ARMS = load_robot("arms")
NOMINAL = load_model("arms")

# The links table (links.py): left arm 0.375 + 0.42 + 0.43 + 0.11 + 0.54 + 0.25 + 0.167493 = 2.292493 kg,
# right arm 0.375 + 0.42073 + 0.43 + 0.11 + 0.54 + 0.25 + 0.167493 = 2.293223 kg.
ARM_MASS_KG = 2.292493 + 2.293223


def _model(spec: str, mode: str = "arms") -> mujoco.MjModel:
    return load_model(mode, perturbed_scene(parse_perturbation(spec)))


def _arm_mass(model: mujoco.MjModel) -> float:
    return sum(float(model.body(name).mass[0]) for name in ARM_BODIES)


def test_nominal_arm_mass_is_the_links_table():
    assert _arm_mass(NOMINAL) == pytest.approx(ARM_MASS_KG, abs=1e-12)


def test_mass_scale_scales_the_arm_links_only():
    m = _model("mass_scale=1.2")
    # 1.2 * 4.585716 = 5.5028592 kg; 14 additions of float64 masses: 1e-12 is far above their rounding.
    assert _arm_mass(m) == pytest.approx(5.5028592, abs=1e-12)
    for name in ARM_BODIES:  # principal inertias scale with the mass (same shape, same frame)
        np.testing.assert_allclose(m.body(name).inertia, 1.2 * NOMINAL.body(name).inertia, rtol=1e-12)
        np.testing.assert_allclose(m.body(name).ipos, NOMINAL.body(name).ipos, atol=1e-15)
    for name in ("chest", "head"):
        assert m.body(name).mass[0] == NOMINAL.body(name).mass[0]
    assert m.nbody == NOMINAL.nbody


@pytest.mark.parametrize(
    ("site", "pos"),
    [("fingertip", (0.0225, 0.225, 0.007)), ("palm", (0.0005, 0.10, -0.01))],  # finger tip; palm capsule
)
def test_payload_is_a_body_of_that_mass_at_the_site(site, pos):
    m = _model(f"payload_kg=0.5,payload_at={site}")
    assert m.nbody == NOMINAL.nbody + 2
    for hand, sign in (("left_hand", 1.0), ("right_hand", -1.0)):
        body = m.body(payload_body_name(hand))
        assert body.mass[0] == 0.5
        assert m.body_parentid[body.id] == m.body(hand).id
        np.testing.assert_allclose(body.pos, (pos[0], sign * pos[1], pos[2]), atol=1e-15)
        # the hand's subtree: the hand's 0.167493 kg and the 0.5 kg payload
        assert m.body_subtreemass[m.body(hand).id] == pytest.approx(0.667493, abs=1e-12)
    if site == "fingertip":  # the payload sits on the fingertip site, at any pose
        d = mujoco.MjData(m)
        d.qpos[:] = ARMS.pose("piano_ready")
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(
            d.body(payload_body_name("left_hand")).xpos, d.site("left_finger2_tip").xpos, atol=1e-12
        )


def test_friction_damping_armature_of_the_arm_joints():
    m = _model("friction_nm=1.0,damping=0.5,armature_scale=2")
    dof = [m.joint(n).dofadr[0] for n in ARMS.joint_names]
    # lite_dummy.json: frictionloss and armature per joint; no passive damping in the model
    np.testing.assert_allclose(m.dof_frictionloss[dof], ARMS.frictionloss + 1.0, atol=1e-15)
    np.testing.assert_allclose(m.dof_damping[dof], 0.5, atol=0)
    np.testing.assert_array_equal(m.dof_dampingpoly[dof], NOMINAL.dof_dampingpoly[dof])  # linear term only
    np.testing.assert_allclose(m.dof_armature[dof], 2.0 * ARMS.armature, atol=1e-15)
    assert np.all(NOMINAL.dof_damping == 0.0)
    # The passive force, by hand: -0.5 N*m*s/rad x 2 rad/s = -1 N*m on the joint moving alone (0.5 x 2 +
    # 0.5 x 4 + 0.5 x 8 = 7 N*m if the damping polynomial's higher-order terms were set too).
    d = mujoco.MjData(m)
    d.qpos[:] = ARMS.pose("piano_ready")
    d.qvel[dof[4]] = 2.0
    mujoco.mj_forward(m, d)
    assert d.qfrc_damper[dof[4]] == pytest.approx(-1.0, abs=1e-12)
    assert m.body_mass.sum() == pytest.approx(NOMINAL.body_mass.sum(), abs=1e-12)


def test_the_neck_is_not_an_arm():
    robot = load_robot("arms_neck")
    m0, m = load_model("arms_neck"), _model("friction_nm=1.0,mass_scale=2", "arms_neck")
    for name in ("neck_yaw", "neck_roll", "neck_pitch"):
        assert m.dof_frictionloss[m.joint(name).dofadr[0]] == m0.dof_frictionloss[m0.joint(name).dofadr[0]]
    assert m.body("head").mass[0] == m0.body("head").mass[0]
    mp = MotorPerturbation.of(parse_perturbation("strength=0.5,offset_rad=0.01"), robot)
    neck = [robot.index(n) for n in ("neck_yaw", "neck_roll", "neck_pitch")]
    assert np.all(mp.strength[neck] == 1.0) and np.all(mp.offset[neck] == 0.0)
    arm = [i for i in range(robot.num_joints) if i not in neck]
    assert np.all(mp.strength[arm] == 0.5) and np.all(mp.offset[arm] == 0.01)


def test_random_draws_per_joint_are_seeded_and_in_range():
    p = parse_perturbation("offset_rad=~0.01,seed=3")
    a = MotorPerturbation.of(p, ARMS).offset
    assert np.all(np.abs(a) <= 0.01) and (a > 0).any() and (a < 0).any()  # random signs
    assert len(set(a.round(12))) == 14  # a spread, not one value
    np.testing.assert_array_equal(
        a, MotorPerturbation.of(parse_perturbation("offset_rad=~0.01,seed=3"), ARMS).offset
    )
    assert not np.array_equal(
        a, MotorPerturbation.of(parse_perturbation("offset_rad=~0.01,seed=4"), ARMS).offset
    )
    # adding another key leaves this key's draws as they were (one stream per key)
    b = MotorPerturbation.of(parse_perturbation("offset_rad=~0.01,strength=~0.2,seed=3"), ARMS)
    np.testing.assert_array_equal(a, b.offset)
    assert np.all(np.abs(b.strength - 1.0) <= 0.2)
    f = parse_perturbation("friction_nm=~0.5,seed=1").values("friction_nm", 14)
    assert np.all((f >= 0.0) & (f <= 0.5))  # one-sided


def test_mass_draw_per_link():
    m = _model("mass_scale=~0.2,seed=7")
    ratios = np.array([m.body(n).mass[0] / NOMINAL.body(n).mass[0] for n in ARM_BODIES])
    assert np.all(np.abs(ratios - 1.0) <= 0.2) and len(set(ratios.round(12))) == len(ARM_BODIES)


def test_pusher_force_magnitude_duration_and_interval():
    pusher = Pusher(NOMINAL, 10.0, seed=5)
    dt = 0.002
    times = np.arange(0, 12.0, dt)
    f = np.array([pusher.force_at(t) for t in times])  # (T, 2 hands, 3)
    norms = np.linalg.norm(f, axis=2)
    on = norms[:, 0] > 0
    np.testing.assert_allclose(norms[on], 10.0, rtol=1e-12)  # both hands, 10 N each, while pushing
    assert np.array_equal(on, norms[:, 1] > 0)
    starts = np.flatnonzero(on[1:] & ~on[:-1]) + 1
    lengths = [int(np.argmin(on[s:])) for s in starts]
    assert all(abs(n * dt - PUSH_DURATION_S) <= dt + 1e-9 for n in lengths)  # 0.1 s, within a step
    gaps = np.diff(times[starts])
    assert 1.0 <= times[starts[0]] <= 3.0 + dt and np.all((gaps >= 1.0 - dt) & (gaps <= 3.0 + dt))
    assert pusher.pushes == len(starts) >= 3
    assert not np.allclose(f[starts[0], 0], f[starts[0], 1])  # each hand its own direction
    d = mujoco.MjData(NOMINAL)
    d.time = times[starts[0]]
    pusher.reset()
    pusher.apply(d)
    hands = [NOMINAL.body(h).id for h in ("left_hand", "right_hand")]
    np.testing.assert_allclose(np.linalg.norm(d.xfrc_applied[hands, :3], axis=1), 10.0, rtol=1e-12)
    assert np.all(d.xfrc_applied[hands, 3:] == 0.0) and np.count_nonzero(d.xfrc_applied) == 6


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("mass_scal=1.1", "unknown perturbation key 'mass_scal'; did you mean 'mass_scale'?"),
        ("mass_scale=3", "mass_scale=3 is out of range: valid 0.5..2 x"),
        ("payload_kg=-1", "payload_kg=-1 is out of range: valid 0..2 kg"),
        ("friction_nm=abc", "friction_nm='abc': not a number (N*m)"),
        ("action_delay_ticks=1.5", "action_delay_ticks='1.5': not a whole number (ticks)"),
        ("offset_rad=nan", "offset_rad='nan': not a finite number"),
        ("strength=0.9,strength=0.8", "perturbation key 'strength' given twice"),
        ("payload_at=palm", "payload_at without payload_kg > 0"),
        ("payload_kg=0.3,payload_at=wrist", "payload_at='wrist': valid values are ['fingertip', 'palm']"),
        ("push_n=~5", "'~' (a random draw) is only allowed for"),
        ("offset_rad=~0.5", "offset_rad=~0.5: the spread must be in (0, 0.2] rad"),
        ("mass_scale", "'mass_scale' is not KEY=VALUE"),
    ],
)
def test_parse_refusals_are_one_line(text, needle):
    with pytest.raises(PerturbationError) as e:
        parse_perturbation(text)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_parse_values_and_nominal():
    p = parse_perturbation(" mass_scale=1.1, payload_kg=0.3 ,action_delay_ticks=1,offset_rad=-0.002")
    assert (p.mass_scale, p.payload_kg, p.action_delay_ticks, p.offset_rad) == (1.1, 0.3, 1, -0.002)
    assert p.payload_at == "fingertip" and p.changes_model and not p.nominal
    assert parse_perturbation("").nominal and parse_perturbation("nominal") == Perturbation()
    assert not parse_perturbation("obs_delay_ticks=1").changes_model
    assert perturbed_scene(parse_perturbation("strength=0.8")) is None  # the model is untouched


def test_suite_rows_parse_and_cover_the_published_rows():
    names = [r.name for r in SUITE]
    assert names[0] == "nominal" and SUITE[0].perturbation.nominal and len(names) == len(set(names)) == 13
    gatings = {r.name: r.gating for r in SUITE}
    assert gatings["offset 0.01 rad"] == "none" and gatings["push 10 N"] == "safety"
    assert sum(g == "all" for g in gatings.values()) == 11
    combined = SUITE[-1].perturbation
    assert (combined.mass_scale, combined.payload_kg, combined.friction_nm, combined.strength) == (
        1.1,
        0.3,
        0.5,
        0.9,
    )
    assert (combined.action_delay_ticks, combined.offset_rad, combined.payload_at) == (1, 0.002, "fingertip")
    assert set(KEYS) == {f for f in Perturbation.__dataclass_fields__ if f not in ("random", "text")}


def test_a_task_scenes_own_joints_and_bodies_are_not_the_robots():
    """A task's scene (here a key on a hinge, named like an arm part) keeps its joint and its mass."""

    def scene(spec: mujoco.MjSpec) -> None:
        key = spec.worldbody.add_body(name="left_key", pos=[0.4, 0.1, 0.2])
        key.add_joint(name="left_key_hinge", type=mujoco.mjtJoint.mjJNT_HINGE, frictionloss=0.05)
        key.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.01, 0.01, 0.01], mass=0.02)

    m = load_model("arms", perturbed_scene(parse_perturbation("friction_nm=1.0,mass_scale=2"), scene))
    assert m.dof_frictionloss[m.joint("left_key_hinge").dofadr[0]] == 0.05
    assert m.body("left_key").mass[0] == pytest.approx(0.02, abs=1e-15)
    assert m.dof_frictionloss[m.joint("left_elbow_pitch").dofadr[0]] == pytest.approx(
        ARMS.frictionloss[ARMS.index("left_elbow_pitch")] + 1.0, abs=1e-15
    )
