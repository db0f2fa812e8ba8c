"""``site_kinematics``: site positions from the body chains only, against C MuJoCo (float64) and MJX.

The tolerance is a worst-case float32 rounding bound, derived per chain from the model (``_bound``):

- Every vector the computation forms on a chain (a body's offset, a joint's anchor and its turn, a body's
  position, the site) is at most ``L`` = the sum of the chain's ``|body_pos|``, ``|jnt_pos|``, slide
  travels and ``|site_pos|`` (m): 1.02 m on each Lite arm.
- An operation on such a vector rounds at ``eps32 = 2**-23 ~ 1.19e-7`` relative to ``L``; a rounding of a
  unit quaternion by ``eps32`` turns the frame by up to ``2 eps32`` rad, which moves every point below it
  by up to ``2 eps32 L``. Counting both, generously, per step of ``site_positions``:
  a joint (axis-angle 3 -> 6 as an angle, its turn about the anchor: a rotate ~10 and a subtract 1, that
  into the body's frame: a rotate 10 and an add 1, the product with the body's quaternion 4 -> 8, margin)
  ``JOINT_ROUNDINGS = 40``; a body down the chain (a rotate 10, an add 1, a quaternion product 4 -> 8,
  the normalisation 4 -> 8, its float32 model values 1, margin) ``BODY_ROUNDINGS = 30``; the site (a
  rotate and an add, its float32 offset) ``SITE_ROUNDINGS = 12``.
- Errors add along the chain, so ``|error| <= (30 n_bodies + 40 n_joints + 12) eps32 L``: on a Lite arm
  (8 bodies, 7 hinges) 532 eps32 x 1.02 m = 6.5e-5 m.

C MuJoCo runs in float64 on the same float32-rounded joint vector (its own error ~1e-16 m), so it is held
to the bound; MJX is another float32 computation of the same maths, so ours and its differ by up to twice
the bound. Measured (this machine's CPU): ~1.3e-7 m against C and against MJX on the Lite, ~500x inside.
A wrong formula (a quaternion product in the wrong order, a missed joint offset, a baked-in value) moves a
fingertip by millimetres or more.
"""

from __future__ import annotations

import copy
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from bar_policy.envs.site_kinematics import SiteChains, plan_sites, site_positions

pytestmark = pytest.mark.numerics  # compares XLA floats with another implementation

EPS32 = float(np.finfo(np.float32).eps)
"""float32 machine epsilon, 2**-23."""
BODY_ROUNDINGS = 30
"""Roundings (in eps32 x L) of one body's offset step and normalisation (module docstring)."""
JOINT_ROUNDINGS = 40
"""Roundings (in eps32 x L) of one hinge or slide step (module docstring)."""
SITE_ROUNDINGS = 12
"""Roundings (in eps32 x L) of the site's offset (module docstring)."""
N_SAMPLES = 20
"""Random joint vectors per comparison."""

TINY = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <site name="on_world" pos="0.3 0.1 0.2"/>
    <body name="a" pos="0.1 0.2 0.3" euler="0.2 0.4 0.6">
      <joint name="h1" type="hinge" axis="0 1 0" pos="0.05 0 0" ref="0.3" range="-1 1"/>
      <joint name="s1" type="slide" axis="1 1 0" ref="0.02" range="-0.1 0.1"/>
      <geom size="0.02"/>
      <body name="b" pos="0 0.2 0" euler="-0.5 0 0.8">
        <joint name="h2" type="hinge" axis="1 0 0" pos="0 0.03 0.02" range="-2 2"/>
        <joint name="h3" type="hinge" axis="0 0.6 0.8" pos="0.01 0 0" range="-2 2"/>
        <geom size="0.02"/>
        <site name="tip_b" pos="0.05 0.1 -0.02"/>
      </body>
      <body name="c" pos="0 -0.15 0.1">
        <joint name="s2" type="slide" axis="0 0 1" range="-0.05 0.05"/>
        <geom size="0.02"/>
        <site name="tip_c" pos="0.02 0 0.03"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""
"""Off-centre hinges, two joints on a body, slides, nonzero ``ref`` (qpos0), rotated bodies, a branch, and a
site on the world body: what the Lite's chains (centred hinges, identity quats, qpos0 = 0) do not test."""


def _bound(m: mujoco.MjModel, plan: SiteChains) -> float:
    """The worst chain's float32 rounding bound, m (module docstring)."""
    worst = 0.0
    for s, path in zip(plan.sites, plan.paths, strict=True):
        reach = float(np.linalg.norm(m.site_pos[s]))
        n = SITE_ROUNDINGS
        for step in path:
            reach += float(np.linalg.norm(m.body_pos[step.body]))
            n += BODY_ROUNDINGS
            for jt in step.joints:
                reach += float(np.linalg.norm(m.jnt_pos[jt.jnt]))
                if jt.slide:
                    reach += float(np.abs(m.jnt_range[jt.jnt] - m.qpos0[jt.qadr]).max())
                n += JOINT_ROUNDINGS
        worst = max(worst, n * EPS32 * reach)
    return worst


def _samples(m: mujoco.MjModel, n: int = N_SAMPLES, seed: int = 0) -> np.ndarray:
    """``n`` joint vectors uniform within the joint limits, rounded to float32, shape (n, nq)."""
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    assert m.nq == m.njnt and m.jnt_limited.all()  # hinges and slides only, all limited
    return np.random.default_rng(seed).uniform(lo, hi, (n, m.nq)).astype(np.float32)


def _c_sites(m: mujoco.MjModel, q: np.ndarray, sites: tuple[int, ...]) -> np.ndarray:
    """``mj_kinematics``'s ``site_xpos[sites]`` (float64) at each row of ``q``, shape (n, len(sites), 3)."""
    d = mujoco.MjData(m)
    out = []
    for row in q:
        d.qpos[:] = row.astype(np.float64)
        mujoco.mj_kinematics(m, d)
        out.append(d.site_xpos[list(sites)].copy())
    return np.array(out)


def _ours(model: mjx.Model, q: np.ndarray, plan: SiteChains) -> np.ndarray:
    """``site_positions`` at each row of ``q`` (one jit; the model an argument, not a constant)."""
    fn = jax.jit(jax.vmap(functools.partial(site_positions, plan=plan), in_axes=(None, 0)))
    return np.asarray(fn(model, jnp.asarray(q)))


@pytest.fixture(scope="module")
def lite(nominal_env) -> dict:
    """The Lite's fingertips: the model, plan, samples, and our float32 positions."""
    m = nominal_env.mj_model
    plan = nominal_env._tip_chains
    q = _samples(m)
    return {"m": m, "plan": plan, "q": q, "ours": _ours(nominal_env.mjx_model, q, plan)}


def test_lite_plan_shares_the_chest(lite) -> None:
    plan = lite["plan"]
    assert plan is not None
    left, right = plan.paths
    assert len(left) == len(right) == 8  # chest + 7 arm bodies
    assert left[0] is right[0] and not left[0].joints  # the chest: shared, fixed
    assert [len(s.joints) for s in left[1:] + right[1:]] == [1] * 14
    assert not any(jt.slide for s in left + right for jt in s.joints)


def test_lite_matches_c_mujoco(lite) -> None:
    want = _c_sites(lite["m"], lite["q"], lite["plan"].sites)
    err = np.abs(lite["ours"] - want).max()
    assert err <= _bound(lite["m"], lite["plan"]), err


def test_lite_matches_mjx(lite, nominal_env) -> None:
    sites = jnp.asarray(lite["plan"].sites)
    data = nominal_env._init_data

    def mjx_sites(model: mjx.Model, q: jax.Array) -> jax.Array:
        return mjx.kinematics(model, data.replace(qpos=q)).site_xpos[sites]

    want = np.asarray(jax.jit(jax.vmap(mjx_sites, in_axes=(None, 0)))(nominal_env.mjx_model, lite["q"]))
    err = np.abs(lite["ours"] - want).max()
    assert err <= 2 * _bound(lite["m"], lite["plan"]), err


def _edited(m: mujoco.MjModel) -> mujoco.MjModel:
    """``m`` with offsets, a rotation, anchors, an axis, a joint's qpos0 and the sites moved on both arms."""
    e = copy.copy(m)
    body, jnt, site = e.body, e.jnt, e.site
    e.body_pos[body("left_elbow_pitch").id] += [0.02, -0.01, 0.03]
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    e.body_quat[body("left_shoulder_yaw").id] = np.r_[np.cos(0.2), np.sin(0.2) * axis]
    e.jnt_pos[body("left_wrist_yaw").jntadr[0]] = [0.01, 0.02, -0.015]
    e.jnt_axis[body("right_elbow_pitch").jntadr[0]] = np.array([0.0, 0.6, 0.8])
    e.qpos0[jnt(int(body("right_shoulder_roll").jntadr[0])).qposadr[0]] = 0.25
    e.body_pos[body("right_hand").id] += [-0.03, 0.0, 0.02]
    e.site_pos[site("left_finger2_tip").id] += [0.01, 0.01, -0.01]
    return e


EDITED_FIELDS = ("body_pos", "body_quat", "jnt_pos", "jnt_axis", "qpos0", "site_pos")
"""The model fields ``_edited`` changes."""


def test_reads_a_batched_model(lite, nominal_env) -> None:
    """A batch of two models (nominal, edited) under vmap, as the randomised wrapper runs: each its own."""
    m, plan = lite["m"], lite["plan"]
    m2 = _edited(m)
    nom, ed = nominal_env.mjx_model, mjx.put_model(m2)
    batched = nom.tree_replace({f: jnp.stack([getattr(nom, f), getattr(ed, f)]) for f in EDITED_FIELDS})
    in_axes = jax.tree.map(lambda _: None, nom).tree_replace(dict.fromkeys(EDITED_FIELDS, 0))
    q = lite["q"][:5]
    per_q = jax.vmap(functools.partial(site_positions, plan=plan), in_axes=(None, 0))
    got = np.asarray(jax.jit(jax.vmap(per_q, in_axes=(in_axes, None)))(batched, jnp.asarray(q)))
    want = np.stack([_c_sites(m, q, plan.sites), _c_sites(m2, q, plan.sites)])
    assert np.linalg.norm(want[1] - want[0], axis=-1).min() > 0.01  # the edit moves both tips > 1 cm
    err = np.abs(got - want).max(axis=(1, 2, 3))
    assert (err <= [_bound(m, plan), _bound(m2, plan)]).all(), err


def test_tiny_model_matches_c_mujoco() -> None:
    m = mujoco.MjModel.from_xml_string(TINY)
    plan = plan_sites(m, [m.site(n).id for n in ("tip_b", "tip_c", "on_world")])
    assert plan is not None
    assert [[s.body for s in p] for p in plan.paths] == [
        [m.body("a").id, m.body("b").id],
        [m.body("a").id, m.body("c").id],
        [],
    ]
    assert m.qpos0[0] == 0.3 and m.qpos0[1] == 0.02  # the hinge's and the slide's ref
    q = _samples(m)
    err = np.abs(_ours(mjx.put_model(m), q, plan) - _c_sites(m, q, plan.sites)).max()
    assert err <= _bound(m, plan), err


def _plan_of(xml: str, site: str = "s") -> SiteChains | None:
    m = mujoco.MjModel.from_xml_string(xml)
    return plan_sites(m, [m.site(site).id])


@pytest.mark.parametrize(
    "joint", ["<freejoint/>", '<joint type="ball"/>', '<joint type="slide"/><joint type="ball"/>']
)
def test_no_plan_through_free_or_ball_joints(joint: str) -> None:
    xml = f"""<mujoco><worldbody><body name="a">{joint}<geom size="0.1"/>
      <body name="b" pos="0 0 0.2"><joint type="hinge"/><geom size="0.1"/><site name="s"/></body>
    </body></worldbody></mujoco>"""
    assert _plan_of(xml) is None


def test_no_plan_through_a_mocap_body_but_one_beside_it() -> None:
    mocap = '<mujoco><worldbody><body mocap="true"><site name="s"/></body></worldbody></mujoco>'
    assert _plan_of(mocap) is None
    beside = """<mujoco><worldbody><body><freejoint/><geom size="0.1"/></body>
      <body pos="0 0 1"><joint type="slide"/><geom size="0.1"/><site name="s"/></body></worldbody></mujoco>"""
    plan = _plan_of(beside)
    assert plan is not None and plan.paths[0][0].joints[0].slide


def test_bad_site_ids() -> None:
    m = mujoco.MjModel.from_xml_string(TINY)
    with pytest.raises(ValueError, match="site id"):
        plan_sites(m, [m.nsite])
    with pytest.raises(ValueError, match="no site"):
        plan_sites(m, [])
