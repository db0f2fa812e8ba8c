"""The robustness randomisation (payload, damping, armature scale, strength, observation latency, the
per-factor share).

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
from bar_policy.envs.randomize import episode_draws, latency_buffers, make_randomizer, payload_scene
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


@pytest.mark.parametrize(
    ("name", "env_name"),
    [("reach-robust", "LiteReach"), ("track-robust", "LiteTrack"), ("piano-robust", "LitePiano")],
)
def test_robust_presets_turn_the_randomisation_on(name, env_name):
    from bar_policy import envs
    from bar_policy.tasks.robust_preset import ROBUST_ENV_OVERRIDES
    from bar_policy.training.config import preset

    cfg = preset(name)
    base = preset(name.replace("-robust", "") if name != "reach-robust" else "gpu")
    # The base preset's own overrides first, then the robust ones, then the task's own; nothing else.
    extra = {
        "reach-robust": (
            "reward.scales.torque_near_cap=-1.0",
            "reward.scales.wrist_posture=-0.5",
            "joint_error_ema=true",
        ),
        "track-robust": (
            "joint_error_ema=true",
            "randomization.factor_share=0.5",
            "reward.scales.torque_near_cap=-1.0",
            "terminate_on_cap_fault=true",
        ),
        "piano-robust": ("joint_error_ema=true", "terminate_on_cap_fault=true"),
    }.get(name, ())
    assert cfg.env_overrides == (*base.env_overrides, *ROBUST_ENV_OVERRIDES, *extra)
    # The tracker's robust stage resumes a nominal run at a third of its learning rate (3e-4 -> 1e-4).
    rate = {"track-robust": 1e-4}.get(name, base.ppo.learning_rate)
    assert cfg.ppo.learning_rate == rate
    same = replace(cfg, preset=base.preset, env_overrides=base.env_overrides, ppo=base.ppo)
    assert same == base and replace(cfg.ppo, learning_rate=base.ppo.learning_rate) == base.ppo
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


# ``factor_share``: each robust factor on per slot (model) or episode (actuator) with that probability.

ROBUST = ModelRandomizationConfig(
    frictionloss=(0.05, 1.35),
    link_mass_scale=(0.8, 1.2),
    damping=(0.0, 1.0),
    armature_scale=(0.8, 1.2),
    payload_kg=(0.0, 0.6),
    payload_at="either",
)
"""The robust preset's model ranges (``tasks/robust_preset.py``)."""
FIELDS = ("dof_frictionloss", "body_mass", "body_inertia", "dof_damping", "dof_armature", "body_pos")
"""Every model field the robust ranges write."""
N_SHARE = 400
"""Slots (and episodes) of the share statistics: 4 binomial sigmas are 0.1 at p = 0.5."""
OPTIONAL_KEY = 0x524F42
"""The optional draws' key constant, as documented (``randomize``, ``envs.robot``)."""


@pytest.fixture(scope="module")
def shares(with_payload):
    """The robust ranges drawn on the same ``N_SHARE`` slot keys under each share: name -> field -> array."""
    _, model = with_payload
    keys = jax.random.split(jax.random.PRNGKey(7), N_SHARE)

    def fields(rc: ModelRandomizationConfig) -> dict[str, np.ndarray]:
        batched, _ = make_randomizer(RobotEnvConfig(randomization=rc))(model, keys)
        return {f: np.asarray(getattr(batched, f)) for f in FIELDS}

    return {
        "wide": fields(ROBUST),
        "nominal": fields(replace(ROBUST, nominal_share=1.0)),
        "none": fields(replace(ROBUST, factor_share=0.0)),
        "half": fields(replace(ROBUST, factor_share=0.5)),
    }


def test_factor_share_one_draws_as_without_it(with_payload, shares):
    m, model = with_payload
    explicit, _ = draw(model, replace(ROBUST, factor_share=1.0))
    plain, _ = draw(model, ROBUST)
    for f in FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(explicit, f)), np.asarray(getattr(plain, f)), f)
    # The draws are the documented recipe's, from the keys it documents (no draw taken from them).
    keys = jax.random.split(jax.random.PRNGKey(7), N_SHARE)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h)) for h in HAND_BODIES]
    wide = shares["wide"]
    for b in (0, 123, N_SHARE - 1):
        _, k_fric, _ = jax.random.split(keys[b], 3)
        k_damp, _, k_pay, _ = jax.random.split(jax.random.fold_in(keys[b], OPTIONAL_KEY), 4)
        fric = jax.random.uniform(k_fric, (14,), minval=0.05, maxval=1.35)
        damp = m.dof_damping.astype(np.float32) + np.asarray(jax.random.uniform(k_damp, (14,), maxval=1.0))
        pay = jax.random.uniform(k_pay, (2,), maxval=0.6)
        np.testing.assert_array_equal(wide["dof_frictionloss"][b], np.asarray(fric))
        np.testing.assert_array_equal(wide["dof_damping"][b], damp)
        np.testing.assert_array_equal(wide["body_mass"][b, ids], np.asarray(pay))


def test_factor_share_zero_is_the_nominal_slot(with_payload, shares):
    m, model = with_payload
    for f in FIELDS:
        np.testing.assert_array_equal(shares["none"][f], shares["nominal"][f], f)
    # The comparison has content: the nominal slot has no added damping and no payload, the wide one has.
    nom, wide = shares["nominal"], shares["wide"]
    np.testing.assert_array_equal(nom["dof_damping"], np.broadcast_to(m.dof_damping, (N_SHARE, m.nv)))
    assert np.all(wide["dof_damping"] > m.dof_damping)
    assert nom["dof_frictionloss"].max() <= 0.35 + 1e-6 < wide["dof_frictionloss"].max()
    # A nominal slot stays nominal in every factor, whatever the share.
    both, _ = draw(model, replace(ROBUST, nominal_share=1.0, factor_share=0.5))
    only, _ = draw(model, replace(ROBUST, nominal_share=1.0))
    for f in FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(both, f)), np.asarray(getattr(only, f)), f)


def test_factor_share_half_turns_each_factor_on_independently(with_payload, shares):
    m, _ = with_payload
    half, wide, nom = shares["half"], shares["wide"], shares["nominal"]
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, payload_body_name(h)) for h in HAND_BODIES]
    links = np.setdiff1d(np.arange(m.nbody), ids)

    def on(field: str, cols=slice(None)) -> np.ndarray:
        """Per slot: the factor's whole draw is the wide one (True) or the nominal one (False), no mix."""
        h, w, n = half[field][:, cols], wide[field][:, cols], nom[field][:, cols]
        is_wide, is_nom = np.all(h == w, axis=1), np.all(h == n, axis=1)
        assert not np.any(np.all(w == n, axis=1)), field  # the two differ in every slot
        assert np.all(is_wide ^ is_nom), field
        return is_wide

    damping = on("dof_damping")
    payload = on("body_mass", ids)
    # The brief's reading: the slot's damping addition is nonzero; the payload mass is nonzero.
    np.testing.assert_array_equal(damping, np.any(half["dof_damping"] != m.dof_damping, axis=1))
    np.testing.assert_array_equal(payload, np.any(half["body_mass"][:, ids] > 0, axis=1))
    factors = np.stack(
        [on("dof_frictionloss"), on("body_mass", links), damping, on("dof_armature"), payload], axis=1
    )
    # Binomial(400, p) fractions: sd sqrt(p (1 - p) / 400); tolerance 4 sd. p = 0.5: 4 * 0.025 = 0.1.
    for k in range(5):
        assert abs(factors[:, k].mean() - 0.5) <= 0.1, (k, factors[:, k].mean())
    # Independent factors: both on with p = 0.25, 4 * sqrt(0.25 * 0.75 / 400) = 0.087.
    assert abs((damping & payload).mean() - 0.25) <= 0.087, (damping & payload).mean()
    # Factors on per slot: mean 5 * 0.5 = 2.5, sd of the mean sqrt(5 * 0.25 / 400) = 0.056; 4 sd = 0.224.
    assert abs(factors.sum(axis=1).mean() - 2.5) <= 0.224


def test_factor_share_is_validated():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"factor_share must be in \[0, 1\], got"):
            ModelRandomizationConfig(factor_share=bad)
    with pytest.raises(ValueError, match=r"got 1\.5$"):
        ModelRandomizationConfig(factor_share=1.5)
    assert ModelRandomizationConfig().factor_share == 1.0
    ModelRandomizationConfig(factor_share=0.0)


WIDE_ACT = ActuatorConfig(
    strength=(0.8, 1.0), latency_steps=(1, 4), obs_latency_steps=(0, 1), encoder_offset=0.03
)
"""Every episode factor's range other than the default's (latency and offset too, so that off differs)."""


def _episodes(act: ActuatorConfig, share: float, n: int = 64, strength=None) -> dict[str, np.ndarray]:
    """``episode_draws`` of ``n`` episodes' reset keys (``split(key, 8)`` each, as ``reset``)."""
    ks = jax.vmap(lambda k: jax.random.split(k, 8))(jax.random.split(jax.random.PRNGKey(11), n))
    out = jax.vmap(lambda k: episode_draws(act, share, k, 14, strength))(ks)
    return {k: np.asarray(v) for k, v in out.items()} | {"ks": ks}


def test_episode_factor_share_one_draws_as_before():
    d = _episodes(WIDE_ACT, 1.0)
    assert set(d) == {"latency", "encoder_offset", "strength", "obs_latency", "ks"}
    assert set(_episodes(ActuatorConfig(), 1.0)) == {"latency", "encoder_offset", "ks"}
    assert latency_buffers(WIDE_ACT, 1.0) == (4, 1) and latency_buffers(ActuatorConfig(), 1.0) == (2, 0)
    # The recipe the env documents: key 2 latency, key 5 offset, fold_in(key 3) strength, fold_in(key 2)
    # observation latency.
    for b in (0, 63):
        ks = d["ks"][b]
        assert d["latency"][b] == jax.random.randint(ks[2], (), 1, 5)
        np.testing.assert_array_equal(
            d["encoder_offset"][b], np.asarray(jax.random.uniform(ks[5], (14,), minval=-0.03, maxval=0.03))
        )
        k_s, k_o = jax.random.fold_in(ks[3], OPTIONAL_KEY), jax.random.fold_in(ks[2], OPTIONAL_KEY)
        np.testing.assert_array_equal(
            d["strength"][b], np.asarray(jax.random.uniform(k_s, (14,), minval=0.8, maxval=1.0))
        )
        assert d["obs_latency"][b] == jax.random.randint(k_o, (), 0, 2)


def test_episode_factor_share_zero_draws_the_default_actuator():
    off, default = _episodes(WIDE_ACT, 0.0), _episodes(ActuatorConfig(), 1.0)
    np.testing.assert_array_equal(off["latency"], default["latency"])  # U{0, 1, 2}, key 2
    np.testing.assert_array_equal(off["encoder_offset"], default["encoder_offset"])  # U(-0.01, 0.01), key 5
    np.testing.assert_array_equal(off["strength"], 1.0)
    np.testing.assert_array_equal(off["obs_latency"], 0)
    assert set(np.unique(off["latency"])) == {0, 1, 2} and np.abs(off["encoder_offset"]).max() <= 0.01
    # Room for the default's latency when the config's range is shorter; a file's strengths stay.
    assert latency_buffers(replace(WIDE_ACT, latency_steps=(0, 1)), 0.5) == (2, 1)
    identified = np.linspace(0.9, 1.0, 14, dtype=np.float32)
    np.testing.assert_array_equal(
        _episodes(WIDE_ACT, 0.0, 4, identified)["strength"], np.tile(identified, (4, 1))
    )


def test_episode_factor_share_half():
    half, wide = _episodes(WIDE_ACT, 0.5, N_SHARE), _episodes(WIDE_ACT, 1.0, N_SHARE)
    strength = np.all(half["strength"] != 1.0, axis=1)  # U(0.8, 1.0) never gives 1
    assert np.all(strength == np.all(half["strength"] == wide["strength"], axis=1))
    offset = np.all(half["encoder_offset"] == wide["encoder_offset"], axis=1)
    # 4 binomial sd, as for the model factors: 0.1 at p = 0.5, 0.087 at p = 0.25.
    assert abs(strength.mean() - 0.5) <= 0.1 and abs(offset.mean() - 0.5) <= 0.1
    assert abs((strength & offset).mean() - 0.25) <= 0.087
