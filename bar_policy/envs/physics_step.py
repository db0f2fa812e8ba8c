"""The env's physics step: ``mjx.step``, with exact speed-ups that the model's structure allows.

1. Contact rows with a static Jacobian mask (``contact_rows``): every scene.
2. The Newton solve factored as an arrowhead where the scene has leaf dofs (``leaf_newton``): the piano's
   keys.
3. Where there are leaves, the Newton loop written out instead of a ``while_loop``
   (``leaf_newton.newton_loop``); every Newton scene on the pyramidal cone builds its start once, not twice.
4. Opt-in (``plan(cholesky="scalar" | "columns")``), where the mass matrix is dense (nv < 60: the robot
   and reach): every Cholesky of the step written out (``small_spd``) instead of a batched ``potrf`` and
   triangular solves: the mass matrix's factor and ``qacc_smooth``, the Newton direction, Euler's implicit
   damping. Off by default: on an H100 under XLA's default schedule the scalar form ran 2.01M physics
   steps/s against 2.13M and doubled the env's compile (2026-11-27). It is kept because XLA never records
   those library calls into a command buffer (a CUDA graph): with them the Newton ``while_loop`` and the
   rollout cannot each be one graph, and the loop's predicate goes to the host every Newton iteration
   (docs/performance.md, 2026-11-28).

None changes the physics: each is MJX's computation rearranged (tests: ``tests/envs/test_physics_step.py``,
equal to ``mjx.step`` to float64 rounding). The sequence below is ``mujoco.mjx._src.forward``'s
``fwd_position``, ``forward`` and ``step`` (mujoco-mjx 3.17) with those calls swapped in.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, sensor, smooth, solver, support
from mujoco.mjx._src import forward as mjx_forward
from mujoco.mjx._src.types import DisableBit, IntegratorType

from bar_policy.envs import contact_rows, leaf_newton, small_spd

_INTEGRATORS = (int(mujoco.mjtIntegrator.mjINT_EULER), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))


@dataclass(frozen=True)
class StepPlan:
    """What :func:`step` needs from the compiled model.

    The (nbody, nv) ancestor mask, the leaf split, and how the dense mass matrix's Cholesky factors are
    computed (``cholesky``, one of ``CHOLESKY``: item 4 above).
    """

    ancestors: np.ndarray
    split: leaf_newton.LeafSplit | None
    cholesky: str = "library"

    @property
    def unrolled(self) -> bool:
        """Whether the factors are written out (``small_spd``) rather than jax's library calls."""
        return self.cholesky != "library"


CHOLESKY = ("library", *small_spd.SOLVERS)
"""``plan``'s ``cholesky`` choices: jax's library calls (MJX's own), or a ``small_spd`` form."""


def plan(m: mujoco.MjModel, cholesky: str = "library") -> StepPlan | None:
    """The plan for ``m``, or None where :func:`step` would not be MJX's step (then ``mjx.step`` runs).

    None for RK4 (MJX's own ``forward`` runs inside it) and the implicit integrator (not followed here).
    ``cholesky``: one of ``CHOLESKY`` (item 4 above); a written-out form needs MJX's mass matrix dense.
    """
    if cholesky not in CHOLESKY:
        raise ValueError(f"physics_step.plan: unknown cholesky {cholesky!r}; valid: {list(CHOLESKY)}")
    if int(m.opt.integrator) not in _INTEGRATORS:
        return None
    if cholesky != "library" and support.is_sparse(m):
        raise ValueError(
            f"physics_step.plan: cholesky {cholesky!r} needs a dense mass matrix, nv = {m.nv} is sparse "
            "(use 'library')"
        )
    split = leaf_newton.leaf_split(m)
    return StepPlan(ancestors=contact_rows.ancestor_dofs(m), split=split, cholesky=cholesky)


def _factor_m(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``smooth.factor_m``; unrolled: ``qLD`` = the upper factor ``L^T``.

    That is MJX's dense layout (``cho_factor``'s ``lower=False``), so MJX's ``solve_m`` reads it as its own.
    """
    if not p.unrolled:
        return smooth.factor_m(m, d)
    factor, _ = small_spd.SOLVERS[p.cholesky]
    return d.tree_replace({"_impl.qLD": factor(d._impl.M).T})


def _fwd_acceleration(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``mjx_forward.fwd_acceleration``; unrolled: ``qacc_smooth`` solved with :func:`_factor_m`'s factor."""
    if not p.unrolled:
        return mjx_forward.fwd_acceleration(m, d)
    qfrc_applied = d.qfrc_applied + support.xfrc_accumulate(m, d)
    qfrc_smooth = d.qfrc_passive - d.qfrc_bias + d.qfrc_actuator + qfrc_applied
    qacc_smooth = small_spd.SOLVERS[p.cholesky][1](d._impl.qLD.T, qfrc_smooth)
    return d.replace(qfrc_smooth=qfrc_smooth, qacc_smooth=qacc_smooth)


def _euler(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``mjx_forward.euler``; unrolled: the implicit damping's ``(M + h D)^-1`` through ``small_spd``."""
    if not p.unrolled:
        return mjx_forward.euler(m, d)
    qacc = d.qacc
    if not m.opt.disableflags & DisableBit.EULERDAMP:
        damped = d._impl.M + jnp.diag(m.opt.timestep * m.dof_damping)
        factor, solve = small_spd.SOLVERS[p.cholesky]
        qacc = solve(factor(damped), d.qfrc_smooth + d.qfrc_constraint)
    return mjx_forward._advance(m, d, d.act_dot, qacc)


def fwd_position(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``mjx_forward.fwd_position`` with :func:`contact_rows.make_constraint`."""
    d = smooth.kinematics(m, d)
    d = smooth.com_pos(m, d)
    d = smooth.camlight(m, d)
    d = smooth.tendon(m, d)
    d = smooth.crb(m, d)
    d = smooth.tendon_armature(m, d)
    d = _factor_m(m, d, p)
    d = collision_driver.collision(m, d)
    d = contact_rows.make_constraint(m, d, p.ancestors)
    return smooth.transmission(m, d)


def forward(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``mjx.forward`` with :func:`fwd_position` and, on Newton's pyramidal cone, ``leaf_newton.solve``.

    Where there are leaves, that solve factors the arrowhead and writes the Newton loop out.
    """
    d = fwd_position(m, d, p)
    d = sensor.sensor_pos(m, d)
    d = mjx_forward.fwd_velocity(m, d)
    d = sensor.sensor_vel(m, d)
    d = mjx_forward.fwd_actuation(m, d)
    d = _fwd_acceleration(m, d, p)
    if d._impl.efc_J.size == 0:
        return d.replace(qacc=d.qacc_smooth)
    if leaf_newton.is_newton_pyramidal(m):
        d = leaf_newton.solve(m, d, p.split, p.cholesky)
    else:
        d = solver.solve(m, d)
    return sensor.sensor_acc(m, d)


def step(m: mjx.Model, d: mjx.Data, p: StepPlan | None) -> mjx.Data:
    """``mjx.step``, planned (None: ``mjx.step`` itself).

    ``m`` may be a randomised copy of the planned model: the plan reads only its structure (bodies, dofs,
    constraint rows), which randomisation keeps.
    """
    if p is None:
        return mjx.step(m, d)
    d = forward(m, d, p)
    if m.opt.integrator == IntegratorType.EULER:
        return _euler(m, d, p)
    return mjx_forward.implicit(m, d)
