"""Where a piano physics step's time goes: MJX's step pieces timed alone, batched, one process.

From states in contact (the held pose plus 0.03 rad noise, 50 physics steps on), each piece runs
``--reps`` times in a ``fori_loop`` under ``jit(vmap)`` at ``--batch`` envs, its output fed back so XLA cannot
hoist it; best of 3 calls; reported as microseconds per env-step (call time / batch / reps) and as a share
of the whole step. The pieces (``mujoco.mjx._src``, as ``forward.py`` and ``solver.py`` call them):

    step           the whole physics step (physics_step.step: the env's)
    mjx_step       mjx.step itself
    fwd_position   kinematics .. factor_m, collision, make_constraint, transmission (physics_step's)
    collision      collision_driver.collision alone
    make_constraint  constraint rows (efc_J, efc_D, efc_aref) alone (contact_rows': static masks)
    mjx_make_constraint  MJX's own
    friction_rows, limit_rows, contact_rows  make_constraint's row groups alone (the rest of it is the
                   impedance and reference acceleration of every row)
    linesearch_while  the line search as a while_loop (``piano_variants.py``'s ``lswhile``)
    fwd_vel_acc    fwd_velocity, fwd_actuation, fwd_acceleration
    ctx_create     solver.Context.create(grad=False) (the warm start builds two, the solve one more)
    linesearch     solver._linesearch (one per Newton iteration)
    update_constraint  solver._update_constraint (one per iteration)
    grad_leaf      the arrowhead Newton direction (leaf_newton._gradient; one per iteration + 1)
    grad_dense     MJX's dense Newton direction (solver._update_gradient)
    mul_m          support.mul_m (sparse M times a vector)
    euler          the integrator

    python bench/piano_solver_parts.py --batch 8192          # GPU
    python bench/piano_solver_parts.py --batch 32 --reps 2   # CPU check
    python bench/piano_solver_parts.py --scene reach --batch 4096   # LiteReach's scene (no leaf dofs)
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from unittest import mock

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, constraint, solver, support
from mujoco.mjx._src import forward as mjx_forward
from piano_variants import held_batch, while_loop_capped  # bench/ is on sys.path when run as a script

from bar_policy.envs import contact_rows, leaf_newton, physics_step
from bar_policy.robot.scene import compile_scene, robot_spec
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.scene import keyboard_scene


def _reach_batch(batch: int) -> tuple[mujoco.MjModel, mjx.Model, mjx.Data]:
    """LiteReach's model and ``batch`` states at uniform random joint angles within the limits (seed 0)."""
    from bar_policy import envs

    m = envs.load("LiteReach").mj_model
    lo, hi = m.jnt_range[:, 0], m.jnt_range[:, 1]
    qs = np.random.default_rng(0).uniform(lo, hi, (batch, m.nq))
    mx, d0 = mjx.put_model(m), mjx.make_data(m)
    return m, mx, jax.jit(jax.vmap(lambda qq: d0.replace(qpos=qq)))(jnp.asarray(qs, jnp.float32))


def _states(batch: int, scene: str = "piano") -> tuple[mjx.Model, mjx.Data, physics_step.StepPlan]:
    if scene == "reach":
        m, mx, d = _reach_batch(batch)
    else:
        spec = robot_spec("arms")
        keyboard_scene(compact_config())(spec)
        m = compile_scene(spec, "arms")
        mx, d = held_batch(m, batch)
    plan = physics_step.plan(m)

    def settle(x: mjx.Data) -> mjx.Data:
        return jax.lax.fori_loop(0, 50, lambda _, y: physics_step.step(mx, y, plan), x)

    d = jax.jit(jax.vmap(settle))(d)
    # The data as the solver sees it: positions, velocities and accelerations done, rows built.
    pre = jax.jit(
        jax.vmap(
            lambda x: mjx_forward.fwd_acceleration(
                mx,
                mjx_forward.fwd_actuation(mx, mjx_forward.fwd_velocity(mx, mjx_forward.fwd_position(mx, x))),
            )
        )
    )(d)
    return mx, jax.block_until_ready(pre), plan


def _time(f: Callable[[mjx.Data], mjx.Data], d: mjx.Data, batch: int, reps: int, min_time: float) -> float:
    """Microseconds per env and call of ``f`` (fed back ``reps`` times), best of 3."""
    g = jax.jit(jax.vmap(lambda x: jax.lax.fori_loop(0, reps, lambda _, y: f(y), x)))
    out = jax.block_until_ready(g(d))
    best = np.inf
    for _ in range(3):
        n, t = 0, time.perf_counter()
        while n < 2 or time.perf_counter() - t < min_time:
            out = jax.block_until_ready(g(d))
            n += 1
        best = min(best, (time.perf_counter() - t) / n)
    del out
    return best / batch / reps * 1e6


def pieces(m: mjx.Model, plan: physics_step.StepPlan) -> dict[str, Callable[[mjx.Data], mjx.Data]]:
    """Each piece as data -> data (a nudge of qacc or qpos carries the result on)."""
    split = plan.split

    def via_ctx(fn: Callable[[solver.Context, mjx.Data], solver.Context]) -> Callable[[mjx.Data], mjx.Data]:
        def run(d: mjx.Data) -> mjx.Data:
            ctx = solver.Context.create(m, d, grad=False)
            ctx = ctx.replace(search=-ctx.grad + 1e-3)  # a fixed direction when grad is not computed
            return d.replace(qacc=fn(ctx, d).qacc)

        return run

    def grad_leaf(ctx: solver.Context, d: mjx.Data) -> solver.Context:
        m_rr, m_kk = leaf_newton._mass_parts(m, d, split)
        out = leaf_newton._gradient(m, d, ctx, split, m_rr, m_kk)
        return out.replace(qacc=ctx.qacc + 1e-6 * out.Mgrad)

    def grad_dense(ctx: solver.Context, d: mjx.Data) -> solver.Context:
        out = solver._update_gradient(m, d, ctx)
        return out.replace(qacc=ctx.qacc + 1e-6 * out.Mgrad)

    def rows(fn: Callable[[mjx.Data], object]) -> Callable[[mjx.Data], mjx.Data]:
        def run(d: mjx.Data) -> mjx.Data:
            efc = fn(d)
            return d.replace(qacc=d.qacc + 1e-9 * efc.J.sum(0) + 1e-9 * efc.pos_aref.sum())

        return run

    def linesearch_while(ctx: solver.Context, d: mjx.Data) -> solver.Context:
        with mock.patch.object(solver, "_while_loop_scan", while_loop_capped):
            return solver._linesearch(m, d, ctx)

    def update_constraint(ctx: solver.Context, d: mjx.Data) -> solver.Context:
        return ctx.replace(qacc=ctx.qacc + 1e-6 * solver._update_constraint(m, d, ctx).qfrc_constraint)

    out = {
        "step": lambda d: physics_step.step(m, d, plan),
        "mjx_step": lambda d: mjx.step(m, d),
        "fwd_position": lambda d: physics_step.fwd_position(m, d, plan),
        "collision": lambda d: collision_driver.collision(m, d),
        "make_constraint": lambda d: contact_rows.make_constraint(m, d, plan.ancestors),
        "mjx_make_constraint": lambda d: constraint.make_constraint(m, d),
        "friction_rows": rows(lambda d: constraint._efc_friction(m, d)),
        "limit_rows": rows(lambda d: constraint._efc_limit_slide_hinge(m, d)),
        "contact_rows": rows(lambda d: contact_rows._frictionless(m, d, jnp.asarray(plan.ancestors))),
        "fwd_vel_acc": lambda d: mjx_forward.fwd_acceleration(
            m, mjx_forward.fwd_actuation(m, mjx_forward.fwd_velocity(m, d))
        ),
        "ctx_create": lambda d: d.replace(qacc=solver.Context.create(m, d, grad=False).Ma * 1e-6 + d.qacc),
        "linesearch": via_ctx(lambda c, d: solver._linesearch(m, d, c)),
        "linesearch_while": via_ctx(linesearch_while),
        "update_constraint": via_ctx(update_constraint),
        "grad_leaf": via_ctx(grad_leaf),
        "grad_dense": via_ctx(grad_dense),
        "mul_m": lambda d: d.replace(qacc=support.mul_m(m, d, d.qacc) * 1e-3),
        "euler": lambda d: mjx_forward.euler(m, d).replace(qpos=d.qpos, qvel=d.qvel),
    }
    if split is None:  # no leaf dofs (reach): no arrowhead direction to time
        out.pop("grad_leaf")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batch", type=int, default=8192)
    p.add_argument("--reps", type=int, default=10, help="calls of a piece per timed program")
    p.add_argument("--min-time", type=float, default=1.0, help="seconds per timing")
    p.add_argument("--pieces", default=None, help="comma-separated subset (default: all)")
    p.add_argument(
        "--scene", default="piano", choices=("piano", "reach"),
        help="piano: the keyboard scene from the held pose; reach: LiteReach's scene from random poses",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args()
    m, d, plan = _states(a.batch, a.scene)
    fns = pieces(m, plan)
    names = a.pieces.split(",") if a.pieces else list(fns)
    rows = [
        f"device {jax.devices()[0].device_kind}, {a.scene}, batch {a.batch}, {a.reps} calls per program",
        "",
        "| piece | us per env-step | share of step |",
        "|---|---:|---:|",
    ]
    print("\n".join(rows), flush=True)
    whole = None
    for name in names:
        us = _time(fns[name], d, a.batch, a.reps, a.min_time)
        whole = us if name == "step" else whole
        share = f"{100 * us / whole:.0f} %" if whole else "-"
        rows.append(f"| {name} | {us:.4f} | {share} |")
        print(rows[-1], flush=True)
    if a.out:
        a.out.write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
