"""The run log: MCAP schema and round trip, reading a file cut by a crash, durability by wall time, errors."""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest
from fault_targets import SteppedMock

from bar_policy.deploy.log.channels import WELL_KNOWN_TOPICS
from bar_policy.deploy.log.files import LogDirError, check_log_dir, log_fields
from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE, TICK_TOPICS, TRANSITION_TOPIC
from bar_policy.deploy.log.read import load_log
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.tasks.reach.commands import SampledCommands


def _run_hold_then_policy(policy, tmp_path):
    """0.2 s of HOLD, then POLICY, 0.4 s in all (20 ticks), on the stepped mock."""
    cfg = RuntimeConfig(duration=0.4, start_mode="hold", safety=SafetyConfig(ramp_time=0.2))
    rt = Runtime(
        policy, SteppedMock(), SampledCommands(policy.obs_manager.command_names), cfg, log_dir=tmp_path
    )
    return rt.run()


def test_mcap_messages_follow_their_json_schema_and_match_the_npz(zero_policy, tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    from mcap.reader import make_reader

    res = _run_hold_then_policy(zero_policy, tmp_path)
    arrays, meta = load_log(res.log_path)
    path = res.log_path.parent / MCAP_FILE
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # a closed file has its summary (Foxglove seeks with it)
        assert summary is not None
        counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
        assert {t: counts[t] for t in TICK_TOPICS} == dict.fromkeys(TICK_TOPICS, 20)
        assert counts[TRANSITION_TOPIC] == len(meta["transitions"]) == 4
        by_topic: dict[str, list[dict]] = {}
        validators = {}
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding != "json":  # the well-known schemas: test_log_foxglove.py
                assert channel.topic in WELL_KNOWN_TOPICS and schema.encoding in ("ros2msg", "protobuf")
                continue
            assert schema.encoding == "jsonschema"
            if schema.id not in validators:
                spec = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(spec)
                validators[schema.id] = jsonschema.Draft202012Validator(spec)
            body = json.loads(message.data)
            validators[schema.id].validate(body)
            by_topic.setdefault(channel.topic, []).append(body)
            if channel.topic != TRANSITION_TOPIC:  # log_time = run start + target time
                expected_ns = round(meta["started_unix"] * 1e9) + round(body["t"] * 1e9)
                assert abs(message.log_time - expected_ns) < 1000
    # HOLD ticks have no action: null in JSON, NaN in the arrays; POLICY ticks carry the action.
    policy_msgs = by_topic["/policy"]
    assert policy_msgs[0]["action"] == [None] * 14 and policy_msgs[-1]["action"] == [0.0] * 14
    assert [m["mode_name"] for m in by_topic["/safety"][:2]] == ["HOLD", "HOLD"]
    assert by_topic["/safety"][-1]["mode_name"] == "POLICY"
    assert by_topic["/joint_state_json"][3]["q"] == arrays["q"][3].tolist()  # exact: floats as shortest repr
    # The MCAP alone gives back every NPZ array exactly (NaN where NaN).
    rec = read_mcap_log(path)
    assert rec.complete and sorted(rec.arrays) == sorted(arrays)
    for k in arrays:
        assert rec.arrays[k].dtype == arrays[k].dtype, k
        np.testing.assert_array_equal(rec.arrays[k], arrays[k], err_msg=k)
    assert rec.transitions == meta["transitions"]
    assert rec.meta["end_reason"] == "duration reached"


def _chunks(path):
    """(end offset, ticks in it) of every chunk of a closed MCAP file, from its chunk index."""
    from mcap.reader import make_reader
    from mcap.records import Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        timing = next(c for c, ch in summary.channels.items() if ch.topic == "/timing")
        out = []
        for idx in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(idx.chunk_start_offset)
            chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            ticks = [
                json.loads(r.data)["tick"]
                for r in breakup_chunk(chunk)
                if isinstance(r, Message) and r.channel_id == timing
            ]
            out.append((idx.chunk_start_offset + idx.chunk_length, ticks))
    return out


def test_cut_mcap_is_read_up_to_its_last_complete_chunk(tmp_path):
    fields = log_fields(2, 2, 3, ())
    log = RunLog(tmp_path, fields, {"run": 1}, flush_interval=0.05)
    for batch in range(3):
        for k in range(10 * batch, 10 * batch + 10):
            log.append({"t": k * 0.02, "q": [k, 2 * k], "mode": 3})
        time.sleep(0.15)  # a durable flush (chunk) per batch, give or take
    log.close()
    path = log.path / MCAP_FILE
    data = path.read_bytes()
    chunks = _chunks(path)
    assert len(chunks) >= 3 and [t for _, ticks in chunks for t in ticks] == list(range(30))
    cut = tmp_path / "cut.mcap"
    done = 0
    for end, ticks in chunks:
        # One byte short of the chunk's end: that chunk is lost, every earlier one is read.
        for n_bytes, expected in ((end - 1, done), (end, done + len(ticks))):
            cut.write_bytes(data[:n_bytes])
            rec = read_mcap_log(cut)
            assert not rec.complete
            assert rec.arrays["t"].size == expected, (n_bytes, rec.error)
            np.testing.assert_array_equal(rec.arrays["q"][:, 1], 2 * np.arange(expected))
            assert rec.meta == {"run": 1, "started_unix": log.meta["started_unix"]}
        done += len(ticks)
    cut.write_bytes(data[:20])  # only the magic and part of the header: not a log
    with pytest.raises(ValueError, match="not a bar-deploy MCAP log"):
        read_mcap_log(cut)
    cut.write_bytes(b"PK\x03\x04 not mcap at all")
    with pytest.raises(ValueError, match="not an MCAP file"):
        read_mcap_log(cut)


def test_nonfinite_values_are_null_in_json_and_nan_when_read(tmp_path):
    fields = log_fields(3, 1, 1, ())
    log = RunLog(tmp_path, fields, {})
    log.append({"t": 0.0, "q": [np.nan, np.inf, 1.5], "dq": [-np.inf, 0, 0], "mode": int(Mode.DAMPING)})
    log.close()
    rec = read_mcap_log(log.path / MCAP_FILE)
    np.testing.assert_array_equal(rec.arrays["q"][0], [np.nan, np.nan, 1.5])  # JSON has no inf: null
    np.testing.assert_array_equal(rec.arrays["dq"][0], [np.nan, 0, 0])
    assert np.isnan(rec.arrays["compute"][0])  # never written
    npz, _ = load_log(log.path)
    np.testing.assert_array_equal(npz["q"][0], [np.nan, np.inf, 1.5])  # the NPZ keeps infinities


def test_log_directory_errors_name_the_directory(tmp_path):
    (tmp_path / "file").write_text("")
    for bad, reason in ((tmp_path / "file" / "sub", "Not a directory"), ("/proc/x", "No such file")):
        with pytest.raises(LogDirError, match=f"cannot write run logs under '{bad}': {reason}"):
            check_log_dir(bad)
        with pytest.raises(LogDirError, match=f"cannot create a run directory under '{bad}': {reason}"):
            RunLog(bad, log_fields(1, 1, 1, ()), {})
    with pytest.raises(ValueError, match="flush_interval must be > 0 s"):
        RunLog(tmp_path, log_fields(1, 1, 1, ()), {}, flush_interval=0)


def test_write_errors_are_counted_and_the_npz_still_written(tmp_path, monkeypatch):
    log = RunLog(tmp_path, log_fields(1, 1, 1, ()), {})

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(log._mcap, "write_tick", broken)
    for k in range(5):
        log.append({"t": k * 0.02, "q": [k]})
    out = log.close()
    arrays, meta = load_log(out)
    assert arrays["q"][:, 0].tolist() == [0, 1, 2, 3, 4]
    assert meta["log_write_error_count"] == 5
    assert "No space left on device" in meta["log_write_errors"][0]


def test_load_log_reads_an_mcap_path_and_old_chunk_logs(tmp_path):
    log = RunLog(tmp_path / "new", log_fields(1, 1, 1, ()), {"x": 2})
    for k in range(3):
        log.append({"t": k * 0.02, "q": [k]})
    log.close()
    arrays, meta = load_log(log.path / MCAP_FILE)
    assert arrays["q"][:, 0].tolist() == [0, 1, 2] and meta["x"] == 2 and meta["status"] == "closed"
    # A run directory of an older version: NPZ chunks and run.json, no MCAP.
    old = tmp_path / "old"
    (old / "chunks").mkdir(parents=True)
    np.savez(old / "chunks" / "chunk_000000.npz", t=np.arange(4) * 0.02, q=np.arange(4.0)[:, None])
    (old / "run.json").write_text(json.dumps({"status": "running"}))
    arrays, meta = load_log(old)
    assert arrays["q"][:, 0].tolist() == [0, 1, 2, 3] and meta["status"] == "running"
    shutil.rmtree(old / "chunks")
    with pytest.raises(FileNotFoundError, match=r"has neither log\.npz, run\.mcap nor chunks"):
        load_log(old)
