"""Clear errors: bar-bus bad arguments (one line, no traceback, non-zero exit), ``BusOpenError`` for a bus
that cannot be opened or is down, and the real target's validated options."""

from __future__ import annotations

import argparse
import errno
import re
import subprocess
import sys

import can
import pytest

import bar_policy.robstride as robstride
from bar_policy.deploy.targets.base import TargetError
from bar_policy.deploy.targets.real import add_arguments, make_target
from bar_policy.robstride import canbus
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.errors import (
    BusOpenError,
    InitializationError,
    OperationError,
    RobstrideError,
)
from bar_policy.robstride.tools import main

UP = "sudo ip link set {} up type can bitrate 1000000"

# (argv, exit status, a fragment of the one error line)
BAD_ARGS = [
    (["discover", "--reply-timeout", "-1"], 2, "argument --reply-timeout: must be a number > 0 s, got '-1'"),
    (["discover", "--reply-timeout", "0"], 2, "argument --reply-timeout: must be a number > 0 s, got '0'"),
    (["discover", "--reply-timeout", "nan"], 2, "argument --reply-timeout: must be finite, got 'nan'"),
    (["discover", "--reply-timeout", "soon"], 2, "argument --reply-timeout: not a number: 'soon'"),
    # The deprecated spelling refuses a bad value the same way (its name in the message).
    (["discover", "--timeout", "-1"], 2, "argument --timeout: must be a number > 0 s, got '-1'"),
    (["discover", "--scan-to", "0"], 2, "argument --scan-to: must be an integer in 1..127, got '0'"),
    (["discover", "--scan-to", "200"], 2, "argument --scan-to: must be an integer in 1..127, got '200'"),
    (["calibrate", "--rate", "0"], 2, "argument --rate: must be a number > 0 Hz, got '0'"),
    (["calibrate", "--duration", "-5"], 2, "argument --duration: must be a number > 0 s, got '-5'"),
    (["calibrate", "--sweep-threshold", "0"], 2, "argument --sweep-threshold: must be a number > 0 rad"),
    (["param", "read", "--id", "0", "--index", "0x700B"], 2, "argument --id: must be an integer in 1..127"),
    (
        ["param", "read", "--id", "11", "--index", "0x10000"],
        2,
        "argument --index: must be an integer in 0..65535",
    ),
    (["param", "read", "--index", "0x700B"], 2, "the following arguments are required: --id"),
    (
        ["watchdog", "--id", "11", "--can-timeout", "0.001"],
        2,
        "argument --can-timeout: the CAN watchdog must be 0 (leave the motors' watchdog setting) "
        "or 0.01..10 s",
    ),
    (
        ["watchdog", "--id", "11", "--can-timeout", "-0.2"],
        2,
        "argument --can-timeout: the CAN watchdog must be",
    ),
    (
        ["watchdog", "--id", "11", "--silences", "0.1,-1"],
        2,
        "argument --silences: must be a number > 0 s, got '-1'",
    ),
    (["watchdog", "--id", "11", "--silences", ","], 2, "argument --silences: must be a comma-separated list"),
    (["frobnicate"], 2, "argument command: invalid choice: 'frobnicate'"),
    (["watchdog", "--id", "11", "--can-timeout", "0"], 1, "watchdog needs --can-timeout > 0"),
    (["watchdog", "--id", "99"], 1, "id 99 is not a joint of the arms robot data: pass --model"),
    (
        ["param", "write", "--id", "11", "--index", "0x7028", "--value", "lots"],
        1,
        "--value 'lots' is not a valid u32",
    ),
    (["param", "write", "--id", "11", "--index", "0x7028"], 1, "param write needs --value"),
    (["param", "read", "--id", "11", "--index", "0x1234"], 1, "parameter 0x1234 is not in the known table"),
    (["discover", "--emulate"], 1, "--emulate needs --can-interface virtual"),
    (["calibrate", "--channels", "a,b,c"], 1, "--channels 'a,b,c': give 2 channels"),
    (
        ["calibrate", "--prior", "/nonexistent/cal.json"],
        1,
        "cannot read calibration file /nonexistent/cal.json",
    ),
]


def _run(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse
        return exc.code


@pytest.mark.parametrize(("argv", "status", "fragment"), BAD_ARGS, ids=[" ".join(a[0]) for a in BAD_ARGS])
def test_bad_arguments_give_one_line(argv, status, fragment, capsys):
    code = _run(argv)
    out, err = capsys.readouterr()
    assert code == status
    assert err.count("\n") == 1 and err.startswith("bar-bus"), err
    assert fragment in err, err
    assert "Traceback" not in err and out == ""


def test_missing_socketcan_or_interface_one_line_from_the_console():
    """A real process: whatever this machine lacks (no SocketCAN, or no interface of that name)."""
    r = subprocess.run(
        [sys.executable, "-m", "bar_policy.robstride.tools", "discover", "--channel", "nocan7"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert r.stderr.startswith("bar-bus: error: cannot open socketcan channel nocan7: ")
    assert f"`{UP.format('nocan7')}`" in r.stderr


@pytest.mark.parametrize(
    ("exc", "fragment"),
    [
        (
            OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"),
            "SocketCAN is not available on this machine",
        ),
        (OSError(errno.ENODEV, "No such device"), "no CAN interface named can0"),
        (can.CanInterfaceNotImplementedError("Unknown interface type"), "CanInterfaceNotImplementedError"),
    ],
)
def test_open_errors_are_typed_one_line_with_the_fix(monkeypatch, exc, fragment):
    def refuse(**kw):
        raise exc

    monkeypatch.setattr(can, "Bus", refuse)
    with pytest.raises(BusOpenError) as info:
        canbus.open_can_bus("socketcan", "can0")
    msg = str(info.value)
    assert fragment in msg and "\n" not in msg and msg.startswith("cannot open socketcan channel can0: ")
    assert info.value.channel == "can0" and info.value.interface == "socketcan"
    assert isinstance(info.value, InitializationError) and isinstance(info.value, RobstrideError)
    assert robstride.BusOpenError is BusOpenError
    if fragment != "CanInterfaceNotImplementedError":
        assert f"`{UP.format('can0')}`" in msg


class _FakeBus:
    def __init__(self, error_code=None):
        self.closed = False
        self.sends = 0
        self.error_code = error_code

    def shutdown(self):
        self.closed = True

    def send(self, msg):
        self.sends += 1
        raise can.CanOperationError("Failed to transmit: Network is down", self.error_code)


@pytest.mark.parametrize(("flags", "down"), [("0x1002", True), ("0x1003", False), ("0x40080", True)])
def test_a_down_interface_is_refused_at_opening(monkeypatch, tmp_path, flags, down):
    (tmp_path / "can0").mkdir()
    (tmp_path / "can0" / "flags").write_text(flags + "\n")  # bit 0 = IFF_UP
    fake = _FakeBus()
    monkeypatch.setattr(can, "Bus", lambda **kw: fake)
    if down:
        msg = r"the interface is down; bring it up with `sudo ip link set can0 up type can bitrate 1000000`$"
        with pytest.raises(BusOpenError, match=msg):
            canbus.open_can_bus("socketcan", "can0", sys_net=tmp_path)
        assert fake.closed
    else:
        assert canbus.open_can_bus("socketcan", "can0", sys_net=tmp_path) is fake


def test_interface_going_down_while_open_names_the_fix_without_retrying():
    fake = _FakeBus(error_code=errno.ENETDOWN)
    bus = RobstrideBus(fake, [], interface="can1")  # type: ignore[arg-type]
    msg = r"can1: cannot send: CAN interface can1 is down; bring it up with `sudo ip link set can1 up "
    with pytest.raises(OperationError, match=msg):
        bus.send((0x0300FD0B, bytes(8)))
    assert fake.sends == 1  # not retried like a full TX queue


# ---------------------------------------------------------------------------------------------------
# the real target's options (bar-deploy --target real)
# ---------------------------------------------------------------------------------------------------
def _parse(argv):
    p = argparse.ArgumentParser(prog="bar-deploy")
    add_arguments(p)
    return p.parse_args(argv)


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["--can-timeout", "-1"], "argument --can-timeout: the CAN watchdog must be 0"),
        (["--can-timeout", "0.001"], "or 0.01..10 s, got 0.001"),
        (["--can-timeout", "inf"], "argument --can-timeout: must be finite"),
        (["--reply-timeout", "0"], "argument --reply-timeout: must be a number > 0 s"),
        (["--emulate-dt", "-0.02"], "argument --emulate-dt: must be a number > 0 s"),
        (["--damping-kd", "-1"], "argument --damping-kd: must be a number >= 0 N*m*s/rad"),
        (["--scan-to", "0"], "argument --scan-to: must be an integer in 1..127"),
    ],
)
def test_real_target_options_are_validated(argv, fragment, capsys):
    with pytest.raises(SystemExit) as info:
        _parse(argv)
    assert info.value.code == 2 and fragment in capsys.readouterr().err


def test_real_target_watchdog_option_default_help_and_control_period(capsys):
    assert _parse([]).can_timeout == 0.2 and _parse(["--can-timeout", "0"]).can_timeout == 0.0
    with pytest.raises(SystemExit):
        _parse(["--help"])
    assert "--can-timeout" in capsys.readouterr().out
    args = _parse(["--can-interface", "virtual", "--can-timeout", "0.05"])
    args.control_dt = 0.02
    with pytest.raises(TargetError, match=r"--can-timeout 0.05 s is shorter than 3 control periods"):
        make_target(args, "arms")


def test_real_target_bus_open_error_is_one_line():
    args = _parse(["--calibration", "none", "--channels", "nocan7,nocan8"])
    with pytest.raises(TargetError) as info:
        make_target(args, "arms")
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("cannot build the real target: cannot open socketcan channel nocan7")
    assert isinstance(info.value.__cause__, BusOpenError) and f"`{UP.format('nocan7')}`" in msg


# ---------------------------------------------------------------------------------------------------
# one name per concept: bar-bus and bar-deploy; the old spellings as hidden deprecated aliases
# ---------------------------------------------------------------------------------------------------
def _bus_help(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([*command, "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    names = []
    for line in text.splitlines():
        if line.startswith("  -"):
            invocation = re.split(r"\s{2,}", line.strip())[0]
            names += [part.split(" ")[0] for part in invocation.split(", ")]
    return text, names


SHARED = {"--can-interface", "--reply-timeout", "--mode"}
"""Options of every bar-bus command."""


@pytest.mark.parametrize(
    ("command", "own"),
    [
        (["discover"], {"--channel", "--scan-to", "--status", "--emulate", "--emulate-perturb"}),
        (
            ["calibrate"],
            {
                "--channels",
                "--calibration",
                "--prior",
                "--sweep-threshold",
                "--rate",
                "--duration",
                "--emulate",
                "--emulate-perturb",
            },
        ),
        (
            ["param", "read"],
            {"--channel", "--id", "--index", "--value", "--type", "--emulate", "--emulate-perturb"},
        ),
        (
            ["watchdog"],
            {"--channel", "--id", "--model", "--can-timeout", "--silences", "--emulate", "--emulate-perturb"},
        ),
    ],
)
def test_bar_bus_help_lists_each_option_once_and_hides_the_old_spellings(command, own, capsys):
    text, names = _bus_help(command, capsys)
    assert sorted(names) == sorted({"-h", "--help"} | SHARED | own)
    for old in ("--interface", "--iface", "--out", "--timeout"):
        assert f"{old} " not in text and f"[{old}" not in text


def test_the_shared_concepts_have_one_name_in_both_tools(capsys):
    from bar_policy.deploy.cli import main as deploy

    with pytest.raises(SystemExit):
        deploy(["--help"])
    deploy_help = capsys.readouterr().out
    for name in (
        "--can-interface",
        "--channels",
        "--calibration",
        "--reply-timeout",
        "--scan-to",
        "--can-timeout",
    ):
        assert f"\n  {name} " in deploy_help, name
    tools = {
        name
        for command in (["discover"], ["calibrate"], ["watchdog"])
        for name in _bus_help(command, capsys)[1]
    }
    assert {
        "--can-interface",
        "--channels",
        "--calibration",
        "--reply-timeout",
        "--scan-to",
        "--can-timeout",
    } <= tools


@pytest.mark.parametrize(
    ("old", "new", "value", "dest"),
    [
        (["discover", "--iface", "vcan3"], ["discover", "--channel", "vcan3"], "vcan3", "iface"),
        (
            ["discover", "--interface", "virtual"],
            ["discover", "--can-interface", "virtual"],
            "virtual",
            "interface",
        ),
        (["discover", "--timeout", "0.5"], ["discover", "--reply-timeout", "0.5"], 0.5, "timeout"),
        (["calibrate", "--out", "c.json"], ["calibrate", "--calibration", "c.json"], "c.json", "out"),
        (
            ["watchdog", "--id", "11", "--iface", "can1"],
            ["watchdog", "--id", "11", "--channel", "can1"],
            "can1",
            "iface",
        ),
    ],
)
def test_deprecated_spellings_still_work_with_a_one_line_notice(old, new, value, dest, capsys):
    from bar_policy.robstride.tools import _parser

    got, want = _parser().parse_args(old), _parser().parse_args(new)
    assert got == want and getattr(got, dest) == value
    prog = "bar-bus " + " ".join(old[:1])
    new_name = next(a for a in new if a.startswith("--") and a not in old)
    old_name = next(a for a in old if a.startswith("--") and a not in new)
    assert capsys.readouterr().err == f"{prog}: note: {old_name} is deprecated; use {new_name}\n"


def test_deprecated_spelling_in_a_child_process_runs_the_command():
    """The old console line still runs: one notice line, then the command's own (here: no SocketCAN)."""
    r = subprocess.run(
        [sys.executable, "-m", "bar_policy.robstride.tools", "discover", "--iface", "nocan7"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    notice, error = r.stderr.splitlines()
    assert notice == "bar-bus discover: note: --iface is deprecated; use --channel"
    assert r.returncode == 1 and error.startswith("bar-bus: error: cannot open socketcan channel nocan7: ")
