"""Which physics options cost what: raw MJX throughput of model variants of the Lite, same harness.

Each variant edits the robot's ``MjSpec`` (``bar_policy.robot.scene.robot_spec``) and times
``jit(vmap(lax.scan(mjx.step) x 10))`` from random in-limit poses (so contacts occur), reporting physics
steps/s and the static constraint-row count ``nefc`` that the solver carries for every env.

    python bench/mjx_variants.py --batches 8192,32768 --out $OUT/variants.md
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy.robot.scene import compile_scene, robot_spec


def variant_model(name: str) -> mujoco.MjModel:
    """The Lite (``arms``) with one change applied (``base``: as built; condim 1, 3 / 5 iterations)."""
    spec = robot_spec("arms")
    if "condim3" in name or name == "first":
        for geom in spec.geoms:
            geom.condim = 3
    if name == "first":  # the first MJCF: condim 3 and 6 Newton iterations / 8 line-search steps
        spec.option.iterations, spec.option.ls_iterations = 6, 8
    if "it1" in name:
        spec.option.iterations, spec.option.ls_iterations = 1, 4
    if "nofric" in name:
        for joint in spec.joints:
            joint.frictionloss = 0.0
    if "nocontact" in name:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return compile_scene(spec, "arms")


def bench(name: str, batch: int, substeps: int, min_time: float) -> tuple[int, float, float]:
    """(nefc, compile s, physics steps/s) of one variant at one batch size."""
    m = variant_model(name)
    mx = mjx.put_model(m)
    nefc = int(mjx.make_data(m)._impl.efc_J.shape[0])
    rng = np.random.default_rng(0)
    q = rng.uniform(m.jnt_range[:, 0], m.jnt_range[:, 1], (batch, m.nq)).astype(np.float32)
    d0 = mjx.make_data(m)
    d = jax.jit(jax.vmap(lambda qq: d0.replace(qpos=qq)))(jnp.asarray(q))

    def roll(m_: mjx.Model, d_: mjx.Data) -> mjx.Data:
        def body(c: mjx.Data, _: None) -> tuple[mjx.Data, None]:
            return mjx.step(m_, c), None

        return jax.lax.scan(body, d_, None, length=substeps)[0]

    f = jax.jit(jax.vmap(roll, in_axes=(None, 0)))
    t = time.perf_counter()
    d = f(mx, d)
    jax.block_until_ready(d.qpos)
    compile_s = time.perf_counter() - t
    d = jax.block_until_ready(f(mx, d))
    n, t = 0, time.perf_counter()
    while time.perf_counter() - t < min_time or n < 3:
        d = f(mx, d)
        n += 1
    jax.block_until_ready(d.qpos)
    dt = time.perf_counter() - t
    return nefc, compile_s, n * substeps * batch / dt


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--variants", default="first,condim3,base,it1,nofric,nocontact")
    p.add_argument("--batches", default="8192,32768")
    p.add_argument("--substeps", type=int, default=10)
    p.add_argument("--min-time", type=float, default=1.0)
    p.add_argument("--out", default=None)
    a = p.parse_args()
    lines = [
        f"devices: {jax.devices()}",
        "",
        "| variant | nefc | batch | compile s | physics steps/s |",
        "|---|---:|---:|---:|---:|",
    ]
    print("\n".join(lines), flush=True)
    for name in a.variants.split(","):
        for b in map(int, a.batches.split(",")):
            nefc, c, sps = bench(name, b, a.substeps, a.min_time)
            row = f"| {name} | {nefc} | {b} | {c:.1f} | {sps:.3e} |"
            print(row, flush=True)
            lines.append(row)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
