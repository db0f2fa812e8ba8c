"""Train the shipped reach policy and publish it (checkpoints/ + docs/), in one shot.

    python train/ship.py                       # train with the gpu preset, then publish
    python train/ship.py --from-run runs/X     # publish an existing run only
    python train/ship.py --from-run runs/X --iterate auto   # ship policy_best.onnx if it scores higher
    python train/ship.py --ppo.num-timesteps 60000000   # any train/ppo.py flag passes through

Writes checkpoints/lite_reach_arms.onnx, checkpoints/lite_reach_arms.json, docs/training_curve.png and the
results block of docs/training.md, then prints whether the issue's targets were met.
"""

from __future__ import annotations

import argparse
import sys
import time

from bar_policy.training.cli import parse_config
from bar_policy.training.publish import ITERATES, publish


def main(argv: list[str] | None = None) -> int:
    """Train (unless ``--from-run``) and publish; exit code 0 when the policy reaches the targets."""
    import json

    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--from-run", default=None, help="publish this finished run instead of training")
    pre.add_argument("--name", default="lite_reach_arms", help="file stem under checkpoints/")
    pre.add_argument(
        "--iterate",
        default="last",
        choices=ITERATES,
        help="ship the last iterate, the best evaluated one, or the one with the higher final evaluation",
    )
    pre.add_argument(
        "--raw-throughput",
        type=int,
        default=4096,
        help="after training, time the batched env alone at this batch size (0 = skip); recorded in the JSON",
    )
    known, rest = pre.parse_known_args(sys.argv[1:] if argv is None else argv)
    if known.from_run is None:
        if not any(a.startswith("--run-name") for a in rest):
            rest = [*rest, "--run-name", f"ship-{time.strftime('%Y%m%d-%H%M%S')}"]
        cfg = parse_config(rest)
        from bar_policy.training.run import run

        run_dir = run(cfg).run_dir
    else:
        run_dir = known.from_run
    paths = publish(run_dir, name=known.name, iterate=known.iterate)
    final = json.loads(paths["json"].read_text())
    if known.raw_throughput:
        from bar_policy import envs
        from bar_policy.training.throughput import raw_env_steps_per_second

        env = envs.load("LiteReach")
        raw = raw_env_steps_per_second(
            env,
            envs.wrap_for_brax_training,
            num_envs=known.raw_throughput,
            randomizer=envs.get_randomizer("LiteReach", env.config),
        )
        final["raw_env_throughput"] = raw
        paths["json"].write_text(json.dumps(final, indent=2, sort_keys=True))
        print(
            f"raw env throughput: {raw['env_steps_per_s']:,.0f} env steps/s at {raw['num_envs']} envs; "
            f"training end to end: {final['train_sps_end_to_end']:,.0f} env steps/s"
        )
    success = final["final_eval"]["success_rate"]
    ttt = final.get("time_to_threshold_s")
    print(f"published: {', '.join(str(p) for p in paths.values())}")
    ok_success = success >= 0.95
    ok_time = ttt is not None and ttt <= 300
    print(f"target >= 95% final success: {'MET' if ok_success else 'NOT MET'} ({100 * success:.2f}%)")
    print(f"target <= 5 min to 95% eval success: {'MET' if ok_time else 'NOT MET'} ({ttt} s)")
    return 0 if ok_success else 1


if __name__ == "__main__":
    sys.exit(main())
