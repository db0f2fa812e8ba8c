"""Raw MJX env throughput per registered env, side by side in one process.

Each env runs ``steps`` control steps of zero actions under one ``jit(scan)`` at the given batch, through
the training wrappers and the env's domain randomiser (``training.throughput``), the best of 3 timed calls.
Physics steps/s = env steps/s x the env's ``n_substeps``.

    python3 bench/env_throughput.py --envs LiteReach,LiteTrack --batch 8192       # one GPU
    python3 bench/env_throughput.py --batch 4 --steps 2                           # CPU smoke, every env
    PJRT_NPROC=1 python3 bench/env_throughput.py --envs LiteReach --batch 256 --steps 20 \
        --env-overrides sim_dt=0.004 fingertip_kinematics=mjx                  # one env variant (CPU)

``--env-overrides`` applies ``key=value`` items to every listed env's default config (``envs.load``'s
overrides; the gpu preset trains reach at ``sim_dt=0.004``). On a CPU with jaxlib 0.10 and two cores, set
``PJRT_NPROC=1`` from 219 envs (the trainer does: ``training.startup.backend_env``), or a batch this size may
hang.

Prints a markdown table (and writes it to ``--out``).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--envs", default="", help="comma-separated registered env names (default: every registered env)"
    )
    p.add_argument("--batch", type=int, default=8192, help="envs per batch")
    p.add_argument("--steps", type=int, default=100, help="control steps per timed call")
    p.add_argument("--env-overrides", nargs="*", default=[], help="key=value items for every env's config")
    p.add_argument("--out", type=Path, default=None, help="also write the table here")
    a = p.parse_args()

    import jax

    from bar_policy import envs
    from bar_policy.provenance import collect, commit_text
    from bar_policy.training.throughput import raw_env_steps_per_second

    rows = [
        f"device {jax.devices()[0].device_kind}, batch {a.batch}, {a.steps} control steps per call, "
        f"commit {commit_text(collect())}, env overrides {' '.join(a.env_overrides) or 'none'}",
        "",
        "| env | substeps | env steps/s | physics steps/s | compile s |",
        "|---|---|---|---|---|",
    ]
    for name in a.envs.split(",") if a.envs else envs.ALL_ENVS:
        env = envs.load(name, overrides=a.env_overrides)
        r = raw_env_steps_per_second(
            env,
            envs.wrap_for_brax_training,
            num_envs=a.batch,
            steps=a.steps,
            randomizer=envs.get_randomizer(name, env.config),
        )
        sps = r["env_steps_per_s"]
        rows.append(
            f"| {name} | {env.n_substeps} | {sps:,.0f} | {sps * env.n_substeps:,.0f} | {r['compile_s']:.1f} |"
        )
        print(rows[-1], flush=True)
    text = "\n".join(rows) + "\n"
    print(text)
    if a.out:
        a.out.write_text(text)


if __name__ == "__main__":
    main()
