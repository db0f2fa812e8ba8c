"""MJX's constraint rows with each contact's Jacobian mask taken from a static table.

``mujoco.mjx._src.support.jac`` finds the dofs that move a body by scanning the whole body tree, once per
contact side (its own TODO: "statically construct mask"). The piano scene has 60 contacts and 113 bodies, and
on an H100 ``make_constraint`` was 31 % of a physics step (``bench/piano_solver_parts.py`` at fdbaf1a). The
mask depends only on the model, so :func:`ancestor_dofs` builds it once (``(nbody, nv)``: dof ``j`` moves body
``b`` when ``j`` belongs to ``b`` or to one of its ancestors) and :func:`make_constraint` reads a row of it,
and projects the Jacobian on the contact normal directly (the only row a frictionless contact has). Everything
else is MJX's code, in MJX's row order; frictionless contacts (condim 1, every contact of the Lite's scenes)
take this path, other condims MJX's own rows.

Pinned to ``mujoco-mjx`` 3.17 (``mujoco.mjx._src``); ``tests/envs/test_physics_step.py`` holds the rows
equal to MJX's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import constraint
from mujoco.mjx._src.types import ConeType, DisableBit


def ancestor_dofs(m: mujoco.MjModel) -> np.ndarray:
    """(nbody, nv) bool: ``[b, j]`` when dof ``j`` moves body ``b`` (``j`` on ``b`` or an ancestor of it)."""
    out = np.zeros((m.nbody, m.nv), bool)
    for b in range(m.nbody):
        a = b
        while a > 0:
            start, n = m.body_dofadr[a], m.body_dofnum[a]
            out[b, start : start + n] = True
            a = m.body_parentid[a]
    return out


def _normal_row(
    d: mjx.Data, anc: jax.Array, point: jax.Array, normal: jax.Array, body: jax.Array, rootid: jax.Array
) -> jax.Array:
    """(nv,) ``normal . J(point on body)``, without forming the (nv, 3) Jacobian.

    ``J`` is ``support.jac``'s translational Jacobian with the static mask.
    ``J_j = cdof_j[3:] + cdof_j[:3] x offset``, so ``n . J_j = cdof_j[3:] . n + cdof_j[:3] . (offset x n)``:
    one (nv, 6) @ (6,) product per side instead of nv cross products and a (3, 3) @ (3, nv) product.
    """
    offset = point - d.subtree_com[rootid[body]]
    return (d.cdof @ jnp.concatenate([jnp.cross(offset, normal), normal])) * anc[body]


def _frictionless(m: mjx.Model, d: mjx.Data, anc: jax.Array) -> constraint._Efc | None:
    """``constraint._efc_contact_frictionless`` with :func:`_normal_row` (the row is ``frame[0] . J``)."""
    con_id = np.nonzero(d._impl.contact.dim == 1)[0]
    if con_id.size == 0:
        return None
    geom_body = jnp.asarray(m.geom_bodyid)
    rootid = jnp.asarray(m.body_rootid)

    @jax.vmap
    def rows(c: mjx.Contact) -> constraint._Efc:
        pos = c.dist - c.includemargin
        active = pos < 0
        body1, body2 = geom_body[c.geom]
        n = c.frame[0]
        j = _normal_row(d, anc, c.pos, n, body2, rootid) - _normal_row(d, anc, c.pos, n, body1, rootid)
        invweight = m.body_invweight0[body1, 0] + m.body_invweight0[body2, 0]
        return constraint._row(
            j * active, pos * active, pos, invweight, c.solref, c.solimp, c.includemargin, jnp.zeros_like(pos)
        )

    contact = jax.tree_util.tree_map(lambda x: x[con_id], d._impl.contact)
    return rows(contact)


def make_constraint(m: mjx.Model, d: mjx.Data, ancestors: np.ndarray) -> mjx.Data:
    """``constraint.make_constraint`` with frictionless contact rows from :func:`_frictionless`."""
    if m.opt.disableflags & DisableBit.CONSTRAINT:
        return constraint.make_constraint(m, d)  # no rows: MJX's own empty arrays
    anc = jnp.asarray(ancestors)
    efcs = (
        constraint._efc_equality_connect(m, d),
        constraint._efc_equality_weld(m, d),
        constraint._efc_equality_joint(m, d),
        constraint._efc_equality_tendon(m, d),
        constraint._efc_friction(m, d),
        constraint._efc_limit_ball(m, d),
        constraint._efc_limit_slide_hinge(m, d),
        constraint._efc_limit_tendon(m, d),
        _frictionless(m, d, anc),
    )
    con_fn = (
        constraint._efc_contact_elliptic
        if m.opt.cone == ConeType.ELLIPTIC
        else constraint._efc_contact_pyramidal
    )
    efcs += tuple(con_fn(m, d, dim) for dim in (3, 4, 6))
    efcs = tuple(e for e in efcs if e is not None)
    if not efcs:
        return constraint.make_constraint(m, d)
    efc = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *efcs)

    @jax.vmap
    def fn(e: constraint._Efc) -> tuple[jax.Array, ...]:
        k, b, imp = constraint._kbi(m, e.solref, e.solimp, e.pos_imp)
        r = jnp.maximum(e.invweight * (1 - imp) / imp, mujoco.mjMINVAL)
        aref = -b * (e.J @ d.qvel) - k * imp * e.pos_aref
        return aref, r, e.pos_aref + e.margin, e.margin, e.frictionloss

    aref, r, pos, margin, frictionloss = fn(efc)
    d = d.tree_replace(
        {
            "_impl.efc_J": efc.J,
            "_impl.efc_D": 1 / r,
            "_impl.efc_aref": aref,
            "_impl.efc_pos": pos,
            "_impl.efc_margin": margin,
        }
    )
    return d.tree_replace({"_impl.efc_frictionloss": frictionloss})
