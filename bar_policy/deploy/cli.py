"""``bar-deploy``: run an ONNX policy on the sim, mock or real target; plot a run log; sim2sim evaluation.

Usage::

    bar-deploy --policy reach.onnx [--target sim|mock|real] [--duration S|inf] [--commands SPEC] [--viewer]
               [--video out.mp4] [--log DIR] [--live [PORT]] [--seed N] [real target: --can-interface, ...]
    bar-deploy --policy track.onnx --motion NAME|PATH [...]      (ends after the clip)
    bar-deploy run ...          (same as above)
    bar-deploy plot LOG [--out DIR]
    bar-deploy log recover RUN_DIR|run.mcap   (a run.mcap cut by a crash -> a complete, indexed MCAP)
    bar-deploy eval --policy reach.onnx [--episodes N] [--seed N]
    bar-deploy eval --policy track.onnx [--clips heldout|gestures|NAME,...] [--hold-s S]
    bar-deploy eval --policy F [--target sim|bus] [--perturb SPEC|suite] [--hand-load estimate|tare|off]

The policy file's task (``bar.task``; for HC-only files the task its terms imply) picks the command source
and the evaluation (``deploy.tasks``); an option of another task is refused with a message that names both.

Stopping: SIGINT (Ctrl+C), SIGTERM and SIGHUP take one path: DAMPING, then the stop frames on every bus,
then the log closed with the reason; exit status 0, also during the real target's start-up. A second
signal is counted and ignored. Every run that started prints its ``end:`` line. Exit status:
0 ran to the end or stopped on request, 1 ended on a fault or an error during the run (the joints were
damped and stopped), 2 refused before anything moved (bad arguments, policy or target), 3 the safe stop was
not confirmed (some joint did not answer the damping or stop frames; the end line names them, also after a
fault, which 3 takes precedence over; ``run_config.EXIT_*``); every refusal is
one line on stderr, ``bar-deploy: error: ...``. A malformed input file (policy metadata, motion clip,
commands file, calibration, run log) is refused the same way: its loader raises ``_files.InputError``
naming the file and the problem, and the line is cut to ``MAX_ERROR_CHARS``. A SIGINT before the stop
handlers are installed ends quietly: ``signals.early_interrupt`` (the console entry point,
``bar_policy.entry``, catches one during the imports too). The real target refuses a step start
(``--start policy``, a ``--ramp-time`` below ``ramp_limit.min_ramp_time``) unless
``--unsafe-allow-step-start`` is given.

The only module that prints. Never imports jax, torch or onnx.

One unit: the console's whole surface, each subcommand a short parse-check-run-print path sharing the
refusal, warning-tally and exit-status helpers (the parsers are ``cli_parser``'s).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from bar_policy.deploy import cli_parser
from bar_policy.deploy.cli_tools import fail as _fail
from bar_policy.deploy.cli_tools import log_command, plot_command
from bar_policy.deploy.log.files import CAN_LOG_FILE
from bar_policy.deploy.signals import early_interrupt, signal_name_of
from bar_policy.deploy.warning_tally import WarningTally
from bar_policy.tasks.cli_types import Parser as _Parser
from bar_policy.tasks.cli_types import asks_help as _asks_help
from bar_policy.tasks.cli_types import one_line as _one_line

# The tasks and provenance modules (numpy and more) are imported where they are used: until ``main`` runs,
# a SIGINT is a ``KeyboardInterrupt`` that ``main`` cannot catch, so the module itself loads in milliseconds.

__all__ = ["main"]

log = logging.getLogger("bar_policy.deploy.cli")

TARGETS, SUBCOMMANDS = cli_parser.TARGETS, cli_parser.SUBCOMMANDS
_common, _run_parser, _target_of = cli_parser.common_options, cli_parser.run_parser, cli_parser.target_of


def _add_real_help(parser: argparse.ArgumentParser) -> None:
    """``--help`` lists the real target's options too; without python-can it says how to get them."""
    try:
        _real_module().add_arguments(parser)
    except SystemExit as e:  # the real target cannot be imported here
        parser.add_argument_group("real target (Robstride over CAN)", f"not available here: {e}")


def _configure_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )


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
    real = None
    if _target_of(argv) == "real":
        real = _real_module()
        real.add_arguments(parser)
    elif _asks_help(argv):  # --help lists the real target's options too
        _add_real_help(parser)
    args = parser.parse_args(argv)
    if args.video and args.target != "sim":
        return _fail("--video needs --target sim")
    if args.viewer and args.target != "sim":
        return _fail("--viewer needs --target sim")
    if args.perturb is not None and args.target == "mock":
        return _fail("--perturb needs --target sim, or --target real --can-interface virtual")
    if args.live is not None and args.no_log:
        return _fail("--live serves the run log's channels: drop --no-log")
    if not args.no_log:
        from bar_policy.deploy.log.files import LogDirError, check_log_dir

        try:
            check_log_dir(args.log)
        except LogDirError as e:
            return _fail(e)
    if args.video and not args.viewer:
        # Headless offscreen GL, chosen before mujoco is imported.
        os.environ.setdefault("MUJOCO_GL", "egl")
        if os.environ["MUJOCO_GL"] == "egl":
            os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    _configure_logging(args.verbose)
    from bar_policy.signals import StopSignals

    # Installed before anything moves and kept until the log is closed: every stop takes one path.
    with StopSignals() as stop:
        live = None
        if args.live is not None:
            from bar_policy.deploy.log.live import LiveError, LiveServer

            try:
                live = LiveServer(args.live)
            except LiveError as e:
                return _fail(f"--live: {e}")
            print(f"live view: {live.url} (Foxglove app: Open connection -> Foxglove WebSocket)")
        try:
            return _run_session(args, argv, real, stop, live)
        finally:
            if live is not None:
                live.stop()


def _policy_task(args: argparse.Namespace, which: str) -> tuple[object, object]:
    """The loaded policy and its deploy task, after refusing the other tasks' options.

    Raises:
        PolicyLoadError, OptionError, ValueError: with the message to print.
    """
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.tasks import all_tasks, get_task
    from bar_policy.provenance import describe as describe_provenance

    policy = _with_action_clip(load_policy(args.policy, control_dt=args.control_dt, mode=args.mode), args)
    task = get_task(policy.task)  # type: ignore[attr-defined]
    others = tuple(t for t in all_tasks() if t.name != task.name)
    task.check_options(args.policy, args, others, which)
    meta = policy.metadata  # type: ignore[attr-defined]
    print("\n".join(describe_provenance(meta.provenance, meta.code_version)))  # informs, refuses nothing
    return policy, task


def _run_session(
    args: argparse.Namespace, argv: Sequence[str], real: object, stop: object, live: object
) -> int:
    from bar_policy.deploy.runtime import Runtime, RuntimeConfig
    from bar_policy.deploy.safety import SafetyConfig
    from bar_policy.deploy.targets.base import TargetError
    from bar_policy.robot.kinematics import Kinematics

    kin = Kinematics(args.mode)
    try:
        policy, task = _policy_task(args, "run")
        safety = SafetyConfig(
            ramp_time=args.ramp_time, max_overruns=args.max_overruns, stale_timeout=args.stale_timeout
        )
        duration = task.default_duration if args.duration is None else args.duration
        config = RuntimeConfig(
            control_dt=args.control_dt,
            duration=None if duration is None or math.isinf(duration) else duration,
            start_mode=args.start,
            damping_after_fault=args.damping_time,
            stop_damping=args.stop_damping,
            hand_load=args.hand_load,
            load_inertia=_on_off(args.load_inertia),
            end_hold=args.end_hold,
            start_tare_s=args.start_tare,
            realtime=args.realtime or args.viewer,
            rt_priority=args.rt_priority,
            safety=safety,
        )
        commands = task.command_source(policy, args, kin)
        # The task's figure of the run (reach: success and final distance; track: errors), after end:.
        figure = task.run_figure(policy, commands, kin)
    except ValueError as e:  # PolicyLoadError, OptionError, bad settings
        return _fail(e)
    if args.target == "real":
        refused = _start_refusal(args, policy, commands.hold_pose)
        if refused is not None:
            commands.close()
            return _fail(refused)

    target = None
    try:
        if args.target == "sim":
            from bar_policy.deploy.targets.perturbed import sim_target
            from bar_policy.deploy.targets.sim import SimConfig, note_physics_dt, training_damping

            note_physics_dt(policy.metadata.physics_dt)
            sim_cfg = SimConfig(
                viewer=args.viewer,
                video_path=str(args.video) if args.video else None,
                damping=training_damping(policy.metadata.randomization),
            )
            scene = task.scene(policy)  # type: ignore[attr-defined]
            target = sim_target(
                args.mode,
                sim_cfg,
                scene=scene,
                perturbation=args.perturb,
                robot_params=getattr(args, "robot_params", None),
            )
        elif args.target == "mock":
            from bar_policy.deploy.targets.mock import MockTarget

            target = MockTarget(args.mode)
        else:
            scene = task.scene(policy)  # type: ignore[attr-defined]
            extra = () if scene is None else (scene,)  # the robot alone: the two-argument contract
            target = real.make_target(args, args.mode, *extra)  # type: ignore[attr-defined]
        rt = Runtime(
            policy,
            target,
            commands,
            config,
            log_dir=None if args.no_log else args.log,
            log_meta={"argv": list(argv), "seed": args.seed, **_params_check(args, policy)},
            log_name=args.target,
            live=live,  # type: ignore[arg-type]
            kinematics=kin,
            on_tick=None if figure is None else figure.tick,
        )
    except (TargetError, ValueError) as e:
        commands.close()
        if target is not None:
            target.close()
        return _fail(f"target {args.target}: {e}")

    if stop.requested:  # type: ignore[attr-defined]
        commands.close()
        target.close()
        print(f"{stop.reason} before the start: nothing was started")  # type: ignore[attr-defined]
        return 0
    print(
        f"policy {args.policy} [{policy.obs_manager.fingerprint}] ({task.name}: {task.summary}) on "
        f"{args.target}, commands {commands.describe()}"
    )
    from bar_policy.deploy.log.files import LogDirError
    from bar_policy.quality.report import run_quality_line

    try:
        try:
            rt.open_log()  # before the target starts: nothing slow between activation and the first tick
        except LogDirError as e:
            return _fail(e)
        try:
            target.start()
        except TargetError as e:
            if stop.requested:  # type: ignore[attr-defined]
                # A requested stop during the start-up: the start-up ended it (anything enabled was damped
                # and stopped): a stop on request, status 0, as promised for every moment of the run.
                rt.close_unstarted(f"stopped during the start-up: {stop.reason}")  # type: ignore[attr-defined]
                print(f"{stop.reason} during the start-up: {_one_line(e)}")  # type: ignore[attr-defined]
                print(f"end: {stop.reason} during the start-up; nothing left enabled")  # type: ignore[attr-defined]
                return 0
            rt.close_unstarted(f"not started: target {args.target}: {_one_line(e)}")
            return _fail(f"target {args.target}: {e}")
        result = rt.run(stop)  # type: ignore[arg-type]
    except Exception as e:
        log.error("the run ended on an exception (safe stop: %s)", _stop_text(rt), exc_info=True)
        if rt.result is not None:
            print(rt.result.end_line())
            if figure is not None:
                print(figure.final_line())
        where = f"; log: {rt.log_path.parent}" if rt.log_path is not None else ""
        msg = f"the run ended on {type(e).__name__}: {e} (safe stop: {_stop_text(rt)}{where})"
        return _fail(msg, _after_exception(rt))
    finally:
        commands.close()
        try:
            target.close()
        except Exception:
            log.exception("closing the %s target failed", args.target)
    print(result.timing.format())
    print(result.end_line())
    if figure is not None:
        print(figure.final_line())
    print(run_quality_line(result.quality))
    for tr in result.transitions:
        print(f"  t={tr['t']:.3f} s  {tr['from']} -> {tr['to']}: {tr['reason']}")
    if result.log_path is not None:
        print(f"log: {result.log_path}  (plot: bar-deploy plot {result.log_path.parent})")
        if (result.log_path.parent / CAN_LOG_FILE).is_file():
            print(f"raw CAN traffic: {result.log_path.parent / CAN_LOG_FILE}")
    video = getattr(target, "video_path", None)
    if video is not None:
        print(f"video: {video}")
    return result.exit_status


def _params_check(args: argparse.Namespace, policy: object) -> dict[str, object]:
    """Warn (one line, stderr) when the run's robot parameters are not the ones the policy trained on.

    The policy's ``bar.robot_params`` (its training file's sha256; none: the nominal model) against
    ``--robot-params`` (none: the nominal model). Returns the ``run.json`` record ``robot_params``: both
    hashes (None: nominal) and ``mismatch_warnings`` (0 or 1), so a log shows the warning was given. The
    mock target models no robot: nothing to compare, an empty record.
    """
    if getattr(args, "target", "sim") == "mock":  # eval has no --target: the sim target
        return {}
    from bar_policy.robot.params import training_mismatch

    trained = policy.metadata.robot_params  # type: ignore[attr-defined]
    params = getattr(args, "robot_params", None)
    line = training_mismatch(trained, params)
    if line is not None:
        print(f"WARNING: {line}", file=sys.stderr, flush=True)
    record = {
        "trained_sha256": trained.get("sha256") or None,
        "run_sha256": None if params is None else params.sha256,
        "mismatch_warnings": int(line is not None),
    }
    return {"robot_params": record}


def _start_refusal(args: argparse.Namespace, policy: object, hold: object) -> str | None:
    """Why the real target refuses ``--start policy`` or a short ``--ramp-time`` (None: it does not).

    The minimum is ``ramp_limit.min_ramp_time`` for the policy's Kp, the torque caps, the joint ranges
    and the control period. ``--unsafe-allow-step-start`` lifts the refusal with a warning on stderr.
    """
    from bar_policy.deploy.ramp_limit import UNSAFE_FLAG, min_ramp_time

    minimum = min_ramp_time(policy, hold=hold)
    short = args.start == "policy" or args.ramp_time < minimum.seconds
    if not short:
        return None
    what = "--start policy (no ramp)" if args.start == "policy" else f"--ramp-time {args.ramp_time:g} s"
    if getattr(args, "unsafe_allow_step_start", False):
        print(
            f"WARNING: {UNSAFE_FLAG}: {what} on the real target, below the safe minimum ramp of "
            f"{minimum.rounded_up:.2f} s ({minimum.reason}): the first ticks may push joints at their "
            "torque cap and snap the arms. Keep clear of the robot.",
            file=sys.stderr,
            flush=True,
        )
        return None
    return (
        f"{what} is refused on the real target: below the safe minimum ramp of {minimum.rounded_up:.2f} s "
        f"({minimum.reason}); use --start hold --ramp-time {minimum.rounded_up:.2f} or longer, or add "
        f"{UNSAFE_FLAG} to accept the step"
    )


def _stop_text(rt: object) -> str:
    """The safe stop's outcome after a run that raised (``Runtime.safe_stop_summary``)."""
    return getattr(rt, "safe_stop_summary", "") or "not reached"


def _after_exception(rt: object) -> int:
    """Exit status of a run that raised: 1, or 3 when the safe stop was not confirmed by every joint."""
    from bar_policy.deploy.run_config import EXIT_FAULT, EXIT_STOP_UNCONFIRMED

    report = getattr(rt, "stop_report", None)
    return EXIT_FAULT if report is not None and report.confirmed else EXIT_STOP_UNCONFIRMED


def _on_off(choice: str | None) -> bool | None:
    """``--load-inertia``'s ``on`` / ``off`` as True / False; None (not given): None, the task's."""
    return None if choice is None else choice == "on"


def _say(line: str) -> None:
    """A progress line of ``bar-deploy eval``, flushed (the episodes take seconds each)."""
    print(line, flush=True)


def _print_warnings(tally: WarningTally) -> None:
    """The counted warnings of an evaluation: ``warnings: N ...`` then one line per kind (none: nothing)."""
    lines = tally.lines()
    if lines:
        print(f"warnings: {tally.total} in {len(lines)} kind(s), each kind once with its count:")
        for line in lines:
            print(f"  {line}")


def _eval(argv: Sequence[str]) -> int:
    p = _Parser(
        prog="bar-deploy eval",
        description="Sim2sim on the C MuJoCo sim target (or the emulated CAN bus) with the policy's task "
        "metric: reach, the segment success rate over seeded episodes; track, the joint / tracked-body / "
        "fingertip errors on held-out clips; piano, key-press F1 on held-out and random songs.",
    )
    from bar_policy.deploy.episodes import RUNNERS
    from bar_policy.deploy.tasks import all_tasks

    _common(p)
    cli_parser.eval_target_option(p)
    cli_parser.robot_options(p, suite=True)
    p.add_argument("--json", type=Path, help="write the per-episode / per-clip results here")
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress line per episode, clip or song (the result and the counted warnings "
        "are printed all the same)",
    )
    for task in all_tasks():
        task.add_eval_arguments(p)
    args = p.parse_args(argv)
    if args.json is not None and not (args.json.parent.is_dir() and os.access(args.json.parent, os.W_OK)):
        return _fail(f"--json {str(args.json)!r}: its directory does not exist or is not writable")
    _configure_logging(args.verbose)
    for name in ("bar_policy.deploy.safety", "bar_policy.deploy.targets", "bar_policy.robstride"):
        if not args.verbose:  # their INFO lines repeat every episode
            logging.getLogger(name).setLevel(logging.WARNING)
    say = None if args.quiet else _say
    # Warnings repeat across episodes (one clip warning per joint and episode): each kind is counted and
    # printed once after the result, never dropped.
    with WarningTally() as tally:
        try:
            policy, task = _policy_task(args, "eval")
            params_record = _params_check(args, policy)
            if args.perturb is None:
                kind = RUNNERS[args.target]
                with kind(
                    policy,
                    robot_params=args.robot_params,
                    say=say,
                    hand_load=args.hand_load,
                    load_inertia=_on_off(args.load_inertia),
                ) as run:
                    result = task.evaluate(policy, args, run)
            else:
                from bar_policy.deploy.robustness import evaluate_perturbed

                result = evaluate_perturbed(
                    policy,
                    task,
                    args,
                    args.perturb,
                    _say,
                    progress=not args.quiet,
                    robot_params=args.robot_params,
                    hand_load=args.hand_load,
                    load_inertia=_on_off(args.load_inertia),
                    target=args.target,
                )
        except ValueError as e:  # PolicyLoadError, OptionError, bad settings
            _print_warnings(tally)
            return _fail(e)
    print(result.format())
    _print_warnings(tally)
    if args.json:
        data = {**result.to_dict(), **params_record, "warnings": tally.to_dict()}
        try:
            args.json.write_text(json.dumps(data, indent=2))
        except OSError as e:
            return _fail(f"cannot write --json {str(args.json)!r}: {e.strerror or e}")
        print(f"per-episode / per-clip results: {args.json}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bar-deploy``; returns the exit status.

    0: ran to the end, or stopped on request (SIGINT / SIGTERM / SIGHUP), also before the start; 1: ended on
    a fault or an error during the run; 2: refused before anything moved (bad arguments, policy, motion
    clip, commands file, log directory or target: one line naming the file and the problem; for ``log
    recover``, a file that is not MCAP or cannot be read or rewritten); 130: ``eval``, ``plot`` or ``log``
    ended by SIGINT. A SIGINT that comes before the stop handlers are installed ends without a traceback
    (``signals.early_interrupt``).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in SUBCOMMANDS:
        sub, rest = args[0], args[1:]
    else:
        sub, rest = "run", args
    try:
        if sub == "plot":
            return plot_command(rest)
        if sub == "eval":
            return _eval(rest)
        if sub == "log":
            return log_command(rest)
        return _run(rest)
    except KeyboardInterrupt as e:  # a signal before StopSignals (run), or during eval / plot: no traceback
        status, line = early_interrupt(sub, signal_name_of(e))
        print(line, file=sys.stdout if status == 0 else sys.stderr, flush=True)
        return status


if __name__ == "__main__":
    raise SystemExit(main())
