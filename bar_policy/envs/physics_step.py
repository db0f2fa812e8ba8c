"""The env's physics step: ``mjx.step``, with exact speed-ups that the model's structure allows.

1. Contact rows with a static Jacobian mask (``contact_rows``): every scene.
2. The Newton solve factored as an arrowhead where the scene has leaf dofs (``leaf_newton``): the piano's
   keys.
3. Where there are leaves, the Newton loop written out instead of a ``while_loop``
   (``leaf_newton.newton_loop``); every Newton scene on the pyramidal cone builds its start once, not twice.

None changes the physics: each is MJX's computation rearranged (tests: ``tests/envs/test_physics_step.py``,
equal to ``mjx.step`` to float64 rounding). The sequence below is ``mujoco.mjx._src.forward``'s
``fwd_position``, ``forward`` and ``step`` (mujoco-mjx 3.17) with those calls swapped in.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, sensor, smooth, solver
from mujoco.mjx._src import forward as mjx_forward
from mujoco.mjx._src.types import IntegratorType

from bar_policy.envs import contact_rows, leaf_newton

_INTEGRATORS = (int(mujoco.mjtIntegrator.mjINT_EULER), int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST))


@dataclass(frozen=True)
class StepPlan:
    """What :func:`step` needs from the compiled model: the (nbody, nv) ancestor mask and the leaf split."""

    ancestors: np.ndarray
    split: leaf_newton.LeafSplit | None


def plan(m: mujoco.MjModel) -> StepPlan | None:
    """The plan for ``m``, or None where :func:`step` would not be MJX's step (then ``mjx.step`` runs).

    None for RK4 (MJX's own ``forward`` runs inside it) and the implicit integrator (not followed here).
    """
    if int(m.opt.integrator) not in _INTEGRATORS:
        return None
    return StepPlan(ancestors=contact_rows.ancestor_dofs(m), split=leaf_newton.leaf_split(m))


def fwd_position(m: mjx.Model, d: mjx.Data, p: StepPlan) -> mjx.Data:
    """``mjx_forward.fwd_position`` with :func:`contact_rows.make_constraint`."""
    d = smooth.kinematics(m, d)
    d = smooth.com_pos(m, d)
    d = smooth.camlight(m, d)
    d = smooth.tendon(m, d)
    d = smooth.crb(m, d)
    d = smooth.tendon_armature(m, d)
    d = smooth.factor_m(m, d)
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
    d = mjx_forward.fwd_acceleration(m, d)
    if d._impl.efc_J.size == 0:
        return d.replace(qacc=d.qacc_smooth)
    d = leaf_newton.solve(m, d, p.split) if leaf_newton.is_newton_pyramidal(m) else solver.solve(m, d)
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
        return mjx_forward.euler(m, d)
    return mjx_forward.implicit(m, d)
