"""The modelled hand-load compensation (``randomization.payload_ff_share``, ``envs.payload_ff``).

The feed-forward must be what C MuJoCo says the payload adds to the gravity torque (``qfrc_bias`` at rest,
float64), scaled by the share; the env must put it into the command's ``tau_ff`` and then hold a loaded
arm where an unloaded one stands; the config must refuse a share without a payload. The function tests
compile one small program per scene; the env test compiles two reach steps (tens of seconds on the CPU).
"""

from __future__ import annotations

import functools
from dataclasses import replace

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from scene_support import key_scene

from bar_policy import envs
from bar_policy.envs.payload_ff import payload_feed_forward
from bar_policy.envs.randomize import payload_body_ids, payload_scene
from bar_policy.envs.robot_config import ModelRandomizationConfig, RobotEnvConfig
from bar_policy.overrides import apply_overrides
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import load_model

MASS = 0.5
"""Payload per hand, kg (the deploy suite's fingertip load)."""

TOL = 1e-4
"""N*m. The feed-forward is float32: the hand's position comes from ~7 chained rigid transforms (a few
dozen float32 ops, each 6e-8 relative on coordinates below 1 m: ~3e-6 m), and the torque is m g (0.5 kg *
9.81 = 4.9 N) times a lever arm of that accuracy plus the Jacobian's own rounding (|tau| <= ~2 N*m here,
~30 ops at 1.2e-7 relative: ~1e-5 N*m). 1e-4 N*m is a few times that sum; measured 3.5e-7 N*m."""


def _pose() -> np.ndarray:
    """A pose away from every symmetry: piano_ready plus a different offset per joint, rad (n,)."""
    robot = load_robot("arms")
    return robot.pose("piano_ready") + np.linspace(-0.3, 0.3, robot.num_joints)


def _bias(scene, masses: tuple[float, float], q: np.ndarray) -> tuple[np.ndarray, RobotIndex]:
    """C MuJoCo (float64) ``qfrc_bias`` at rest at robot pose ``q`` with ``masses`` (kg) on the payloads.

    Returns the bias at the robot's dofs, N*m (n,), and the scene's robot index.
    """
    m = load_model("arms", scene)
    ids = payload_body_ids(m, "payload_ff_share")
    m.body_mass[ids] = masses
    index = RobotIndex.from_model(m, load_robot("arms").joint_names)
    d = mujoco.MjData(m)
    d.qpos[index.qpos] = q
    mujoco.mj_forward(m, d)  # qvel = 0: qfrc_bias is the gravity torque alone
    return d.qfrc_bias[index.dof], index


@pytest.fixture(scope="module", params=["robot", "key_scene"])
def scene(request):
    """(scene edit, jitted ``(masses, share) -> feed-forward`` at ``_pose()``, robot index).

    ``robot``: the robot and its payload bodies (dofs = the robot's); ``key_scene``: with a key and a
    pendulum hung from the left hand, whose dof sits between the arms' (the feed-forward is gathered).
    """
    scene = payload_scene(key_scene if request.param == "key_scene" else None)
    m = load_model("arms", scene)
    ids = payload_body_ids(m, "payload_ff_share")
    index = RobotIndex.from_model(m, load_robot("arms").joint_names)
    assert index.robot_only == (request.param == "robot")
    model = mjx.put_model(m)
    qpos = np.array(m.qpos0, dtype=np.float32)
    qpos[index.qpos] = _pose()
    data = mjx.put_data(m, mujoco.MjData(m)).replace(qpos=jnp.asarray(qpos))
    dof = None if index.robot_only else index.dof

    @jax.jit
    def ff(masses: jax.Array, share: jax.Array) -> jax.Array:
        mdl = model.replace(body_mass=model.body_mass.at[ids].set(masses))
        return payload_feed_forward(mdl, data, ids, share, dof)

    return scene, ff, index


@pytest.mark.numerics
def test_full_share_is_c_mujocos_gravity_difference(scene):
    edit, ff, _ = scene
    q = _pose()
    loaded, _ = _bias(edit, (MASS, MASS), q)
    empty, _ = _bias(edit, (0.0, 0.0), q)
    expected = loaded - empty
    assert np.abs(expected).max() > 0.5  # a real load: N*m at the shoulders
    out = np.asarray(ff(jnp.full(2, MASS), jnp.ones(2)))
    assert out.dtype == np.float32 and out.shape == (14,)
    np.testing.assert_allclose(out, expected, rtol=0, atol=TOL)
    # Half the share, half the torque (the same rounding, halved: tolerance TOL / 2 + the halving's).
    half = np.asarray(ff(jnp.full(2, MASS), jnp.full(2, 0.5)))
    np.testing.assert_allclose(half, expected / 2, rtol=0, atol=TOL)


@pytest.mark.numerics
def test_share_is_per_hand(scene):
    # Share (1, 0): the left payload's torque alone, which C MuJoCo gives with the left mass alone; the
    # right arm's joints get none (no chain from them to the left hand).
    edit, ff, _ = scene
    q = _pose()
    left, _ = _bias(edit, (MASS, 0.0), q)
    empty, _ = _bias(edit, (0.0, 0.0), q)
    out = np.asarray(ff(jnp.full(2, MASS), jnp.array([1.0, 0.0])))
    np.testing.assert_allclose(out, left - empty, rtol=0, atol=TOL)
    assert np.all(out[7:] == 0.0) and np.abs(out[:7]).max() > 0.5


@pytest.mark.numerics
def test_no_payload_feeds_nothing(scene):
    # Mass 0 (a slot or an episode without the payload factor): exactly 0, whatever the share.
    _, ff, _ = scene
    np.testing.assert_array_equal(np.asarray(ff(jnp.zeros(2), jnp.ones(2))), 0.0)


def test_config_validation():
    with pytest.raises(ValueError, match=r"payload_ff_share.*payload_kg"):
        ModelRandomizationConfig(payload_ff_share=(0.5, 1.0))
    with pytest.raises(ValueError, match="payload_ff_share"):
        ModelRandomizationConfig(payload_kg=(0.0, 0.6), payload_ff_share=(-0.1, 1.0))
    with pytest.raises(ValueError, match="payload_ff_share"):
        ModelRandomizationConfig(payload_kg=(0.0, 0.6), payload_ff_share=(1.0, 0.5))
    assert ModelRandomizationConfig().payload_ff_share is None


def test_override_sets_the_field():
    cfg = apply_overrides(
        RobotEnvConfig(), ["randomization.payload_kg=0.0,0.6", "randomization.payload_ff_share=0.5,1.0"]
    )
    assert cfg.randomization.payload_ff_share == (0.5, 1.0)
    with pytest.raises(ValueError, match="payload_kg"):
        apply_overrides(RobotEnvConfig(), ["randomization.payload_ff_share=0.5,1.0"])


STEPS = 25
"""Control steps the arm holds its default pose, 0.5 s: the Kp 50 / Kd 2 law settles well inside it."""


def _reach(ff_share: tuple[float, float] | None):
    """Nominal LiteReach with the payload bodies (``payload_kg`` set), and the feed-forward share."""
    cfg = envs.nominal_config()
    rc = replace(cfg.randomization, payload_kg=(MASS, MASS), payload_ff_share=ff_share)
    return envs.load("LiteReach", config=replace(cfg, randomization=rc))


def _hold(env, masses: float) -> tuple[np.ndarray, object]:
    """The robot's q after ``STEPS`` steps of action 0 from the default pose, payload ``masses`` kg."""
    ids = payload_body_ids(env.mj_model, "payload_ff_share")
    model = env.mjx_model.replace(body_mass=env.mjx_model.body_mass.at[ids].set(masses))
    reset, step = _compiled(env)
    state = reset(model, jax.random.PRNGKey(0))
    first = state
    zero = jnp.zeros(env.action_size)
    for _ in range(STEPS):
        state = step(model, state, zero)
    return np.asarray(env.robot_q(state.data)), first


@functools.cache
def _compiled(env):
    return jax.jit(env.reset_with_model), jax.jit(env.step_with_model)


@pytest.mark.numerics
def test_compensated_arm_holds_its_pose():
    # Hand-worked expectation: at the default pose C MuJoCo's payload torque (test above's method) is 1.75
    # N*m at each shoulder pitch and 1.70 at each elbow, 0.5 kg * 9.81 m/s^2 on ~0.35 m of lever; with Kp
    # 50 N*m/rad the uncompensated arm sags by tau / Kp = 0.035 rad there, 0.0175 rad averaged over the 14
    # joints (measured 0.0141: the 0.1 N*m friction stops each moving joint up to 2 mrad short, which
    # matters most for the joints that sag 3.5 mrad). Full compensation cancels that torque up to its
    # one-step lag (the arm at rest: none), the 16-bit tau_ff (5e-4 N*m, 1e-5 rad) and the friction's
    # +-2 mrad band -- but the loaded and unloaded arms take the same path, so they stop alike. The
    # residual must be below 20 % of the sag: well under what the runtime's tare leaves (it reads 0.68 of
    # the load, 32 % left), so a broken or halved feed-forward fails. Measured: 0.3 mrad (2 %).
    plain, ffd = _reach(None), _reach((1.0, 1.0))
    q_empty, _ = _hold(plain, 0.0)
    q_sag, s_plain = _hold(plain, MASS)
    q_ff, s_ff = _hold(ffd, MASS)
    sag = np.abs(q_sag - q_empty).mean()
    residual = np.abs(q_ff - q_empty).mean()
    print(f"payload sag {sag:.4f} rad, with the feed-forward {residual:.5f} rad")
    assert 0.6 * 0.0175 < sag < 1.4 * 0.0175
    assert residual < 0.2 * sag

    # The None env's state carries nothing new; the compensated one's the share and the next tau_ff.
    assert not {"payload_ff", "payload_ff_share"} & set(s_plain.info)
    np.testing.assert_array_equal(np.asarray(s_ff.info["payload_ff_share"]), 1.0)
    # The reset's feed-forward is the command's tau_ff, through the 16-bit wire (one LSB of +-t_max over
    # 65535 steps: at most 2 * 17 / 65535 = 5.2e-4 N*m).
    _, _, cmd = ffd._command(s_ff.info, jnp.zeros(ffd.action_size))
    ff0 = np.asarray(s_ff.info["payload_ff"])
    assert np.abs(ff0).max() > 1.0
    np.testing.assert_allclose(np.asarray(cmd.tau_ff), ff0, rtol=0, atol=5.3e-4)
    _, _, cmd0 = plain._command(s_plain.info, jnp.zeros(plain.action_size))
    assert np.abs(np.asarray(cmd0.tau_ff)).max() < 5.3e-4  # 0 on the wire (its nearest code)
