"""The tester's malformed-input reports, reproduced: every one is one error line, exit status 2.

Empty and corrupt ``.npz`` files (``--motion``, ``--commands file:``), deeply nested JSON in a policy's
metadata and in a commands file, a 5 MB metadata value (cut in the message), a NaN in ``run.json`` (written
as ``null``), and a SIGINT before the stop handlers are installed (no traceback).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from policy_factory import default_metadata, make_policy_file

from bar_policy._files import ECHO_LIMIT, InputError, shorten
from bar_policy.deploy import cli, cli_tools
from bar_policy.deploy.cli import main
from bar_policy.deploy.contract import PolicyLoadError
from bar_policy.deploy.log.files import log_fields
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.metadata import MetadataError, PolicyMetadata
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.signals import INTERRUPT_STATUS, early_interrupt
from bar_policy.motion.clip import ClipError, load_clip
from bar_policy.tasks.reach.commands import CommandError, FileCommands

REPO = Path(__file__).resolve().parents[2]
DEEP = 5000
"""Nesting depth of the deep JSON (far past the interpreter's recursion limit)."""
NAMES = ("target_pos_left", "target_pos_right")


def _deep(depth: int = DEEP) -> str:
    return "[" * depth + "]" * depth


def _status(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse's own exit path
        return e.code if isinstance(e.code, int) else 1


def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("bar-deploy: error: "), lines[0]
    return lines[0]


def _empty(path: Path) -> Path:
    path.write_bytes(b"")
    return path


def _corrupt(path: Path) -> Path:
    path.write_bytes(b"PK\x03\x04" + bytes(range(256)) * 4)  # a zip header, then garbage
    return path


# ---------------------------------------------------------------------------------------------------
# Item 1: empty or corrupt .npz through the CLI
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("make", [_empty, _corrupt], ids=["empty", "corrupt"])
def test_motion_npz_refused_in_one_line(make, tmp_path, capsys):
    policy = make_policy_file(tmp_path / "track.onnx", metadata=default_metadata(task="track"))
    clip = make(tmp_path / "x.npz")
    argv = ["--policy", str(policy), "--motion", str(clip), "--log", str(tmp_path / "runs")]
    assert _status(argv) == 2
    line = _one_error_line(capsys)
    assert str(clip) in line and "not a readable NPZ clip" in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # nothing ran


@pytest.mark.parametrize("make", [_empty, _corrupt], ids=["empty", "corrupt"])
def test_commands_npz_refused_in_one_line(make, policy_path, tmp_path, capsys):
    commands = make(tmp_path / "x.npz")
    argv = ["--policy", str(policy_path), "--commands", f"file:{commands}", "--log", str(tmp_path / "runs")]
    assert _status(argv) == 2
    line = _one_error_line(capsys)
    assert str(commands) in line and "is not a readable NPZ" in line


@pytest.mark.parametrize("make", [_empty, _corrupt], ids=["empty", "corrupt"])
def test_npz_loaders_raise_the_input_error(make, tmp_path):
    with pytest.raises(ClipError) as clip_err:
        load_clip(make(tmp_path / "clip.npz"))
    with pytest.raises(CommandError) as cmd_err:
        FileCommands(NAMES, make(tmp_path / "cmd.npz"))
    assert isinstance(clip_err.value, InputError) and isinstance(cmd_err.value, InputError)


# ---------------------------------------------------------------------------------------------------
# Item 1: deeply nested JSON
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", ["bar.randomization", "bar.obs_schema", "bar.training", "bar.action_filter"])
def test_nested_metadata_json_refused(key, tmp_path, capsys):
    props = default_metadata().to_props() | {key: _deep()}
    with pytest.raises(MetadataError, match="nested too deeply"):
        PolicyMetadata.from_props(props)
    path = make_policy_file(tmp_path / "deep.onnx", props={key: _deep()})
    with pytest.raises(PolicyLoadError, match=re.escape(f"metadata key '{key}' is nested too deeply")):
        load_policy(path)
    assert _status(["--policy", str(path), "--log", str(tmp_path / "runs")]) == 2
    line = _one_error_line(capsys)
    assert str(path) in line and "nested too deeply" in line


def test_nested_provenance_informs_and_refuses_nothing():
    props = default_metadata().to_props() | {"bar.provenance": _deep()}
    meta = PolicyMetadata.from_props(props)
    assert "nested too deeply" in meta.provenance["error"]


def test_nested_action_clip_refused(tmp_path):
    path = make_policy_file(tmp_path / "deep.onnx", props={"bar.action_clip": _deep()})
    with pytest.raises(PolicyLoadError, match=r"'bar\.action_clip' is nested too deeply"):
        load_policy(path)


def test_nested_commands_file_refused(policy_path, tmp_path, capsys):
    commands = tmp_path / "deep.json"
    commands.write_text('{"commands": ' + _deep() + "}")
    with pytest.raises(CommandError, match="nested too deeply"):
        FileCommands(NAMES, commands)
    argv = ["--policy", str(policy_path), "--commands", f"file:{commands}", "--log", str(tmp_path / "runs")]
    assert _status(argv) == 2
    line = _one_error_line(capsys)
    assert str(commands) in line and "nested too deeply" in line


# ---------------------------------------------------------------------------------------------------
# Item 8: a 5 MB metadata value is cut in the message
# ---------------------------------------------------------------------------------------------------
def test_huge_metadata_value_is_truncated(tmp_path, capsys):
    huge = "x" * 5_000_000
    path = make_policy_file(tmp_path / "huge.onnx", props={"bar.action_filter": json.dumps(huge)})
    with pytest.raises(PolicyLoadError) as err:
        load_policy(path)
    msg = str(err.value)
    assert len(msg) < 1000 and f"({len(json.dumps(huge)) + 2} chars)" in msg, msg[:300]
    assert _status(["--policy", str(path), "--log", str(tmp_path / "runs")]) == 2
    line = _one_error_line(capsys)
    assert len(line) <= cli_tools.MAX_ERROR_CHARS + 100 and str(path) in line


def test_huge_task_name_is_cut(tmp_path, capsys):
    path = make_policy_file(tmp_path / "task.onnx", props={"bar.task": json.dumps("t" * 5_000_000)})
    with pytest.raises(PolicyLoadError, match="unknown task") as err:
        load_policy(path)
    assert len(str(err.value)) < 1000 and "chars)" in str(err.value)
    assert _status(["--policy", str(path), "--log", str(tmp_path / "runs")]) == 2
    line = _one_error_line(capsys)
    assert len(line) <= cli_tools.MAX_ERROR_CHARS + 100 and str(path) in line


def test_shorten():
    assert shorten("abc") == "abc"
    cut = shorten("y" * 1000)
    assert cut == "y" * ECHO_LIMIT + "... (1000 chars)"


# ---------------------------------------------------------------------------------------------------
# Item 8: run.json is strict JSON (NaN -> null)
# ---------------------------------------------------------------------------------------------------
def _strict_loads(text: str) -> object:
    def refuse(token: str) -> None:
        raise ValueError(f"non-standard JSON constant {token}")

    return json.loads(text, parse_constant=refuse)


def test_run_json_has_no_nan(tmp_path):
    meta = {
        "nan": float("nan"),
        "inf": np.float64(np.inf),
        "nested": {"x": [1.0, -np.inf, np.float32("nan")]},
    }
    log = RunLog(tmp_path, log_fields(14, 7, 10), meta, name="nan")
    running = _strict_loads((log.path / "run.json").read_text())
    assert running["nan"] is None and running["inf"] is None and running["status"] == "running"
    log.append({"t": 0.0, "compute": float("nan")})
    log.close(
        end_reason="test", timing={"jitter_max": float("nan"), "mean": 0.5}, values=np.array([np.nan, 1])
    )
    closed = _strict_loads((log.path / "run.json").read_text())
    assert closed["timing"] == {"jitter_max": None, "mean": 0.5}
    assert closed["nested"] == {"x": [1.0, None, None]} and closed["values"] == [None, 1.0]
    with np.load(log.path / "log.npz") as z:
        assert _strict_loads(str(z["meta_json"]))["nan"] is None


# ---------------------------------------------------------------------------------------------------
# Item 8: SIGINT before the stop handlers
# ---------------------------------------------------------------------------------------------------
def test_early_interrupt_status_and_line():
    assert early_interrupt("run") == (0, "SIGINT received before the start: nothing was started")
    status, line = early_interrupt("eval")
    assert status == INTERRUPT_STATUS == 130 and "interrupted (SIGINT)" in line


def test_keyboard_interrupt_before_the_handlers_is_quiet(policy_path, tmp_path, monkeypatch, capsys):
    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_configure_logging", interrupted)  # just before StopSignals is installed
    assert main(["--policy", str(policy_path), "--log", str(tmp_path / "runs")]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and captured.err == ""
    assert captured.out.strip() == "SIGINT received before the start: nothing was started"


_CHILD = """
import os, signal, sys
from bar_policy.deploy import cli
real = cli._run_parser
def parser():
    os.kill(os.getpid(), signal.SIGINT)  # a real SIGINT, Python's default handler: KeyboardInterrupt
    return real()
cli._run_parser = parser
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.skipif(not hasattr(signal, "SIGINT"), reason="needs SIGINT")
def test_real_sigint_before_the_handlers_in_a_child(policy_path, tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run(
        [sys.executable, "-c", _CHILD, "--policy", str(policy_path), "--log", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert "Traceback" not in r.stderr and "KeyboardInterrupt" not in r.stderr, r.stderr
    assert r.returncode == 0 and r.stderr == ""
    assert r.stdout.strip() == "SIGINT received before the start: nothing was started"
