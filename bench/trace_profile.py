"""Where a cold start's main-thread trace and lowering go, program by program.

A cold run traces and lowers ``reset``, ``rollout``, ``update`` and ``init`` on its main thread, then
``evaluate`` on a worker, before their compiles can start (``training.brax.ppo.train_brax``). On the lent H200
hosts that took 9.9-14.0 s on the main thread plus 7-10 s for the evaluation, beside the other
programs' compiles (2026-11-29). This machine's CPU does the same alone in about 6 s plus 4 s.

This bench builds the run's programs as the trainer does: the task's evaluation env, its model
randomiser and the reference prior, one device. It then traces and lowers each program in the
trainer's order, in this fresh process, and prints for each the seconds of each step and the size of
its StableHLO text. Nothing is compiled.

``--profile NAME`` runs that program's trace and lowering under cProfile and prints the ``--top``
functions by their own time and by cumulative time. That shows whether a host spends its seconds in
Python (jax's tracing, MJX's model code) or in calls that reach the device: constants put on it, arrays
read back from it while lowering.

Examples::

    python bench/trace_profile.py --out $OUT/trace.md                     # gpu preset, LiteReach
    python bench/trace_profile.py --profile rollout --top 40              # where the rollout's trace goes
    python bench/trace_profile.py --preset track --env LiteTrack
    python bench/trace_profile.py --preset tiny                           # CPU smoke check
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time
from typing import Any

from config_args import add_config_args, config_label, config_of, load_env
from report import emit

PROGRAMS = ("reset", "rollout", "update", "init", "evaluate")
"""The trainer's programs in the order it traces them (``training.brax.ppo.train_brax``)."""


def build(args: argparse.Namespace) -> tuple[Any, dict[str, float]]:
    """The run's programs and abstract arguments on one device, and the seconds each set-up step took."""
    import jax
    import numpy as np
    from jax.sharding import Mesh

    from bar_policy import envs
    from bar_policy.envs import reward_weights
    from bar_policy.training.brax.learner import make_learner
    from bar_policy.training.brax.programs import make_programs
    from bar_policy.training.parallel import AXIS, DataParallel
    from bar_policy.training.prior import action_prior

    steps: dict[str, float] = {}
    t = time.perf_counter()
    cfg = config_of(args)
    env = load_env(args.env, cfg)
    randomizer = envs.get_randomizer(args.env, env.config)
    eval_env = env.evaluation_env() if hasattr(env, "evaluation_env") else None
    eval_env = None if eval_env is env else eval_env  # as training.run: a distinct one runs nominal
    steps["env build"] = time.perf_counter() - t
    t = time.perf_counter()
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    prior = action_prior(env, cfg.network, cfg.env_name)
    learner = make_learner(env.observation_size, env.action_size, cfg.ppo, cfg.network, prior)
    progs = make_programs(env, cfg, learner, dp, envs.wrap_for_brax_training, randomizer, eval_env, None)
    key_abs = dp.abstract(np.zeros(2, np.uint32), sharded=False)
    ts_abs = dp.abstract(jax.eval_shape(learner.init, key_abs), sharded=False)
    steps["programs"] = time.perf_counter() - t
    ctx = {
        "progs": progs,
        "dp": dp,
        "key_abs": key_abs,
        "i_abs": dp.abstract(np.zeros((), np.int32), sharded=False),
        "ts_abs": ts_abs,
        "w_abs": dp.abstract(reward_weights.weights(env), sharded=False),
    }
    return ctx, steps


def arguments(name: str, ctx: dict[str, Any], lowered: dict[str, Any]) -> tuple:
    """Program ``name``'s abstract arguments; the rollout's and the update's come from earlier outputs."""
    from bar_policy.training.brax.programs import _policy_params

    dp, key, i, ts, w = ctx["dp"], ctx["key_abs"], ctx["i_abs"], ctx["ts_abs"], ctx["w_abs"]
    if name == "reset":
        return (key, key)
    if name == "rollout":
        return (ts, dp.abstract(lowered["reset"].out_info, sharded=True), key, i, w)
    if name == "update":
        return (ts, dp.abstract(lowered["rollout"].out_info[1], sharded=True), key, i)
    if name == "init":
        return (key,)
    return (_policy_params(ts), key, key, w)


def top_functions(profile: cProfile.Profile, order: str, n: int) -> list[str]:
    """The ``n`` costliest functions by ``order`` (``tottime`` or ``cumulative``), as table rows."""
    stats = pstats.Stats(profile, stream=io.StringIO())
    stats.sort_stats(order)
    rows = []
    for func in stats.fcn_list[:n]:  # type: ignore[attr-defined]
        _, calls, own, cum, _ = stats.stats[func]  # type: ignore[attr-defined]
        where = f"{func[0].split('site-packages/')[-1]}:{func[1]} {func[2]}"
        rows.append(f"| `{where}` | {calls:,} | {own:.3f} | {cum:.3f} |")
    return rows


def own_time_by_package(profile: cProfile.Profile) -> list[str]:
    """Own time summed per top-level package (``jax``, ``mujoco``, ``bar_policy``, C builtins), as rows."""
    stats = pstats.Stats(profile, stream=io.StringIO())
    per: dict[str, float] = {}
    for (path, _, _), (_, _, own, _, _) in stats.stats.items():  # type: ignore[attr-defined]
        if path == "~":
            pkg = "builtins (C)"
        elif "site-packages/" in path:
            pkg = path.split("site-packages/")[-1].split("/")[0]
        elif "/bar_policy/" in path:
            pkg = "bar_policy"
        else:
            pkg = "other (stdlib)"
        per[pkg] = per.get(pkg, 0.0) + own
    return [f"| {k} | {v:.2f} |" for k, v in sorted(per.items(), key=lambda kv: -kv[1])]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--profile", choices=PROGRAMS, default=None, help="cProfile this program's trace, lower")
    p.add_argument("--top", type=int, default=30, help="functions per profile table")
    p.add_argument("--out", default="")
    args = p.parse_args()
    if args.top < 1:
        p.error(f"--top must be at least 1, got {args.top}")

    t0 = time.perf_counter()
    import jax

    imports_s = time.perf_counter() - t0
    ctx, steps = build(args)
    lowered: dict[str, Any] = {}
    rows = []
    profile = cProfile.Profile()
    for name in PROGRAMS:
        fn = getattr(ctx["progs"], name)
        args_abs = arguments(name, ctx, lowered)
        on = name == args.profile
        if on:
            profile.enable()
        t = time.perf_counter()
        traced = fn.trace(*args_abs)
        t_trace = time.perf_counter() - t
        t = time.perf_counter()
        lowered[name] = traced.lower()
        t_lower = time.perf_counter() - t
        if on:
            profile.disable()
        chars = len(lowered[name].as_text())
        rows.append((name, t_trace, t_lower, chars))

    dev = jax.devices()[0]
    lines = [
        f"trace profile: {args.env}, {config_label(args)}, {getattr(dev, 'device_kind', dev.platform)}",
        f"jax import {imports_s:.2f} s, env build {steps['env build']:.2f} s, "
        f"programs {steps['programs']:.2f} s",
        "",
        "| program | trace s | lower s | StableHLO characters |",
        "|---|---:|---:|---:|",
        *(f"| {n} | {a:.2f} | {b:.2f} | {c:,} |" for n, a, b, c in rows),
        f"| all | {sum(r[1] for r in rows):.2f} | {sum(r[2] for r in rows):.2f} | |",
    ]
    if args.profile:
        lines += [
            "",
            f"{args.profile}'s trace and lowering under cProfile, own time by package:",
            "",
            "| package | own s |",
            "|---|---:|",
            *own_time_by_package(profile),
        ]
        for order, title in (("tottime", "own time"), ("cumulative", "cumulative time")):
            lines += [
                "",
                f"{args.profile}'s trace and lowering under cProfile, by {title} (cProfile slows Python):",
                "",
                "| function | calls | own s | cumulative s |",
                "|---|---:|---:|---:|",
                *top_functions(profile, order, args.top),
            ]
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
