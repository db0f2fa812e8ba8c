"""A run log written before ``/joint_state`` became ``/joint_state_json`` reads the same.

The JSON topic of the measured joint state was ``/joint_state``, one letter from ROS 2's ``/joint_states``
in the same file; it is ``/joint_state_json`` now, and the reader maps the old name (``LEGACY_TOPICS``).
The old log is made by rewriting a new one's file with the old topic name, record by record.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer
from test_deploy_log import _run_hold_then_policy

from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import JOINT_STATE_TOPIC, LEGACY_TOPICS, MCAP_FILE


def _with_old_topic(src: Path, dst: Path) -> None:
    """Copy the MCAP file ``src`` to ``dst`` with ``/joint_state_json`` named ``/joint_state``."""
    old = {new: name for name, new in LEGACY_TOPICS.items()}
    with src.open("rb") as f, dst.open("wb") as g:
        reader = make_reader(f)
        writer = Writer(g)
        header = reader.get_header()
        writer.start(header.profile, header.library)
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, m.metadata)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    old.get(channel.topic, channel.topic),
                    channel.message_encoding,
                    schemas.get(schema.id, 0) if schema is not None else 0,
                    channel.metadata,
                )
            writer.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        writer.finish()


def test_an_old_named_log_reads_the_same(zero_policy, tmp_path):
    result = _run_hold_then_policy(zero_policy, tmp_path)
    new = result.log_path.parent / MCAP_FILE
    old = tmp_path / "old.mcap"
    _with_old_topic(new, old)
    with old.open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert "/joint_state" in topics and JOINT_STATE_TOPIC not in topics  # the old name, as before
    before, after = read_mcap_log(new), read_mcap_log(old)
    assert sorted(after.arrays) == sorted(before.arrays)
    for k in ("q", "dq", "tau"):  # the fields of that topic, read back exactly
        assert np.isfinite(before.arrays[k]).all()
        np.testing.assert_array_equal(after.arrays[k], before.arrays[k], err_msg=k)
    assert after.complete and after.meta["end_reason"] == before.meta["end_reason"]
