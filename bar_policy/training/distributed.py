"""Several processes through ``jax.distributed``: connect at the start, place the model, shut down in order.

``init_distributed`` connects this process to the coordinator (process 0) when a run names one;
``local_default_devices`` keeps MJX's model on this process's own device while the env is built;
``shutdown_distributed`` ends the session on every process once the run is over, the coordinator's service
last, so no process is left talking to a coordinator that is gone.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator
from typing import Any

from bar_policy.training.config import TrainConfig

__all__ = ["drop_own_watch_cancelled", "init_distributed", "local_default_devices", "shutdown_distributed"]

SERVICE_GRACE_S = 1.0
"""Seconds the coordinator waits, after every process passed the shutdown barrier, before it stops the
coordination service (see ``shutdown_distributed``)."""

_SETTLE_S = 0.3
"""Seconds stderr stays captured after the service stopped (the cancelled watch logs from a gRPC thread;
on an H100 its record was always in the capture)."""


def init_distributed(cfg: TrainConfig) -> None:
    """``jax.distributed.initialize`` when a coordinator address is configured (multi-host).

    Must run before anything touches a device. On CPU the cross-process collectives are gloo's (jax's
    default ``jax_cpu_collectives_implementation``); on GPUs NCCL's.
    """
    d = cfg.distributed
    if d.coordinator_address:
        import jax

        if getattr(jax.distributed, "is_initialized", lambda: False)():
            return
        jax.distributed.initialize(
            coordinator_address=d.coordinator_address,
            num_processes=d.num_processes,
            process_id=d.process_id,
            local_device_ids=list(d.local_device_ids) if d.local_device_ids is not None else None,
        )
    elif d.num_processes > 1:
        raise ValueError(
            f"distributed.num_processes = {d.num_processes} needs distributed.coordinator_address "
            "(host:port of process 0)"
        )


@contextlib.contextmanager
def local_default_devices() -> Iterator[None]:
    """While building the env under ``jax.distributed``, ``jax.devices()`` lists this process's devices.

    MJX's ``put_model``/``put_data`` place the model on ``jax.devices()[0]`` when given no device; with
    several processes that is process 0's device, so every other process would hold a model it cannot read
    (and the trainer cannot close over it). Listing the local devices first puts it on this process's first
    device, as on one host.
    """
    import jax

    if jax.process_count() == 1:
        yield
        return
    real = jax.devices
    jax.devices = lambda backend=None: jax.local_devices(backend=backend)  # type: ignore[assignment]
    try:
        yield
    finally:
        jax.devices = real  # type: ignore[assignment]


def shutdown_distributed(timeout_s: float = 1800.0) -> None:
    """End the ``jax.distributed`` session on every process, the coordinator's service last (no-op alone).

    Called by ``run`` on every process after its last collective. Left to jax's ``atexit`` hook, each
    process shuts down whenever it happens to exit, and on GPU hosts (jax 0.11.2, H100) both processes of
    a 2-process session logged gRPC warnings at exit although the run succeeded: the GPU client's
    coordination watch (``WatchTasksAsync failed for task N``) ended ``CANCELLED`` or ``UNAVAILABLE:
    failed to connect to all addresses`` when process 0, which hosts the coordination service, had gone.
    Here:

    1. a barrier, so every process has finished its work (process 0 may still be exporting the policy);
    2. ``jax.distributed.shutdown`` without the service: the preemption manager, then the client, whose
       shutdown barrier (all processes) is where each client stops polling and disconnects;
    3. process 0 only: ``SERVICE_GRACE_S`` for the other processes to disconnect and exit, then the
       service (``_stop_service``).

    Measured with 2 processes on one H100 (``local_device_ids=[0]`` each), 6 sessions of each order of
    exit: with 1-3 the other process printed nothing; process 0 still logged its own client's watch
    ``UNAVAILABLE: Cancelling all calls`` as its service stopped, which ``_stop_service`` drops. On CPU
    (jax 0.10.2 here) neither order printed anything, before or after.

    Args:
        timeout_s: how long a process waits at the barrier for the slowest one, s.
    """
    import jax
    from jax._src import distributed

    state = distributed.global_state
    if state.client is None:
        return
    from bar_policy.training.parallel import barrier

    barrier("bar_policy: run finished", timeout_s)
    service, state.service = state.service, None
    jax.distributed.shutdown()
    if service is not None:
        time.sleep(SERVICE_GRACE_S)
        _stop_service(service, jax.process_index())


_ABSL_HEADER = re.compile(r"^[IWEF]\d{4} \d\d:\d\d:\d\d\.\d+ ")
"""The first line of an absl log record (``W1125 09:40:40.413933   676 file.cc:1605] message``)."""


def drop_own_watch_cancelled(text: str, process_id: int) -> str:
    """``text`` less the absl records of this process's task watch ended by its own service's stop.

    A record is its header line (``_ABSL_HEADER``) and the lines up to the next header; dropped are the
    records whose header says ``WatchTasksAsync failed for task <process_id>`` with ``Cancelling all
    calls`` or ``CANCELLED``. Everything else (other records, other tasks, lines before any header) stays.
    """
    kept: list[str] = []
    drop = False
    own = f"WatchTasksAsync failed for task {process_id}:"
    for line in text.splitlines(keepends=True):
        if _ABSL_HEADER.match(line):
            drop = own in line and ("Cancelling all calls" in line or "CANCELLED" in line)
        if not drop:
            kept.append(line)
    return "".join(kept)


def _stop_service(service: Any, process_id: int) -> None:
    """Stop the coordination service with stderr (fd 2) captured; pass on all but its expected warning.

    On a GPU host this process's own GPU client keeps a watch call open on the service, and stopping the
    service cancels it: XLA's C++ logging then writes one warning record straight to fd 2 (no Python
    logger or warnings filter sees it), from a gRPC thread, within the stop. The capture covers the stop
    and ``_SETTLE_S`` after it; ``drop_own_watch_cancelled`` removes that record and nothing else.
    """
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            service.shutdown()
            time.sleep(_SETTLE_S)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        text = tmp.read().decode(errors="replace")
    sys.stderr.write(drop_own_watch_cancelled(text, process_id))
    sys.stderr.flush()
