"""MJX's Newton constraint solve, factored for scenes with *leaf* dofs (the piano's keys).

MJX's Newton solver (``mujoco.mjx._src.solver``) builds the dense Hessian ``H = M + J^T D J``
(``nv x nv`` from all ``nefc`` rows) and Cholesky-factors it at the start and at every iteration. The
keyboard brings ``nv`` from 14 to 63 and ``nefc`` to 137, and on an H100 the solve is 81 % of a physics step
(``bench/piano_variants.py`` at fdbaf1a: 0.47M physics steps/s with it, 2.52M without any constraint solve).

A *leaf* dof is the only dof of a body hinged to the static world, with no dofs below it, that no
constraint row couples to another leaf dof. A key is one: its hinge hangs from the world, and keys touch
only the fingertips (never each other). Ordering the dofs robot (R, ``nr``) then leaves (K, ``nk``), ``H`` is
an *arrowhead* matrix::

    H = [[A,   B      ],     A = M_RR + J_R^T D J_R          (nr x nr, dense)
         [B^T, diag(c)]]     B = J_R^T D J_K                 (nr x nk: only rows that touch a leaf)
                             c = diag(M_KK) + sum_rows D J_K^2  (nk: each row touches <= 1 leaf)

because ``M_RK = 0`` and ``M_KK`` is diagonal (no leaf has ancestor or descendant dofs) and ``J_K^T D J_K`` is
diagonal (no row touches two leaves). ``H x = g`` is then solved exactly through the Schur complement
``S = A - B diag(1/c) B^T`` (``nr x nr``): ``x_R = S^-1 (g_R - B (g_K / c))``, ``x_K = (g_K - B^T x_R) / c``.
That is the same Newton step as MJX's, in ``nr^2 nefc + nr nk ncon + nk nefc`` multiply-adds for the products
(``B`` needs the ``ncon`` contact rows only) and an ``nr x nr`` factorisation, instead of ``nv^2 nefc`` and an
``nv x nv`` one (for the piano: ~0.08M instead of ~0.63M per direction, four directions a step).
Everything else -- constraint rows, line search, warm start, iterations, tolerance -- is MJX's own code,
called as MJX calls it; ``physics_step`` puts it in the step.

Shapes: ``split.robot`` (nr,) and ``split.leaf`` (nk,) dof indices; ``efc_J`` (nefc, nv).
Pinned to ``mujoco-mjx`` 3.17 (it calls ``mujoco.mjx._src`` functions); ``tests/envs/test_physics_step.py``
holds it equal to MJX's solve.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import constraint, solver, support
from mujoco.mjx._src.types import ConeType, DisableBit, SolverType

from bar_policy.envs.small_spd import SOLVERS, spd_solve

_ONE_DOF = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


@dataclass(frozen=True)
class LeafSplit:
    """The dofs of a model split into the rest (``robot``, nr) and leaves (``leaf``, nk), both sorted.

    ``contact_rows``: the first constraint row that is a contact and the row count (MJX orders rows
    equality, friction, limits, contacts). Only a contact row can touch a robot dof and a leaf dof
    together, so ``B`` is taken over those rows alone.
    """

    robot: np.ndarray
    leaf: np.ndarray
    contact_rows: tuple[int, int]

    def take(self, x: jax.Array, which: np.ndarray, axis: int = -1) -> jax.Array:
        """``x``'s entries at the dof indices ``which`` along ``axis`` (a slice where they are contiguous)."""
        if which.size and np.array_equal(which, np.arange(which[0], which[0] + which.size)):
            return jax.lax.slice_in_dim(x, int(which[0]), int(which[0]) + which.size, axis=axis)
        return jnp.take(x, which, axis=axis)

    def join(self, x_r: jax.Array, x_k: jax.Array) -> jax.Array:
        """The (nv,) vector whose robot entries are ``x_r`` (nr,) and leaf entries ``x_k`` (nk,)."""
        nr, nk = self.robot.size, self.leaf.size
        if np.array_equal(self.robot, np.arange(nr)) and np.array_equal(self.leaf, nr + np.arange(nk)):
            return jnp.concatenate([x_r, x_k])
        out = jnp.zeros(self.robot.size + self.leaf.size, x_r.dtype)
        return out.at[self.robot].set(x_r).at[self.leaf].set(x_k)


def _can_collide(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    """Whether the contype/conaffinity bit filter lets geoms ``g1`` and ``g2`` collide (not ``<pair>``s)."""
    bits = (m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1])
    return bool(bits)


def leaf_split(m: mujoco.MjModel) -> LeafSplit | None:
    """The leaf dofs of ``m`` (module docstring), or None where it has none or the solve is not Newton.

    None also where the factorisation would not be MJX's Newton step: CG, an elliptic cone, equality
    constraints or tendons (rows this check does not follow), no constraints at all. Which integrators can
    carry it is ``physics_step.plan``'s concern.
    """
    if (
        m.opt.solver != mujoco.mjtSolver.mjSOL_NEWTON
        or m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
        or m.neq
        or m.ntendon
        or m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    ):
        return None
    has_child = np.zeros(m.nv, bool)
    parents = m.dof_parentid[m.dof_parentid >= 0]
    has_child[parents] = True
    leaf = [
        j
        for j in range(m.nv)
        if m.dof_parentid[j] == -1
        and not has_child[j]
        and m.body_dofnum[m.dof_bodyid[j]] == 1
        and int(m.jnt_type[m.dof_jntid[j]]) in _ONE_DOF
    ]
    # No contact row may touch two leaves: drop every leaf whose body can touch another leaf's body.
    body_leaf = {int(m.dof_bodyid[j]): j for j in leaf}
    coupled: set[int] = set()
    geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in body_leaf]
    for a, g1 in enumerate(geoms):
        for g2 in geoms[a + 1 :]:
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            if b1 != b2 and _can_collide(m, g1, g2):
                coupled |= {body_leaf[b1], body_leaf[b2]}
    for p in range(m.npair):
        b1, b2 = int(m.geom_bodyid[m.pair_geom1[p]]), int(m.geom_bodyid[m.pair_geom2[p]])
        if b1 != b2 and b1 in body_leaf and b2 in body_leaf:
            coupled |= {body_leaf[b1], body_leaf[b2]}
    leaf = [j for j in leaf if j not in coupled]
    if not leaf:
        return None
    robot = np.setdiff1d(np.arange(m.nv), leaf)
    efc_type = constraint.make_efc_type(m)
    nc = constraint.counts(efc_type)[3]
    rows = (int(efc_type.size - nc), int(efc_type.size))
    return LeafSplit(robot=robot, leaf=np.asarray(leaf), contact_rows=rows)


def _mass_parts(m: mjx.Model, d: mjx.Data, split: LeafSplit) -> tuple[jax.Array, jax.Array]:
    """(M_RR (nr, nr), diag(M_KK) (nk,)): fixed for the whole solve, so taken once."""
    sparse = support.is_sparse(m)
    diag = d._impl.M[m.M_rowadr + m.M_rownnz - 1] if sparse else jnp.diagonal(d._impl.M)
    full = support.full_m(m, d)
    m_rr = split.take(split.take(full, split.robot, axis=0), split.robot, axis=1)
    return m_rr, split.take(diag, split.leaf)


def _gradient(
    m: mjx.Model, d: mjx.Data, ctx: solver.Context, split: LeafSplit, m_rr: jax.Array, m_kk: jax.Array
) -> solver.Context:
    """MJX's ``_update_gradient`` for Newton (pyramidal cone), with ``H^-1 grad`` through the arrowhead."""
    grad = ctx.Ma - d.qfrc_smooth - ctx.qfrc_constraint
    jac = d._impl.efc_J
    dw = d._impl.efc_D * ctx.active  # (nefc,)
    j_r = split.take(jac, split.robot)  # (nefc, nr)
    j_k = split.take(jac, split.leaf)  # (nefc, nk)
    dj_r = j_r * dw[:, None]
    a = m_rr + j_r.T @ dj_r  # (nr, nr)
    c = m_kk + dw @ (j_k * j_k)  # (nk,)
    start, nefc = split.contact_rows
    if nefc != jac.shape[0]:
        raise ValueError(
            f"leaf_newton: the split was made for {nefc} constraint rows, the data has {jac.shape[0]}"
        )
    b = dj_r[start:].T @ j_k[start:]  # (nr, nk): the other rows touch robot dofs or one leaf, never both
    b_c = b / c
    s = a - b_c @ b.T
    s = (s + s.T) * 0.5  # as MJX symmetrises H before its Cholesky
    g_r, g_k = split.take(grad, split.robot), split.take(grad, split.leaf)
    x_r = spd_solve(s, g_r - b_c @ g_k)
    x_k = (g_k - b.T @ x_r) / c
    mgrad = split.join(x_r, x_k)
    return ctx.replace(grad=grad, Mgrad=mgrad)


def _gradient_dense(m: mjx.Model, d: mjx.Data, ctx: solver.Context, cholesky: str) -> solver.Context:
    """MJX's ``_update_gradient`` for Newton (pyramidal cone, dense M), solved by a ``small_spd`` form.

    ``H = M + J^T diag(D active) J``, symmetrised as MJX does before its Cholesky; ``Mgrad = H^-1 grad``.
    ``cholesky``: a key of ``small_spd.SOLVERS``.
    """
    grad = ctx.Ma - d.qfrc_smooth - ctx.qfrc_constraint
    jac = d._impl.efc_J
    h = support.full_m(m, d) + (jac.T * (d._impl.efc_D * ctx.active)) @ jac
    factor, solve = SOLVERS[cholesky]
    return ctx.replace(grad=grad, Mgrad=solve(factor((h + h.T) * 0.5), grad))


def newton_loop(
    cond: Callable[[solver.Context], jax.Array],
    body: Callable[[solver.Context], solver.Context],
    ctx: solver.Context,
    iterations: int,
) -> solver.Context:
    """MJX's Newton loop ``while cond: ctx = body(ctx)`` written out as ``iterations`` bodies.

    Each body is kept only where ``cond`` held before it. The same values as the ``while_loop``
    (:func:`while_newton_loop`): ``cond`` is False once ``ctx.solver_niter`` reaches ``iterations``, and once
    False the context no longer changes, so it stays False. Under ``vmap`` a ``while_loop`` already runs every
    env until the last one is done, selecting per env, so the work is the same; written out, the GPU needs no
    host round trip per iteration for the predicate and XLA fuses across iterations. The piano env at 8192
    envs on one H100: 1.057M physics steps/s against 0.931M with the ``while_loop``, in one call
    (docs/performance.md, 2026-11-27).
    """
    for _ in range(iterations):
        ctx = jax.tree_util.tree_map(functools.partial(jnp.where, cond(ctx)), body(ctx), ctx)
    return ctx


def while_newton_loop(
    cond: Callable[[solver.Context], jax.Array],
    body: Callable[[solver.Context], solver.Context],
    ctx: solver.Context,
    iterations: int,
) -> solver.Context:
    """:func:`newton_loop` as MJX runs it, a ``jax.lax.while_loop``: :func:`solve`'s loop without leaves."""
    del iterations
    return jax.lax.while_loop(cond, body, ctx)


def is_newton_pyramidal(m: mjx.Model) -> bool:
    """Whether :func:`solve` applies: MJX's Newton solver on the pyramidal cone (static model options)."""
    return m.opt.solver == SolverType.NEWTON and m.opt.cone == ConeType.PYRAMIDAL


def solve(m: mjx.Model, d: mjx.Data, split: LeafSplit | None, cholesky: str = "library") -> mjx.Data:
    """MJX's ``solver.solve`` (Newton): the same warm start, direction, line search and exits.

    Two changes where the scene has leaves (``split``), neither to the values: the direction comes from the
    arrowhead factorisation (:func:`_gradient`) and the Newton loop is written out (:func:`newton_loop`).
    Without leaves the direction is MJX's dense Hessian's Cholesky (``solver._update_gradient``; with
    ``cholesky`` a ``small_spd.SOLVERS`` form, :func:`_gradient_dense`'s written-out one) in MJX's
    ``while_loop``, which is faster there (measured; comment below); only the start is shared.
    """
    if not is_newton_pyramidal(m):
        raise ValueError(
            f"leaf_newton.solve needs the Newton solver and the pyramidal cone; the model has "
            f"{m.opt.solver} and {m.opt.cone} (use mjx.step)"
        )
    # The direction: the arrowhead's with leaves, else the dense Hessian's (MJX's, or written out).
    gradient: Callable[[solver.Context], solver.Context]
    if split is not None:
        m_rr, m_kk = _mass_parts(m, d, split)
        gradient = functools.partial(_gradient, m, d, split=split, m_rr=m_rr, m_kk=m_kk)
    elif cholesky == "library":
        gradient = functools.partial(solver._update_gradient, m, d)
    else:
        gradient = functools.partial(_gradient_dense, m, d, cholesky=cholesky)

    def cond(ctx: solver.Context) -> jax.Array:
        improvement = solver._rescale(m, d, ctx.prev_cost - ctx.cost)
        norm = solver._rescale(m, d, jnp.linalg.norm(ctx.grad))
        done = ctx.solver_niter >= m.opt.iterations
        done |= improvement < m.opt.tolerance
        done |= norm < m.opt.tolerance
        return ~done

    def body(ctx: solver.Context) -> solver.Context:
        ctx = solver._linesearch(m, d, ctx)
        ctx = solver._update_constraint(m, d, ctx)
        ctx = gradient(ctx)
        return ctx.replace(search=-ctx.Mgrad, solver_niter=ctx.solver_niter + 1)

    if m.opt.disableflags & DisableBit.WARMSTART:
        start = solver.Context.create(m, d.replace(qacc=d.qacc_smooth), grad=False)
    else:
        # MJX builds the chosen start's context a third time; it is the cheaper of these two, so pick it.
        warm = solver.Context.create(m, d.replace(qacc=d.qacc_warmstart), grad=False)
        smooth = solver.Context.create(m, d.replace(qacc=d.qacc_smooth), grad=False)
        use_warm = warm.cost < smooth.cost
        start = jax.tree_util.tree_map(functools.partial(jnp.where, use_warm), warm, smooth)
    d = d.replace(qacc=start.qacc)
    ctx = gradient(start)
    ctx = ctx.replace(search=-ctx.Mgrad)
    if m.opt.iterations == 1:
        return _result(d, body(ctx))
    # Measured at 8192 envs on one H100, same calls: written out, the piano's loop is 1.057M physics steps/s
    # against 0.931M as a while_loop; reach's (MJX's dense direction) 2.53M against 2.84M as a while_loop.
    loop = newton_loop if split is not None else while_newton_loop
    return _result(d, loop(cond, body, ctx, m.opt.iterations))


def _result(d: mjx.Data, ctx: solver.Context) -> mjx.Data:
    """``d`` with the solve's constraint force, acceleration and row forces."""
    return d.tree_replace(
        {"qfrc_constraint": ctx.qfrc_constraint, "qacc": ctx.qacc, "_impl.efc_force": ctx.efc_force}
    )
