"""The robustness randomisation (payload, damping, armature scale, strength, observation latency).

Each draw must change exactly the model field it names, inside its range; the defaults must change nothing
(today's presets randomise bit for bit as before); the payload must be the body the deploy side's
perturbation builds in C MuJoCo (``robot.perturb.apply_to_spec``); strength must scale the MJX law's torque
and its cap. Model-level tests use the robot's bare MJX model (no env: no step compile); batches are tiny.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from bar_policy.envs.actuator import ActuatorParams, motor_torque
from bar_policy.envs.randomize import make_randomizer, payload_scene
from bar_policy.envs.robot_config import ActuatorConfig, ModelRandomizationConfig, RobotEnvConfig
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand
from bar_policy.robot.perturb import HAND_BODIES, PAYLOAD_POS, apply_to_spec, payload_body_name
from bar_policy.robot.perturb_spec import parse_perturbation
from bar_policy.robot.scene import load_model, robot_spec

B = 16
"""Env slots per draw: enough to see a range's spread, small for a shared CPU."""

OFF = ModelRandomizationConfig(armature=False, frictionloss=None, link_mass_scale=None)
"""Every model draw off: each test turns on one."""


@pytest.fixture(scope="module")
def bare():
    """The robot alone: (C model, MJX model)."""
    m = load_model("arms")
    return m, mjx.put_model(m)


@pytest.fixture(scope="module")
def with_payload():
    """The robot with the training scene's massless payload bodies: (C model, MJX model)."""
    m = load_model("arms", payload_scene())
    return m, mjx.put_model(m)


def draw(model: mjx.Model, rc: ModelRandomizationConfig, seed: int = 0):
    """(batched model, in_axes) of ``B`` slots."""
    rand = make_randomizer(RobotEnvConfig(randomization=rc))
    return rand(model, jax.random.split(jax.random.PRNGKey(seed), B))


def randomised_fields(in_axes) -> set[str]:
    """The array fields ``in_axes`` maps with 0 (the randomised ones; static ints and flags are skipped)."""
    return {
        k for k, v in vars(in_axes).items() if type(v) is int and v == 0 and not k.startswith(("n", "flg"))
    }


def test_new_fields_default_off():
    rc, act = ModelRandomizationConfig(), ActuatorConfig()
    assert (rc.damping, rc.armature_scale, rc.payload_kg, rc.payload_at) == (None, None, None, "fingertip")
    assert act.strength == (1.0, 1.0) and act.obs_latency_steps == (0, 0)


def test_defaults_randomise_as_before(bare):
    # The default config draws armature, friction and link mass only, from the same keys as before: the
    # values are those of the pre-existing recipe, recomputed here with the split(key, 3) it documents.
    _, model = bare
    batched, in_axes = draw(model, ModelRandomizationConfig())
    assert randomised_fields(in_axes) == {"dof_armature", "dof_frictionloss", "body_mass", "body_inertia"}
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    for b in (0, B - 1):
        _, k_fric, k_mass = jax.random.split(keys[b], 3)
        fric = jax.random.uniform(k_fric, (14,), minval=0.05, maxval=0.35)
        s = jax.random.uniform(k_mass, model.body_mass.shape, minval=0.9, maxval=1.1)
        np.testing.assert_array_equal(np.asarray(batched.dof_frictionloss[b]), np.asarray(fric))
        np.testing.assert_array_equal(np.asarray(batched.body_mass[b]), np.asarray(model.body_mass * s))


def test_default_scene_has_no_payload_body(bare, with_payload):
    m, _ = bare
    mp, _ = with_payload
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)]
    assert not any(n.endswith("_payload") for n in names)
    assert mp.nbody == m.nbody + 2 and (mp.nq, mp.nv) == (m.nq, m.nv)


def test_massless_payload_body_changes_no_dynamics(bare, with_payload):
    # A massless welded body adds nothing to its parent's composite inertia: the same state gives the same
    # bias forces and accelerations in C MuJoCo (float64; 1e-12 is rounding of sums in another order).
    (m, _), (mp, _) = bare, with_payload
    d, dp = mujoco.MjData(m), mujoco.MjData(mp)
    q = load_robot("arms").pose("piano_ready")
    d.qpos[:], dp.qpos[:] = q, q
    d.qvel[:] = dp.qvel[:] = 0.3
    mujoco.mj_forward(m, d)
    mujoco.mj_forward(mp, dp)
    np.testing.assert_allclose(dp.qfrc_bias, d.qfrc_bias, atol=1e-12)
    np.testing.assert_allclose(dp.qacc, d.qacc, atol=1e-10)  # accelerations of up to ~1e2 rad/s^2


def test_damping_adds_to_the_mjcf_damping_only(bare):
    m, model = bare
    batched, in_axes = draw(model, replace(OFF, damping=(0.2, 1.0)))
    assert randomised_fields(in_axes) == {"dof_damping"}
    added = np.asarray(batched.dof_damping) - m.dof_damping[None]
    assert added.shape == (B, 14)
    assert added.min() >= 0.2 - 1e-6 and added.max() <= 1.0 + 1e-6  # float32 of values <= 1: 1e-6
    assert added.std() > 0.1  # U(0.2, 1.0) has std 0.23: drawn, not a constant


def test_armature_scale_multiplies_the_armature(bare):
    m, model = bare
    batched, in_axes = draw(model, replace(OFF, armature_scale=(0.5, 2.0)))
    assert randomised_fields(in_axes) == {"dof_armature"}
    r = np.asarray(batched.dof_armature) / m.dof_armature[None]
    assert r.min() >= 0.5 - 1e-5 and r.max() <= 2.0 + 1e-5
    # On top of the description->identified draw: the product of the two, same keys for the first.
    both, _ = draw(model, replace(OFF, armature=True, armature_scale=(0.5, 2.0)))
    alone, _ = draw(model, replace(OFF, armature=True))
    np.testing.assert_allclose(np.asarray(both.dof_armature), np.asarray(alone.dof_armature) * r, rtol=1e-6)


def test_payload_mass_is_the_drawn_value(with_payload):
    m, model = with_payload
    batched, in_axes = draw(model, replace(OFF, payload_kg=(0.0, 0.6)))
    assert randomised_fields(in_axes) == {"body_mass", "body_inertia"}
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h)) for h in HAND_BODIES]
    mass = np.asarray(batched.body_mass)
    pay = mass[:, ids]
    assert pay.min() >= 0.0 and pay.max() <= 0.6 + 1e-6 and pay.std() > 0.05  # U(0, 0.6): std 0.17
    assert not np.allclose(pay[:, 0], pay[:, 1])  # one draw per hand
    # The drawn value: U(0, 0.6) from the documented key (fold_in of the optional key, third of four).
    keys = jax.random.split(jax.random.PRNGKey(0), B)
    k_pay = jax.random.split(jax.random.fold_in(keys[3], 0x524F42), 4)[2]
    np.testing.assert_array_equal(pay[3], np.asarray(jax.random.uniform(k_pay, (2,), maxval=0.6)))
    # Every other body keeps its mass; the inertia is a 1 cm solid sphere's: 2/5 m (0.01 m)^2.
    others = np.setdiff1d(np.arange(m.nbody), ids)
    np.testing.assert_array_equal(
        mass[:, others], np.broadcast_to(m.body_mass[others].astype(np.float32), (B, len(others)))
    )
    inertia = np.asarray(batched.body_inertia)[:, ids]
    np.testing.assert_allclose(inertia, np.repeat(0.4 * pay[..., None] * 1e-4, 3, axis=-1), rtol=1e-6)


@pytest.mark.parametrize("at", ["fingertip", "palm"])
def test_payload_matches_the_deploy_perturbation(with_payload, at):
    # The C model the deploy side's ``payload_kg=0.5,payload_at=AT`` builds has, at the payload bodies,
    # the mass, inertia and position this randomiser writes for a draw of 0.5 kg at AT.
    m, model = with_payload
    batched, _ = draw(model, replace(OFF, payload_kg=(0.5, 0.5), payload_at=at))
    spec = robot_spec("arms")
    apply_to_spec(spec, parse_perturbation(f"payload_kg=0.5,payload_at={at}"))
    ref = spec.compile()
    for h in HAND_BODIES:
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h))
        j = mujoco.mj_name2id(ref, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h))
        np.testing.assert_allclose(np.asarray(batched.body_mass)[:, i], ref.body_mass[j], rtol=1e-6)
        inertia = np.asarray(batched.body_inertia)[:, i]
        np.testing.assert_allclose(inertia, np.broadcast_to(ref.body_inertia[j], inertia.shape), rtol=1e-6)
        pos = np.asarray(batched.body_pos)[:, i] if at == "palm" else np.asarray(model.body_pos)[i][None]
        np.testing.assert_allclose(pos, np.broadcast_to(ref.body_pos[j], pos.shape), atol=1e-7)
        np.testing.assert_allclose(ref.body_pos[j], PAYLOAD_POS[at][h], atol=1e-12)


def test_payload_either_site(with_payload):
    m, model = with_payload
    batched, in_axes = draw(model, replace(OFF, payload_kg=(0.1, 0.2), payload_at="either"))
    assert randomised_fields(in_axes) == {"body_mass", "body_inertia", "body_pos"}
    for k, h in enumerate(HAND_BODIES):
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h))
        pos = np.asarray(batched.body_pos)[:, i]
        tip = np.all(np.abs(pos - PAYLOAD_POS["fingertip"][h]) < 1e-7, axis=1)
        palm = np.all(np.abs(pos - PAYLOAD_POS["palm"][h]) < 1e-7, axis=1)
        assert np.all(tip | palm) and tip.any() and palm.any(), (k, tip, palm)
    # Only the payload bodies move.
    body_pos = np.asarray(batched.body_pos)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h)) for h in HAND_BODIES]
    others = np.setdiff1d(np.arange(m.nbody), ids)
    np.testing.assert_array_equal(
        body_pos[:, others], np.broadcast_to(np.asarray(model.body_pos)[others], (B, len(others), 3))
    )


def test_payload_without_its_bodies_is_refused(bare):
    _, model = bare
    with pytest.raises(ValueError, match="payload bodies"):
        draw(model, replace(OFF, payload_kg=(0.0, 0.6)))


def test_strength_scales_the_torque_and_its_cap():
    # No quantisation, measured q = 0, dq = 0.5 rad/s, Kp 50, Kd 2 on every joint:
    # q_cmd 0.07 rad: law = 50 * 0.07 - 2 * 0.5 = 2.5 N*m, under every cap (4, 14, 17 N*m): 0.8 * 2.5 = 2.0.
    robot = load_robot("arms")
    params = ActuatorParams.from_robot(robot, quantize_wire=False, torque_saturation=True)
    n = robot.num_joints
    z = np.zeros(n, np.float32)
    full = lambda x: np.full(n, x, np.float32)  # noqa: E731
    cmd = MitCommand(q=full(0.07), dq=z, kp=full(50.0), kd=full(2.0), tau_ff=z)
    dq, s = full(0.5), full(0.8)
    # float32: 0.07 is off by 1e-9 relative, the products by a few ulps: rtol 1e-6.
    np.testing.assert_allclose(np.asarray(motor_torque(cmd, z, dq, params, s)), 2.0, rtol=1e-6)
    # q_cmd 1 rad: law = 50 - 1 = 49 N*m, above every cap: the joint gets 0.8 * cap (3.2, 11.2, 13.6 N*m).
    big = cmd._replace(q=full(1.0))
    cap = robot.torque_cap
    assert np.all(cap < 49.0)
    np.testing.assert_allclose(np.asarray(motor_torque(big, z, dq, params, s)), 0.8 * cap, rtol=1e-6)
    # None is the unscaled law, bit for bit, at the cap.
    plain = np.asarray(motor_torque(big, z, dq, params))
    np.testing.assert_array_equal(np.asarray(motor_torque(big, z, dq, params, None)), plain)
    np.testing.assert_allclose(plain, cap, rtol=1e-6)


def test_config_errors():
    with pytest.raises(ValueError, match="payload_at"):
        ModelRandomizationConfig(payload_at="wrist")
    with pytest.raises(ValueError, match="damping"):
        ModelRandomizationConfig(damping=(1.0, 0.5))
    with pytest.raises(ValueError, match="strength"):
        ActuatorConfig(strength=(0.0, 1.0))
    with pytest.raises(ValueError, match="obs_latency_steps"):
        ActuatorConfig(obs_latency_steps=(0, 11))


@pytest.mark.parametrize(("name", "env_name"), [("reach-robust", "LiteReach"), ("track-robust", "LiteTrack"),
                                                ("piano-robust", "LitePiano")])  # fmt: skip
def test_robust_presets_turn_the_randomisation_on(name, env_name):
    from bar_policy import envs
    from bar_policy.tasks.robust_preset import ROBUST_ENV_OVERRIDES
    from bar_policy.training.config import preset

    cfg = preset(name)
    base = preset(name.replace("-robust", "") if name != "reach-robust" else "gpu")
    # The base preset's own overrides first, then the robust ones; nothing else differs.
    assert cfg.env_overrides == (*base.env_overrides, *ROBUST_ENV_OVERRIDES)
    assert replace(cfg, preset=base.preset, env_overrides=base.env_overrides) == base
    env_cfg = envs.apply_overrides(envs.default_config(env_name), cfg.env_overrides)
    rc, act = env_cfg.randomization, env_cfg.actuator
    assert (rc.link_mass_scale, rc.frictionloss, rc.damping) == ((0.8, 1.2), (0.05, 1.35), (0.0, 1.0))
    assert (rc.armature_scale, rc.payload_kg, rc.payload_at) == ((0.8, 1.2), (0.0, 0.6), "either")
    assert (act.strength, act.latency_steps, act.obs_latency_steps) == ((0.8, 1.0), (0, 2), (0, 1))
    assert act.encoder_offset == 0.01 and rc.armature
    # nominal() of it turns every one off again.
    nom = envs.nominal_config(env_cfg)
    assert nom.randomization == ModelRandomizationConfig(
        armature=False, frictionloss=None, link_mass_scale=None
    )
    assert nom.actuator.strength == (1.0, 1.0) and nom.actuator.obs_latency_steps == (0, 0)
