"""Which part of the rollout program its compile time goes to (the cold start's critical path).

The trainer's ``rollout`` (policy sampling + 20 env steps + transitions, one program) compiles in 25-34 s on
an H100, half of it in one thread's HLO passes (``program_split.py --profile``). Programs compile
concurrently on threads, so a part compiled as a program of its own would come off that critical path.
This bench compiles, each in a fresh process on an empty compile cache with the shipped autotune seeds:

- ``rollout``: the trainer's rollout program;
- ``step``: one control step of the batched training env (randomised models, auto-reset), no policy;
- ``step-noreset``: the same without the auto-reset (the evaluation's env step);
- ``physics``: the 10 physics substeps of a control step alone (``physics_step.step`` on the randomised
  batched model, zero applied force), no MIT law, observation, reward or reset; ``physics20``: 20 control
  steps of it in one ``scan`` (an iteration's physics);
- ``rest``: the rollout with ``physics_step.step`` replaced by the identity: what a second program would
  compile if the physics were a program of its own;
- ``physics+rest``: both traced, then compiled concurrently in one process (the critical path of a split);

and reports each one's trace + lower s, compile s and HLO lines. ``physics`` and ``physics20`` also run on
a reset batch: ``physics`` called 20 times from Python against ``physics20`` once, the cost of driving the
physics from the host one control step at a time. ``rollout - step`` is what the policy and
the learner's bookkeeping add; ``step - physics`` what the env's own code around the physics adds.

Examples::

    python bench/compile_parts.py --out $OUT/compile_parts.md             # GPU (~4 min)
    python bench/compile_parts.py --preset tiny --parts step,physics      # CPU smoke check
"""

from __future__ import annotations

import argparse
import functools
import json
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from config_args import add_config_args, config_argv, config_label, pick
from json_child import json_child
from one_device import one_device
from report import emit

PARTS = ("rollout", "step", "step-noreset", "physics", "physics20", "rest", "physics+rest")


def _compile_part(args: argparse.Namespace) -> dict[str, Any]:
    """Trace, lower and compile one part in this fresh process."""
    import jax
    import jax.numpy as jnp

    from bar_policy import envs
    from bar_policy.envs import physics_step
    from bar_policy.training.brax.programs import host_key, slot_env
    from bar_policy.training.parallel import AXIS

    o = one_device(args, args.cache_dir)
    dp, progs, key_abs, i_abs, ts_abs, envs_abs = o.dp, o.progs, o.key_abs, o.i_abs, o.ts_abs, o.envs_abs
    env, randomizer, wrap = o.env, o.randomizer, envs.wrap_for_brax_training
    shard = jax.sharding.PartitionSpec(AXIS)
    n_act = env.action_size

    def step(envs_carry: Any, auto_reset: bool) -> Any:
        state, model_keys = envs_carry
        batch = slot_env(env, wrap, randomizer, model_keys, auto_reset=auto_reset)
        return batch.step(state, jnp.zeros((state.obs.shape[0], n_act)))

    def physics(envs_carry: Any, steps: int = 1) -> Any:
        state, model_keys = envs_carry
        batch = slot_env(env, wrap, randomizer, model_keys)
        plan = env._step_plan  # the env's own step plan (private: a bench reads it)

        def sub(d: Any, _: None) -> tuple[Any, None]:
            one = jax.vmap(lambda m, dd: physics_step.step(m, dd, plan), in_axes=(batch._in_axes, 0))
            return one(batch.model, d), None

        data = jax.lax.scan(sub, state.data, None, length=env.n_substeps * steps)[0]
        return state.replace(data=data), model_keys

    def rest_rollout() -> Any:
        """The rollout program lowered with the physics step as the identity (traced after the patch)."""
        real = physics_step.step
        physics_step.step = lambda m, d, plan: d
        try:
            return progs.rollout.trace(ts_abs, envs_abs, key_abs, i_abs, o.w_abs).lower()
        finally:
            physics_step.step = real

    name = args.compile_part
    out: dict[str, Any] = {"part": name}
    t0 = time.monotonic()
    if name == "rollout":
        lowered = {name: progs.rollout.trace(ts_abs, envs_abs, key_abs, i_abs, o.w_abs).lower()}
    elif name in ("step", "step-noreset"):
        lowered = {name: dp.map(lambda c: step(c, name == "step"), (shard,), shard).trace(envs_abs).lower()}
    elif name in ("physics", "physics20"):
        fn = dp.map(functools.partial(physics, steps=20 if name == "physics20" else 1), (shard,), shard)
        lowered = {name: fn.trace(envs_abs).lower()}
    elif name == "rest":
        lowered = {name: rest_rollout()}
    else:
        fn = dp.map(physics, (shard,), shard)
        lowered = {"physics": fn.trace(envs_abs).lower(), "rest": rest_rollout()}
    t1 = time.monotonic()

    def compile_one(item: tuple[str, Any]) -> tuple[str, Any, float]:
        t = time.monotonic()
        return item[0], item[1].compile(), time.monotonic() - t

    with ThreadPoolExecutor(len(lowered)) as pool:
        done = list(pool.map(compile_one, lowered.items()))
    t2 = time.monotonic()
    out.update(trace_lower_s=t1 - t0, compile_s=t2 - t1)
    out["each_s"] = {n: round(s, 1) for n, _, s in done}
    out["hlo_lines"] = sum(lw.compiler_ir("hlo").as_hlo_text().count("\n") for lw in lowered.values())
    if name in ("physics", "physics20"):
        compiled = done[0][1]
        carry = o.reset.compile()(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
        calls = 20 if name == "physics" else 1
        best = float("inf")
        for _ in range(4):  # the first is a warm-up
            t = time.perf_counter()
            c = carry
            for _ in range(calls):
                c = compiled(c)
            jax.block_until_ready(c)
            best = min(best, time.perf_counter() - t)
        out["run_ms_20_steps"] = 1e3 * best
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--parts", default=",".join(PARTS))
    p.add_argument("--timeout", type=float, default=150, help="seconds per child process")
    p.add_argument("--out", default="")
    p.add_argument("--compile-part", default="", help=argparse.SUPPRESS)
    p.add_argument("--cache-dir", default="", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.compile_part:
        print(json.dumps(_compile_part(args)))
        return 0
    parts = pick(p, args.parts, PARTS, "parts")
    work = Path(tempfile.mkdtemp(prefix="compile_parts_"))
    rows = []
    for part in parts:
        argv = ["--compile-part", part, *config_argv(args), "--cache-dir", str(work / f"cache_{part}")]
        rows.append({"part": part, **json_child(__file__, argv, timeout=args.timeout)})
        print(json.dumps(rows[-1]), flush=True)
    lines = [
        f"compile parts: {args.env}, {config_label(args)} (each in a fresh process, empty cache + seeds)",
        "",
        "| part | trace + lower s | compile s (wall) | each program's compile s | HLO lines | ms per 20 "
        "control steps | note |",
        "|---|---:|---:|---|---:|---:|---|",
    ]
    for r in rows:
        tl, c = r.get("trace_lower_s", float("nan")), r.get("compile_s", float("nan"))
        hlo, err, run = r.get("hlo_lines", 0), r.get("error", ""), r.get("run_ms_20_steps")
        each = ", ".join(f"{k} {v}" for k, v in r.get("each_s", {}).items())
        run_s = f"{run:.1f}" if run is not None else "-"
        lines.append(f"| {r['part']} | {tl:.1f} | {c:.1f} | {each} | {hlo:,} | {run_s} | {err} |")
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
