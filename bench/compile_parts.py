"""Which part of the rollout program its compile time goes to (issue 19: the cold start's critical path).

The trainer's ``rollout`` (policy sampling + 20 env steps + transitions, one program) compiles in 25-34 s on
an H100, half of it in one thread's HLO passes (``program_split.py --profile``). Programs compile
concurrently on threads, so a part compiled as a program of its own would come off that critical path.
This bench compiles, each in a fresh process on an empty compile cache with the shipped autotune seeds:

- ``rollout``: the trainer's rollout program;
- ``step``: one control step of the batched training env (randomised models, auto-reset), no policy;
- ``step-noreset``: the same without the auto-reset (the evaluation's env step);
- ``physics``: the 10 physics substeps of a control step alone (``physics_step.step`` on the randomised
  batched model, zero applied force), no MIT law, observation, reward or reset;

and reports each one's trace + lower s, compile s and HLO lines. ``rollout - step`` is what the policy and
the learner's bookkeeping add; ``step - physics`` what the env's own code around the physics adds.

Examples::

    python bench/compile_parts.py --out $OUT/compile_parts.md             # GPU (~4 min)
    python bench/compile_parts.py --preset tiny --parts step,physics      # CPU smoke check
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from json_child import json_child
from one_device import one_device

PARTS = ("rollout", "step", "step-noreset", "physics")


def _compile_part(args: argparse.Namespace) -> dict[str, Any]:
    """Trace, lower and compile one part in this fresh process."""
    import jax
    import jax.numpy as jnp

    from bar_policy import envs
    from bar_policy.envs import physics_step
    from bar_policy.training.brax_programs import slot_env
    from bar_policy.training.parallel import AXIS

    o = one_device(args.preset, args.env, args.set, args.cache_dir)
    dp, progs, key_abs, i_abs, ts_abs, envs_abs = o.dp, o.progs, o.key_abs, o.i_abs, o.ts_abs, o.envs_abs
    env = envs.load(args.env)
    randomizer = envs.get_randomizer(args.env, env.config)
    wrap = envs.wrap_for_brax_training
    shard = jax.sharding.PartitionSpec(AXIS)
    n_act = env.action_size

    def step(envs_carry: Any, auto_reset: bool) -> Any:
        state, model_keys = envs_carry
        batch = slot_env(env, wrap, randomizer, model_keys, auto_reset=auto_reset)
        return batch.step(state, jnp.zeros((state.obs.shape[0], n_act)))

    def physics(envs_carry: Any) -> Any:
        state, model_keys = envs_carry
        batch = slot_env(env, wrap, randomizer, model_keys)
        plan = env._step_plan  # the env's own step plan (private: a bench reads it)

        def sub(d: Any, _: None) -> tuple[Any, None]:
            one = jax.vmap(lambda m, dd: physics_step.step(m, dd, plan), in_axes=(batch._in_axes, 0))
            return one(batch.model, d), None

        return jax.lax.scan(sub, state.data, None, length=env.n_substeps)[0]

    name = args.compile_part
    if name == "rollout":
        fn, fargs = progs.rollout, (ts_abs, envs_abs, key_abs, i_abs)
    elif name in ("step", "step-noreset"):
        fn = dp.map(lambda c: step(c, name == "step"), (shard,), shard)
        fargs = (envs_abs,)
    else:
        fn, fargs = dp.map(physics, (shard,), shard), (envs_abs,)
    t0 = time.monotonic()
    lowered = fn.trace(*fargs).lower()
    t1 = time.monotonic()
    lowered.compile()
    t2 = time.monotonic()
    hlo = lowered.compiler_ir("hlo").as_hlo_text().count("\n")
    return {"part": name, "trace_lower_s": t1 - t0, "compile_s": t2 - t1, "hlo_lines": hlo}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="gpu")
    p.add_argument("--env", default="LiteReach")
    p.add_argument("--set", nargs="*", default=[], help="config overrides, e.g. ppo.num_envs=8192")
    p.add_argument("--parts", default=",".join(PARTS))
    p.add_argument("--timeout", type=float, default=150, help="seconds per child process")
    p.add_argument("--out", default="")
    p.add_argument("--compile-part", default="", help=argparse.SUPPRESS)
    p.add_argument("--cache-dir", default="", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.compile_part:
        print(json.dumps(_compile_part(args)))
        return 0
    parts = [s for s in args.parts.split(",") if s]
    bad = [s for s in parts if s not in PARTS]
    if bad:
        p.error(f"unknown parts {bad}; valid: {list(PARTS)}")
    work = Path(tempfile.mkdtemp(prefix="compile_parts_"))
    rows = []
    for part in parts:
        argv = ["--compile-part", part, "--preset", args.preset, "--env", args.env]
        argv += ["--cache-dir", str(work / f"cache_{part}")] + (["--set", *args.set] if args.set else [])
        rows.append({"part": part, **json_child(__file__, argv, timeout=args.timeout)})
        print(json.dumps(rows[-1]), flush=True)
    lines = [
        f"compile parts: {args.env}, preset {args.preset} {' '.join(args.set)} (each in a fresh process, "
        "empty cache + seeds)",
        "",
        "| part | trace + lower s | compile s | HLO lines | note |",
        "|---|---:|---:|---:|---|",
    ]
    for r in rows:
        tl, c = r.get("trace_lower_s", float("nan")), r.get("compile_s", float("nan"))
        hlo, err = r.get("hlo_lines", 0), r.get("error", "")
        lines.append(f"| {r['part']} | {tl:.1f} | {c:.1f} | {hlo:,} | {err} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
