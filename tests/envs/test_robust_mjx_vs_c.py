"""The robust reach env's physics in MJX against C MuJoCo, for one env slot's randomised model.

``bench/mjx_vs_c.py``'s pieces: the ``reach-robust`` env (sim_dt 4 ms, every robust draw on, no nominal
slot) steps 30 control steps of smooth open-loop actions on slot 0's model; C MuJoCo replays the commands
the env decoded on the same model (every randomised field copied) with the env's actuator (firmware law at
``q + offset``, ``strength``, implicit Kd). Checked:

- over the episode, MJX and C agree far inside what the draw itself does to the arm;
- one control step from the same state, MJX and C agree to float32 rounding and the solver's start
  (measured 1.1e-5 rad), while leaving out any one randomised field, the strengths or the offsets moves
  C by at least 50 times that (6e-4 rad and more): each reaches the MJX step;
- the link inertias (whose one-step effect is below that resolution) through the mass matrix MJX builds.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import jax
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from mujoco.mjx._src import support

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from mjx_vs_c import RANDOMISED, actions, c_replay, mjx_rollout, robust_env, slot_model

STEPS = 30


@pytest.fixture(scope="module")
def slot():
    """The env (every robust draw on, no nominal slot) and slot 0's randomised MJX model."""
    env = robust_env("reach-robust", ("randomization.nominal_share=0.0",))
    return env, slot_model(env, 0)


@pytest.fixture(scope="module")
def episode(slot):
    env, model = slot
    first, cols = mjx_rollout(env, model, 0, actions(STEPS, env.action_size, 0))
    info = {k: np.asarray(first.info[k], np.float64) for k in ("encoder_offset", "strength")}
    idx = env.robot_index
    start = (
        np.asarray(first.data.qpos, np.float64)[idx.qpos],
        np.asarray(first.data.qvel, np.float64)[idx.dof],
    )
    return env, model, info, start, cols


def _c_model(env, model, skip: str | None = None) -> mujoco.MjModel:
    m = copy.copy(env.mj_model)
    for f in RANDOMISED:
        if f != skip:
            getattr(m, f)[:] = np.asarray(getattr(model, f), np.float64).reshape(getattr(m, f).shape)
    return m


def test_the_slot_is_a_robust_draw(episode):
    env, model, info, _, _ = episode
    dof = env.robot_index.dof
    assert np.asarray(model.dof_frictionloss)[dof].max() > 0.35  # beyond the default range
    assert np.asarray(model.dof_damping)[dof].max() > 0.0
    assert info["strength"].min() < 1.0


def test_mjx_and_c_agree_over_the_episode(episode):
    env, model, info, (q0, dq0), (q_cmd, kp, kd, q_mjx, _) = episode
    dt = env.config.sim_dt
    q_c, _, _ = c_replay(env, _c_model(env, model), info, q0, dq0, (q_cmd, kp, kd), dt)
    q_desc, _, _ = c_replay(env, copy.copy(env.mj_model), info, q0, dq0, (q_cmd, kp, kd), dt)
    diff, effect = np.abs(q_mjx - q_c).max(), np.abs(q_desc - q_c).max()
    print(f"MJX vs C {diff:.2e} rad, the draw's own effect {effect:.2e} rad")
    # float32 MJX against float64 C through the slot's friction (up to 1.35 N*m: the light wrists stick and
    # slip, which amplifies rounding; the nominal parity test's bound is 1e-3 rad): measured 1.9e-3 rad at
    # 2 s; a field lost on the way to the step would show at the draw's scale (0.15 rad).
    assert diff < 5e-3
    assert diff < effect / 20


@pytest.mark.parametrize("k", [10, 20])
def test_each_randomised_field_reaches_the_step(episode, k):
    env, model, info, _, (q_cmd, kp, kd, q_mjx, dq_mjx) = episode
    dt = env.config.sim_dt
    one = (q_cmd[k + 1 : k + 2], kp[k + 1 : k + 2], kd[k + 1 : k + 2])

    def c_step(m, inf):
        q, _, _ = c_replay(env, m, inf, q_mjx[k], dq_mjx[k], one, dt)
        return q[0]

    full = c_step(_c_model(env, model), info)
    diff = np.abs(full - q_mjx[k + 1]).max()
    effects = {f: np.abs(c_step(_c_model(env, model, skip=f), info) - full).max() for f in RANDOMISED}
    effects["strength"] = np.abs(c_step(_c_model(env, model), {**info, "strength": np.ones(14)}) - full).max()
    effects["offset"] = np.abs(
        c_step(_c_model(env, model), {**info, "encoder_offset": np.zeros(14)}) - full
    ).max()
    print(f"step {k}: MJX vs C {diff:.2e} rad; without each: { {f: f'{e:.1e}' for f, e in effects.items()} }")
    assert diff < 1e-4  # float32 rounding over 5 substeps and the Newton solver's start: measured 1.1e-5
    for f, e in effects.items():
        if f != "body_inertia":  # below this resolution: the mass-matrix test checks it
            assert e > 10 * diff, (f, e, diff)


def test_mjx_mass_matrix_holds_the_slots_inertias(slot):
    env, model = slot
    q = env.robot.pose("piano_ready") + 0.3 * np.sin(np.arange(14))  # a pose away from symmetry
    m = _c_model(env, model)
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    dx = jax.jit(mjx.forward)(model, mjx.put_data(env.mj_model, d))
    m_mjx = np.asarray(support.full_m(model, dx), np.float64)
    # float32: entries up to ~0.2 kg*m^2 to 1e-6 relative, sums of ~10 terms: 1e-6 absolute.
    np.testing.assert_allclose(m_mjx, full, rtol=0, atol=1e-6)
    m_desc = _c_model(env, model, skip="body_inertia")
    d2 = mujoco.MjData(m_desc)
    d2.qpos[:] = q
    mujoco.mj_forward(m_desc, d2)
    without = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m_desc, d2, without)
    assert np.abs(without - full).max() > 100 * 1e-6  # the inertia draw is visible at that resolution
