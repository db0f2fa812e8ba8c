"""``recover_mcap`` / ``bar-deploy log recover``: a run.mcap cut by a crash made complete and indexed."""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import pytest
from fault_targets import SteppedMock

from bar_policy.deploy.cli import main
from bar_policy.deploy.log.files import NOT_CLOSED, LogReadError, log_fields
from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE, TICK_TOPICS, TRANSITION_TOPIC
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.log.recover import recover_mcap
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands


def _strict(text: str | bytes) -> object:
    """``json.loads`` that refuses NaN and infinities (strict JSON)."""

    def refuse(constant: str) -> None:
        raise ValueError(f"non-strict JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def _indexed(path: Path) -> tuple[object, list[tuple[str, int, int, bytes]]]:
    """The summary and the messages (topic, log_time, publish_time, data) in file order, indexed reader."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [
            (ch.topic, m.log_time, m.publish_time, m.data)
            for _, ch, m in reader.iter_messages(log_time_order=False)
        ]
    return summary, msgs


def _indexed_fails(path: Path) -> bool:
    """The ``mcap`` indexed reader cannot read ``path`` (it raises, or finds no summary)."""
    try:
        summary, _ = _indexed(path)
    except Exception:
        return True
    return summary is None


def _streamed(path: Path) -> list[tuple[str, int, int, bytes]]:
    """The messages a sequential reader gets from ``path`` before it stops (what a cut file holds)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics: dict[int, str] = {}
    out = []
    with path.open("rb") as f:
        try:
            for rec in StreamReader(f, validate_crcs=True).records:
                if isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    out.append((topics[rec.channel_id], rec.log_time, rec.publish_time, rec.data))
        except Exception:
            pass
    return out


def _chunk_ends(path: Path) -> list[tuple[int, int]]:
    """(start, end) offsets of every chunk record of a closed MCAP file, from its chunk index."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    idx = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    return [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length) for c in idx]


def _counts(msgs: list[tuple[str, int, int, bytes]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for topic, *_ in msgs:
        out[topic] = out.get(topic, 0) + 1
    return out


def _check_recovered(run: Path, cut_bytes: bytes) -> None:
    """Recover ``run``'s run.mcap (holding ``cut_bytes``) and check it against what the cut file held."""
    path = run / MCAP_FILE
    assert _indexed_fails(path)
    before = read_mcap_log(path)
    streamed = _streamed(path)
    report = recover_mcap(run)
    assert not report.complete and report.original == path.with_name("run.mcap.cut")
    assert report.original.read_bytes() == cut_bytes  # nothing lost
    summary, msgs = _indexed(path)
    assert summary is not None and summary.statistics.message_count == len(msgs) == report.messages
    assert msgs == streamed  # every readable message, exactly, in order
    counts = _counts(msgs)
    assert {t: n for t, n in report.per_topic.items() if n} == counts
    n_ticks = before.arrays["t"].size
    for topic in TICK_TOPICS:
        assert counts.get(topic, 0) == n_ticks
    assert counts.get(TRANSITION_TOPIC, 0) == len(before.transitions)
    if n_ticks:  # the same first and last ticks: log_time = run start + t
        start_ns = round(before.meta["started_unix"] * 1e9)
        timing = [m for m in msgs if m[0] == "/timing"]
        for m, t in ((timing[0], before.arrays["t"][0]), (timing[-1], before.arrays["t"][-1])):
            assert abs(m[1] - (start_ns + round(t * 1e9))) < 1000
    # Read back by the project's reader: the same arrays; still a run that never closed.
    after = read_mcap_log(path)
    assert not after.complete and after.meta == before.meta and after.transitions == before.transitions
    assert sorted(after.arrays) == sorted(before.arrays)
    for k, v in before.arrays.items():
        np.testing.assert_array_equal(after.arrays[k], v, err_msg=k)
    assert report.bytes_dropped == len(cut_bytes) - _salvaged_end(cut_bytes)
    # A second recover finds the file complete and changes nothing.
    data = path.read_bytes()
    again = recover_mcap(path)
    assert again.complete and again.messages == report.messages and "nothing changed" in again.line()
    assert path.read_bytes() == data and not path.with_name("run.mcap.cut.1").exists()


def _salvaged_end(cut_bytes: bytes) -> int:
    """Offset past the last whole record of ``cut_bytes`` (walking the record heads)."""
    pos, size = 8, len(cut_bytes)
    while pos + 9 <= size:
        length = int.from_bytes(cut_bytes[pos + 1 : pos + 9], "little")
        if pos + 9 + length > size:
            break
        pos += 9 + length
    return pos


def _multi_chunk_log(root: Path, meta: dict) -> RunLog:
    """A RunLog with 30 ticks in at least 3 durable flushes (chunks), and a transition."""
    log = RunLog(root, log_fields(2, 2, 3, ()), meta, flush_interval=0.05)
    for batch in range(3):
        for k in range(10 * batch, 10 * batch + 10):
            log.append({"t": k * 0.02, "q": [k, 2 * k], "mode": 3})
        if batch == 1:
            log.transition({"t": 0.3, "tick": 15, "from": "HOLD", "to": "POLICY", "reason": "ramp done"})
        time.sleep(0.15)
    return log


def test_recover_a_file_cut_mid_chunk_and_right_after_a_chunk(tmp_path):
    log = _multi_chunk_log(tmp_path / "src", {"run": 1})
    log.close()
    data = (log.path / MCAP_FILE).read_bytes()
    chunks = _chunk_ends(log.path / MCAP_FILE)
    assert len(chunks) >= 3
    (start1, end1), (start2, end2) = chunks[1], chunks[2]
    cuts = {
        "mid_chunk": (start1 + end1) // 2,
        "one_byte_short": end1 - 1,
        "after_chunk": end1,
        "after_last_chunk": chunks[-1][1],
        "mid_record_head": start2 + 4,
        "before_summary": end2 + 3,
    }
    for name, n_bytes in cuts.items():
        run = tmp_path / name
        run.mkdir()
        (run / MCAP_FILE).write_bytes(data[:n_bytes])
        _check_recovered(run, data[:n_bytes])
        arrays, meta = load_log(run)  # still reported as a run that never closed
        assert meta["end_reason"] == NOT_CLOSED
        assert arrays["t"].size == read_mcap_log(run / MCAP_FILE).arrays["t"].size


def test_recover_the_file_a_live_run_leaves_on_disk(tmp_path):
    """The bytes of run.mcap while the writer is running (no footer): what a SIGKILL leaves."""
    log = _multi_chunk_log(tmp_path / "src", {"run": 2})
    live = (log.path / MCAP_FILE).read_bytes()
    log.close()
    run = tmp_path / "killed"
    run.mkdir()
    (run / MCAP_FILE).write_bytes(live)
    _check_recovered(run, live)
    assert read_mcap_log(run / MCAP_FILE).arrays["t"].size == 30


def test_cli_recovers_a_cut_run_of_the_runtime(zero_policy, tmp_path, capsys, caplog):
    caplog.set_level(logging.INFO, logger="bar_policy.deploy.safety")  # the mode changes go to /log
    cfg = RuntimeConfig(duration=0.4, start_mode="hold", safety=SafetyConfig(ramp_time=0.2))
    rt = Runtime(
        zero_policy,
        SteppedMock(),
        SampledCommands(zero_policy.obs_manager.command_names),
        cfg,
        log_dir=tmp_path / "runs",
    )
    res = rt.run()
    run = res.log_path.parent
    path = run / MCAP_FILE
    full = path.read_bytes()
    cut = full[: _chunk_ends(path)[-1][1] + 5]  # the last chunk whole, then the kill
    (run / "log.npz").unlink()
    path.write_bytes(cut)
    expected = read_mcap_log(path)
    assert expected.transitions and expected.arrays["t"].size == 20
    streamed = _counts(_streamed(path))
    # The JSON topics, and the well-known ones beside them (ROS 2 joint states, transforms, one scene, the
    # log lines: one per mode change here).
    assert {t: streamed[t] for t in (*TICK_TOPICS, "/joint_states", "/tf")} == dict.fromkeys(
        (*TICK_TOPICS, "/joint_states", "/tf"), 20
    )
    assert streamed["/robot/scene"] == 1 and streamed["/log"] >= len(expected.transitions)
    capsys.readouterr()
    assert main(["log", "recover", str(run)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    n = sum(streamed.values())
    assert len(out) == 1 and f"recovered {n} messages" in out[0] and "/joint_state_json 20" in out[0]
    assert "/joint_states 20" in out[0]
    assert "dropped 5 bytes" in out[0] and "run.mcap.cut" in out[0]
    assert (run / "run.mcap.cut").read_bytes() == cut
    summary, msgs = _indexed(path)
    assert summary is not None and _counts(msgs)["/policy"] == 20
    assert _counts(msgs)[TRANSITION_TOPIC] == len(expected.transitions)
    # A complete file: said so, nothing changed, exit 0.
    data = path.read_bytes()
    assert main(["log", "recover", str(path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "already complete" in out[0] and path.read_bytes() == data


def test_not_an_mcap_file_is_refused_in_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    junk = b"PK\x03\x04 not mcap at all"
    (run / MCAP_FILE).write_bytes(junk)
    with pytest.raises(LogReadError, match="not an MCAP file"):
        recover_mcap(run)
    assert main(["log", "recover", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bar-deploy: error: ") and "not an MCAP file" in err[0]
    assert (run / MCAP_FILE).read_bytes() == junk and not (run / "run.mcap.cut").exists()
    (run / MCAP_FILE).write_bytes(b"\x89MCAP0\r\n\x01\x20")  # the magic, then a cut header
    with pytest.raises(LogReadError, match="no complete header"):
        recover_mcap(run / MCAP_FILE)
    assert main(["log", "recover", str(tmp_path / "nowhere")]) == 2
    assert "no MCAP file at" in capsys.readouterr().err
    assert sorted(p.name for p in run.iterdir()) == [MCAP_FILE]  # no temporary file left


def test_metadata_is_strict_json_nan_is_null(tmp_path):
    from mcap.reader import make_reader

    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {"x": math.nan, "y": [1.0, math.inf], "z": np.float32(2)})
    log.append({"t": 0.0, "q": [1.0]})
    log.close(score=math.nan)
    path = log.path / MCAP_FILE
    with path.open("rb") as f:
        records = {m.name: _strict(m.metadata["json"]) for m in make_reader(f).iter_metadata()}
    assert records["bar_deploy.run"]["x"] is None and records["bar_deploy.run"]["y"] == [1.0, None]
    assert records["bar_deploy.run"]["z"] == 2.0
    assert records["bar_deploy.end"]["score"] is None
    assert read_mcap_log(path).meta["x"] is None


def test_recover_rewrites_legacy_nan_metadata_as_strict_json(tmp_path):
    """A file written before metadata was strict JSON: the recovered copy has ``null`` for NaN."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    path = tmp_path / MCAP_FILE
    with path.open("wb") as f:
        w = Writer(f)
        w.start(library="old")
        w.add_metadata("bar_deploy.run", {"json": '{"x": NaN, "y": Infinity}'})
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/timing", "json", sid)
        w.add_message(cid, log_time=1, data=b'{"tick": 0, "t": 0.0}', publish_time=1)
        w.flush()
    report = recover_mcap(path)
    assert report.messages == 1 and report.metadata == 1 and report.per_topic == {"/timing": 1}
    with path.open("rb") as f:
        reader = make_reader(f)
        meta = {m.name: _strict(m.metadata["json"]) for m in reader.iter_metadata()}
        assert reader.get_header().library == "old"
    assert meta == {"bar_deploy.run": {"x": None, "y": None}}
