"""``bar-deploy`` refuses bad arguments with one line on stderr, no traceback, exit status 2.

The table runs ``main()`` in-process (fast); two rows also run the installed console path in a child
process, where a stray traceback or print would show up exactly as a user sees it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bar_policy.deploy.cli import main

REPO = Path(__file__).resolve().parents[2]

# (id, argv after the policy (POLICY is replaced), expected status, text the one error line must contain)
RUN_ROWS = [
    ("duration-negative", ["--duration", "-5"], "argument --duration: expected a time > 0 s, or 'inf'"),
    ("duration-zero", ["--duration", "0"], "argument --duration: expected a time > 0 s"),
    ("duration-nan", ["--duration", "nan"], "argument --duration: expected a time > 0 s"),
    ("duration-text", ["--duration", "ten"], "got 'ten'"),
    ("control-dt-zero", ["--control-dt", "0"], "argument --control-dt: expected a time > 0 s, got '0'"),
    ("control-dt-negative", ["--control-dt", "-0.02"], "argument --control-dt: expected a time > 0 s"),
    ("stale-timeout-zero", ["--stale-timeout", "0"], "argument --stale-timeout: expected a time > 0 s"),
    ("ramp-time-negative", ["--ramp-time", "-1"], "argument --ramp-time: expected a time >= 0 s"),
    ("damping-time-negative", ["--damping-time", "-1"], "argument --damping-time: expected a time >= 0 s"),
    ("max-overruns-negative", ["--max-overruns", "-1"], "argument --max-overruns: expected an integer >= 0"),
    ("rt-priority-range", ["--rt-priority", "100"], "argument --rt-priority: expected an integer in 1..99"),
    ("action-clip-negative", ["--action-clip", "-1"], "argument --action-clip: expected a number >= 0"),
    ("target-unknown", ["--target", "gazebo"], "invalid choice: 'gazebo' (choose from 'sim', 'mock'"),
    ("log-in-proc", ["--log", "/proc/x"], "cannot write run logs under '/proc/x': No such file or directory"),
    ("log-under-a-file", ["--log", "FILE/sub"], "Not a directory (give a writable --log DIR, or --no-log)"),
    ("commands-unknown", ["--commands", "joystick"], "unknown command source 'joystick'; valid: sampled"),
    ("commands-period", ["--commands", "sampled:-1"], "resample period must be > 0 s, got -1.0"),
    ("motion-rate-zero", ["--motion-rate", "0"], "argument --motion-rate: expected a rate > 0 Hz, got '0'"),
    ("motion-for-reach", ["--motion", "wave"], "--motion wave is for 'track' policies (motion tracking)"),
    ("video-not-sim", ["--target", "mock", "--video", "x.mp4"], "--video needs --target sim"),
    ("policy-missing", ["--policy", "missing.onnx"], "cannot read the file: No such file or directory"),
    ("mode-mismatch", ["--mode", "arms_neck"], "joint set mismatch: the policy drives mode 'arms'"),
    (
        "real-channels",
        ["--target", "real", "--can-interface", "virtual", "--channels", "a,b,c"],
        "target real: cannot build the real target: --channels 'a,b,c': give 2 channels",
    ),
    # No SocketCAN here (or no can0): the driver's own message, printed on one line, with the fix.
    (
        "real-socketcan",
        ["--target", "real", "--can-interface", "socketcan", "--calibration", "none"],
        "ip link set can0 up type can bitrate 1000000",
    ),
]

OTHER_ROWS = [
    ("eval-episodes", ["eval", "--episodes", "0"], "bar-deploy eval: error: argument --episodes"),
    ("eval-length", ["eval", "--episode-length", "-1"], "argument --episode-length: expected a time > 0 s"),
    (
        "eval-period",
        ["eval", "--resample-period", "-2.5"],
        "argument --resample-period: expected a time >= 0",
    ),
    ("eval-json", ["eval", "--json", "/proc/x/e.json"], "--json '/proc/x/e.json': its directory does not"),
    ("eval-hold-negative", ["eval", "--hold-s", "-1"], "argument --hold-s: expected a time >= 0 s"),
    ("eval-clips-for-reach", ["eval", "--clips", "wave"], "--clips wave is for 'track' policies"),
    ("plot-missing", ["plot", "nowhere"], "no run log at nowhere"),
]


def _argv(argv: list[str], policy: Path, tmp: Path) -> list[str]:
    (tmp / "FILE").write_text("")
    out = [a.replace("FILE", str(tmp / "FILE")) for a in argv]
    if "--policy" in out:
        i = out.index("--policy")
        out[i + 1] = str(tmp / out[i + 1])
    elif out and out[0] == "eval":
        out = ["eval", "--policy", str(policy), *out[1:]]
    elif not out or out[0] != "plot":
        out = ["--policy", str(policy), *out]
    if out[0] != "plot" and out[0] != "eval" and "--log" not in out:
        out += ["--log", str(tmp / "runs")]
    return out


def _status(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse's own exit path
        return e.code if isinstance(e.code, int) else 1


@pytest.mark.parametrize(
    ("argv", "expected"), [r[1:] for r in RUN_ROWS + OTHER_ROWS], ids=[r[0] for r in RUN_ROWS + OTHER_ROWS]
)
def test_bad_argument_gives_one_line_error(argv, expected, policy_path, tmp_path, capsys):
    status = _status(_argv(argv, policy_path, tmp_path))
    captured = capsys.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert status == 2, captured
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(("bar-deploy: error: ", "bar-deploy eval: error: ")), lines[0]
    assert expected in lines[0]
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # nothing ran


@pytest.mark.parametrize("argv", [["--duration", "-5"], ["--log", "/proc/x"]], ids=["duration", "log"])
def test_bad_argument_in_a_child_process(argv, policy_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run(
        [sys.executable, "-m", "bar_policy.deploy.cli", "--policy", str(policy_path), *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.splitlines()) == 1 and r.stderr.startswith("bar-deploy: error: "), r.stderr


def test_real_target_help_lists_its_options(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--target", "real", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "real target (Robstride over CAN)" in out
    for option in (
        "--can-interface",
        "--channels",
        "--calibration",
        "--dry-run",
        "--emulate",
        "--reply-timeout",
    ):
        assert option in out
    # Without --target real, --help says where to find them.
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "bar-deploy --target real --help" in capsys.readouterr().out
