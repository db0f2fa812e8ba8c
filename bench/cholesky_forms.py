"""The physics step's Cholesky forms side by side: compile time, step time, program size, library calls.

``physics_step.plan(cholesky=...)``: ``library`` (jax's batched ``potrf`` and triangular solves, MJX's own),
``scalar`` and ``columns`` (``envs.small_spd``, written out at trace time). For each form, in one process:
the batched physics step of the arms scene (``--batch`` envs at the ``piano_ready`` pose, the model's
timestep) lowered and compiled (s), its time per step (best of ``--iters`` calls of ``--steps`` steps), the
lowered program's HLO text lines, and the custom calls and triangular solves of the same step lowered for
CUDA (no GPU needed: a form that XLA can record whole into a CUDA graph has none).

Examples::

    python bench/cholesky_forms.py --batch 64                     # this CPU: compile and program size
    python bench/cholesky_forms.py --batch 4096 --out $OUT/chol.md  # one GPU
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from bar_policy.envs import physics_step
from bar_policy.robot.constants import load_robot
from bar_policy.robot.scene import load_model


def measure(form: str, batch: int, steps: int, iters: int) -> dict[str, object]:
    """One form's row (see the module docstring)."""
    from jax import export

    m = load_model("arms")
    d = mjx.make_data(m).replace(qpos=jnp.asarray(load_robot("arms").pose("piano_ready")))
    mx, plan = mjx.put_model(m), physics_step.plan(m, cholesky=form)
    data = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), d)
    one = jax.vmap(lambda s: physics_step.step(mx, s, plan))

    def roll(s: mjx.Data) -> mjx.Data:
        return jax.lax.fori_loop(0, steps, lambda _, c: one(c), s)

    t0 = time.perf_counter()
    lowered = jax.jit(roll).lower(data)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    out = jax.block_until_ready(compiled(data))
    best = float("inf")
    for _ in range(iters):
        t = time.perf_counter()
        out = jax.block_until_ready(compiled(out))
        best = min(best, time.perf_counter() - t)
    cuda = export.export(jax.jit(one), platforms=("cuda",))(data).mlir_module()
    return {
        "form": form,
        "lower_s": t1 - t0,
        "compile_s": t2 - t1,
        "ms_per_step": 1e3 * best / steps,
        "physics_steps_per_s": batch * steps / best,
        "hlo_lines": lowered.as_text().count("\n"),
        "cuda_calls": sorted(set(re.findall(r"custom_call @([\w$]+)", cuda))),
        "cuda_trsm": cuda.count("triangular_solve"),
        "finite": bool(np.isfinite(np.asarray(out.qpos)).all()),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--forms", default=",".join(physics_step.CHOLESKY), help="comma-separated forms")
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--steps", type=int, default=20, help="physics steps per timed call")
    p.add_argument("--iters", type=int, default=3, help="timed calls (the best is kept)")
    p.add_argument("--out", default="")
    args = p.parse_args()
    forms = [f for f in args.forms.split(",") if f]
    bad = [f for f in forms if f not in physics_step.CHOLESKY]
    if bad:
        p.error(f"unknown forms {bad}; valid: {list(physics_step.CHOLESKY)}")
    lines = [
        f"Cholesky forms: {jax.devices()[0].device_kind}, jax {jax.__version__}, batch {args.batch}, "
        f"{args.steps} physics steps per call",
        "",
        "| form | lower s | compile s | ms / step | physics steps/s | HLO lines | CUDA: custom calls, "
        "triangular solves | finite |",
        "|---|---:|---:|---:|---:|---:|---|---|",
    ]
    print("\n".join(lines), flush=True)
    for form in forms:
        r = measure(form, args.batch, args.steps, args.iters)
        lines.append(
            f"| {form} | {r['lower_s']:.1f} | {r['compile_s']:.1f} | {r['ms_per_step']:.3f} | "
            f"{r['physics_steps_per_s']:,.0f} | {r['hlo_lines']:,} | {r['cuda_calls'] or 'none'}, "
            f"{r['cuda_trsm']} | {r['finite']} |"
        )
        print(lines[-1], flush=True)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
