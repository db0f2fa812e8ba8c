"""``bar-bus``: the bench tools for the Robstride buses.

    bar-bus discover --channel can0 --scan-to 32 [--can-interface socketcan|virtual] [--status]
    bar-bus calibrate [--channels can0,can1] [--calibration cal.json] [--prior old.json] [--duration S]
    bar-bus param read  --channel can0 --id 11 --index 0x700B [--type f32]
    bar-bus param write --channel can0 --id 11 --index 0x700B --value 12.0 [--type f32]
    bar-bus watchdog --channel can0 --id 11 [--can-timeout 0.2] [--silences 0.1,0.18,0.22,0.3]
    bar-bus identify --out params.json [--arms left,right] [--seconds 40] [--budget 0.5] [--unloaded]
                     [--known-payload KG [--known-payload-at fingertip|palm]]
    bar-bus check-calibration [--calibration cal.json] [--pose arms_hanging] [--threshold 0.005]

Option names are ``bar-deploy``'s for the same things (``robstride.cli_args``): ``--can-interface``,
``--channel`` / ``--channels``, ``--calibration``, ``--reply-timeout``, ``--scan-to``, ``--can-timeout``.
The old spellings ``--interface``, ``--iface``, ``--out`` and ``--timeout`` still work, with a one-line
notice.

``discover`` is read-only (type-0 scan and type-17 parameter reads); ``--status`` also sends each found
motor a stop frame (it disables the motor) to read its type-2 mode and fault bits. ``calibrate`` keeps the
motors disabled (stop frames) while a person sweeps every joint to both stops, and writes the calibration
JSON on Ctrl+C (or after ``--duration``). ``watchdog`` measures the CAN watchdog of one motor on a bench
(``watchdog.probe_watchdog``; the motor is enabled with zero torque). ``--emulate`` (with ``--can-interface
virtual``) answers with the in-process emulator, for a demonstration without hardware.

``identify`` (``robstride.excitation_run``, then ``robstride.identify``; docs/sysid.md) excites each arm
in turn around held poses inside a torque budget, then fits friction, damping, armature, strength and the
hand's payload and writes a robot-parameters file (``robot.params``); on ``--can-interface virtual`` the
lockstep emulator answers.
``check-calibration`` reads the joints (motors disabled) through a saved calibration against a resting pose
and exits 2 beyond the threshold.

Stop path of ``calibrate``, ``identify`` and ``watchdog`` (the commands that command motors): SIGINT,
SIGTERM and SIGHUP (``StopSignals``) and any exception end the same way: damping frames, then stop frames,
on every bus (``RobstrideGroup.damping_then_stop``); a second signal is counted and cannot skip them. Then
``calibrate`` writes the calibration (a stop signal is its documented way to finish: exit 0) or discards it
(an exception: exit 1). Errors are one line on stderr (``bar-bus: error: ...``), never a traceback: exit 1
at run time, 2 for bad arguments.

One unit: this is the ``bar-bus`` command line, one parser whose six commands share the bus options
(``common``), the in-process emulator's context, the stop path and the error-to-exit-status policy; each
command's work lives in its own module (``identify``, ``calibration``, ``watchdog``, ``bus``) and what
remains here per command is its options and the calls in order. Split per command, those shared parts would
have to be passed around or duplicated.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import time
from collections.abc import Iterator, Sequence
from typing import NoReturn

import can
import numpy as np

from bar_policy.robot.actuators import ROBSTRIDE_MODELS
from bar_policy.robot.constants import MODES, load_robot
from bar_policy.robot.perturb_spec import PAYLOAD_SITES
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.bus_types import MotorConfig
from bar_policy.robstride.calibration import Calibration, SweepRecorder
from bar_policy.robstride.canbus import open_can_bus, open_can_buses
from bar_policy.robstride.cli_args import (
    CAN_INTERFACES,
    HELP,
    can_timeout_arg,
    deprecated_alias,
    emulate_perturb_help,
    float_list,
    int_range,
    parse_channels,
    perturbation_arg,
    positive,
)
from bar_policy.robstride.errors import InitializationError, RobstrideError
from bar_policy.robstride.group import RobstrideGroup
from bar_policy.robstride.watchdog import arm_can_timeout, probe_watchdog, read_can_timeouts, verdict
from bar_policy.signals import StopSignals

__all__ = ["main", "model_guess"]


def model_guess(limit_torque: float) -> str:
    """Models whose power-on torque cap (T_max) equals the read ``limit_torque`` (a lowered cap: ``?``)."""
    names = [m for m, s in ROBSTRIDE_MODELS.items() if abs(s.t_max - limit_torque) < 1e-3]
    return "/".join(names) if names else f"? (cap {limit_torque:g} lowered?)"


@contextlib.contextmanager
def _emulator(args: argparse.Namespace, channels: dict[str, str], **kwargs: object) -> Iterator[None]:
    if not getattr(args, "emulate", False):
        if getattr(args, "emulate_perturb", None) is not None:
            raise ValueError("--emulate-perturb perturbs the emulator's robot: give --emulate too")
        yield
        return
    if args.interface != "virtual":
        raise ValueError("--emulate needs --can-interface virtual")
    from bar_policy.robstride.emulator_perturb import emulator

    perturb = getattr(args, "emulate_perturb", None)
    kwargs.setdefault("mode", "realtime")
    with emulator(load_robot(args.mode), channels, perturbation=perturb, **kwargs):  # type: ignore[arg-type]
        yield


def _robot_channels(args: argparse.Namespace) -> dict[str, str]:
    robot = load_robot(args.mode)
    return parse_channels(
        getattr(args, "channels", None), list(dict.fromkeys(j.can_interface for j in robot.joints))
    )


def _discover(args: argparse.Namespace) -> int:
    channels = {i: i for i in dict.fromkeys(j.can_interface for j in load_robot(args.mode).joints)}
    with (
        _emulator(args, channels),
        RobstrideBus(open_can_bus(args.interface, args.iface), [], interface=args.iface) as bus,
    ):
        found = bus.scan(range(1, args.scan_to + 1), timeout=args.timeout)
        print(f"{args.iface}: {len(found)} device(s) answered ids 1..{args.scan_to}")
        print(f"{'id':>4}  {'uid':<16}  {'model guess':<22} {'run_mode':>8}  {'faultSta':>10}  status")
        for can_id, uid in found.items():
            cells = []
            for index in (proto.PARAM_LIMIT_TORQUE, 0x7005, 0x3022):
                try:
                    cells.append(bus.read_param(can_id, index, timeout=args.timeout))
                except RobstrideError:
                    cells.append(None)
            guess = model_guess(float(cells[0])) if cells[0] is not None else "? (0x700B unreadable)"
            status = "-"
            if args.status:
                try:
                    fb = bus.request(
                        proto.stop_frame(can_id),
                        lambda r, i=can_id: isinstance(r, proto.Feedback) and r.motor_id == i,
                        args.timeout,
                    )
                    if not isinstance(fb, proto.Feedback):  # pragma: no cover - guaranteed by the match
                        raise TypeError(fb)
                    names = ", ".join(proto.fault_names(fb.faults)) or "no faults"
                    status = f"mode={proto.MODE_NAMES[fb.mode]} faults={names} pos={fb.position:+.3f} rad"
                except RobstrideError as exc:
                    status = f"no feedback ({exc})"
            fault = "n/a" if cells[2] is None else f"{int(cells[2]):#010x}"
            run_mode = "n/a" if cells[1] is None else str(cells[1])
            print(f"{can_id:>4}  {uid.hex():<16}  {guess:<22} {run_mode:>8}  {fault:>10}  {status}")
    return 0


def _param(args: argparse.Namespace) -> int:
    index = args.index
    dtype = args.type or (proto.PARAMS[index].dtype if index in proto.PARAMS else None)
    if dtype is None:
        raise ValueError(f"parameter {index:#06x} is not in the known table: pass --type")
    value: float | int | None = None
    if args.action == "write":
        if args.value is None:
            raise ValueError("param write needs --value")
        try:
            value = float(args.value) if dtype == "f32" else int(args.value, 0)
        except ValueError:
            raise ValueError(f"--value {args.value!r} is not a valid {dtype}") from None
    with RobstrideBus(open_can_bus(args.interface, args.iface), [], interface=args.iface) as bus:
        if value is not None:
            bus.write_param(args.id, index, value, dtype=dtype, timeout=args.timeout)
            print(f"wrote {value} to parameter {index:#06x} of id {args.id} on {args.iface}")
        got = bus.read_param(args.id, index, dtype=dtype, timeout=args.timeout)
        name = proto.PARAMS[index].name if index in proto.PARAMS else "?"
        print(f"id {args.id} parameter {index:#06x} ({name}) = {got}")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    robot = load_robot(args.mode)
    channels = _robot_channels(args)
    prior = Calibration.load(args.prior) if args.prior else None
    recorder = SweepRecorder(robot)
    with StopSignals() as stop:
        with _emulator(args, channels):
            group = RobstrideGroup.from_robot(  # zero offsets; nothing is armed or enabled
                robot, open_can_buses(args.interface, channels), reply_timeout=args.timeout, can_timeout=0.0
            )
            try:
                group.scan_and_verify(range(1, 128), timeout=args.timeout)
                d = robot.direction
                print(
                    "Motors are disabled. Move each joint to both mechanical stops, then Ctrl+C to save.",
                    flush=True,
                )
                end = time.monotonic() + args.duration if args.duration else None
                last_print = 0.0
                while not stop.requested and (end is None or time.monotonic() < end):
                    reading = group.poll_disabled()
                    recorder.update(d * reading.q)  # zero offsets: q = direction * raw
                    if time.monotonic() - last_print > 0.2 and sys.stdout.isatty():
                        last_print = time.monotonic()
                        _print_sweep(robot.joint_names, d * reading.q, recorder)
                    time.sleep(1.0 / args.rate)
            finally:  # a signal, the duration, or an exception: damping, then stop frames, on every bus
                group.damping_then_stop()
                group.shutdown()
        print(f"\nstopping: {stop.reason or 'duration reached'}; damping and stop frames sent", flush=True)
        result = recorder.result(prior, sweep_threshold=args.sweep_threshold)
        if not result.swept:
            raise InitializationError(
                f"no joint was swept by {args.sweep_threshold} rad or more ({recorder.samples} samples): "
                f"nothing written, {args.out} is untouched"
            )
        result.calibration.save(args.out)
    print(f"Wrote calibration to {args.out} ({recorder.samples} samples)")
    if result.kept:
        print(f"kept the prior offset (sweep < {args.sweep_threshold} rad) for: {', '.join(result.kept)}")
    for w in result.warnings:
        print(f"WARNING: {w}")
    return 0


def _identify(args: argparse.Namespace) -> int:
    """``bar-bus identify``: excitation, fit, parameters file (``robstride.identify``)."""
    import datetime

    from bar_policy.robot.params import HANDS, Estimate, ParamsError, Payload, load_params
    from bar_policy.robot.perturb import PAYLOAD_POS
    from bar_policy.robot.sysid_excitation import Excitation
    from bar_policy.robot.sysid_file import held_from, to_params
    from bar_policy.robstride.can_record import CanRecorder
    from bar_policy.robstride.excitation_run import Supervisor, run_excitation
    from bar_policy.robstride.identify import fit_recording

    robot = load_robot(args.mode)
    if args.interface == "virtual":
        args.emulate = True  # nothing else answers on the in-process bus
    channels = _robot_channels(args)
    arms = tuple(args.arms)
    period = 1.0 / args.rate
    strength = armature = prior = known = None
    if args.known_payload is None and args.known_payload_at is not None:
        raise _UsageError("--known-payload-at places the --known-payload mass: give --known-payload KG too")
    if args.known_payload is not None:
        if args.unloaded or args.unloaded_from:
            other = "--unloaded" if args.unloaded else "--unloaded-from"
            raise _UsageError(f"--known-payload fits every strength with the payload held: not with {other}")
        site = args.known_payload_at or "fingertip"
        known = {arm: Payload(Estimate(args.known_payload), PAYLOAD_POS[site][HANDS[arm]]) for arm in arms}
    if args.unloaded_from:
        try:
            prior = load_params(args.unloaded_from, robot)
        except ParamsError as exc:
            raise _UsageError(str(exc)) from None
        names = {arm: [j.name for j in robot.joints if j.group == f"{arm}_arm"] for arm in arms}
        missing = [n for arm in arms for n in names[arm] if n not in prior.joints]
        if missing:
            raise _UsageError(
                f"--unloaded-from {args.unloaded_from}: no values for {', '.join(missing)} "
                f"(identify those arms --unloaded first)"
            )
        strength = {a: np.array([prior.joints[n].strength.value for n in names[a]]) for a in arms}
        armature = {a: np.array([prior.joints[n].armature.value for n in names[a]]) for a in arms}
    calibration = Calibration.load(args.calibration) if args.calibration else None
    supervisor = Supervisor(robot, budget=args.budget)
    emu_kw = {"mode": "lockstep", "control_dt": period} if args.emulate else {}
    if args.emulate and args.timeout < 1.0:  # the lockstep emulator shares this host's CPU: no deadline
        print(f"identify: emulated bus: reply timeout {args.timeout:g} s raised to 1 s", flush=True)
        args.timeout = 1.0
    with StopSignals() as stop, _emulator(args, channels, **emu_kw):
        group = RobstrideGroup.from_robot(
            robot,
            open_can_buses(args.interface, channels),
            calibration=calibration,
            reply_timeout=args.timeout,
            can_timeout=0.0 if args.emulate else proto.DEFAULT_CAN_TIMEOUT,
        )
        recorder = CanRecorder(args.can_log) if args.can_log else None
        for bus in group.buses:
            bus.record_to(recorder)
        try:
            recs = {}
            for arm in arms:  # one arm at a time (measured: both at once fit worse, 0.2 vs 0.03 N*m)
                reading = group.activate(lower=robot.lower, upper=robot.upper)
                moment = (
                    None if known is None else known[arm].mass_kg.value * np.linalg.norm(known[arm].com_m)
                )
                excitation = Excitation.plan(
                    robot, reading.q, (arm,), args.seconds, payload_moment_kgm=moment
                )
                load = "" if known is None else f", {known[arm].mass_kg.value:g} kg known in the hand"
                print(
                    f"identify: {excitation.duration:.1f} s of excitation of the {arm} arm at "
                    f"{args.rate:g} Hz, budget {args.budget:.0%} of each cap{load}",
                    flush=True,
                )
                recs[arm] = run_excitation(
                    group,
                    robot,
                    excitation,
                    supervisor,
                    period=period,
                    stop=lambda: stop.requested,
                    realtime=not args.emulate,
                )
        except KeyboardInterrupt:
            print(f"stopped by {stop.reason}: damping and stop frames sent; nothing written", file=sys.stderr)
            return 130
        finally:
            group.shutdown()
            if recorder is not None:
                recorder.stop()
    rounds = sum(len(r.t) - 1 for r in recs.values())
    peak = max(r.peak_fraction for r in recs.values())
    print(
        f"excitation done: {rounds} rounds, peak torque {peak:.0%} of a cap; damping and stop frames "
        "sent; fitting",
        flush=True,
    )
    fits = {}
    for arm, rec in recs.items():
        fits.update(
            fit_recording(
                robot,
                rec,
                (arm,),
                period,
                strength=strength,
                armature=armature,
                payload=not args.unloaded,
                known_payload=None if known is None else {arm: known[arm]},
            )
        )
    perturb = getattr(args, "emulate_perturb", None)
    source: dict[str, object] = {
        "kind": "identify",
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": "bar-bus " + " ".join(sys.argv[1:])
        if sys.argv[1:2] == ["identify"]
        else "bar-bus identify",
        "mode": args.mode,
        "emulated": bool(args.emulate),
        "can_log": args.can_log,
        "excitation_s": round(sum(len(r.t) - 1 for r in recs.values()) * period, 3),
        "samples": sum(len(r.t) - 1 for r in recs.values()),
    }
    notes = []
    if known is not None:
        notes.append(
            f"payload held known: {args.known_payload:g} kg at the {args.known_payload_at or 'fingertip'} "
            "(--known-payload), every strength fitted"
        )
    if perturb is not None:
        notes.append(f"hidden emulator perturbation: {perturb.describe()}")
    if notes:
        source["notes"] = "; ".join(notes)
    params = to_params(fits, source)
    if prior is not None:  # held: the unloaded run's own estimates, intervals included
        params = held_from(params, prior, args.unloaded_from)
    params.save(args.out)
    print(f"wrote {args.out} (sha256 {params.sha256[:16]}...)")
    for arm, f in fits.items():
        pay = "" if args.unloaded else f"; payload {f.mass:.3f} +- {f.mass_half95:.3f} kg"
        if known is not None:
            pay = f"; payload {f.mass:g} kg (held); strength {' '.join(f'{x:.3f}' for x in f.strength)}"
        print(f"  {arm}: residual {f.rms:.3f} N*m over {f.rows} rows{pay}")
    return 0


def _check_calibration(args: argparse.Namespace) -> int:
    """``bar-bus check-calibration``: the joints read (motors disabled) against a named resting pose."""
    from bar_policy.robot.calibration_check import check_pose

    robot = load_robot(args.mode)
    channels = _robot_channels(args)
    try:
        calibration = Calibration.load(args.calibration)
    except (OSError, ValueError) as exc:
        raise _UsageError(" ".join(str(exc).split())) from None
    try:
        pose = robot.pose(args.pose)
    except ValueError as exc:
        raise _UsageError(str(exc)) from None
    with _emulator(args, channels):
        group = RobstrideGroup.from_robot(
            robot,
            open_can_buses(args.interface, channels),
            calibration=calibration,
            reply_timeout=args.timeout,
            can_timeout=0.0,
        )
        try:
            group.scan_and_verify(range(1, 128), timeout=args.timeout)
            if args.settle:
                time.sleep(args.settle)
            q = np.mean([group.poll_disabled(strict=True).q for _ in range(args.reads)], axis=0)
        finally:
            group.stop()
            group.shutdown()
    ok, text = check_pose(robot, q, pose, threshold=args.threshold, pose_name=args.pose)
    if not ok:
        print(f"bar-bus: error: {text}", file=sys.stderr)
        return 2
    print(text)
    return 0


class _UsageError(ValueError):
    """A bad argument found after parsing (a file's content): one line, exit 2."""


def _print_sweep(names: Sequence[str], raw: np.ndarray, rec: SweepRecorder) -> None:
    lines = ["\x1b[H\x1b[J"]
    for n, p, lo, hi, s in zip(names, raw, rec.raw_min, rec.raw_max, rec.sweep, strict=True):
        lines.append(f"  {n:<22} raw={p:+.3f}  min={lo:+.3f}  max={hi:+.3f}  sweep={s:.3f}")
    print("\n".join(lines), flush=True)


def _watchdog(args: argparse.Namespace) -> int:
    robot = load_robot(args.mode)
    if args.can_timeout == 0:
        raise ValueError("watchdog needs --can-timeout > 0 (the window to measure)")
    model = args.model or next((j.model for j in robot.joints if j.can_id == args.id), None)
    if model is None:
        raise ValueError(f"id {args.id} is not a joint of the {args.mode} robot data: pass --model")
    silences = args.silences or [round(f * args.can_timeout, 4) for f in (0.5, 0.9, 1.1, 1.5)]
    channels = {i: i for i in dict.fromkeys(j.can_interface for j in robot.joints)}
    name = f"id {args.id}"
    motor = MotorConfig(name=name, can_id=args.id, model=model, can_timeout=args.can_timeout)
    results = []
    with StopSignals() as stop, _emulator(args, channels):
        bus = RobstrideBus(
            open_can_bus(args.interface, args.iface),
            [motor],
            interface=args.iface,
            reply_timeout=args.timeout,
        )
        group = RobstrideGroup([bus], [name])
        try:
            if args.id not in bus.scan([args.id], timeout=args.timeout):
                raise InitializationError(f"{args.iface}: id {args.id} does not answer a scan")
            read_can_timeouts(bus)
            arm_can_timeout(bus)
            print(
                f"{args.iface} id {args.id} ({model}): canTimeout armed at {args.can_timeout:g} s; "
                f"probing silences {silences} s with zero torque (free shaft)",
                flush=True,
            )
            results = probe_watchdog(bus, silences, timeout=args.timeout, stop=lambda: stop.requested)
        finally:
            group.damping_then_stop()
            group.shutdown()
    for r in results:
        state = {2: "still running", 0: "tripped (reset mode)"}.get(r.mode, "no reply")
        print(f"  silence {r.silence:.3f} s: {state}")
    if stop.requested:
        print(f"stopped by {stop.reason} before the end; damping and stop frames sent")
        return 128 + signal.Signals[stop.signal_name].value if stop.signal_name else 1
    ok, text = verdict(results, args.can_timeout)
    print(text)
    return 0 if ok else 1


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``prog: error: message (see prog --help)``), exit status 2."""

    def error(self, message: str) -> NoReturn:
        """Print one line and exit 2."""
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="bar-bus", description="Robstride CAN bench tools")
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        iface = sp.add_argument(
            "--can-interface",
            dest="interface",
            choices=CAN_INTERFACES,
            default="socketcan",
            help=HELP["--can-interface"],
        )
        deprecated_alias(sp, "--interface", iface)
        timeout = sp.add_argument(
            "--reply-timeout",
            dest="timeout",
            type=positive("s"),
            default=0.05,
            metavar="S",
            help=f"{HELP['--reply-timeout']} (default 0.05)",
        )
        deprecated_alias(sp, "--timeout", timeout)
        sp.add_argument("--mode", choices=MODES, default="arms", help="robot joint set")
        sp.add_argument(
            "--emulate",
            action="store_true",
            help="answer with the in-process emulator (--can-interface virtual)",
        )
        sp.add_argument(
            "--emulate-perturb",
            type=perturbation_arg,
            default=None,
            metavar="KEY=VALUE,...",
            help=emulate_perturb_help(),
        )

    def channel(sp: argparse.ArgumentParser) -> None:
        one = sp.add_argument(
            "--channel", dest="iface", default="can0", metavar="NAME", help=HELP["--channel"]
        )
        deprecated_alias(sp, "--iface", one)

    d = sub.add_parser("discover", help="read-only scan: id, model guess, run mode, faults")
    common(d)
    channel(d)
    d.add_argument(
        "--scan-to",
        type=int_range(1, 127),
        default=32,
        metavar="ID",
        help=f"{HELP['--scan-to']} (default 32)",
    )
    d.add_argument("--status", action="store_true", help="also send a stop frame to read mode and fault bits")

    c = sub.add_parser("calibrate", help="record homing offsets from swept extremes")
    common(c)
    c.add_argument("--channels", default=None, metavar="SPEC", help=HELP["--channels"])
    out = c.add_argument(
        "--calibration",
        dest="out",
        default="calibration.json",
        metavar="PATH",
        help="calibration JSON to write (bar-deploy --target real --calibration reads it; "
        "default calibration.json)",
    )
    deprecated_alias(c, "--out", out)
    c.add_argument(
        "--prior",
        default=None,
        metavar="PATH",
        help="previous calibration JSON: un-swept joints keep its offsets",
    )
    c.add_argument(
        "--sweep-threshold",
        type=positive("rad"),
        default=0.5,
        metavar="RAD",
        help="minimum sweep to recompute a joint's offset, rad (default 0.5)",
    )
    c.add_argument(
        "--rate", type=positive("Hz"), default=50.0, metavar="HZ", help="sampling rate, Hz (default 50)"
    )
    c.add_argument(
        "--duration",
        type=positive("s"),
        default=None,
        metavar="S",
        help="stop after this long, s (default: at Ctrl+C)",
    )

    pa = sub.add_parser("param", help="read or write one parameter")
    pa.add_argument("action", choices=("read", "write"))
    common(pa)
    channel(pa)
    pa.add_argument("--id", type=int_range(1, 127), required=True, help="motor CAN id (1..127)")
    pa.add_argument("--index", type=int_range(0, 0xFFFF), required=True, help="parameter index, e.g. 0x700B")
    pa.add_argument("--value", default=None, help="value to write (in the parameter's unit)")
    pa.add_argument(
        "--type",
        default=None,
        choices=("f32", "u8", "u16", "u32", "i16"),
        help="wire type (default: from the known-parameter table)",
    )

    w = sub.add_parser("watchdog", help="measure one motor's CAN watchdog (enables it with zero torque)")
    common(w)
    channel(w)
    w.add_argument("--id", type=int_range(1, 127), required=True, help="motor CAN id (1..127)")
    w.add_argument(
        "--model",
        choices=sorted(ROBSTRIDE_MODELS),
        default=None,
        help="motor model (default: from the robot data for --id)",
    )
    w.add_argument(
        "--can-timeout",
        type=can_timeout_arg,
        default=proto.DEFAULT_CAN_TIMEOUT,
        metavar="S",
        help=f"watchdog to arm and measure, s (default {proto.DEFAULT_CAN_TIMEOUT})",
    )
    w.add_argument(
        "--silences",
        type=float_list(positive("s")),
        default=None,
        metavar="S,S,...",
        help="silences to probe, s, comma separated (default 0.5,0.9,1.1,1.5 x it)",
    )
    ident = sub.add_parser("identify", help="excite the arms, fit friction, armature, strength, payload")
    common(ident)
    ident.add_argument("--channels", default=None, metavar="SPEC", help=HELP["--channels"])
    ident.add_argument("--out", required=True, metavar="FILE", help="robot-parameters JSON to write")
    ident.add_argument(
        "--arms",
        type=_arms,
        default=["left", "right"],
        metavar="ARMS",
        help="arms to excite, comma separated: left,right (default both, at once)",
    )
    ident.add_argument(
        "--seconds",
        type=_seconds,
        default=40.0,
        metavar="S",
        help="excitation time per arm at the four poses, ramps included, 20.5..60 s (default 40); the fast "
        "single-joint phase adds 16.5 s (a 2.5 s ramp, then 2 s per joint)",
    )
    ident.add_argument(
        "--rate",
        type=positive("Hz"),
        default=500.0,
        metavar="HZ",
        help="command rounds per second (default 500: one 2 ms physics step per round)",
    )
    ident.add_argument(
        "--budget",
        type=_budget,
        default=0.5,
        metavar="FRACTION",
        help="torque budget, fraction of each joint's cap, at most 0.5 (default 0.5)",
    )
    ident.add_argument(
        "--calibration", default=None, metavar="PATH", help="calibration JSON (default: zeros)"
    )
    ident.add_argument(
        "--can-log",
        default=None,
        metavar="FILE",
        help="raw CAN traffic to this .blf or .asc file (as bar-deploy's run.blf)",
    )
    ident.add_argument(
        "--unloaded",
        action="store_true",
        help="the hands carry nothing: fit each joint's strength (payload held at 0)",
    )
    ident.add_argument(
        "--unloaded-from",
        default=None,
        metavar="FILE",
        help="parameters file of an --unloaded run of the same arms: its strengths and armatures are "
        "held (written as that file has them) while the payload is fitted (default: strength 1, "
        "armature fitted)",
    )
    ident.add_argument(
        "--known-payload",
        type=_known_payload,
        default=None,
        metavar="KG",
        help="a calibration mass of KG kg (0 < KG <= 2; measured within the budget: 0.4 at the fingertip) "
        "fixed in each hand at --known-payload-at: held known, every joint's strength fitted, the "
        "wrists' included; adds the lever phase (7.5 s per arm). Not with --unloaded or --unloaded-from",
    )
    ident.add_argument(
        "--known-payload-at",
        choices=PAYLOAD_SITES,
        default=None,
        metavar="SITE",
        help="where the --known-payload mass sits on each hand: fingertip (the finger's tip site, 0.225 m "
        "along the hand) or palm (the palm's centre, 0.1 m) (default fingertip)",
    )
    ck = sub.add_parser("check-calibration", help="verify a saved calibration against a known resting pose")
    common(ck)
    ck.add_argument("--channels", default=None, metavar="SPEC", help=HELP["--channels"])
    ck.add_argument(
        "--calibration",
        default="calibration.json",
        metavar="PATH",
        help="calibration JSON to check (default calibration.json)",
    )
    ck.add_argument(
        "--pose",
        default="arms_hanging",
        metavar="NAME",
        help="the pose the robot rests in, disabled (default arms_hanging: arms hanging at their stops)",
    )
    ck.add_argument(
        "--threshold",
        type=positive("rad"),
        default=0.005,
        metavar="RAD",
        help="largest error on any joint, rad (default 0.005); beyond it: exit 2",
    )
    ck.add_argument(
        "--reads", type=int_range(1, 1000), default=10, metavar="N", help="readings averaged (default 10)"
    )
    ck.add_argument(
        "--settle",
        type=positive("s"),
        default=None,
        metavar="S",
        help="wait this long before reading, s (default: none)",
    )
    return p


def _seconds(text: str) -> float:
    from bar_policy.robot.sysid_excitation import min_seconds

    value = positive("s")(text)
    if not min_seconds() <= value <= 60.0:
        raise argparse.ArgumentTypeError(
            f"must be {min_seconds():g}..60 s of excitation per arm, got {text!r}"
        )
    return value


def _budget(text: str) -> float:
    value = positive("x")(text)
    if value > 0.5:
        raise argparse.ArgumentTypeError(f"must be a fraction of the cap in (0, 0.5], got {text!r}")
    return value


def _known_payload(text: str) -> float:
    from bar_policy.robot.params import MASS_RANGE

    value = positive("kg")(text)
    if value > MASS_RANGE[1]:
        raise argparse.ArgumentTypeError(f"must be a mass in (0, {MASS_RANGE[1]:g}] kg, got {text!r}")
    return value


def _arms(text: str) -> list[str]:
    arms = [a.strip() for a in text.split(",") if a.strip()]
    bad = [a for a in arms if a not in ("left", "right")]
    if bad or not arms or len(set(arms)) != len(arms):
        raise argparse.ArgumentTypeError(f"arms must be left, right or left,right; got {text!r}")
    return arms


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``bar-bus``; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    implied = args.command == "identify" and args.interface == "virtual"
    if getattr(args, "emulate_perturb", None) is not None and not args.emulate and not implied:
        parser.error("--emulate-perturb perturbs the in-process emulator's robot: give --emulate too")
    commands = {
        "discover": _discover,
        "calibrate": _calibrate,
        "param": _param,
        "watchdog": _watchdog,
        "identify": _identify,
        "check-calibration": _check_calibration,
    }
    try:
        return commands[args.command](args)
    except _UsageError as exc:
        print(f"bar-bus: error: {exc}", file=sys.stderr)
        return 2
    except (RobstrideError, can.CanError, OSError, ValueError) as exc:
        print(f"bar-bus: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # discover and param: read-only or a single write, nothing to stop
        print("bar-bus: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
