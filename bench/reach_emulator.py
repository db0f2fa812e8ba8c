"""Reach success of an ONNX policy through the CAN emulator vs the C MuJoCo sim target.

    python bench/reach_emulator.py --policy x.onnx [--episodes 20] [--seed 0]

Both runs use the deploy team's sim2sim protocol (``bar_policy.tasks.reach.evaluate``: seeded targets, 5 s
episodes, success = both fingertips within 3 cm at each segment end). The "real" run drives ``RealTarget``
over two python-can virtual buses to a *lockstep* ``RobstrideEmulator`` (``EmulatedBusTarget``, through
``deploy.episodes.BusEpisodes``, ``bar-deploy eval --target bus``): every command round advances one control
period of MuJoCo physics, so the episode runs faster than real time and the state the policy sees went
through the 16-bit feedback codec. Per episode the target is rebuilt and started (scan, cap writes, enable,
one 20 ms damping round: the only difference in the initial condition).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bar_policy.deploy.episodes import BusEpisodes, SimEpisodes
from bar_policy.deploy.policy import load_policy
from bar_policy.tasks.reach.evaluate import EvalConfig, evaluate


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    policy = load_policy(args.policy)
    cfg = EvalConfig(episodes=args.episodes, seed=args.seed)
    t0 = time.perf_counter()
    runner = SimEpisodes(policy)
    sim = evaluate(policy, cfg, runner=runner)
    t1 = time.perf_counter()
    with BusEpisodes(policy) as bus:  # bar-deploy eval --target bus's runner
        real = evaluate(policy, cfg, runner=bus)
    t2 = time.perf_counter()
    print(f"policy {args.policy}: {args.episodes} episodes, seed {args.seed}")
    for name, r, dt in (
        ("sim target (C MuJoCo)", sim, t1 - t0),
        ("real target via CAN emulator", real, t2 - t1),
    ):
        lo, hi = r.wilson_interval()
        dl = np.concatenate([e.dist_left for e in r.episodes])
        dr = np.concatenate([e.dist_right for e in r.episodes])
        ci = f"95% CI {100 * lo:.1f}-{100 * hi:.1f}"
        med = f"median dist L {1000 * np.median(dl):.1f} mm R {1000 * np.median(dr):.1f} mm"
        print(f"  {name:<30} success {100 * r.success_rate:5.1f} % ({ci})  {med}  ({dt:.1f} s)")
    diff = 100 * (real.success_rate - sim.success_rate)
    print(f"  difference {diff:+.1f} percentage points (target: within 5)")


if __name__ == "__main__":
    main()
