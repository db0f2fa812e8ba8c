"""The ``bar-deploy`` argument parser: the run options, the options ``run`` and ``eval`` share.

``cli.py`` holds the program (``main``); the real target adds its own group (``cli._add_real_help``).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from bar_policy.deploy.log.live import LIVE_PORT
from bar_policy.tasks.cli_types import Parser as _Parser
from bar_policy.tasks.cli_types import count0 as _count0
from bar_policy.tasks.cli_types import duration as _duration
from bar_policy.tasks.cli_types import number as _number
from bar_policy.tasks.cli_types import port as _port
from bar_policy.tasks.cli_types import priority as _priority
from bar_policy.tasks.cli_types import seconds as _seconds
from bar_policy.tasks.cli_types import seconds0 as _seconds0

__all__ = [
    "SUBCOMMANDS",
    "TARGETS",
    "common_options",
    "perturb_option",
    "robot_params_option",
    "run_parser",
    "target_of",
]

TARGETS = ("sim", "mock", "real")
SUBCOMMANDS = ("run", "plot", "eval", "log")
_EPILOG = """subcommands:
  run   (default) run a policy:         bar-deploy --policy x.onnx --target sim --duration 10
  plot  PNG plots of a run log:          bar-deploy plot runs/deploy/20250101-120000-sim
  eval  sim2sim, the task's metric:      bar-deploy eval --policy x.onnx
  log   recover a run.mcap cut by a crash: bar-deploy log recover runs/deploy/20250101-120000-sim
command sources (by the policy's task):
  reach --commands sampled | sampled:PERIOD | file:PATH (.json/.csv/.npz) | stream:stdin | stream:udp:PORT
  track --motion wave | clap | reach_sweep | hanging_to_piano_ready | random-s<seed>-<index> | clip.npz | .csv
real target options: the group above (also listed by bar-deploy --target real --help)
stopping: SIGINT (Ctrl+C), SIGTERM, SIGHUP -> DAMPING, stop frames, log closed; a second signal is ignored
exit status: 0 done or stopped on request (at any moment, the start-up included), 1 fault or error during
the run, 2 refused before the start (on the real target also --start policy or a --ramp-time below the
safe minimum, unless --unsafe-allow-step-start), 3 the safe stop was not confirmed by every joint,
130 eval / plot / log ended by a signal
"""


def common_options(p: argparse.ArgumentParser) -> None:
    """The options ``run`` and ``eval`` share (policy, mode, control period, action clip, verbosity)."""
    p.add_argument(
        "--policy",
        required=True,
        type=Path,
        metavar="PATH",
        help="ONNX policy file (bar_policy's, or one with the Humanoid Control keys)",
    )
    p.add_argument("--mode", default="arms", choices=("arms", "arms_neck"), help="joint set of the robot")
    p.add_argument(
        "--control-dt",
        type=_seconds,
        default=0.02,
        metavar="S",
        help="control period, s: the policy's dt (default 0.02)",
    )
    p.add_argument(
        "--action-clip",
        type=_number("a number >= 0", lambda v: v >= 0),
        metavar="A",
        help="clip raw actions to +-A, action units (default: the file's bar.action_clip, else "
        "1.0 as in training; 0: none)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")


def perturb_option(p: argparse.ArgumentParser, *, suite: bool) -> None:
    """``--perturb SPEC``: the robot differs from the model (``robot.perturb_spec``); ``suite`` when allowed.

    A bad spec is refused by the parser in one line (exit 2).
    """
    from bar_policy.robot.perturb_spec import PerturbationError, help_text, parse_perturbation

    def parse(text: str) -> object:
        if text.strip() == "suite":
            if suite:
                return "suite"
            raise argparse.ArgumentTypeError("'suite' is for bar-deploy eval --perturb suite")
        try:
            return parse_perturbation(text)
        except PerturbationError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    where = "the sim target's robot" + (
        " ('suite': the robustness suite, one table)"
        if suite
        else "; on the real target's virtual bus the in-process emulator's robot, hidden from the "
        "runtime (there the same as --emulate-perturb)"
    )
    p.add_argument(
        "--perturb",
        type=parse,
        default=None,
        metavar="KEY=VALUE,..." + ("|suite" * suite),
        help=f"perturb {where}. Keys: {help_text()}",
    )


def run_parser() -> argparse.ArgumentParser:
    """The parser of ``bar-deploy [run]``: every option once, each task's in its own group."""
    from bar_policy.deploy.tasks import all_tasks

    seed_help = "; ".join(t.seed_help for t in all_tasks() if t.seed_help) or "seed of the task's commands"
    p = _Parser(
        prog="bar-deploy",
        description="Run an ONNX policy at its policy rate on a target, under the safety supervisor.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    common_options(p)
    p.add_argument("--target", default="sim", choices=TARGETS, help="where to run (default: sim)")
    p.add_argument(
        "--duration",
        type=_duration,
        metavar="S|inf",
        help="run length in s, or 'inf' until stopped (default: 10 s; track policies: until the clip ends)",
    )
    p.add_argument("--seed", type=int, default=0, metavar="N", help=f"{seed_help} (default 0)")
    p.add_argument(
        "--log",
        type=Path,
        default=Path("runs/deploy"),
        metavar="DIR",
        help="directory of run logs (default: runs/deploy)",
    )
    p.add_argument("--no-log", action="store_true", help="record no run log")
    p.add_argument(
        "--live",
        nargs="?",
        const=LIVE_PORT,
        type=_port,
        metavar="PORT",
        help="serve the run log's channels live on 127.0.0.1:PORT for the Foxglove app (Open "
        f"connection -> Foxglove WebSocket -> ws://localhost:PORT; default {LIVE_PORT}; 0: "
        "any free port)",
    )
    p.add_argument(
        "--ramp-time",
        type=_seconds0,
        default=3.0,
        metavar="S",
        help="HOLD ramp to the default pose, s (default 3)",
    )
    p.add_argument(
        "--start", default="hold", choices=("hold", "policy"), help="start with the ramp or the policy"
    )
    p.add_argument(
        "--max-overruns",
        type=_count0,
        default=5,
        metavar="N",
        help="consecutive overrun ticks that trip damping (0: off; default 5)",
    )
    p.add_argument(
        "--stale-timeout",
        type=_seconds,
        default=0.1,
        metavar="S",
        help="state age that trips damping, s (default 0.1)",
    )
    p.add_argument(
        "--damping-time",
        type=_seconds0,
        default=1.0,
        metavar="S",
        help="after a fault or a stop signal, damp this long before the stop frames, s (default 1)",
    )
    p.add_argument(
        "--stop-damping",
        default="gravity",
        choices=("gravity", "plain"),
        help="damping of the fault and end stops: gravity = Kd plus the model's gravity torque at "
        "the measured q as feed-forward, within the torque caps (default); plain = Kd alone "
        "(the arms sag)",
    )
    p.add_argument(
        "--end-hold",
        type=_seconds0,
        default=1.0,
        metavar="S",
        help="after the commands end (a motion clip's last frame), HOLD that pose this long, s (default 1)",
    )
    p.add_argument(
        "--start-tare",
        type=_seconds0,
        default=1.0,
        metavar="S",
        help="with the hand-load tare (the piano's): after the start's ramp, HOLD the pose still this long "
        "while the fit reads the load and lifts it, s (default 1; 0: the count-in alone)",
    )
    p.add_argument(
        "--rt-priority",
        type=_priority,
        metavar="1-99",
        help="run the loop under SCHED_FIFO at this priority (root or CAP_SYS_NICE)",
    )
    p.add_argument("--viewer", action="store_true", help="sim: live MuJoCo viewer (runs at real time)")
    p.add_argument("--realtime", action="store_true", help="sim: pace at wall-clock rate")
    p.add_argument(
        "--video", type=Path, metavar="PATH", help="sim: write a video (.mp4, or .gif without ffmpeg)"
    )
    robot_options(p, suite=False)
    for task in all_tasks():
        task.add_run_arguments(p)
    return p


def robot_options(p: argparse.ArgumentParser, *, suite: bool) -> None:
    """The robot a run or an evaluation meets, and how the runtime meets it.

    ``--perturb`` (``suite``: the suite allowed), ``--robot-params``, ``--hand-load``, ``--load-inertia``.
    """
    perturb_option(p, suite=suite)
    robot_params_option(p)
    hand_load_option(p)
    load_inertia_option(p)


def eval_target_option(p: argparse.ArgumentParser) -> None:
    """``bar-deploy eval --target sim|bus``: the keys of ``deploy.episodes.RUNNERS``."""
    from bar_policy.deploy.episodes import RUNNERS

    p.add_argument(
        "--target",
        default="sim",
        choices=tuple(RUNNERS),
        help="sim = the C MuJoCo sim target (default); bus = the real target's CAN code over python-can "
        "virtual buses to the in-process Robstride emulator in lockstep (16-bit feedback, the firmware's "
        "law), whose robot --perturb and --robot-params make",
    )


def hand_load_option(p: argparse.ArgumentParser) -> None:
    """``--hand-load estimate|tare|off``: the hand-load compensation (``deploy.hand_load``)."""
    from bar_policy.deploy.run_config import HAND_LOAD_KINDS

    p.add_argument(
        "--hand-load",
        default=None,
        choices=HAND_LOAD_KINDS,
        help="hand-load compensation: estimate = fit what each hand carries from the motors' torque and "
        "add its gravity torque as the MIT law's feed-forward (tau_ff, within the caps); tare = fit it "
        "while the commands hold the arms still at the start (the piano's count-in), then keep it; off = "
        "none (default: the task's: track estimate, piano tare, reach off)",
    )


def load_inertia_option(p: argparse.ArgumentParser) -> None:
    """``--load-inertia on|off``: the hand load's inertia fed forward (``deploy.load_inertia``)."""
    p.add_argument(
        "--load-inertia",
        default=None,
        choices=("on", "off"),
        help="on = add the inertia of the hand-load fit's masses to the feed-forward, from a reference arm "
        "(the nominal robot simulated in the task's scene under the same commands); needs --hand-load "
        "estimate or tare (default: the task's: piano on, track and reach off)",
    )


def robot_params_option(p: argparse.ArgumentParser) -> None:
    """``--robot-params FILE``: sim target and emulator model the identified robot (``robot.params``).

    A bad file is refused by argparse in one line (exit 2).
    """

    def parse(text: str) -> object:
        from bar_policy.robot.params import ParamsError, load_params

        try:
            return load_params(text)
        except ParamsError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    p.add_argument(
        "--robot-params",
        type=parse,
        default=None,
        metavar="FILE",
        help="robot-parameters file (bar-bus identify --out): the sim target and the in-process "
        "emulator model that robot (friction, damping, armature, payloads, strength); a policy trained "
        "on other parameters (its bar.robot_params hash) gets a warning, counted in run.json",
    )


def target_of(argv: Sequence[str]) -> str | None:
    """The ``--target`` value in ``argv`` (None when absent), before the full parser exists."""
    pre = _Parser(prog="bar-deploy", add_help=False)
    pre.add_argument("--target")
    known, _ = pre.parse_known_args(argv)
    return known.target
