"""Why a reach file's first commands touch the wrists' torque caps (the ship gate's one recurring miss).

The gate counts a tick at a cap when a joint's unclipped MIT demand reaches its cap; the misses of sessions
36-38 were all the first two ticks of every episode, one to three wrist joints at 4.0-5.8 N m of 4 N m.
This bench runs an ONNX reach policy (deterministic, as the gate runs it) in the MJX env at the file's
physics step and reports:

- per tick of the first ``--ticks``, the share of ``--batch`` envs with a joint at its cap and the worst
  demand / cap per joint, in the training env (domain randomisation on, as training sees it) and in the
  nominal env (what the gate's C MuJoCo sim is closest to);
- per wrist joint, the raw action at the first tick and its mean and spread over ticks 50-250 of
  ``--episodes`` nominal episodes: where the policy holds each wrist once it has started.

Example (CPU, a few minutes, mostly compiling)::

    python bench/first_command.py runs/X/policy.onnx --out first_command.md

On this project's 2-core CPU a batch of 256 hung in jaxlib 0.10's batched LAPACK kernels (docs/performance.md
2026-11-27): run this bench with ``PJRT_NPROC=1`` there above the default batch, 64.
"""

from __future__ import annotations

import argparse
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from report import emit

from bar_policy import envs
from bar_policy.deploy.onnx_file import metadata, read_bytes, session
from bar_policy.robot.constants import load_robot


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("policy", help="reach ONNX file")
    p.add_argument("--batch", type=int, default=64, help="envs per config for the first ticks")
    p.add_argument("--ticks", type=int, default=3)
    p.add_argument("--episodes", type=int, default=4, help="nominal episodes for the held wrist actions")
    p.add_argument("--out", default="")
    args = p.parse_args()

    # The deploy runtime's loader (never a pickle), its single-threaded session and its metadata parser.
    path = Path(args.policy)
    sess = session(path, read_bytes(path), 1)
    meta = metadata(path, sess)
    if meta.task != "reach":
        p.error(f"{args.policy} is not a reach file (its task: {meta.task!r})")
    over = [f"sim_dt={meta.physics_dt:g}"] if meta.physics_dt is not None else []
    obs_size = sess.get_inputs()[0].shape[1]

    def act(obs: jax.Array) -> np.ndarray:
        return sess.run(None, {"obs": np.asarray(obs, np.float32).reshape(-1, obs_size)})[0]

    robot = load_robot("arms")
    cap, names = robot.torque_cap, [j.name for j in robot.joints]
    lines = [f"first commands of {args.policy} ({', '.join(over) or 'the model step'})", ""]
    lines += ["| env | tick | envs at a cap | worst demand / cap (top 3) |", "|---|---:|---:|---|"]
    for label, cfg in (("training (DR on)", None), ("nominal", envs.nominal_config())):
        env = envs.load("LiteReach", config=cfg, overrides=over or None)
        keys = jax.random.split(jax.random.PRNGKey(3), args.batch)
        rand = None if cfg else functools.partial(envs.get_randomizer("LiteReach", env.config), rng=keys)
        w = envs.wrap_for_brax_training(env, episode_length=env.episode_length, randomization_fn=rand)
        step = jax.jit(w.step)
        demand = jax.jit(jax.vmap(lambda s, a, e=env: e.quality_signals(s, a)["demand"]))
        s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(11), args.batch))
        for t in range(1, args.ticks + 1):
            a = jnp.asarray(act(s.obs))
            d = np.abs(np.asarray(demand(s, a))) / cap
            worst = d.max(axis=0)
            top = ", ".join(f"{names[i]} {worst[i]:.2f}" for i in np.argsort(-worst)[:3])
            lines.append(f"| {label} | {t} | {(d >= 1.0).any(axis=1).mean():.0%} | {top} |")
            s = step(s, a)

    env = envs.load("LiteReach", config=envs.nominal_config(), overrides=over or None)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    steps = int(env.episode_length)
    actions = np.zeros((args.episodes, steps, len(names)))
    for e in range(args.episodes):
        s = reset(jax.random.PRNGKey(e))
        for t in range(steps):
            actions[e, t] = act(s.obs)[0]
            s = step(s, jnp.asarray(actions[e, t]))
    wrists = [i for i, n in enumerate(names) if "wrist" in n]
    held = actions[:, 50:, :]
    lines += ["", "| wrist joint | raw action, tick 1 | held: mean over ticks 50+ (per episode) | spread |"]
    lines += ["|---|---:|---|---:|"]
    for i in wrists:
        means = ", ".join(f"{m:+.2f}" for m in held[:, :, i].mean(axis=1))
        lines.append(
            f"| {names[i]} | {actions[0, 0, i]:+.2f} | {means} | {held[:, :, i].std(axis=1).mean():.2f} |"
        )
    emit("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
