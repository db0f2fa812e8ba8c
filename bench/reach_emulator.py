"""Reach success of an ONNX policy through the CAN emulator vs the C MuJoCo sim target (issue 6 target).

    python bench/reach_emulator.py --policy x.onnx [--episodes 20] [--seed 0]

Both runs use the deploy team's sim2sim protocol (``bar_policy.deploy.sim2sim.evaluate``: seeded targets,
5 s episodes, success = both fingertips within 3 cm at each segment end). The "real" run drives
``RealTarget`` over two python-can virtual buses to a *lockstep* ``RobstrideEmulator``: every command round
advances one control period of MuJoCo physics, so the episode runs faster than real time and the state
the policy sees went through the 16-bit feedback codec. Per episode the target is rebuilt and started
(scan, cap writes, enable, one 20 ms damping round: the only difference in the initial condition).
"""

from __future__ import annotations

import argparse
import time

import can
import numpy as np

from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.robstride.emulator import RobstrideEmulator
from bar_policy.deploy.robstride.group import RobstrideGroup
from bar_policy.deploy.sim2sim import EvalConfig, evaluate
from bar_policy.deploy.targets.base import JointState, Target
from bar_policy.deploy.targets.real import RealTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand


class LockstepRealTarget(Target):
    """``RealTarget`` + lockstep emulator, presented as a synchronous, resettable target for ``evaluate``."""

    synchronous = True

    def __init__(self, mode: str, control_dt: float) -> None:
        self.robot = load_robot(mode)
        super().__init__(self.robot.joint_names)
        k = f"reach-{time.monotonic_ns()}"
        self.channels = {"can0": f"{k}-can0", "can1": f"{k}-can1"}
        self.emu = RobstrideEmulator(
            self.robot, self.channels, mode="lockstep", control_dt=control_dt
        ).start()
        self.inner: RealTarget | None = None

    def reset(self, q: np.ndarray | None = None) -> None:
        """Teleport the emulated robot to ``q`` at rest, then start a fresh real target on it."""
        if self.inner is not None:
            self.inner.close()
        self.emu.set_joint_positions(self.robot.pose("piano_ready") if q is None else q)
        buses = {i: can.Bus(interface="virtual", channel=c) for i, c in self.channels.items()}
        group = RobstrideGroup.from_robot(self.robot, buses, reply_timeout=0.2)
        self.inner = RealTarget(
            self.robot, group, refresh_on_read=False, damping_hold_s=0.0, scan_ids=range(1, 33)
        )
        self.inner.start()

    def read_state(self) -> JointState:
        """The real target's state (post-step in lockstep)."""
        return self.inner.read_state()

    def write_command(self, cmd: MitCommand) -> None:
        """One command round = one control period of physics."""
        self.inner.write_command(cmd)

    def now(self) -> float:
        """Emulator physics time, s."""
        return self.emu.sim_time

    def safe_stop(self, q: np.ndarray | None = None, kd: float = 1.0) -> None:
        """Damping then stop on the buses."""
        self.inner.safe_stop(q, kd)

    def close(self) -> None:
        """Close the target and the emulator."""
        if self.inner is not None:
            self.inner.close()
        self.emu.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", required=True)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    policy = load_policy(args.policy)
    cfg = EvalConfig(episodes=args.episodes, seed=args.seed)
    t0 = time.perf_counter()
    sim = evaluate(policy, cfg)
    t1 = time.perf_counter()
    target = LockstepRealTarget(policy.robot.mode, policy.policy_dt)
    try:
        real = evaluate(policy, cfg, target=target)  # type: ignore[arg-type]
    finally:
        target.close()
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
