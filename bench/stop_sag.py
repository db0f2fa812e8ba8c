"""How far the arms sag under the stop's damping: damping alone vs gravity-compensated damping.

    python bench/stop_sag.py [--policy checkpoints/lite_reach_arms.onnx] [--damping-time 1] [--json out.json]

For each target (``sim``: C MuJoCo, ``emulated``: the real target's CAN code over the lockstep Robstride
emulator) and each ``--stop-damping`` kind (``plain``, ``gravity``) it runs the policy from its rest pose
(``--start policy``) for ``--stop-at`` s, requests a stop, and records q through the ``--damping-time`` s of
DAMPING that follow. The sag is the largest joint excursion from the q at the stop request over the damping,
per joint; the table gives the worst joint and its value, rad.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands

ROOT = Path(__file__).resolve().parents[1]


def measure(policy_path: Path, target_name: str, kind: str, stop_at: float, damping: float) -> dict:
    """One run: the sag (rad) per joint over the damping after a stop request at ``stop_at`` s."""
    policy = load_policy(policy_path)
    if target_name == "sim":
        from bar_policy.deploy.targets.sim import SimTarget

        target = SimTarget(policy.robot.mode)
        target.reset(policy.hold_pose)
    else:
        from bar_policy.deploy.targets.emulated import EmulatedBusTarget

        target = EmulatedBusTarget(policy.robot.mode, policy.policy_dt, reply_timeout=0.5)
        target.reset(policy.hold_pose)
    qs: list[np.ndarray] = []

    def on_tick(k: int, t: float, rt: Runtime) -> None:
        if t >= stop_at - 1e-9 and rt.safety.mode == Mode.POLICY:
            rt.request_stop("measurement")
        if rt.safety.mode == Mode.DAMPING:
            qs.append(rt.last_state.q.copy())

    cfg = RuntimeConfig(
        control_dt=policy.policy_dt,
        duration=stop_at + damping + 1.0,
        start_mode="policy",
        damping_after_fault=damping,
        stop_damping=kind,
        handle_signals=False,
        safety=SafetyConfig(ramp_time=0.0, max_overruns=0),
    )
    rt = Runtime(
        policy, target, SampledCommands(policy.obs_manager.command_names, seed=0), cfg, on_tick=on_tick
    )
    try:
        res = rt.run()
    finally:
        target.close()
    q = np.asarray(qs)
    sag = np.abs(q - q[0]).max(axis=0)
    worst = int(np.argmax(sag))
    return {
        "target": target_name,
        "stop_damping": kind,
        "damping_s": damping,
        "damping_ticks": len(qs),
        "worst_joint": policy.robot.joint_names[worst],
        "sag_rad": float(sag[worst]),
        "sag_per_joint_rad": {n: float(v) for n, v in zip(policy.robot.joint_names, sag, strict=True)},
        "end_reason": res.end_reason,
        "safe_stop": res.safe_stop,
        "gravity": None if rt.gravity is None else rt.gravity.record(),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--policy", type=Path, default=ROOT / "checkpoints" / "lite_reach_arms.onnx")
    p.add_argument("--stop-at", type=float, default=1.0, help="stop request after this long in POLICY, s")
    p.add_argument("--damping-time", type=float, default=1.0, help="the damping measured, s")
    p.add_argument("--targets", default="sim,emulated")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args()
    rows = [
        measure(args.policy, t, kind, args.stop_at, args.damping_time)
        for t in args.targets.split(",")
        for kind in ("plain", "gravity")
    ]
    print("| target | stop damping | sag over the damping, rad (worst joint) | gravity clips |")
    print("|---|---|---|---|")
    for r in rows:
        clips = "-" if r["gravity"] is None else r["gravity"]["clipped_joint_evaluations"]
        print(f"| {r['target']} | {r['stop_damping']} | {r['sag_rad']:.4f} ({r['worst_joint']}) | {clips} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
