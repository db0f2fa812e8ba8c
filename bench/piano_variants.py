"""What makes the piano's MJX step expensive: the keyboard scene's variants side by side, one process.

Each variant is the keyboard scene of ``LitePiano`` (``compact_config()``, 49 keys) with edits joined by
``+``; ``robot`` is the robot alone (physics) or LiteReach (env), the anchor:

    capped      the scene as built (MJX's contact caps on: scene.MAX_GEOM_PAIRS, MAX_CONTACT_POINTS)
    uncapped    the caps off: the scene before them (commit 218165f)
    nolimit     the keys' travel stops off (no joint-limit rows; a press past 1 N goes past the stop)
    cg          MuJoCo's CG solver instead of Newton
    dense       dense mass matrix and Jacobian (MJX's AUTO picks sparse at nv >= 60, the keyboard's 63, while
                MJX says GPUs are usually faster dense; unmeasured: on the 2-core CPU its compile had not
                finished after 4 min at batch 32, against 16 s for ``capped``)
    nocon       no constraint solve at all (mjDSBL_CONSTRAINT: no contacts, limits or friction loss): not
                physics for the task, the ceiling a cheaper solver could reach
    leaf        --level physics: the step through ``envs.physics_step`` (static contact-row masks, the keys'
                dofs factored as an arrowhead in MJX's Newton); at --level env the env's default
    mjxsolve    --level env: the env on ``mjx.step`` itself (``physics_step.plan`` off)
    spd, spdcol --level env, ``robot``: the dense mass matrix's Cholesky factors written out (``small_spd``'s
                scalar or columns form, ``physics_step.plan(cholesky=...)``) instead of jax's library calls
    lswhile     the line search's fixed ``ls_iterations`` scan (a cond per step: under vmap every step runs)
                as a ``while_loop`` that stops once every env's search is done: the same values (the scan's
                late steps are no-ops), without reverse-mode autodiff; an experiment, patched while tracing
    libchol     the arrowhead's 14 x 14 solve through jax's Cholesky (``cho_factor``/``cho_solve``: a batched
                ``potrf`` and triangular solves on a GPU) instead of ``leaf_newton.spd_solve``'s unrolled one
    newtonwhile the Newton loop as MJX's while_loop (``leaf_newton.while_newton_loop``) instead of written out
                (``newton_loop``, the env's since 2026-11-27; ``newtonfor`` before it)
    lsunroll    the line search's scan unrolled (``unroll=True``: the same values, straight-line code)
    itN, lsN    N solver / line-search iterations (the robot's scene: 3 and 5)

Per variant: nv, constraint rows (nefc), contact rows, the narrow-phase pairs MJX tests each step (and the
pairs its contype/conaffinity filter allows, in brackets), and throughput:

- ``--level physics``: ``jit(vmap(scan(mjx.step x 10)))`` from the held ``piano_ready`` pose plus 0.03 rad
  noise (the arms fall onto the keys), best of 3 timings of ``--min-time`` s;
- ``--level env``: ``training.throughput.raw_env_steps_per_second`` (zero actions through the training
  wrappers and the randomiser, best of 3 calls), as ``env_throughput.py``; ``robot`` is LiteReach.

    python bench/piano_variants.py --level physics --batch 64 --variants robot,uncapped,capped   # CPU
    python bench/piano_variants.py --level env --batch 8192 --variants robot,uncapped,capped,capped+cg

Prints a markdown table (and writes it to ``--out``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver, solver

from bar_policy.envs import leaf_newton, physics_step
from bar_policy.robot.constants import load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.scene import SceneEdit, compile_scene, robot_spec
from bar_policy.tasks.piano import env as piano_env
from bar_policy.tasks.piano.held import held_pose
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.scene import keyboard_scene


def _edit(part: str) -> Callable[[mujoco.MjSpec], None]:
    """One variant edit of a spec that already holds the keyboard."""

    def apply(spec: mujoco.MjSpec) -> None:
        keys = [j for j in spec.joints if j.name.startswith("piano_key")]
        if part == "uncapped":
            for name in ("max_geom_pairs", "max_contact_points"):
                spec.delete(spec.numeric(name))
        elif part == "nolimit":
            for j in keys:
                j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        elif part == "cg":
            spec.option.solver = mujoco.mjtSolver.mjSOL_CG
        elif part == "dense":
            spec.option.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
        elif part == "nocon":
            spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
        elif part in ("leaf", "mjxsolve", "lswhile", "libchol", "newtonwhile", "lsunroll", "spd", "spdcol"):
            pass  # not a scene edit: the step function (``physics``, ``env_level``)
        elif part.startswith("it"):
            spec.option.iterations = int(part[2:])
        elif part.startswith("ls"):
            spec.option.ls_iterations = int(part[2:])
        elif part != "capped":
            valid = (
                "capped, uncapped, nolimit, cg, dense, nocon, leaf, mjxsolve, lswhile, libchol, newtonwhile, "
                "lsunroll, spd, spdcol, itN, lsN"
            )
            raise ValueError(f"unknown edit {part!r}; valid: {valid}")

    return apply


def variant_scene(variant: str) -> SceneEdit:
    """The keyboard scene of ``LitePiano`` with ``variant``'s edits (``+``-joined)."""
    base = keyboard_scene(compact_config())
    edits = [_edit(p) for p in variant.split("+")]

    def scene(spec: mujoco.MjSpec) -> None:
        base(spec)
        for e in edits:
            e(spec)

    return scene


def counts(m: mujoco.MjModel) -> dict[str, int]:
    """nv, nefc, contact rows, narrow-phase pairs per step and the pairs the bit filter allows."""
    d = mjx.make_data(m)
    groups = collision_driver._geom_groups(m)
    cap = int(m.numeric_data[m.numeric_adr[m.numeric("max_geom_pairs").id]]) if m.nnumeric else -1
    allowed = sum(len(p) for p in groups.values())
    tested = sum(min(len(p), cap) if cap > 0 else len(p) for p in groups.values())
    return {
        "nv": m.nv,
        "nefc": int(d._impl.efc_J.shape[0]),
        "ncon": int(d._impl.contact.dist.shape[0]),
        "pairs": tested,
        "allowed": allowed,
    }


def held_batch(m: mujoco.MjModel, batch: int) -> tuple[mjx.Model, mjx.Data]:
    """``m`` on the device and ``batch`` states: the held ``piano_ready`` pose + 0.03 rad noise (seed 0)."""
    robot = load_robot("arms")
    idx = RobotIndex.from_model(m, robot.joint_names)
    q = np.array(m.qpos0)
    q[idx.qpos] = held_pose(np.asarray(robot.pose("piano_ready")))
    qs = np.tile(q, (batch, 1))
    qs[:, idx.qpos] += np.random.default_rng(0).normal(0.0, 0.03, (batch, len(idx.qpos)))
    mx, d0 = mjx.put_model(m), mjx.make_data(m)
    return mx, jax.jit(jax.vmap(lambda qq: d0.replace(qpos=qq)))(jnp.asarray(qs, jnp.float32))


def physics(
    m: mujoco.MjModel, batch: int, min_time: float, substeps: int = 10, leaf: bool = False
) -> tuple[float, float]:
    """(compile s, physics steps/s) of raw ``mjx.step`` (``leaf``: ``leaf_newton.step``) from the held pose
    plus noise."""
    mx, d = held_batch(m, batch)

    plan = physics_step.plan(m) if leaf else None
    if leaf and (plan is None or plan.split is None):
        raise ValueError("variant leaf: the scene has no leaf dofs (leaf_newton.leaf_split)")

    def roll(m_: mjx.Model, d_: mjx.Data) -> mjx.Data:
        return jax.lax.scan(lambda c, _: (physics_step.step(m_, c, plan), None), d_, None, length=substeps)[0]

    f = jax.jit(jax.vmap(roll, in_axes=(None, 0)))
    t = time.perf_counter()
    d = jax.block_until_ready(f(mx, d))
    compile_s = time.perf_counter() - t
    best = 0.0
    for _ in range(3):
        n, t = 0, time.perf_counter()
        while n < 2 or time.perf_counter() - t < min_time:
            d = jax.block_until_ready(f(mx, d))  # one call at a time (queued CPU calls once hung here)
            n += 1
        best = max(best, n * substeps * batch / (time.perf_counter() - t))
    return compile_s, best


def while_loop_capped(cond_fun: Callable, body_fun: Callable, init_val: object, max_iter: int) -> object:
    """``solver._while_loop_scan`` (at most ``max_iter`` bodies while ``cond_fun``) as a while loop."""

    def cond(carry: tuple[object, jax.Array]) -> jax.Array:
        val, it = carry
        return (it < max_iter) & cond_fun(val)

    def body(carry: tuple[object, jax.Array]) -> tuple[object, jax.Array]:
        val, it = carry
        return body_fun(val), it + 1

    return jax.lax.while_loop(cond, body, (init_val, jnp.int32(0)))[0]


def _patches(variant: str) -> list[Any]:
    """The patches a variant's step needs while tracing (``lswhile``)."""
    parts = variant.split("+")
    patches = []
    if "lswhile" in parts:
        patches.append(mock.patch.object(solver, "_while_loop_scan", while_loop_capped))
    if "lsunroll" in parts:
        patches.append(mock.patch.object(solver, "_while_loop_scan", scan_unrolled))
    if "newtonwhile" in parts:
        patches.append(mock.patch.object(leaf_newton, "newton_loop", leaf_newton.while_newton_loop))
    if "libchol" in parts:
        patches.append(mock.patch.object(leaf_newton, "spd_solve", library_spd_solve))
    return patches


def scan_unrolled(cond_fun: Callable, body_fun: Callable, init_val: object, max_iter: int) -> object:
    """``solver._while_loop_scan`` with its scan unrolled (``lsunroll``): the same steps, no loop."""

    def step(carry: tuple[object, jax.Array], _: None) -> tuple[tuple[object, jax.Array], None]:
        val, go = carry
        new = body_fun(val)
        val = jax.tree_util.tree_map(lambda a, b: jnp.where(go, a, b), new, val)
        return (val, go & cond_fun(val)), None

    return jax.lax.scan(step, (init_val, cond_fun(init_val)), None, length=max_iter, unroll=True)[0][0]


def library_spd_solve(a: jax.Array, y: jax.Array) -> jax.Array:
    """``a^-1 y`` through jax's Cholesky (``libchol``): what ``leaf_newton`` did before ``spd_solve``."""
    return jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(a), y)


def env_level(variant: str, batch: int, steps: int) -> tuple[mujoco.MjModel, float, float]:
    """(model, compile s, physics steps/s) of LitePiano in ``variant``'s scene (``robot``: LiteReach, whose
    step takes the step-function variants: ``robot+newtonwhile``, ``robot+mjxsolve``)."""
    from bar_policy import envs
    from bar_policy.training.throughput import raw_env_steps_per_second

    name = "LiteReach" if variant.split("+")[0] == "robot" else "LitePiano"
    parts = variant.split("+")
    plan = physics_step.plan
    if "mjxsolve" in parts:
        plan = lambda _m: None  # noqa: E731
    elif "spd" in parts or "spdcol" in parts:
        plan = functools.partial(physics_step.plan, cholesky="scalar" if "spd" in parts else "columns")
    with (
        mock.patch.object(piano_env, "keyboard_scene", lambda _kb: variant_scene(variant)),
        mock.patch.object(physics_step, "plan", plan),
    ):
        env = envs.load(name)
    with contextlib.ExitStack() as stack:
        for patch in _patches(variant):
            stack.enter_context(patch)
        r = raw_env_steps_per_second(
            env,
            envs.wrap_for_brax_training,
            num_envs=batch,
            steps=steps,
            randomizer=envs.get_randomizer(name, env.config),
        )
    return env.mj_model, r["compile_s"], r["env_steps_per_s"] * env.n_substeps


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", default="robot,uncapped,capped")
    p.add_argument("--level", choices=("physics", "env"), default="physics")
    p.add_argument("--batch", type=int, default=64, help="envs per batch")
    p.add_argument("--min-time", type=float, default=2.0, help="physics: seconds per timing")
    p.add_argument("--steps", type=int, default=20, help="env: control steps per timed call")
    p.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = p.parse_args()
    rows = [
        f"device {jax.devices()[0].device_kind}, level {a.level}, batch {a.batch}",
        "",
        "| variant | nv | nefc | contact rows | narrow-phase pairs (allowed) | compile s | physics steps/s |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    print("\n".join(rows), flush=True)
    for v in a.variants.split(","):
        if a.level == "env":
            m, c, sps = env_level(v, a.batch, a.steps)
        else:
            spec = robot_spec("arms")
            if v != "robot":
                variant_scene(v)(spec)
            m = compile_scene(spec, "arms")
            with contextlib.ExitStack() as stack:
                for patch in _patches(v):
                    stack.enter_context(patch)
                c, sps = physics(m, a.batch, a.min_time, leaf="leaf" in v.split("+"))
        k = counts(m)
        pairs = f"{k['pairs']} ({k['allowed']})"
        rows.append(f"| {v} | {k['nv']} | {k['nefc']} | {k['ncon']} | {pairs} | {c:.1f} | {sps:,.0f} |")
        print(rows[-1], flush=True)
    if a.out:
        a.out.write_text("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
