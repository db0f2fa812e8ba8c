"""Does a GPU program compute the same under other XLA_FLAGS? (command-buffer scheduling)

``training.startup.backend_env`` runs GPU programs with
``--xla_gpu_command_buffer_scheduling_mode=CONCURRENT``: kernels without a buffer dependency between them may
run at once. A missing dependency would be a data race. This bench runs the trainer's own programs
(``training.brax.programs.make_programs``: init, reset, rollout, update) for ``--iterations`` PPO iterations
from fixed seeds, twice in one process, and:

- reports whether the second pass equals the first bit for bit (run-to-run determinism under this process's
  XLA_FLAGS), and the largest difference if not;
- saves the final parameters, the loss metrics and the rollout statistics to ``--dump`` (.npz), so that two
  processes under different XLA_FLAGS can be compared (``--compare A.npz B.npz``).

Under ``--xla_gpu_deterministic_ops=true`` (scatters without atomics) both modes should repeat bit for bit,
and a race-free concurrent schedule should equal the serial one bit for bit: the same kernels on the same
inputs, only their start times differ.

Examples::

    XLA_FLAGS="--xla_gpu_deterministic_ops=true" python bench/schedule_parity.py --dump $OUT/serial.npz
    python bench/schedule_parity.py --compare $OUT/serial.npz $OUT/concurrent.npz
    python bench/schedule_parity.py --preset tiny --iterations 1             # CPU smoke check
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def max_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| over two same-shape arrays, in float64 (0 for empty ones)."""
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0


def compare(a_path: str, b_path: str) -> str:
    """One line per differing array of two dumps, then a summary line."""
    a, b = np.load(a_path), np.load(b_path)
    lines, worst, differ = [], 0.0, 0
    for k in a.files:
        x = a[k]
        d = max_abs_diff(x, b[k])
        if d > 0:
            differ += 1
            scale = float(np.max(np.abs(x.astype(np.float64))))
            worst = max(worst, d / max(scale, 1e-30))
            lines.append(f"{k} {x.shape}: max |diff| {d:.3g}, max |a| {scale:.3g}")
    lines.append(
        f"{a_path} vs {b_path}: {differ} of {len(a.files)} arrays differ; worst relative {worst:.3g}"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> str:
    """The programs, twice from the same seeds; the dump of the first pass; the report."""
    import jax
    from config_args import config_of, load_env
    from jax.sharding import Mesh

    from bar_policy import envs
    from bar_policy.envs.reward_weights import weights
    from bar_policy.training.brax.learner import make_learner
    from bar_policy.training.brax.programs import make_programs
    from bar_policy.training.brax.state import host_key, run_epoch
    from bar_policy.training.parallel import AXIS, DataParallel

    cfg = config_of(args)
    jax.config.update(
        "jax_default_matmul_precision", "highest" if cfg.matmul_precision == "highest" else None
    )
    env = load_env(args.env, cfg)
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(env.observation_size, env.action_size, cfg.ppo, cfg.network)
    progs = make_programs(env, cfg, learner, dp, envs.wrap_for_brax_training, envs.get_randomizer(args.env))
    index = [dp.replicate(np.int32(i)) for i in range(args.iterations)]
    w = dp.replicate(weights(env))

    def one_pass() -> list[np.ndarray]:
        ts = progs.init(dp.replicate(host_key(0, 1)))
        carry = progs.reset(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))
        ts, carry, metrics, stats = run_epoch(
            progs.rollout, progs.update, ts, carry, dp.replicate(host_key(0, 9)), index, w
        )
        return [np.asarray(x) for x in jax.tree.leaves(dp.to_host((ts, metrics, stats, carry[0].obs)))]

    t0 = time.perf_counter()
    first = one_pass()
    t1 = time.perf_counter()
    second = one_pass()
    t2 = time.perf_counter()
    diffs = [max_abs_diff(a, b) for a, b in zip(first, second, strict=True)]
    if args.dump:
        np.savez(args.dump, *first)
    return (
        f"schedule parity: {jax.devices()[0].device_kind}, XLA_FLAGS {os.environ.get('XLA_FLAGS', '')!r}, "
        f"preset {args.preset}, {args.iterations} iterations\n"
        f"first pass (compiles included) {t1 - t0:.1f} s, second {t2 - t1:.2f} s\n"
        f"repeat: {sum(d > 0 for d in diffs)} of {len(diffs)} arrays differ, largest |diff| {max(diffs):.3g}"
    )


def main() -> int:
    from config_args import add_config_args
    from report import emit

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_config_args(p)
    p.add_argument("--iterations", type=int, default=3, help="PPO iterations per pass")
    p.add_argument("--dump", default="", help="save the first pass's final state to this .npz")
    p.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two dumps and exit")
    p.add_argument("--out", default="")
    args = p.parse_args()
    emit(compare(*args.compare) if args.compare else run(args), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
