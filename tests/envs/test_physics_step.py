"""The env's physics step (``envs.physics_step``) is ``mjx.step``: the same computation rearranged.

Expected values come from MJX itself (``mjx.step``, ``mjx.forward``) and from the model's structure worked
out by hand. The comparisons run in float64 (``jax.enable_x64``), where the rearranged sums differ from
MJX's only by rounding: relative 1e-12 is ~5000 float64 ulps, far above the differences seen (<= 4e-15
relative) and far below any physical difference (a missed contact row or a wrong mask changes qacc by
O(1)).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from bar_policy.envs import contact_rows, leaf_newton, physics_step, small_spd
from bar_policy.robot.constants import load_robot
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.scene import keyboard_scene

ROBOT = load_robot("arms")
RTOL = 1e-12


@pytest.fixture(scope="module")
def piano() -> mujoco.MjModel:
    return _reference("piano")[0]


def _press_states(m: mujoco.MjModel, n: int = 6) -> list[mujoco.MjData]:
    """C MuJoCo states with both hands on the keys: piano_ready with both elbows (joint 3 of each arm)
    commanded 0.25 rad further, held by the MIT law at Kp 50, Kd 2, sampled every 40 ms."""
    d = mujoco.MjData(m)
    q_ref = np.asarray(ROBOT.pose("piano_ready")) + np.tile([0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0], 2)
    d.qpos[:14] = ROBOT.pose("piano_ready")
    out = []
    for i in range(n * 20):
        d.qfrc_applied[:14] = 50.0 * (q_ref - d.qpos[:14]) - 2.0 * d.qvel[:14]
        mujoco.mj_step(m, d)
        if i % 20 == 19:
            out.append(copy.copy(d))
    return out


def test_leaf_split_by_hand(piano) -> None:
    # The robot's 14 arm dofs come first (qpos order of the MJCF), then the 49 keys: each hinged to the
    # world, the only dof of its body, touching only the fingertips.
    split = leaf_newton.leaf_split(piano)
    np.testing.assert_array_equal(split.robot, np.arange(14))
    np.testing.assert_array_equal(split.leaf, np.arange(14, 63))
    # Rows: 14 friction loss + 63 limits, then 60 contacts (MAX_CONTACT_POINTS): contacts start at 77.
    assert split.contact_rows == (77, 137)
    # The robot alone has no leaf (every dof with no parent dof has children), nor does a CG scene.
    assert leaf_newton.leaf_split(load_model("arms")) is None
    cg = copy.deepcopy(piano)
    cg.opt.solver = mujoco.mjtSolver.mjSOL_CG
    assert leaf_newton.leaf_split(cg) is None


def test_keys_that_touch_each_other_are_not_leaves(piano) -> None:
    # Give C4's key (midi 60) conaffinity with the keys' contype... keys have contype 0, so make C4 and D4
    # collide with each other through a shared bit: both lose their leaf status, the others keep it.
    m = copy.deepcopy(piano)
    kb = compact_config()
    c4, d4 = (m.geom(f"piano_key{k}").id for k in (60, 62))
    m.geom_contype[c4] = 16
    m.geom_conaffinity[d4] = m.geom_conaffinity[d4] | 16
    split = leaf_newton.leaf_split(m)
    lost = {14 + 60 - kb.lowest, 14 + 62 - kb.lowest}
    assert set(split.robot.tolist()) == set(range(14)) | lost
    assert len(split.leaf) == 47


def test_ancestor_mask_by_hand() -> None:
    m = load_model("arms")
    anc = contact_rows.ancestor_dofs(m)
    # The world and the fixed torso move with no dof; a body 3 joints down the left arm moves with 3.
    for b in range(m.nbody):
        chain, a = set(), b
        while a > 0:
            chain |= set(range(m.body_dofadr[a], m.body_dofadr[a] + m.body_dofnum[a]))
            a = m.body_parentid[a]
        assert set(np.flatnonzero(anc[b]).tolist()) == chain
    assert anc[0].sum() == 0
    # The last link of each arm is moved by its 7 joints and only those.
    wrists = [b for b in range(m.nbody) if anc[b].sum() == 7]
    assert len(wrists) == 2
    assert sorted(np.flatnonzero(anc[wrists[0]] | anc[wrists[1]]).tolist()) == list(range(14))


@functools.cache
def _reference(
    model: str,
) -> tuple[mujoco.MjModel, mjx.Model, Callable[[mjx.Data], tuple[mjx.Data, mjx.Data]]]:
    """``model`` (``arms`` or ``piano``), its float64 MJX model and MJX's own ``(forward, step)`` of it as
    one jitted function.

    One program for both (the step's forward is the same computation), built once a process for every test
    that compares against it (each an XLA compile of a minute or more on a CPU).
    """
    m = load_model("arms", keyboard_scene(compact_config())) if model == "piano" else load_model("arms")
    with jax.enable_x64(True):
        mx = mjx.put_model(m)
    return m, mx, jax.jit(lambda d: (mjx.forward(mx, d), mjx.step(mx, d)))


def _compare(model: str, states: list[mujoco.MjData], cholesky: str = "library") -> int:
    """physics_step.forward/step against mjx.forward/step from each state, float64; returns the largest
    number of active contact rows seen (to show the states are in contact). ``cholesky``: the plan's."""
    m, mx, reference = _reference(model)
    plan = physics_step.plan(m, cholesky=cholesky)
    most = 0
    with jax.enable_x64(True):
        ours = jax.jit(lambda d: (physics_step.forward(mx, d, plan), physics_step.step(mx, d, plan)))
        for s in states:
            d = mjx.put_data(m, s)
            (a, a_step), (b, b_step) = reference(d), ours(d)
            assert a.qacc.dtype == jnp.float64
            np.testing.assert_allclose(b._impl.efc_J, a._impl.efc_J, rtol=RTOL, atol=RTOL)
            np.testing.assert_allclose(b._impl.efc_aref, a._impl.efc_aref, rtol=RTOL, atol=RTOL * 1e2)
            scale = float(np.abs(a.qacc).max())
            np.testing.assert_allclose(b.qacc, a.qacc, rtol=0, atol=RTOL * scale)
            np.testing.assert_allclose(b.qfrc_constraint, a.qfrc_constraint, rtol=0, atol=RTOL * scale)
            a, b = a_step, b_step
            np.testing.assert_allclose(b.qpos, a.qpos, rtol=0, atol=RTOL)
            np.testing.assert_allclose(b.qvel, a.qvel, rtol=0, atol=RTOL * scale)
            active = np.asarray(a._impl.efc_D) * (np.asarray(a._impl.efc_pos) < 0)
            most = max(most, int((active[-60:] > 0).sum()))
    return most


@pytest.mark.slow
def test_piano_step_equals_mjx_step_in_contact(piano) -> None:
    states = _press_states(piano)
    # The states push keys down (> 0.01 rad; a key's full travel is 0.067-0.105 rad) in C MuJoCo.
    assert max(np.abs(s.qpos[14:]).max() for s in states) > 0.01
    assert _compare("piano", states) >= 2  # both fingertips on keys (contact rows active)


@pytest.mark.slow
@pytest.mark.parametrize("cholesky", physics_step.CHOLESKY)
def test_reach_step_equals_mjx_step(cholesky: str) -> None:
    # scalar / columns: every Cholesky of the step written out (small_spd; opt-in, for the GPU's graphs).
    m = _reference("arms")[0]
    rng = np.random.default_rng(3)
    states = []
    for _ in range(4):
        d = mujoco.MjData(m)
        d.qpos[:] = np.asarray(ROBOT.pose("piano_ready")) + rng.normal(0, 0.3, m.nq)
        d.qvel[:] = rng.normal(0, 1.0, m.nv)
        mujoco.mj_forward(m, d)
        states.append(d)
    assert physics_step.plan(m).split is None
    assert physics_step.plan(m, cholesky=cholesky).unrolled is (cholesky != "library")
    _compare("arms", states, cholesky)


def test_small_spd_against_numpy() -> None:
    # A 14 x 14 SPD matrix with eigenvalues 1 .. 1e3 (condition 1e3): a backward-stable solve in float64
    # has relative error <= ~n * cond * eps = 14 * 1e3 * 2.2e-16 = 3e-12; checked at 1e-10. The factor is
    # numpy's Cholesky (unique with a positive diagonal): error ~n * eps * cond^0.5 = 1e-13, checked at 1e-12.
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(14, 14)))
    a = (q * np.geomspace(1.0, 1e3, 14)) @ q.T
    y = rng.normal(size=14)
    expected = np.linalg.solve(a, y)
    upper_garbage = np.tril(a) + np.triu(np.full((14, 14), 7.0), 1)  # only the lower triangle is read
    with jax.enable_x64(True):
        for m in (a, upper_garbage):
            x = np.asarray(jax.jit(small_spd.spd_solve)(jnp.asarray(m), jnp.asarray(y)))
            np.testing.assert_allclose(x, expected, rtol=1e-10, atol=0)
            # Each form's factor (zeros above the diagonal) and solve against numpy, the same bounds.
            for factor, solve in small_spd.SOLVERS.values():
                low = np.asarray(jax.jit(factor)(jnp.asarray(m)))
                np.testing.assert_allclose(low, np.linalg.cholesky(a), rtol=0, atol=1e-12 * np.abs(low).max())
                assert not np.triu(low, 1).any()
                x = np.asarray(jax.jit(solve)(jnp.asarray(low), jnp.asarray(y)))
                np.testing.assert_allclose(x, expected, rtol=1e-10, atol=0)
    # The piano's Newton direction takes the same solve through leaf_newton.
    assert leaf_newton.spd_solve is small_spd.spd_solve


def test_written_out_cholesky_needs_a_dense_mass_matrix(piano) -> None:
    # The keyboard's 63 dofs make MJX's mass matrix sparse (nv >= 60): no written-out factor for it.
    assert not physics_step.plan(piano).unrolled
    with pytest.raises(ValueError, match="cholesky 'columns' needs a dense mass matrix, nv = 63 is sparse"):
        physics_step.plan(piano, cholesky="columns")
    with pytest.raises(ValueError, match=r"unknown cholesky 'lu'; valid: \['library', 'scalar', 'columns'\]"):
        physics_step.plan(piano, cholesky="lu")


def test_env_config_picks_the_cholesky_form(piano) -> None:
    # The env option reaches the robot's step plan; a bad name and the sparse piano fail at build time.
    from bar_policy import envs

    assert envs.load("LiteReach")._step_plan.cholesky == "library"
    assert envs.load("LiteReach", overrides=["cholesky=columns"])._step_plan.cholesky == "columns"
    with pytest.raises(ValueError, match=r"unknown cholesky 'lu'; valid: \['library', 'scalar', 'columns'\]"):
        envs.load("LiteReach", overrides=["cholesky=lu"])
    with pytest.raises(ValueError, match="cholesky 'scalar' needs a dense mass matrix, nv = 63"):
        envs.load("LitePiano", overrides=["cholesky=scalar"])


def _cuda_library_calls(m: mujoco.MjModel, cholesky: str) -> tuple[list[str], int]:
    """The custom-call targets and the triangular solves of a batch of physics steps lowered for CUDA."""
    import re

    from jax import export

    mx, p = mjx.put_model(m), physics_step.plan(m, cholesky=cholesky)
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (4, *x.shape)), mjx.make_data(m))
    f = jax.jit(jax.vmap(lambda d: physics_step.step(mx, d, p)))
    text = export.export(f, platforms=("cuda",))(batch).mlir_module()
    return sorted(set(re.findall(r"custom_call @([\w$]+)", text))), text.count("triangular_solve")


@pytest.mark.slow
def test_written_out_step_has_no_library_call_on_cuda() -> None:
    # XLA records no cuSOLVER potrf and no cuBLAS triangular solve into a command buffer (a CUDA graph), so
    # those split the step's graphs (physics_step, item 4). Lowered for CUDA (no GPU needed): the default
    # step holds the mass matrix's and the Newton direction's potrf and their solves; written out, none.
    m = load_model("arms")
    calls, trsm = _cuda_library_calls(m, "library")
    assert "cusolver_potrf_ffi" in calls and trsm > 0
    for form in small_spd.SOLVERS:
        assert _cuda_library_calls(m, form) == ([], 0), form


@pytest.mark.slow
def test_while_newton_loop_gives_the_same_step(piano, monkeypatch) -> None:
    # The env's Newton loop is written out, keeping a body's result only where the loop's condition held
    # before it; MJX's while_loop gives the same step (compared at the module's float64 tolerance, _compare).
    monkeypatch.setattr(leaf_newton, "newton_loop", leaf_newton.while_newton_loop)
    assert _compare("piano", _press_states(piano, n=3)) >= 2
