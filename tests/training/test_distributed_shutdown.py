"""The ordered ``jax.distributed`` shutdown, the parts one process shows (two: ``test_distributed.py``)."""

from __future__ import annotations

from bar_policy.training.distributed import drop_own_watch_cancelled, shutdown_distributed

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


def test_only_this_process_watch_cancelled_record_is_dropped():
    other_task = OWN_WATCH.replace("for task 0:", "for task 1:")
    unrelated = "E1125 09:40:40.500000     676 client.cc:80] Terminating process because of fatal errors\n"
    before = "a line before any record\n"
    text = before + OWN_WATCH + unrelated + other_task
    # The whole six-line record of task 0 goes; the line before it, the error and task 1's record stay.
    assert drop_own_watch_cancelled(text, 0) == before + unrelated + other_task
    assert drop_own_watch_cancelled(OWN_WATCH, 1) == OWN_WATCH  # another process's id: not its record
    assert drop_own_watch_cancelled("", 0) == ""


def test_shutdown_without_a_session_does_nothing():
    import jax

    assert not jax.distributed.is_initialized()
    shutdown_distributed()  # no client: returns at once (every single-process run calls it)
    assert jax.process_count() == 1
