"""CLI glue of the real target for ``bar-deploy --target real``: ``add_arguments(parser)``, ``make_target``.

With ``--can-interface virtual`` an in-process emulator (``RobstrideEmulator``) answers on the same channels.
Opening a channel that cannot be used raises ``BusOpenError`` with a one-line fix (``canbus``).
"""

from __future__ import annotations

import argparse
import logging
import signal
from dataclasses import replace

import can

from bar_policy.deploy.ramp_limit import START_LIMIT_MARGIN, UNSAFE_FLAG
from bar_policy.deploy.targets.base import Target, TargetError
from bar_policy.deploy.targets.real_target import RealTarget
from bar_policy.robot.constants import load_robot
from bar_policy.robot.perturb_spec import Perturbation
from bar_policy.robot.scene import SceneEdit
from bar_policy.robstride.bus_types import DEFAULT_REPLY_TIMEOUT
from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.canbus import open_can_buses
from bar_policy.robstride.cli_args import (
    CAN_INTERFACES,
    HELP,
    can_timeout_arg,
    emulate_perturb_help,
    int_range,
    non_negative,
    parse_channels,
    perturbation_arg,
    positive,
)
from bar_policy.robstride.errors import InitializationError, RobstrideError
from bar_policy.robstride.framing import DEFAULT_CAN_TIMEOUT
from bar_policy.robstride.group import RobstrideGroup
from bar_policy.robstride.startup import DEFAULT_RETRIES, DEFAULT_RETRY_BACKOFF

__all__ = [
    "VIRTUAL_REPLY_TIMEOUT",
    "add_arguments",
    "emulated_perturbation",
    "installed_stop_request",
    "make_target",
]

log = logging.getLogger("bar_policy.deploy.targets.real")  # the real target's logger, as before the split

VIRTUAL_REPLY_TIMEOUT = 0.05
"""Default reply deadline on the in-process virtual bus, s (Python thread hand-offs, not wire time)."""


# ---------------------------------------------------------------------------------------------------
# CLI glue
# ---------------------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the real target's options to ``bar-deploy``'s parser (one argument group, units in the help).

    The names and wording shared with ``bar-bus`` come from ``robstride.cli_args`` (one name per concept).
    """
    g = parser.add_argument_group("real target (Robstride over CAN)")
    add = g.add_argument
    add("--can-interface", choices=CAN_INTERFACES, default="socketcan", help=HELP["--can-interface"])
    add("--channels", metavar="SPEC", default=None, help=HELP["--channels"])
    add(
        "--calibration",
        metavar="PATH|none",
        default=None,
        help="calibration JSON written by bar-bus calibrate --calibration PATH; 'none': zero offsets "
        "(required on socketcan)",
    )
    add(
        "--dry-run",
        action="store_true",
        help="scan, verify, decode and log commands; write no caps, enable nothing",
    )
    add(
        "--emulate",
        choices=("auto", "none", "realtime", "lockstep"),
        default="auto",
        help="in-process emulator: auto = realtime on virtual (lockstep with a task's scene, the piano's "
        "keyboard), none on socketcan",
    )
    add(
        "--emulate-perturb",
        type=perturbation_arg,
        default=None,
        metavar="KEY=VALUE,...",
        help=emulate_perturb_help() + " (the same as --perturb on this target)",
    )
    add(
        "--emulate-dt",
        type=positive("s"),
        default=None,
        metavar="S",
        help="lockstep emulator: physics s per command round (default: --control-dt, else 0.02)",
    )
    add(
        "--reply-timeout",
        type=positive("s"),
        default=None,
        metavar="S",
        help=f"{HELP['--reply-timeout']} (default {DEFAULT_REPLY_TIMEOUT} socketcan, "
        f"{VIRTUAL_REPLY_TIMEOUT} virtual)",
    )
    add(
        "--can-timeout",
        type=can_timeout_arg,
        default=DEFAULT_CAN_TIMEOUT,
        metavar="S",
        help="motor-side CAN watchdog canTimeout (0x7028), s: a motor that hears no frame for this long "
        f"disables itself; 0 leaves the motors' setting (default {DEFAULT_CAN_TIMEOUT})",
    )
    add(
        "--damping-kd",
        type=non_negative("N*m*s/rad"),
        default=1.0,
        metavar="KD",
        help="Kd of the damping fail-safe, N*m*s/rad (default 1.0)",
    )
    add(
        "--scan-to",
        type=int_range(1, 127),
        default=127,
        metavar="ID",
        help=f"{HELP['--scan-to']}, before enabling (default 127)",
    )
    add(
        UNSAFE_FLAG,
        action="store_true",
        help="UNSAFE: allow --start policy or a --ramp-time below the safe minimum on the real target "
        "(refused without it: the step can snap the arms; the minimum is derived from the policy's Kp, "
        "the torque caps and the joint ranges, deploy.ramp_limit)",
    )
    add(
        "--activation-retries",
        type=int_range(0, 20),
        default=DEFAULT_RETRIES,
        metavar="N",
        help="start-up: tries again after a missing reply this many times (backoff "
        f"{DEFAULT_RETRY_BACKOFF * 1e3:g} ms, doubling) before refusing "
        f"(default {DEFAULT_RETRIES})",
    )


def make_target(args: argparse.Namespace, mode: str, scene: SceneEdit | None = None) -> Target:
    """Build the real target from parsed options (nothing is enabled before ``start()``).

    ``scene``: the task's additions to the MuJoCo scene of the in-process emulator (``--can-interface
    virtual``; the piano's keyboard), None for the robot alone; a real bus ignores it. With a scene the
    emulated robot starts where the sim target does (``SimConfig.initial_pose``), the pose the scene's
    objects are placed for, and ``--emulate auto`` is lockstep (physics steps with the commands, as the
    sim target's): from the bare robot's ``arms_hanging``, or after the drop a free-running emulator
    simulates before the first enable, the start-up ramp drags the fingertips up under the keyboard
    (measured: F1 0.10 on g_major_scales_two_hands, no key ever down; 0.95 with both).
    """
    try:
        return _make_target(args, mode, scene)
    except (RobstrideError, ValueError, OSError, can.CanError) as exc:
        raise TargetError(f"cannot build the real target: {exc}") from exc


def _make_target(args: argparse.Namespace, mode: str, scene: SceneEdit | None = None) -> RealTarget:
    robot = load_robot(mode)
    interface = getattr(args, "can_interface", "socketcan")
    interfaces = list(dict.fromkeys(j.can_interface for j in robot.joints))
    channels = parse_channels(getattr(args, "channels", None), interfaces)
    emulate = getattr(args, "emulate", "auto")
    if emulate == "auto":
        # A free-running emulator steps its physics before the runtime enables a motor: with a scene the
        # arms would drop from the pose its objects are placed for (the piano's fingertips under the keys).
        emulate = ("lockstep" if scene is not None else "realtime") if interface == "virtual" else "none"
    calib_arg = getattr(args, "calibration", None)
    if calib_arg is None and interface == "socketcan":
        raise InitializationError("--calibration PATH is required on socketcan ('none' for zero offsets)")
    calibration = Calibration.zeros(robot) if calib_arg in (None, "none") else Calibration.load(calib_arg)
    timeout = getattr(args, "reply_timeout", None) or (
        VIRTUAL_REPLY_TIMEOUT if interface == "virtual" else DEFAULT_REPLY_TIMEOUT
    )
    can_timeout = getattr(args, "can_timeout", DEFAULT_CAN_TIMEOUT)
    control_dt = getattr(args, "control_dt", None)
    if can_timeout and control_dt and can_timeout < 3 * control_dt:
        raise InitializationError(
            f"--can-timeout {can_timeout:g} s is shorter than 3 control periods (--control-dt "
            f"{control_dt:g} s): one late tick would disable the motors; use a longer watchdog, or 0 to "
            "leave the motors' own"
        )
    companions: list[object] = []
    perturbation = emulated_perturbation(args, emulate)
    if getattr(args, "robot_params", None) is not None and emulate == "none":
        log.info("--robot-params: a real robot is what it is; the file models only sim and emulated targets")
    if emulate != "none":
        from bar_policy.robstride.emulator_perturb import emulator as make_emulator

        offsets = dict(zip(robot.joint_names, calibration.offsets(robot), strict=True))
        if scene is not None:
            from bar_policy.deploy.targets.sim import SimConfig

            start = SimConfig().initial_pose
            log.info("emulated robot starts at %s (the task's scene is placed for it)", start)
        emulator = make_emulator(
            robot,
            channels,
            interface=interface,
            mode=emulate,
            initial_q=None if scene is None else robot.pose(start),
            control_dt=getattr(args, "emulate_dt", None) or getattr(args, "control_dt", 0.02),
            offsets=offsets,
            scene=scene,
            perturbation=perturbation,
            robot_params=getattr(args, "robot_params", None),
        )
        companions.append(emulator.start())
        log.info("started the %s Robstride emulator on %s", emulate, channels)
    try:
        buses = open_can_buses(interface, {i: channels[i] for i in interfaces})
    except BaseException:
        for c in companions:
            c.close()  # type: ignore[attr-defined]
        raise
    group = RobstrideGroup.from_robot(
        robot, buses, calibration=calibration, reply_timeout=timeout, can_timeout=can_timeout
    )
    return RealTarget(
        robot,
        group,
        dry_run=getattr(args, "dry_run", False),
        refresh_on_read=emulate != "lockstep",
        damping_kd=getattr(args, "damping_kd", 1.0),
        damping_hold_s=getattr(args, "damping_time", 0.2),
        limit_margin=START_LIMIT_MARGIN,
        scan_ids=range(1, getattr(args, "scan_to", 127) + 1),
        companions=companions,
        stop_requested=installed_stop_request,
        activation_retries=getattr(args, "activation_retries", DEFAULT_RETRIES),
    )


def emulated_perturbation(args: argparse.Namespace, emulate: str) -> Perturbation | None:
    """The emulator's hidden perturbation: ``--perturb`` or ``--emulate-perturb`` (one meaning here).

    On this target both options perturb the in-process emulator's robot and the runtime does not know it;
    given both, they must be the same spec. Without an emulator (socketcan, ``--emulate none``) there is
    no robot to perturb: refused.

    Raises:
        InitializationError: the two disagree, or there is no emulator.
    """
    a, b = getattr(args, "perturb", None), getattr(args, "emulate_perturb", None)
    if a is not None and b is not None and replace(a, text="") != replace(b, text=""):
        raise InitializationError(
            f"--perturb {a.describe()!r} and --emulate-perturb {b.describe()!r} differ: on the real target "
            "both perturb the emulator's robot; give one"
        )
    p = a if a is not None else b
    if p is not None and emulate == "none":
        raise InitializationError(
            "--perturb / --emulate-perturb perturb the in-process emulator's robot: they need "
            "--can-interface virtual with an emulator (a real robot is what it is)"
        )
    return p


def installed_stop_request() -> bool:
    """Whether the process's installed ``StopSignals`` (the SIGINT handler's owner) has a stop request.

    ``bar-deploy`` installs its ``StopSignals`` before it builds the target, so ``make_target`` can check
    it during ``start()`` without being handed it. False when no ``StopSignals`` handles SIGINT.
    """
    from bar_policy.signals import StopSignals

    owner = getattr(signal.getsignal(signal.SIGINT), "__self__", None)
    return isinstance(owner, StopSignals) and owner.requested
