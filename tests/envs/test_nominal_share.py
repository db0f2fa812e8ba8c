"""The nominal robot inside the robust training distribution, and evaluated on.

``randomization.nominal_share``: a share of env slots is drawn as a nominal robot (friction and link
mass in the default ranges, by the same uniform draw mapped onto them; no added damping, armature scale 1,
no payload); the other slots are drawn as before. ``evaluate_nominal``: the trainer's evaluation env is the
task on its nominal config. Model-level draws on the bare robot (no step compiled).
"""

from __future__ import annotations

from dataclasses import replace

import jax
import numpy as np
from mujoco import mjx

from bar_policy import envs
from bar_policy.envs.randomize import make_randomizer, payload_scene
from bar_policy.envs.robot_config import ModelRandomizationConfig, RobotEnvConfig, nominal
from bar_policy.robot.scene import load_model

ROBUST = ModelRandomizationConfig(
    frictionloss=(0.05, 1.35),
    link_mass_scale=(0.8, 1.2),
    damping=(0.0, 1.0),
    armature_scale=(0.8, 1.2),
    payload_kg=(0.0, 0.6),
)
B = 64


def _draw(rc: ModelRandomizationConfig):
    m = load_model("arms", payload_scene())
    model = mjx.put_model(m)
    batched, _ = make_randomizer(RobotEnvConfig(randomization=rc))(
        model, jax.random.split(jax.random.PRNGKey(5), B)
    )
    return m, batched


def test_every_slot_nominal_maps_the_same_draws_onto_the_default_ranges():
    m, wide = _draw(ROBUST)
    _, nom = _draw(replace(ROBUST, nominal_share=1.0))
    # Friction: 0.05 + (f - 0.05) * 0.3 / 1.3, the same uniform in (0.05, 0.35); float32 sums below 1.4.
    f = np.asarray(wide.dof_frictionloss)
    np.testing.assert_allclose(np.asarray(nom.dof_frictionloss), 0.05 + (f - 0.05) * (0.3 / 1.3), atol=3e-7)
    assert np.asarray(nom.dof_frictionloss).max() <= 0.35 + 1e-6
    # Link mass: x(0.9 + (s - 0.8) * 0.2 / 0.4) of the description's mass (the payload bodies: mass 0).
    s_wide = np.asarray(wide.body_mass) / np.where(m.body_mass > 0, m.body_mass, 1.0)
    s_nom = np.asarray(nom.body_mass) / np.where(m.body_mass > 0, m.body_mass, 1.0)
    real = m.body_mass > 0
    np.testing.assert_allclose(s_nom[:, real], 0.9 + (s_wide[:, real] - 0.8) * 0.5, atol=1e-6)
    # No added damping (the description's), armature scale 1 (the description-identified draw), no payload.
    np.testing.assert_array_equal(np.asarray(nom.dof_damping), np.broadcast_to(m.dof_damping, (B, m.nv)))
    _, arm_only = _draw(ModelRandomizationConfig(frictionloss=None, link_mass_scale=None))
    np.testing.assert_array_equal(np.asarray(nom.dof_armature), np.asarray(arm_only.dof_armature))
    ids = [m.body("left_hand_payload").id, m.body("right_hand_payload").id]
    np.testing.assert_array_equal(np.asarray(nom.body_mass)[:, ids], 0.0)


def test_a_share_of_slots_is_nominal_the_others_unchanged():
    _, wide = _draw(ROBUST)
    _, half = _draw(replace(ROBUST, nominal_share=0.5))
    f_wide, f_half = np.asarray(wide.dof_frictionloss), np.asarray(half.dof_frictionloss)
    same = np.all(f_wide == f_half, axis=1)
    mapped = np.all(np.isclose(f_half, 0.05 + (f_wide - 0.05) * (0.3 / 1.3), atol=3e-7, rtol=0), axis=1)
    assert np.all(same ^ mapped)  # every slot one or the other
    # Binomial(64, 0.5): mean 32, sd 4; within 4 sd.
    assert 16 <= int(mapped.sum()) <= 48


def test_evaluate_nominal_gives_the_nominal_task():
    cfg = envs.apply_overrides(envs.default_config("LiteReach"), ["evaluate_nominal=true"])
    env = envs.load("LiteReach", config=cfg)
    ev = env.evaluation_env()
    assert ev is not env and type(ev) is type(env)
    assert ev.config == nominal(cfg)
    assert ev.obs_manager.fingerprint == env.obs_manager.fingerprint
    plain = envs.load("LiteReach")
    assert plain.evaluation_env() is plain
