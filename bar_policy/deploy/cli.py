"""``bar-deploy``: run an ONNX policy on the sim, mock or real target; plot a run log; sim2sim evaluation.

Usage::

    bar-deploy --policy x.onnx [--target sim|mock|real] [--duration S] [--commands SPEC] [--viewer]
               [--video out.mp4] [--log DIR] [--seed N]
    bar-deploy run ...          (same as above)
    bar-deploy plot LOG [--out DIR]
    bar-deploy eval --policy x.onnx [--episodes N] [--seed N]

The only module that prints. Never imports jax, torch or onnx.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main"]

TARGETS = ("sim", "mock", "real")
SUBCOMMANDS = ("run", "plot", "eval")
_EPILOG = """subcommands:
  run   (default) run a policy:         bar-deploy --policy x.onnx --target sim --duration 10
  plot  PNG plots of a run log:          bar-deploy plot runs/deploy/20250101-120000-sim
  eval  sim2sim success rate:            bar-deploy eval --policy x.onnx --episodes 100
command sources (--commands):
  sampled | sampled:PERIOD | file:PATH (.json/.csv/.npz) | stream:stdin | stream:udp:PORT (127.0.0.1 only)
"""


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--policy", required=True, type=Path, help="ONNX policy file exported by bar_policy")
    p.add_argument("--mode", default="arms", choices=("arms", "arms_neck"), help="joint set of the robot")
    p.add_argument("--control-dt", type=float, default=0.02, help="control period in s (the policy's dt)")
    p.add_argument(
        "--action-clip",
        type=float,
        help="clip raw actions to +-this (default: the file's bar.action_clip, else 1.0 as in training; "
        "0: none)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bar-deploy",
        description="Run an ONNX policy at its policy rate on a target, under the safety supervisor.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _common(p)
    p.add_argument("--target", default="sim", choices=TARGETS, help="where to run (default: sim)")
    p.add_argument("--duration", type=float, default=10.0, help="run length in s (0: until Ctrl+C)")
    p.add_argument("--commands", default="sampled", help="command source (see below); default: sampled")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampled command source")
    p.add_argument(
        "--log", type=Path, default=Path("runs/deploy"), help="directory of run logs (default: runs/deploy)"
    )
    p.add_argument("--no-log", action="store_true", help="record no run log")
    p.add_argument("--ramp-time", type=float, default=3.0, help="HOLD ramp to the default pose, s")
    p.add_argument(
        "--start", default="hold", choices=("hold", "policy"), help="start with the ramp or the policy"
    )
    p.add_argument("--max-overruns", type=int, default=5, help="consecutive overruns that trip damping")
    p.add_argument("--stale-timeout", type=float, default=0.1, help="state age that trips damping, s")
    p.add_argument(
        "--rt-priority", type=int, help="run the loop under SCHED_FIFO at this priority (1-99, needs root)"
    )
    p.add_argument("--viewer", action="store_true", help="sim: live MuJoCo viewer (runs at real time)")
    p.add_argument("--realtime", action="store_true", help="sim: pace at wall-clock rate")
    p.add_argument("--video", type=Path, help="sim: write a video (.mp4, or .gif without ffmpeg)")
    return p


def _configure_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )


def _fail(msg: str) -> int:
    print(f"bar-deploy: error: {msg}", file=sys.stderr)
    return 2


def _with_action_clip(policy: object, args: argparse.Namespace) -> object:
    """The policy with ``--action-clip`` applied when given (0 disables the clip)."""
    if args.action_clip is None:
        return policy
    import dataclasses

    if args.action_clip < 0:
        raise ValueError(f"--action-clip must be >= 0, got {args.action_clip}")
    return dataclasses.replace(policy, action_clip=args.action_clip or None)


def _real_module():  # noqa: ANN202 - module
    import importlib

    try:
        return importlib.import_module("bar_policy.deploy.targets.real")
    except ModuleNotFoundError as e:
        if e.name in ("bar_policy.deploy.targets.real",):
            raise SystemExit(
                "bar-deploy: error: --target real is not available: bar_policy.deploy.targets.real is not "
                "installed yet (the Robstride CAN target); use --target sim or mock"
            ) from None
        raise SystemExit(f"bar-deploy: error: --target real needs {e.name!r}: {e}") from None


def _run(argv: Sequence[str]) -> int:
    parser = _run_parser()
    pre, _ = parser.parse_known_args(argv)
    real = None
    if pre.target == "real":
        real = _real_module()
        real.add_arguments(parser)
    args = parser.parse_args(argv)
    if args.video and args.target != "sim":
        return _fail("--video needs --target sim")
    if args.viewer and args.target != "sim":
        return _fail("--viewer needs --target sim")
    if args.video and not args.viewer:
        # Headless offscreen GL, chosen before mujoco is imported.
        os.environ.setdefault("MUJOCO_GL", "egl")
        if os.environ["MUJOCO_GL"] == "egl":
            os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    _configure_logging(args.verbose)

    from bar_policy.deploy.commands import CommandError, make_command_source
    from bar_policy.deploy.policy import PolicyLoadError, load_policy
    from bar_policy.deploy.runtime import Runtime, RuntimeConfig
    from bar_policy.deploy.safety import SafetyConfig
    from bar_policy.deploy.targets.base import TargetError
    from bar_policy.robot.kinematics import Kinematics

    try:
        policy = _with_action_clip(load_policy(args.policy, control_dt=args.control_dt, mode=args.mode), args)
        safety = SafetyConfig(
            ramp_time=args.ramp_time, max_overruns=args.max_overruns, stale_timeout=args.stale_timeout
        )
        config = RuntimeConfig(
            control_dt=args.control_dt,
            duration=args.duration if args.duration > 0 else None,
            start_mode=args.start,
            realtime=args.realtime or args.viewer,
            rt_priority=args.rt_priority,
            safety=safety,
        )
    except (PolicyLoadError, ValueError) as e:
        return _fail(str(e))
    kin = Kinematics(args.mode)
    left, right = kin.fingertips(policy.default_joint_pos)
    try:
        commands = make_command_source(
            args.commands,
            policy.obs_manager.command_names,
            seed=args.seed,
            initial={"target_pos_left": left, "target_pos_right": right},
        )
    except CommandError as e:
        return _fail(str(e))

    if args.target == "sim":
        from bar_policy.deploy.targets.sim import SimConfig, SimTarget, training_damping

        sim_cfg = SimConfig(
            viewer=args.viewer,
            video_path=str(args.video) if args.video else None,
            damping=training_damping(policy.metadata.randomization),
        )
        target = SimTarget(args.mode, sim_cfg)
    elif args.target == "mock":
        from bar_policy.deploy.targets.mock import MockTarget

        target = MockTarget(args.mode)
    else:
        try:
            target = real.make_target(args, args.mode)
        except TargetError as e:
            commands.close()
            return _fail(f"target real: {e}")

    print(
        f"policy {args.policy} [{policy.obs_manager.fingerprint}] on {args.target}, "
        f"commands {commands.describe()}"
    )
    meta = {"argv": list(argv), "seed": args.seed}
    try:
        with target:
            rt = Runtime(
                policy,
                target,
                commands,
                config,
                log_dir=None if args.no_log else args.log,
                log_meta=meta,
                log_name=args.target,
                kinematics=kin,
            )
            result = rt.run()
    except TargetError as e:
        return _fail(f"target {args.target}: {e}")
    finally:
        commands.close()
    print(result.timing.format())
    print(
        f"end: {result.end_reason}; final mode {result.final_mode.name}; "
        f"q_cmd clipped {result.clip_count} joint-ticks"
    )
    for tr in result.transitions:
        print(f"  t={tr['t']:.3f} s  {tr['from']} -> {tr['to']}: {tr['reason']}")
    if result.log_path is not None:
        print(f"log: {result.log_path}  (plot: bar-deploy plot {result.log_path.parent})")
    video = getattr(target, "video_path", None)
    if video is not None:
        print(f"video: {video}")
    return 0 if result.fault_count == 0 else 1


def _plot(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(prog="bar-deploy plot", description="Write PNG plots of a run log.")
    p.add_argument("log", type=Path, help="run directory or its log.npz")
    p.add_argument("--out", type=Path, help="output directory (default: the run directory)")
    args = p.parse_args(argv)
    from bar_policy.deploy.plot import plot_log

    try:
        files = plot_log(args.log, args.out)
    except (FileNotFoundError, ValueError) as e:
        return _fail(str(e))
    for f in files:
        print(f)
    return 0


def _eval(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(
        prog="bar-deploy eval",
        description="Sim2sim: success rate of the policy on the C MuJoCo sim target over seeded episodes.",
    )
    _common(p)
    p.add_argument("--episodes", type=int, default=100, help="number of episodes (default 100)")
    p.add_argument("--seed", type=int, default=0, help="seed of episode 0 (episode e uses seed + e)")
    p.add_argument("--episode-length", type=float, default=5.0, help="episode length in s (env: 5)")
    p.add_argument(
        "--resample-period", type=float, default=2.5, help="target resampling period in s (env: 2.5; 0: none)"
    )
    p.add_argument("--init-noise", type=float, default=0.0, help="initial joint noise half-width, rad")
    p.add_argument("--json", type=Path, help="write per-episode results here")
    args = p.parse_args(argv)
    _configure_logging(args.verbose)
    logging.getLogger("bar_policy.deploy.safety").setLevel(logging.WARNING)
    from bar_policy.deploy.policy import PolicyLoadError, load_policy
    from bar_policy.deploy.sim2sim import EvalConfig, evaluate

    try:
        policy = _with_action_clip(load_policy(args.policy, control_dt=args.control_dt, mode=args.mode), args)
        cfg = EvalConfig(
            episodes=args.episodes,
            seed=args.seed,
            episode_length=args.episode_length,
            resample_period=args.resample_period if args.resample_period > 0 else None,
            init_noise=args.init_noise,
        )
    except (PolicyLoadError, ValueError) as e:
        return _fail(str(e))
    result = evaluate(policy, cfg)
    print(result.format())
    if args.json:
        args.json.write_text(json.dumps(result.to_dict(), indent=2))
        print(f"per-episode results: {args.json}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bar-deploy``; returns the exit status (0 ok, 1 run ended on a fault, 2 error)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in SUBCOMMANDS:
        sub, rest = args[0], args[1:]
    else:
        sub, rest = "run", args
    if sub == "plot":
        return _plot(rest)
    if sub == "eval":
        return _eval(rest)
    return _run(rest)


if __name__ == "__main__":
    raise SystemExit(main())
