"""Where a training iteration's time goes: env alone, rollout, SGD, the epoch program.

At the training batch of a preset (default ``gpu``: 4096 envs, 81,920 env steps and 128 Adam steps per
iteration), on one device, every part compiled once and timed over ``--iters`` calls after a warm-up:

- ``env``: the batched env alone (zero actions, as ``mjx_throughput.py``'s harness c), as many steps as one
  iteration collects; ``env random``: the same with uniform random actions in [-1, 1];
- ``rollout``: env + policy sampling + transitions (``Learner.rollout``), the same steps;
- ``update``: normaliser update + ``num_updates_per_batch`` x ``num_minibatches`` Adam steps on one
  iteration's data (``Learner.update``);
- ``epoch``: the trainer's epoch (its rollout and update programs, ``training.brax.state.run_epoch``) over
  ``--epoch-iters`` iterations, per iteration;
- ``loop``: the same epoch called as the training loop calls it (host sync and metrics read each call);
- ``env random, mid-training`` and ``rollout, mid-training``: the same as above, from the envs' state and the
  networks after the epoch rows (mid-episode: the states training steps from), not from a fresh reset;
- ``--concurrent``: an evaluation on a thread while an epoch runs, against the two one after the other;
- ``evaluate``: one periodic evaluation (``eval.num_eval_envs`` deterministic episodes of the env's
  ``episode_length`` steps), reported in s per evaluation below the table;
- with ``--fused``, ``epoch, one program`` and ``loop, one program``: the same for the one-program epoch
  the trainer had until 2026-11-27 (``bench/fused_epoch.py``), in the same process.
- with ``--loop-only``: ``env``, ``epoch`` and ``loop`` alone, the programs they need and no others (the
  tracker's nine programs did not compile within a 280 s call on an H200, 2026-11-29).

Every row runs under this process's ``XLA_FLAGS``; the trainer adds
``--xla_gpu_command_buffer_scheduling_mode=CONCURRENT`` on a GPU (``training.startup.backend_env``), so set it
to time the trainer's schedule (``...=LHS``: XLA's default). The training loop's target is ``loop`` >= 90 % of
``env`` steps/s. ``rollout - env`` is the policy's cost,
``update`` the learner's, ``loop - epoch`` the host's.

Examples::

    python bench/train_breakdown.py --out $OUT/breakdown.md            # gpu preset, one GPU
    python bench/train_breakdown.py --preset tiny --iters 2            # CPU smoke check
    python bench/train_breakdown.py --set ppo.num_updates_per_batch=4  # what an override would change
    python bench/train_breakdown.py --preset track --env LiteTrack --loop-only --epoch-iters 4
"""

from __future__ import annotations

import argparse
import functools
import os
import threading
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
from config_args import add_config_args, config_label, config_of, load_env
from fused_epoch import fused_epoch
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from report import emit
from trace_summary import device_summary, ops_tables, profiled

from bar_policy import envs
from bar_policy.envs import reward_weights
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.programs import _policy_params, make_programs, slot_env
from bar_policy.training.brax.state import epoch_iterations, host_key, run_epoch
from bar_policy.training.parallel import AXIS, DataParallel
from bar_policy.training.startup.autotune import seed_autotune_cache
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compile_cache import configure_compile_cache
from bar_policy.training.startup.compiler import Compiler


def best_time(fn: Any, iters: int) -> float:
    """Seconds per call (best of ``iters`` calls after one warm-up)."""
    jax.block_until_ready(fn())
    best = float("inf")
    for _ in range(iters):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--iters", type=int, default=5, help="timed calls per part")
    p.add_argument("--epoch-iters", type=int, default=0, help="iterations per epoch call (0: the trainer's)")
    p.add_argument("--no-compile-cache", action="store_true")
    p.add_argument(
        "--fused",
        action="store_true",
        help="also the one-program epoch of before 2026-11-27 (bench/fused_epoch.py)",
    )
    p.add_argument(
        "--profile",
        default="",
        help="also trace one rollout + update call and one epoch under jax.profiler into this folder and "
        "print what the device did in each (bench/trace_summary.py device_summary)",
    )
    p.add_argument(
        "--profile-eval", action="store_true", help="with --profile, one evaluation too (a large trace)"
    )
    p.add_argument(
        "--profile-ops",
        type=int,
        default=0,
        help="with --profile, a table per program of its N instructions with the most kernel time",
    )
    p.add_argument(
        "--concurrent",
        action="store_true",
        help="also an evaluation on a thread while an epoch runs: the wall time against the two in turn",
    )
    p.add_argument(
        "--dump",
        default="",
        help="save the first rollout's data and the update of it to this .npz (two processes' XLA_FLAGS: "
        "compare with bench/schedule_parity.py --compare A B)",
    )
    p.add_argument(
        "--loop-only",
        action="store_true",
        help="only the env alone and the trainer's epoch and loop: four programs fewer to compile, for "
        "presets whose programs compile long (the tracker's)",
    )
    p.add_argument("--out", default="")
    args = p.parse_args()
    if args.loop_only and (args.fused or args.profile or args.concurrent or args.dump):
        p.error(
            "--loop-only times env, epoch and loop alone; --fused, --profile, --concurrent and --dump need "
            "the other programs"
        )

    cache_dir = configure_compile_cache(not args.no_compile_cache)
    cfg = config_of(args)
    # As the trainer (training.run): its matmul precision, and the shipped autotune seed before compiling.
    jax.config.update(
        "jax_default_matmul_precision", "highest" if cfg.matmul_precision == "highest" else None
    )
    print("autotune seed:", seed_autotune_cache(cache_dir, enabled=cfg.autotune_seed))
    ppo = cfg.ppo
    env = load_env(args.env, cfg)  # --env-overrides cholesky=columns reaches the env
    randomizer = envs.get_randomizer(args.env, env.config)
    wrap = envs.wrap_for_brax_training
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(env.observation_size, env.action_size, ppo, cfg.network)
    n, steps = ppo.num_envs, ppo.steps_per_iteration
    unrolls = steps // (n * ppo.unroll_length)
    args.epoch_iters = args.epoch_iters or epoch_iterations(cfg)  # the trainer's: its compile is cached
    progs = make_programs(env, cfg, learner, dp, wrap, randomizer)

    def env_only(envs_carry: Any, key: jax.Array, scale: float) -> Any:
        """The env alone: zero actions (as bench/mjx_throughput.py's harness c), or uniform random ones
        (motion like a young policy's: more contacts for the solver)."""
        state, model_keys = envs_carry
        batch = slot_env(env, wrap, randomizer, model_keys)

        def step(s: Any, k: jax.Array) -> tuple[Any, None]:
            a = jax.random.uniform(k, (n, env.action_size), minval=-1.0, maxval=1.0) * scale
            return batch.step(s, a), None

        keys = jax.random.split(key, steps // n)
        return jax.lax.scan(step, state, keys)[0].obs

    def rollout(ts: Any, envs_carry: Any, key: jax.Array) -> Any:
        batch = slot_env(env, wrap, randomizer, envs_carry[1])
        return learner.rollout(ts, envs_carry[0], key, batch, unrolls)[1]

    rep, shard = P(), P(AXIS)
    f_env = dp.sharded_jit(functools.partial(env_only, scale=0.0), (shard, rep), shard)
    f_env_random = dp.sharded_jit(functools.partial(env_only, scale=1.0), (shard, rep), shard)
    f_roll = dp.sharded_jit(rollout, (rep, shard, rep), shard)
    f_update = dp.sharded_jit(lambda ts, data, key: learner.update(ts, data, key)[0], (rep, shard, rep), rep)

    timer = StartupTimer()
    compiler = Compiler(timer)
    key_abs = dp.abstract(np.zeros(2, np.uint32), sharded=False)
    w_host = reward_weights.weights(env)  # the rollout's and evaluation's reward weights (an argument)
    w_abs, w = dp.abstract(w_host, sharded=False), dp.replicate(w_host)
    ts_abs = dp.abstract(jax.eval_shape(learner.init, key_abs), sharded=False)
    envs_abs = dp.abstract(compiler.submit("reset", progs.reset, key_abs, key_abs).out_info, sharded=True)
    compiler.submit("init", progs.init, key_abs)
    i_abs = dp.abstract(np.zeros((), np.int32), sharded=False)
    train_rollout = compiler.submit("train rollout", progs.rollout, ts_abs, envs_abs, key_abs, i_abs, w_abs)
    train_data_abs = dp.abstract(train_rollout.out_info[1], sharded=True)
    compiler.submit("train update", progs.update, ts_abs, train_data_abs, key_abs, i_abs)
    compiler.submit("env", f_env, envs_abs, key_abs)
    if not args.loop_only:
        compiler.submit("env random", f_env_random, envs_abs, key_abs)
        rollout_lowered = compiler.submit("rollout", f_roll, ts_abs, envs_abs, key_abs)
        data_abs = dp.abstract(rollout_lowered.out_info, sharded=True)
        compiler.submit("update", f_update, ts_abs, data_abs, key_abs)
        compiler.submit("evaluate", progs.evaluate, _policy_params(ts_abs), key_abs, key_abs, w_abs)
    if args.fused:
        fused = fused_epoch(env, cfg, learner, dp, wrap, randomizer, args.epoch_iters)
        compiler.submit("fused epoch", fused, ts_abs, envs_abs, key_abs)

    key = dp.replicate(host_key(0, 9))
    ts = compiler.get("init")(dp.replicate(host_key(0, 1)))
    carry = compiler.get("reset")(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
    data = None if args.loop_only else compiler.get("rollout")(ts, carry, key)  # the update row's data
    if args.dump:  # that rollout and its update from the seeds: what another process's flags must reproduce
        leaves = dp.to_host(jax.tree.leaves((data, compiler.get("update")(ts, data, key))))
        np.savez(args.dump, *[np.asarray(x) for x in leaves])
    rows: dict[str, float] = {}
    rows["env"] = best_time(lambda: compiler.get("env")(carry, key), args.iters)
    if not args.loop_only:
        rows["env random"] = best_time(lambda: compiler.get("env random")(carry, key), args.iters)
        rows["rollout"] = best_time(lambda: compiler.get("rollout")(ts, carry, key), args.iters)
        rows["update"] = best_time(lambda: compiler.get("update")(ts, data, key), args.iters)
    programs = (compiler.get("train rollout"), compiler.get("train update"))
    index = [dp.replicate(np.int32(i)) for i in range(args.epoch_iters)]
    state = {"ts": compiler.get("init")(dp.replicate(host_key(0, 1))), "carry": carry}

    def epoch_call(epoch: Any, read: bool) -> Any:
        """One epoch call ``epoch(ts, carry) -> (ts, carry, metrics, stats)`` on ``state``; ``read``: its
        metrics and stats copied to the host, as the training loop does."""
        state["ts"], state["carry"], metrics, stats = epoch(state["ts"], state["carry"])
        if read:
            dp.to_host((metrics, stats))
        return stats

    def one_epoch(read: bool) -> Any:
        return epoch_call(lambda ts_, carry_: run_epoch(*programs, ts_, carry_, key, index, w), read)

    rows["epoch"] = best_time(lambda: one_epoch(False), args.iters) / args.epoch_iters
    rows["loop"] = best_time(lambda: one_epoch(True), args.iters) / args.epoch_iters
    # From where training left the envs (mid-episode, the policy's poses and contacts), not a fresh reset.
    mid_ts, mid = state["ts"], state["carry"]
    if not args.loop_only:
        rows["env random, mid-training"] = best_time(lambda: compiler.get("env random")(mid, key), args.iters)
        rows["rollout, mid-training"] = best_time(
            lambda: compiler.get("rollout")(mid_ts, mid, key), args.iters
        )
    if args.fused:
        fused_program = compiler.get("fused epoch")

        def fused(ts_: Any, carry_: Any) -> Any:
            return fused_program(ts_, carry_, key)

        for row, read in (("epoch, one program", False), ("loop, one program", True)):
            rows[row] = best_time(lambda read=read: epoch_call(fused, read), args.iters) / args.epoch_iters

    profiles = {}

    def profile(name: str, folder: str, fn: Any) -> None:
        """``fn()`` traced into ``--profile``/``folder``; what the device did is reported as ``name``."""
        with profiled(Path(args.profile) / folder, python=False):
            jax.block_until_ready(fn())
        profiles[name] = device_summary(Path(args.profile) / folder, ops=args.profile_ops)

    if args.profile:
        jax.block_until_ready(state["ts"])
        profile(
            "rollout + update (the rows' programs)",
            "parts",
            lambda: compiler.get("update")(  # the current state: the epoch calls donate the one before
                state["ts"], compiler.get("rollout")(state["ts"], state["carry"], key), key
            ),
        )
        profile(
            f"epoch ({args.epoch_iters} iterations, the trainer's programs)", "epoch", lambda: one_epoch(True)
        )
        if args.profile_eval:
            evaluate = compiler.get("evaluate")
            profile("one evaluation", "evaluate", lambda: evaluate(_policy_params(state["ts"]), key, key, w))
    eval_s = (
        None
        if args.loop_only
        else best_time(lambda: compiler.get("evaluate")(_policy_params(ts), key, key, w), args.iters)
    )
    overlap = ""
    if args.concurrent:
        # An evaluation on a thread of its own while the main thread runs an epoch: does the device overlap
        # them (both programs are bound by kernel launches, not by the device's arithmetic)?
        evaluate = compiler.get("evaluate")
        epoch_s = best_time(lambda: one_epoch(True), args.iters)
        walls = []
        for _ in range(args.iters):
            done: dict[str, float] = {}
            t0 = time.perf_counter()

            def run_eval(t0: float = t0, done: dict[str, float] = done) -> None:
                jax.block_until_ready(evaluate(_policy_params(ts), key, key, w))
                done["eval"] = time.perf_counter() - t0

            worker = threading.Thread(target=run_eval)
            worker.start()
            one_epoch(True)
            done["epoch"] = time.perf_counter() - t0
            worker.join()
            walls.append((time.perf_counter() - t0, done["epoch"], done["eval"]))
        wall, ep_end, ev_end = min(walls)
        overlap = (
            f"epoch ({args.epoch_iters} iterations) and evaluation concurrently: {wall:.3f} s wall "
            f"(epoch done at {ep_end:.3f} s, evaluation at {ev_end:.3f} s) against {epoch_s:.3f} + "
            f"{eval_s:.3f} = {epoch_s + eval_s:.3f} s one after the other"
        )
    dev = jax.devices()[0].device_kind
    lines = [
        f"train breakdown: {args.env}, {config_label(args)}, {dev}, {n} envs, "
        f"{steps:,} env steps and {ppo.num_updates_per_batch * ppo.num_minibatches} Adam steps per iteration",
        "",
        "| part | ms per iteration | env steps/s | env alone / part (time) |",
        "|---|---:|---:|---:|",
    ]
    for name in rows:
        sps = steps / rows[name]
        lines.append(f"| {name} | {1e3 * rows[name]:.1f} | {sps:,.0f} | {rows['env'] / rows[name]:.1%} |")
    lines.append("")
    if eval_s is not None:
        eval_steps = cfg.eval.num_eval_envs * int(env.episode_length)
        lines.append(
            f"evaluate: {eval_s:.3f} s per evaluation ({cfg.eval.num_eval_envs} envs x "
            f"{int(env.episode_length)} steps, {eval_steps / eval_s:,.0f} env steps/s)"
        )
    lines.append(f"XLA_FLAGS: {os.environ.get('XLA_FLAGS', '')!r}")
    peak = (jax.devices()[0].memory_stats() or {}).get("peak_bytes_in_use")
    if peak is not None:  # GPUs report it; XLA's CPU client does not
        lines.append(f"device memory, peak in this process: {peak / 2**30:.2f} GiB")
    if overlap:
        lines.append(overlap)
    compiles = [f"{k} {p.compile_s:.1f}" for k, p in timer.programs.items()]
    lines.append("compile s (concurrent): " + ", ".join(compiles))
    for name, summary in profiles.items():
        lines += ["", f"device profile, {name}:", ""]
        lines += [f"- {k}: {v}" for k, v in summary.items() if k not in ("modules", "ops")]
        lines += [
            f"- module {k}: {v[0]:,.1f} ms in {v[1]} kernels" for k, v in summary.get("modules", {}).items()
        ]
        lines += ops_tables(summary)
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
