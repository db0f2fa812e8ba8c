"""Command sources: sampled (training distribution, seeded), file (JSON/CSV/NPZ), stream (stdin/UDP)."""

from __future__ import annotations

import io
import json
import socket
import time

import numpy as np
import pytest

from bar_policy.tasks.reach.commands import (
    CommandError,
    FileCommands,
    SampledCommands,
    StreamCommands,
    make_command_source,
)

NAMES = ("target_pos_left", "target_pos_right")
LO = np.array([0.22, 0.08, 0.12])
HI = np.array([0.42, 0.30, 0.40])
"""The left target box of ReachTargetConfig, m."""


def test_sampled_follows_the_training_distribution_and_seed():
    src = SampledCommands(NAMES, seed=7, period=2.0)
    rng = np.random.default_rng(7)
    u0, u1 = rng.random(6), rng.random(6)
    # left = lo + u * (hi - lo); right = the same on u[3:], y mirrored.
    left0 = LO + u0[:3] * (HI - LO)
    right0 = (LO + u0[3:] * (HI - LO)) * np.array([1, -1, 1])
    c = src(0.0)
    np.testing.assert_allclose(c["target_pos_left"], left0, atol=1e-15)
    np.testing.assert_allclose(c["target_pos_right"], right0, atol=1e-15)
    np.testing.assert_array_equal(src(1.98)["target_pos_left"], c["target_pos_left"])  # held
    np.testing.assert_allclose(src(2.0)["target_pos_left"], LO + u1[:3] * (HI - LO), atol=1e-15)  # resampled
    # Same seed, same sequence even when queried at other times (draws happen in period order).
    other = SampledCommands(NAMES, seed=7, period=2.0)
    np.testing.assert_array_equal(other(2.5)["target_pos_right"], src(2.5)["target_pos_right"])
    assert src.outside_count == 0


def test_file_json_zero_order_hold(tmp_path):
    p = tmp_path / "c.json"
    entries = [
        {"t": 0.0, "target_pos_left": [0.3, 0.2, 0.2], "target_pos_right": [0.3, -0.2, 0.2]},
        {"t": 1.5, "target_pos_left": [0.35, 0.15, 0.3], "target_pos_right": [0.25, -0.1, 0.3]},
    ]
    p.write_text(json.dumps(entries))
    src = make_command_source(f"file:{p}", NAMES)
    assert isinstance(src, FileCommands)
    np.testing.assert_array_equal(src(0.0)["target_pos_left"], [0.3, 0.2, 0.2])
    np.testing.assert_array_equal(src(1.49)["target_pos_right"], [0.3, -0.2, 0.2])
    np.testing.assert_array_equal(src(1.5)["target_pos_left"], [0.35, 0.15, 0.3])
    np.testing.assert_array_equal(src(99.0)["target_pos_right"], [0.25, -0.1, 0.3])


def test_file_csv_and_npz(tmp_path):
    csv = tmp_path / "c.csv"
    csv.write_text(
        "t,target_pos_left_x,target_pos_left_y,target_pos_left_z,"
        "target_pos_right_x,target_pos_right_y,target_pos_right_z\n"
        "0,0.3,0.2,0.2,0.3,-0.2,0.2\n"
        "0.5,0.4,0.1,0.3,0.4,-0.1,0.3\n"
    )
    src = make_command_source(f"file:{csv}", NAMES)
    np.testing.assert_array_equal(src(0.7)["target_pos_left"], [0.4, 0.1, 0.3])
    npz = tmp_path / "c.npz"
    np.savez(
        npz,
        t=np.array([0.0, 1.0]),
        target_pos_left=np.array([[0.3, 0.2, 0.2], [0.31, 0.21, 0.21]]),
        target_pos_right=np.array([[0.3, -0.2, 0.2], [0.31, -0.21, 0.21]]),
    )
    src = make_command_source(f"file:{npz}", NAMES)
    np.testing.assert_array_equal(src(1.0)["target_pos_right"], [0.31, -0.21, 0.21])


@pytest.mark.parametrize(
    ("content", "suffix", "message"),
    [
        ('[{"t": 0, "target_pos_left": [0.3, 0.2]}]', ".json", "missing \\['target_pos_right'\\]"),
        (
            '[{"t": 0, "target_pos_left": [0.3, 0.2], "target_pos_right": [0.3, -0.2, 0.2]}]',
            ".json",
            "target_pos_left must have 3 numbers",
        ),
        (
            '[{"t": 1, "target_pos_left": [0.3,0.2,0.2], "target_pos_right": [0.3,-0.2,0.2]},'
            ' {"t": 0.5, "target_pos_left": [0.3,0.2,0.2], "target_pos_right": [0.3,-0.2,0.2]}]',
            ".json",
            "strictly increasing",
        ),
        ("{not json", ".json", "not valid JSON"),
        ("t,x\n0,1\n", ".csv", "missing columns"),
        ("", ".yaml", "unsupported type '.yaml'"),
    ],
)
def test_file_errors_are_clear(tmp_path, content, suffix, message):
    p = tmp_path / f"bad{suffix}"
    p.write_text(content)
    with pytest.raises(CommandError, match=message):
        make_command_source(f"file:{p}", NAMES)


def test_file_rejects_nan(tmp_path):
    p = tmp_path / "c.npz"
    np.savez(
        p, t=np.array([0.0]), target_pos_left=np.array([[np.nan, 0, 0]]), target_pos_right=np.zeros((1, 3))
    )
    with pytest.raises(CommandError, match="non-finite"):
        make_command_source(f"file:{p}", NAMES)


def _initial():
    return {
        "target_pos_left": np.array([0.36, 0.16, 0.21]),
        "target_pos_right": np.array([0.36, -0.16, 0.21]),
    }


def _wait_for(predicate, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.005)
    return False


def test_stream_stdin_json_lines_and_bad_lines():
    lines = (
        '{"target_pos_left": [0.3, 0.2, 0.25]}\n'
        "garbage\n"
        '{"target_pos_right": [0.3, -0.2, NaN]}\n'
        '{"target_pos_right": [0.31, -0.21, 0.26], "t": 3}\n'
    )
    src = StreamCommands(NAMES, _initial(), stdin=io.StringIO(lines))
    try:
        assert _wait_for(lambda: (src(0.0) is not None) and src.messages + src.bad_messages == 4)
        c = src(0.0)
        np.testing.assert_array_equal(c["target_pos_left"], [0.3, 0.2, 0.25])
        np.testing.assert_array_equal(c["target_pos_right"], [0.31, -0.21, 0.26])
        assert src.messages == 2 and src.bad_messages == 2
    finally:
        src.close()


def test_stream_before_any_message_uses_initial():
    src = StreamCommands(NAMES, _initial(), stdin=io.StringIO(""))
    np.testing.assert_array_equal(src(0.0)["target_pos_left"], [0.36, 0.16, 0.21])
    src.close()


def test_stream_udp_on_loopback():
    src = make_command_source("stream:udp:0", NAMES, initial=_initial())
    try:
        assert src._sock is not None and src._sock.getsockname()[0] == "127.0.0.1"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(b'{"target_pos_left": [0.25, 0.1, 0.3]}', ("127.0.0.1", src.port))
        assert _wait_for(lambda: src(0.0)["target_pos_left"][0] == 0.25)
        np.testing.assert_array_equal(src(0.0)["target_pos_right"], [0.36, -0.16, 0.21])
    finally:
        src.close()


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("random", "unknown command source 'random'; valid: sampled"),
        ("stream:tcp:9000", "unknown command source"),
        ("stream:udp:abc", "integer port"),
        ("stream:udp:70000", "0..65535"),
        ("sampled:-1", "period must be > 0"),
        ("file:/nonexistent/x.json", "does not exist"),
    ],
)
def test_bad_specs_name_the_valid_choices(spec, message):
    with pytest.raises(CommandError, match=message):
        make_command_source(spec, NAMES, initial=_initial())


def test_outside_workspace_is_counted_not_clipped(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(
        json.dumps([{"t": 0, "target_pos_left": [0.9, 0.2, 0.2], "target_pos_right": [0.3, -0.2, 0.2]}])
    )
    src = make_command_source(f"file:{p}", NAMES)
    np.testing.assert_array_equal(src(0.0)["target_pos_left"], [0.9, 0.2, 0.2])
    src(0.1)
    assert src.outside_count == 2
