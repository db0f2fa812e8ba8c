"""Can the update run beside the rollout on one GPU? (issue 19: steady training >= 90 % of the raw env.)

The update (128 Adam steps) and the rollout (the env's physics) are both bound by the number of small
kernels they launch, not by the device's arithmetic, and the device runs one program at a time (session 35:
an evaluation on a thread did not overlap an epoch). XLA runs a computation annotated with a stream
(``jax.experimental.compute_on.compute_on2(compute_type="gpu_stream:N")``, XLA's
``xla_gpu_experimental_stream_annotation``) on a stream of its own, so one program can hold both. This bench
measures, at a preset's training batch on one device:

- ``micro``: two independent chains of ``--micro-steps`` small matmuls, alone, one after the other in one
  program, both in one loop whose body holds a step of each, with the second chain on stream 1, and with
  the second chain's (loop-free) step on stream 1 inside that loop's body;
- ``real``: the trainer's rollout alone, the update alone, and the one-program forms of a pipelined
  iteration (the update of the previous iteration's data while the rollout collects the next, with a policy
  one update older than brax's; ``--forms`` picks them, as each compiles for minutes): ``pipelined``, the
  update on stream 1 beside the rollout; ``interleaved`` (``one_loop.overlapped``), each of the rollout's
  first control steps and one SGD pass (16 Adam steps at the gpu preset) in one loop body, so that inside
  the body's graph nothing orders the two (session 43: two loops side by side in one program ran one after
  the other); ``streamed`` (``one_loop.streamed``, session 53), the same with each SGD pass, its Adam steps
  written out, on stream 1 (``training.gpu_stream``). Per iteration, after a warm-up, best of ``--iters``.

It checks that the one-program forms' outputs equal the two programs' (same inputs, same keys), and counts
the calls and loops inside the streamed form's stream computations (XLA refuses any).

Session 38 (H100, jax 0.11.2): XLA refused the micro rows' annotated program, whose chain is a loop ("No
ExecutionStreamId found for call-start ... only reachable through embedded calls": the annotation reached
the loop's own computations); a refused row now holds XLA's message and the others still run. Session 53
(H200, jax 0.11.2): a loop-free step on stream 1 inside a loop's body is accepted (two chains in 3.1-3.8
ms, one alone 5.4-6.1). The streamed iteration, once its stream computation held no call, ran: 219.9 ms
against 124.7 ms for the two programs with the library Cholesky, 106.8 against 111.7 ms with
``cholesky=columns`` and ``+WHILE`` (docs/benchmarks.md "Session 53"). On this CPU (jax 0.10) the
annotation is accepted and ignored.

``--plain``: the same rows with no stream annotation: the two chains (or the update and the rollout) are
merely independent in one program. Run under ``XLA_FLAGS=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT
--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL`` it asks whether XLA's command buffers (CUDA graphs,
whose nodes run concurrently where no buffer dependency orders them) overlap the two loops on their own.
Session 41 (H100): with the loops in graphs (``+WHILE,+CONDITIONAL``) the micro chains overlap (two in
4.1 ms, one alone 5.4 ms), the trainer's update and rollout do not (141.7 ms against 110.1 + 32.1).

Examples::

    python bench/stream_overlap.py --out $OUT/overlap.md                # gpu preset, one GPU
    python bench/stream_overlap.py --preset tiny --iters 1 --micro-steps 4   # CPU smoke check
    XLA_FLAGS="--xla_gpu_command_buffer_scheduling_mode=CONCURRENT" python bench/stream_overlap.py --plain
    XLA_FLAGS="$C --xla_gpu_enable_command_buffer=+WHILE" python bench/stream_overlap.py --forms streamed \
        --env-overrides cholesky=columns                                  # session 53's call 4
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from config_args import add_config_args, config_label, config_of, load_env
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from report import emit
from train_breakdown import best_time

from bar_policy import envs
from bar_policy.training import gpu_stream, one_loop
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.ppo import host_key, make_programs, slot_env
from bar_policy.training.parallel import AXIS, DataParallel
from bar_policy.training.startup.autotune import seed_autotune_cache
from bar_policy.training.startup.compiler import configure_compile_cache


def _place(fn: Any, stream: int, plain: bool) -> Any:
    """``fn`` annotated for GPU stream ``stream`` as it is (``gpu_stream.annotate``), or ``fn`` itself when
    ``plain``."""
    return fn if plain else gpu_stream.annotate(fn, stream)


def micro(steps: int, iters: int, plain: bool = False) -> dict[str, Any]:
    """Two chains of ``steps`` dependent (256, 256) matmuls + tanh: alone, in turn, in one loop whose body
    holds a step of each, on two streams (ms; a refused row holds XLA's message); ``plain``: the first
    three rows only (what XLA's own scheduling makes of two loops in one program)."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    w = jax.random.normal(k1, (256, 256), jnp.float32) / 16.0
    x = jax.random.normal(k2, (256, 256), jnp.float32)

    def chain(x: jax.Array) -> jax.Array:
        return jax.lax.fori_loop(0, steps, lambda _, y: jnp.tanh(y @ w), x)

    def one_step(y: jax.Array) -> jax.Array:
        return jnp.tanh(y @ w)

    def in_body(second: Any) -> Any:
        """Both chains in one loop: each body holds a step of each (``second``: the second's step)."""
        return lambda a, b: jax.lax.fori_loop(0, steps, lambda _, c: (one_step(c[0]), second(c[1])), (a, b))

    both = jax.jit(lambda a, b: (chain(a), chain(b)))
    streamed = jax.jit(lambda a, b: (chain(a), _place(chain, 1, plain)(b)))
    one = jax.jit(chain)
    out: dict[str, Any] = {"one chain": best_time(lambda: one(x), iters)}
    out["two chains, one program"] = best_time(lambda: both(x, x), iters)
    body_plain = jax.jit(in_body(one_step))
    out["two chains in one loop body"] = best_time(lambda: body_plain(x, x), iters)
    if not plain:  # plain: ``streamed`` is ``both``, so neither row says anything
        # Session 53: each row on its own, so that XLA refusing one (session 38: the annotated loop) still
        # leaves the other. The second row annotates a loop-free step inside the loop's body.
        body_streamed = jax.jit(in_body(gpu_stream.annotate(one_step, 1)))
        for row, fn in (
            ("two chains, second on stream 1", streamed),
            ("one loop, the second's step on stream 1 in each body", body_streamed),
        ):
            try:
                out[row] = best_time(lambda fn=fn: fn(x, x), iters)
                a, b = fn(x, x)
            except jax.errors.JaxRuntimeError as err:
                out[row] = f"refused: {str(err)[:300]}"
                continue
            diff = jnp.max(jnp.abs(jnp.stack(both(x, x)) - jnp.stack([a, b])))
            out[f"max |{row} - plain|"] = float(diff)
    return {k: (1e3 * v if isinstance(v, float) and "|" not in k else v) for k, v in out.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--iters", type=int, default=5, help="timed calls per row")
    p.add_argument("--micro-steps", type=int, default=400, help="matmuls per chain in the micro rows")
    p.add_argument("--no-real", action="store_true", help="the micro rows only")
    p.add_argument("--plain", action="store_true", help="no stream annotation (see the module docstring)")
    p.add_argument(
        "--forms",
        default="pipelined,interleaved,streamed",
        help="which one-program forms to compile and time (comma-separated; each compile takes minutes)",
    )
    p.add_argument("--out", default="")
    args = p.parse_args()

    api = gpu_stream.stream_api()
    lines = [
        f"stream overlap: {jax.devices()[0].device_kind}, jax {jax.__version__}, {api}, plain {args.plain}, "
        f"XLA_FLAGS {os.environ.get('XLA_FLAGS', '')!r}"
    ]
    lines += ["", "| micro row | ms |", "|---|---:|"]
    try:
        rows = micro(args.micro_steps, args.iters, args.plain)
    except jax.errors.JaxRuntimeError as err:  # the trainer's programs hold loops too: no point going on
        emit("\n".join([*lines[:1], "", f"XLA refused the annotated program: {str(err)[:400]}"]), args.out)
        return 1
    lines += [f"| {k} | {v:.4g} |" if isinstance(v, float) else f"| {k} | {v} |" for k, v in rows.items()]
    emit("\n".join(lines), args.out)
    if args.no_real:
        return 0

    cache_dir = configure_compile_cache(True)
    cfg = config_of(args)
    jax.config.update(
        "jax_default_matmul_precision", "highest" if cfg.matmul_precision == "highest" else None
    )
    print("autotune seed:", seed_autotune_cache(cache_dir, enabled=cfg.autotune_seed))
    ppo = cfg.ppo
    env = load_env(args.env, cfg)
    randomizer = envs.get_randomizer(args.env, env.config)
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(env.observation_size, env.action_size, ppo, cfg.network)
    n, steps = ppo.num_envs, ppo.steps_per_iteration
    unrolls = steps // (n * ppo.unroll_length)

    progs = make_programs(env, cfg, learner, dp, envs.wrap_for_brax_training, randomizer)

    def rollout(ts: Any, carry: Any, key: jax.Array) -> Any:
        batch = slot_env(env, envs.wrap_for_brax_training, randomizer, carry[1])
        state, data, _ = learner.rollout(ts, carry[0], key, batch, unrolls)
        return (state, carry[1]), data

    def update(ts: Any, data: Any, key: jax.Array) -> Any:
        return learner.update(ts, data, key)[0]

    def pipelined(ts: Any, carry: Any, data: Any, key: jax.Array) -> Any:
        """The update of ``data`` on stream 1 while the rollout (with ``ts``) collects the next data."""
        new_ts = _place(update, 1, args.plain)(ts, data, key)
        carry, next_data = rollout(ts, carry, key)
        return new_ts, carry, next_data

    def interleaved(ts: Any, carry: Any, data: Any, key: jax.Array) -> Any:
        """The pipelined iteration as one loop (``one_loop.overlapped``): each of the rollout's first
        control steps beside one SGD pass over ``data`` in one loop body."""
        batch = slot_env(env, envs.wrap_for_brax_training, randomizer, carry[1])
        out = one_loop.overlapped(learner, ts, carry[0], key, batch, unrolls, data, key)
        new_ts, state, next_data = out[:3]
        return new_ts, (state, carry[1]), next_data

    def streamed(ts: Any, carry: Any, data: Any, key: jax.Array) -> Any:
        """The pipelined iteration as one loop (``one_loop.streamed``): each of the rollout's first
        control steps beside one whole SGD pass on GPU stream 1 in one loop body."""
        batch = slot_env(env, envs.wrap_for_brax_training, randomizer, carry[1])
        out = one_loop.streamed(learner, ts, carry[0], key, batch, unrolls, data, key)
        new_ts, state, next_data = out[:3]
        return new_ts, (state, carry[1]), next_data

    rep, shard = P(), P(AXIS)
    f_roll = dp.map(rollout, (rep, shard, rep), (shard, shard))
    f_update = dp.map(update, (rep, shard, rep), rep)
    f_pipe = dp.map(pipelined, (rep, shard, shard, rep), (rep, shard, shard))
    f_inter = dp.map(interleaved, (rep, shard, shard, rep), (rep, shard, shard))
    f_streamed = dp.map(streamed, (rep, shard, shard, rep), (rep, shard, shard))
    key = dp.replicate(host_key(0, 9))
    t0 = time.perf_counter()
    ts = progs.init(dp.replicate(host_key(0, 1)))
    carry = progs.reset(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
    carry, data = f_roll(ts, carry, key)
    jax.block_until_ready(f_update(ts, data, key))
    compile_parts = time.perf_counter() - t0
    t0 = time.perf_counter()
    forms = set(args.forms.split(","))
    piped = inter = stream_out = "not run (--forms)"
    try:  # session 38: XLA refuses the annotated update (it holds loops)
        if "pipelined" in forms:
            piped = f_pipe(ts, carry, data, key)
            jax.block_until_ready(piped)
    except jax.errors.JaxRuntimeError as err:
        piped = f"refused: {str(err)[:300]}"
    compile_pipe = time.perf_counter() - t0
    t0 = time.perf_counter()
    if "interleaved" in forms:
        inter = f_inter(ts, carry, data, key)
        jax.block_until_ready(inter)
    compile_inter = time.perf_counter() - t0
    if "streamed" in forms:  # what XLA refuses (gpu_stream's docstring): a call or loop inside the stream's
        text = f_streamed.lower(ts, carry, data, key).as_text()
        funcs = text.split("func.func ")
        stream_fns = [f for f in funcs if f.startswith("private @compute_on")]
        nested = sum(f.count("call @") + f.count("stablehlo.while") for f in stream_fns)
        print(f"streamed: {len(stream_fns)} stream computations, {nested} calls or loops inside them")
    t0 = time.perf_counter()
    try:
        if "streamed" in forms:
            stream_out = f_streamed(ts, carry, data, key)
            jax.block_until_ready(stream_out)
    except (jax.errors.JaxRuntimeError, ValueError) as err:  # XLA's or gpu_stream's refusal
        stream_out = f"refused: {str(err)[:400]}"
    compile_streamed = time.perf_counter() - t0

    # Same inputs and keys: each one-program form's outputs against the two programs'.
    ref = (f_update(ts, data, key), f_roll(ts, carry, key)[1])

    def max_diff(out: tuple) -> float:
        diffs = jax.tree.map(
            lambda a, b: (
                float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))))
                if np.size(a)
                else 0.0
            ),
            (out[0], out[2]),
            ref,
        )
        return max(jax.tree.leaves(diffs))

    rows = {
        "rollout alone": best_time(lambda: f_roll(ts, carry, key), args.iters),
        "update alone": best_time(lambda: f_update(ts, data, key), args.iters),
    }
    rows["rollout then update (two programs)"] = best_time(
        lambda: f_update(ts, f_roll(ts, carry, key)[1], key), args.iters
    )
    piped_row = "pipelined, one program, no annotation" if args.plain else "pipelined (update on stream 1)"
    if not isinstance(piped, str):
        rows[piped_row] = best_time(lambda: f_pipe(ts, carry, data, key), args.iters)
    if not isinstance(inter, str):
        rows["interleaved: a control step beside an SGD pass per loop body"] = best_time(
            lambda: f_inter(ts, carry, data, key), args.iters
        )
    if not isinstance(stream_out, str):
        rows["streamed: a control step beside an SGD pass on stream 1 per loop body"] = best_time(
            lambda: f_streamed(ts, carry, data, key), args.iters
        )
    lines += [
        "",
        f"{args.env}, {config_label(args)}, {n} envs, {steps:,} env steps and "
        f"{ppo.num_updates_per_batch * ppo.num_minibatches} Adam steps per iteration",
        "",
        "| row | ms per iteration | env steps/s |",
        "|---|---:|---:|",
    ]
    lines += [f"| {k} | {1e3 * v:.1f} | {steps / v:,.0f} |" for k, v in rows.items()]
    lines += [
        "",
        f"compile + first call: rollout, update {compile_parts:.1f} s; pipelined {compile_pipe:.1f} s; "
        f"interleaved {compile_inter:.1f} s; streamed {compile_streamed:.1f} s",
        f"max |one program - two programs| over the new params and the data: pipelined "
        f"{piped if isinstance(piped, str) else format(max_diff(piped), '.3g')}, "
        f"interleaved {inter if isinstance(inter, str) else format(max_diff(inter), '.3g')}, streamed "
        + (stream_out if isinstance(stream_out, str) else f"{max_diff(stream_out):.3g}"),
    ]
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
