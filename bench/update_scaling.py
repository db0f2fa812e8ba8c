"""The update program on one device and on several (target: two GPUs >= 1.9x one).

Each Adam step of the data-parallel update all-reduces the gradients (one all-reduce per step after XLA's
combiner: the gradients and the KL estimate), 128 per iteration at the gpu preset; with twice the SGD steps
per env step (2026-11-27) the update is a larger share of an iteration, so its all-reduces weigh more on
two GPUs. This bench times only the update (``Learner.update`` under the trainer's ``DataParallel`` mesh),
on synthetic transitions of the preset's per-device sizes, so that XLA or NCCL settings can be compared
in a process each without compiling the env:

    python bench/update_scaling.py --devices 1 --label "1 GPU"
    python bench/update_scaling.py --devices 2 --label "2 GPUs"
    NCCL_PROTO=LL python bench/update_scaling.py --devices 2 --label "2 GPUs, NCCL_PROTO=LL"

Sizes: ``num_envs`` and ``batch_size`` of ``--preset`` (default gpu) are per device, as the multi-GPU
commands give them. The line printed (and appended to ``--out``) gives ms per update call, best of
``--iters`` after a warm-up, and the compile seconds.

What an Adam step costs on one GPU (2026-11-28: the update is one CUDA graph of 96 kernels per Adam step;
2026-11-28: its time is the float32 GEMMs, so the precision of the products is the lever, not Adam's form;
docs/performance.md, 2026-11-28):

    python bench/update_scaling.py --label "per-leaf Adam" --profile /tmp/upd --profile-ops 30
    python bench/update_scaling.py --label "flat Adam" --flat-adam
    python bench/update_scaling.py --label "TF32" --precision tensorfloat32

``--flat-adam``: the same optimizer under ``optax.flatten`` (Adam and the norm clip over one vector of every
parameter instead of per leaf; the same elementwise arithmetic, the clip's norm summed in another order); the
line also gives the largest difference of its new parameters from the per-leaf update's.
``--precision P``: the update's matrix products at ``P`` (``jax.default_matmul_precision``: ``tensorfloat32``,
``bfloat16``, or an algorithm such as ``BF16_BF16_F32_X3`` or ``TF32_TF32_F32_X3``) instead of the config's
``ppo.update_precision`` (the gpu preset's TF32 since 2026-11-28; ``--precision highest`` for float32), with
the same difference column against the float32 per-leaf update.
``--profile DIR``: one call under jax.profiler; ``--profile-ops N`` prints its N kernels with the most time
(``trace_summary.device_summary``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import jax
import numpy as np
import optax
from brax.training import types
from config_args import add_config_args, config_of, load_env
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from trace_summary import device_summary, ops_tables, profiled
from train_breakdown import best_time

from bar_policy.training.brax.learner import make_learner
from bar_policy.training.parallel import AXIS, DataParallel
from bar_policy.training.startup.autotune import seed_autotune_cache
from bar_policy.training.startup.compile_cache import configure_compile_cache


def transitions(rows: int, steps: int, obs: int, act: int, seed: int) -> types.Transition:
    """Random transitions shaped as ``Learner.rollout`` returns them: leaves ``(rows, steps, ...)``."""
    rng = np.random.default_rng(seed)

    def f(*shape: int) -> np.ndarray:
        return rng.standard_normal((rows, steps, *shape)).astype(np.float32)

    ones = np.ones((rows, steps), np.float32)
    return types.Transition(
        observation=f(obs),
        action=np.tanh(f(act)),
        reward=f(),
        discount=ones,
        next_observation=f(obs),
        extras={
            "policy_extras": {"log_prob": f() - 5.0, "raw_action": f(act)},
            "state_extras": {"truncation": 0.0 * ones},
        },
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--devices", type=int, default=1)
    p.add_argument("--iters", type=int, default=10)
    p.add_argument("--label", default="")
    p.add_argument("--out", default="")
    p.add_argument("--flat-adam", action="store_true", help="the optimizer under optax.flatten (docstring)")
    p.add_argument(
        "--precision", default="", help="the update's matmul precision instead of the config's (docstring)"
    )
    p.add_argument("--profile", default="", help="also trace one update call into this folder")
    p.add_argument("--profile-ops", type=int, default=25, help="with --profile: the kernels listed")
    args = p.parse_args()

    cache_dir = configure_compile_cache(True)
    cfg = config_of(args)
    jax.config.update(
        "jax_default_matmul_precision", "highest" if cfg.matmul_precision == "highest" else None
    )
    seed_autotune_cache(cache_dir, enabled=cfg.autotune_seed)
    ppo = cfg.ppo
    env = load_env(args.env, cfg)
    learner = make_learner(env.observation_size, env.action_size, ppo, cfg.network)
    devices = jax.devices()[: args.devices]
    if len(devices) < args.devices:
        p.error(f"--devices {args.devices}: this process sees {len(jax.devices())} device(s)")
    dp = DataParallel(Mesh(np.asarray(devices), (AXIS,)))
    rows = ppo.batch_size * ppo.num_minibatches * args.devices  # global; each device its own share
    data = transitions(rows, ppo.unroll_length, env.observation_size, env.action_size, 0)
    data = jax.device_put(data, dp.sharded)
    ts = dp.replicate(jax.device_get(jax.jit(learner.init)(jax.random.PRNGKey(0))))
    key = dp.replicate(np.asarray(jax.random.PRNGKey(1)))
    # The reference: per-leaf Adam, products at float32 (ppo.update_precision="run" under "highest" below).
    base, ts_leaf = dataclasses.replace(learner, ppo=dataclasses.replace(ppo, update_precision="run")), ts
    if args.precision:  # the outer precision below governs the SGD passes too, not the preset's setting
        learner = dataclasses.replace(learner, ppo=base.ppo)
    if args.flat_adam:
        learner = dataclasses.replace(learner, optimizer=optax.flatten(learner.optimizer))
        ts = ts.replace(optimizer_state=dp.replicate(jax.device_get(learner.optimizer.init(ts.params))))

    def program(lr: object) -> object:
        return dp.sharded_jit(lambda t, d, k: lr.update(t, d, k)[0], (P(), P(AXIS), P()), P())

    t0 = time.perf_counter()
    with jax.default_matmul_precision(args.precision or jax.config.jax_default_matmul_precision):
        compiled = program(learner).lower(ts, data, key).compile()
    compile_s = time.perf_counter() - t0
    best = best_time(lambda: compiled(ts, data, key), args.iters)
    adam = ppo.num_updates_per_batch * ppo.num_minibatches
    diff = ""
    if args.flat_adam or args.precision:  # per leaf at full float32, same parameters, data and key
        with jax.default_matmul_precision("highest"):
            reference = jax.jit(program(base))(ts_leaf, data, key)
        a, b = jax.device_get((compiled(ts, data, key).params, reference.params))
        pairs = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
        gap = max(float(np.max(np.abs(x - y))) for x, y in pairs)
        diff = f" params minus per-leaf float32's, largest magnitude {gap:.2e};"
    diff += f" precision {args.precision or ppo.update_precision};"
    line = (
        f"| {args.label or f'{args.devices} device(s)'} | {devices[0].device_kind} x {len(devices)} | "
        f"{1e3 * best:.2f} | {1e6 * best / adam:.0f} | {compile_s:.1f} |{diff} "
        f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r} NCCL_PROTO={os.environ.get('NCCL_PROTO', '')!r} |"
    )
    print("| run | devices | ms per update | us per Adam step | compile s | settings |")
    print(line)
    if args.profile:
        with profiled(args.profile, python=False):
            jax.block_until_ready(compiled(ts, data, key))
        summary = device_summary(args.profile, ops=args.profile_ops)
        print({k: v for k, v in summary.items() if k != "ops"})
        print("\n".join(ops_tables(summary, "kernel")))
    if args.out:
        with Path(args.out).open("a") as fh:
            fh.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
