"""MJX's contact caps in the keyboard scene (scene.py: ``max_geom_pairs``, ``max_contact_points``).

The caps make the piano's MJX step cheaper (docs/physics.md, "A cheaper keyboard step") and must drop no
contact that touches. Checked here: the structural counts before and after, worked out by hand; the two
geometric bounds the caps rest on; an MJX step with the caps against one without, in contact; and a
fingertip pressing a key in MJX as in C MuJoCo.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from mujoco.mjx._src import collision_driver

from bar_policy.robot.constants import load_robot
from bar_policy.robot.scene import load_model
from bar_policy.tasks.piano.keyboard import compact_config, default_config, key_table, pressed
from bar_policy.tasks.piano.reach import ReachChecker
from bar_policy.tasks.piano.scene import (
    FINGERTIP_GEOMS,
    MAX_CONTACT_POINTS,
    MAX_GEOM_PAIRS,
    keyboard_scene,
)
from bar_policy.training.startup.compile_cache import QUICK_COMPILE

KB = compact_config()
ROBOT = load_robot("arms")


def _uncapped(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` with both caps off (-1: MJX's "no cap"), i.e. the scene as it was before."""
    out = copy.deepcopy(model)
    for name in ("max_geom_pairs", "max_contact_points"):
        out.numeric_data[out.numeric_adr[out.numeric(name).id]] = -1.0
    return out


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return load_model("arms", keyboard_scene(KB))


def _pair_groups(m: mujoco.MjModel) -> dict[str, int]:
    names = {int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere", int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule"}
    names[int(mujoco.mjtGeom.mjGEOM_BOX)] = "box"
    groups = collision_driver._geom_groups(m)
    return {"-".join(names[int(t)] for t in key.types): len(pairs) for key, pairs in groups.items()}


def test_counts_before_and_after_by_hand(model) -> None:
    # Pairs MJX may collide (contype/conaffinity filtering): the robot's 30 capsule-capsule and 12
    # capsule-box pairs (the chest boxes), and each of the 2 fingertip spheres against each of the 49 keys.
    assert _pair_groups(model) == {"capsule-capsule": 30, "capsule-box": 12, "sphere-box": 98}
    before, after = _uncapped(model), model
    # Contacts (each a constraint row at condim 1): capsule-capsule gives 1 per pair, capsule-box 2,
    # sphere-box 1. Before: 30 + 2 * 12 + 98 = 152. After: the narrow phase runs on min(98, 30) sphere-box
    # pairs, 30 + 24 + 30 = 84 contacts, of which the deepest 60 are kept.
    assert len(collision_driver.make_condim(before)) == 152
    assert len(collision_driver.make_condim(after)) == 60
    # Constraint rows: 14 friction-loss rows (the robot's joints), 63 joint limits (14 robot + 49 key
    # travel stops), and the contacts: 14 + 63 + 152 = 229 before, 14 + 63 + 60 = 137 after.
    for m, nefc in ((before, 229), (after, 137)):
        d = mjx.make_data(m)
        assert d._impl.efc_J.shape == (nefc, 14 + 49)
    # The C MuJoCo side (the sim target) reads neither numeric: the same model steps the same.
    d1, d2 = mujoco.MjData(before), mujoco.MjData(after)
    for d in (d1, d2):
        d.qpos[:14] = ROBOT.pose("piano_ready")
        for _ in range(50):
            mujoco.mj_step(before if d is d1 else after, d)
    np.testing.assert_array_equal(d1.qpos, d2.qpos)


@pytest.mark.parametrize("mode", ["arms", "arms_neck"])
def test_robot_contacts_are_never_capped(mode: str) -> None:
    # The robot alone: no group above MAX_GEOM_PAIRS (MJX culls a group only past the cap), and all its
    # contacts plus 3 per fingertip sphere within MAX_CONTACT_POINTS. arms: 30 + 12 groups, 30 + 24 = 54
    # contacts; arms_neck (no head capsule): 22 + 12, 46.
    alone = load_model(mode)
    groups = _pair_groups(alone)
    assert max(groups.values()) <= MAX_GEOM_PAIRS
    assert len(collision_driver.make_condim(alone)) + 2 * 3 <= MAX_CONTACT_POINTS
    assert (max(groups.values()), len(collision_driver.make_condim(alone))) == {
        "arms": (30, 54),
        "arms_neck": (22, 46),
    }[mode]


def test_geom_pair_cap_keeps_every_touching_pair() -> None:
    """A touching sphere-key pair has |p_tip - p_box| <= r_tip + rbound_box (the box lies inside its
    bounding sphere). Count, over a 5 mm grid of fingertip positions, the keys whose bounding sphere so
    inflated contains the point, inflating further by the grid's half-diagonal (4.33 mm) and by how far a
    key's box centre moves at full travel (|centre - hinge| * angle_max: 76 mm * 0.0667 = 5.0 mm white,
    49 mm * 0.105 = 5.1 mm black), so no point between grid nodes or key angle is missed. On the full
    74-key keyboard (any smaller one counts no more): at most 13 per fingertip sphere (11 on a 2 mm grid
    without the inflation, e.g. F4..E5: 7 white and 4 black), 26 for both <= 30, so
    MJX's nearest 30 pairs always hold the touching ones."""
    cfg = default_config()
    m = load_model("arms", keyboard_scene(cfg))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    keys = key_table(cfg)
    gid = np.array([m.geom(f"piano_key{k.midi}").id for k in keys])
    centre = d.geom_xpos[gid]
    swing = np.array([np.hypot(k.lever / 2, 0.01) * k.angle_max for k in keys])
    step = 0.005
    reach = m.geom_rbound[gid] + m.geom_rbound[m.geom(FINGERTIP_GEOMS[0]).id] + swing + step * 3**0.5 / 2
    lo, hi = (centre - reach[:, None]).min(0), (centre + reach[:, None]).max(0)
    axes = [np.arange(a, b + step, step) for a, b in zip(lo, hi, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    most = 0
    for chunk in np.array_split(grid, 1 + len(grid) // 50_000):
        inside = np.linalg.norm(chunk[:, None] - centre[None], axis=2) <= reach
        most = max(most, int(inside.sum(1).max()))
    assert most == 13
    assert 2 * most <= MAX_GEOM_PAIRS


def test_contact_point_cap_by_y_extent() -> None:
    """A fingertip sphere (radius 6 mm) touches a key only if its y span [c - 6, c + 6] mm meets the key's
    y extent [y - w/2, y + w/2] (the hinge turns a key about y, so that extent never moves). The most key
    extents a 12 mm window meets: 3. At a white boundary under a black key, e.g. C4 | D4: C4, D4 and C#4
    (D#4 begins 23.5 - 6.85 = 16.65 mm away). Between two black keys, over D4's 9.8 mm gap: C#4, D#4 and
    D4 (C4 and E4 end 11.75 mm from D4's centre). So 54 robot contacts + 2 * 3 = 60 = MAX_CONTACT_POINTS."""
    cfg = default_config()
    r = cfg.fingertip_radius
    lo, hi = [], []
    for k in key_table(cfg):
        w = cfg.black_width if k.black else cfg.white_pitch - cfg.white_gap
        lo.append(k.y - w / 2)
        hi.append(k.y + w / 2)
    lo, hi = np.array(lo), np.array(hi)
    # The count changes only where the window's edge crosses an extent's end: test those centres.
    centres = np.concatenate([lo - r, hi + r, lo + r, hi - r])
    counts = [int(np.sum((lo <= c + r) & (hi >= c - r))) for c in centres]
    assert max(counts) == 3
    assert 54 + 2 * max(counts) == MAX_CONTACT_POINTS


def _press_states(model: mujoco.MjModel, midi: int) -> tuple[np.ndarray, np.ndarray]:
    """The right fingertip driven (joint positions prescribed) from 5 mm above ``midi``'s aim point to 7 mm
    below it over 0.3 s, held 0.2 s (``test_piano_keyboard.test_fingertip_presses_key``): the robot's q
    and dq per 2 ms step, shape (250, 14) each."""
    key = next(k for k in key_table(KB) if k.midi == midi)
    x, y, z = key.site
    checker = ReachChecker(KB)
    q_up, _ = checker.solve("right", np.array([x, y, z + 0.006 + 0.005]), ROBOT.pose("piano_ready"))
    q_dn, _ = checker.solve("right", np.array([x, y, z + 0.006 - 0.007]), q_up)
    dt = model.opt.timestep
    n_move, n_hold = int(0.3 / dt), int(0.2 / dt)
    s = np.minimum(np.arange(n_move + n_hold) / n_move, 1.0)[:, None]
    q = (1 - s) * q_up + s * q_dn
    dq = np.where(np.arange(n_move + n_hold)[:, None] < n_move, (q_dn - q_up) / (n_move * dt), 0.0)
    return q, dq


def _run_mjx(model: mujoco.MjModel, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The prescribed robot trajectory on MJX: (key angles after each step (250, 49), qacc (250, nv))."""
    mx = mjx.put_model(model)

    def body(d: mjx.Data, x: tuple[jax.Array, jax.Array]) -> tuple[mjx.Data, tuple[jax.Array, jax.Array]]:
        d = d.replace(qpos=d.qpos.at[:14].set(x[0]), qvel=d.qvel.at[:14].set(x[1]))
        d = mjx.step(mx, d)
        return d, (d.qpos[14:], d.qacc)

    # Quick compile (LLVM at -O1, as the tiny training preset): the same program, compiled sooner.
    roll = jax.jit(
        lambda d: jax.lax.scan(body, d, (jnp.asarray(q), jnp.asarray(dq)))[1], compiler_options=QUICK_COMPILE
    )
    angles, qacc = roll(mjx.make_data(model))
    return np.asarray(angles), np.asarray(qacc)


@pytest.mark.slow
def test_mjx_caps_change_no_step_and_press_as_c_mujoco(model) -> None:
    """The fingertip pressing C5 (72): MJX with the caps steps as MJX without them (float32 rounding: the
    kept contacts come in another order), and ends as C MuJoCo does: C5 alone pressed, its angle within
    2 mrad of C MuJoCo's (~0.056 rad: asin(0.007 / 0.125) less the contact's give; the threshold is 0.033)."""
    q, dq = _press_states(model, 72)
    capped, acc_capped = _run_mjx(model, q, dq)
    uncapped, acc_uncapped = _run_mjx(_uncapped(model), q, dq)
    np.testing.assert_allclose(capped, uncapped, atol=1e-6)
    np.testing.assert_allclose(acc_capped, acc_uncapped, rtol=1e-4, atol=1e-2)
    d = mujoco.MjData(model)
    for qi, dqi in zip(q, dq, strict=True):
        d.qpos[:14], d.qvel[:14] = qi, dqi
        mujoco.mj_step(model, d)
    c_angles = d.qpos[14:]
    assert pressed(capped[-1], KB).tolist() == pressed(c_angles, KB).tolist()
    assert np.flatnonzero(pressed(capped[-1], KB)).tolist() == [72 - KB.lowest]
    np.testing.assert_allclose(capped[-1], c_angles, atol=2e-3)
    assert 0.045 < capped[-1, 72 - KB.lowest] < 0.0667 * 1.02
