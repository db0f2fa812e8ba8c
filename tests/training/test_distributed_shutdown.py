"""The ordered ``jax.distributed`` shutdown, the parts one process shows (two: ``test_distributed.py``)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from bar_policy.training import watch_filter
from bar_policy.training.distributed import shutdown_distributed

# What process 0 wrote to stderr while its coordination service stopped, on an H100 (jax 0.11.2): its own
# GPU client's watch of the service, cancelled by that stop.
OWN_WATCH = (
    "W1125 09:40:40.413933     676 pjrt_client.cc:1605] WatchTasksAsync failed for task 0: UNAVAILABLE: "
    "Cancelling all calls\n"
    "Additional GRPC error information from remote target coordination_service while calling "
    "/xla.coordination.CoordinationService/WatchTasks:\n"
    ":UNAVAILABLE:Cancelling all calls\n"
    "=== Source Location Trace: ===\n"
    "external/xla+/xla/tsl/distributed_runtime/rpc/grpc_util.h:89\n"
    "\n"
)
# What process 0 wrote after the stop on two H100s (2026-11-27): the client called the stopped service again.
OWN_WATCH_REFUSED = (
    "W1127 17:07:38.031651    4341 pjrt_client.cc:1605] WatchTasksAsync failed for task 0: UNAVAILABLE: "
    "failed to connect to all addresses; last error: UNKNOWN: ipv4:127.0.0.1:24993: Failed to connect to "
    "remote host: Connection refused\n"
    "Additional GRPC error information from remote target coordination_service while calling "
    "/xla.coordination.CoordinationService/WatchTasks:\n"
    ":UNAVAILABLE:failed to connect to all addresses; last error: UNKNOWN: ipv4:127.0.0.1:24993: Failed to "
    "connect to remote host: Connection refused\n"
    "=== Source Location Trace: === \n"
    "external/xla+/xla/tsl/distributed_runtime/rpc/grpc_util.h:89\n"
    "\n"
)


def _drop(text: str, pid: int) -> str:
    return "".join(watch_filter.drop_own_watch_records(text.splitlines(keepends=True), pid))


def test_only_this_process_watch_records_are_dropped():
    other_task = OWN_WATCH_REFUSED.replace("for task 0:", "for task 1:")
    unrelated = "E1125 09:40:40.500000     676 client.cc:80] Terminating process because of fatal errors\n"
    before = "a line before any record\n"
    after = "a plain line after a dropped record's empty line\n"
    text = before + OWN_WATCH + unrelated + OWN_WATCH_REFUSED + after + other_task
    # Both six-line records of task 0 go, each with its closing empty line; the line before them, the
    # error, the plain line after the second and task 1's record stay, in order.
    assert _drop(text, 0) == before + unrelated + after + other_task
    assert _drop(OWN_WATCH, 1) == OWN_WATCH  # another process's id: not its record
    assert _drop("", 0) == ""


def test_installed_filter_drops_the_record_and_passes_everything_else_to_the_end():
    """A process that installs the filter, then writes straight to fd 2 (as XLA's C++ logging does) and
    through Python, and exits: its stderr holds every byte but the record, in order, also what came last."""
    script = textwrap.dedent(
        f"""
        import os, sys
        from bar_policy.training import watch_filter
        sys.stderr.write("before\\n")
        assert watch_filter.install(0)
        os.write(2, {OWN_WATCH_REFUSED!r}.encode())
        sys.stderr.write("python after\\n")
        sys.stderr.flush()
        os.write(2, b"last bytes, no newline")
        """
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "before\npython after\nlast bytes, no newline"


def test_shutdown_without_a_session_does_nothing():
    import jax

    assert not jax.distributed.is_initialized()
    shutdown_distributed()  # no client: returns at once (every single-process run calls it)
    assert jax.process_count() == 1
