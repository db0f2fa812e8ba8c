"""Several processes through ``jax.distributed``: connect at the start, place the model, shut down in order.

``init_distributed`` connects this process to the coordinator (process 0) when a run names one;
``local_default_devices`` keeps MJX's model on this process's own device while the env is built;
``shutdown_distributed`` ends the session on every process once the run is over, the coordinator's service
last, so no process is left talking to a coordinator that is gone (``watch_filter`` keeps the coordinator's
own client's last word on it off stderr).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

from bar_policy.training.config import TrainConfig
from bar_policy.training.watch_filter import install as install_watch_filter

__all__ = ["init_distributed", "local_default_devices", "shutdown_distributed"]

SERVICE_GRACE_S = 1.0
"""Seconds the coordinator waits, after every process passed the shutdown barrier, before it stops the
coordination service (see ``shutdown_distributed``)."""


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
       service (``_stop_service``), with its stderr filtered from then on.

    Measured with 2 processes on one H100 (``local_device_ids=[0]`` each), 6 sessions of each order of
    exit: with 1-3 the other process printed nothing; process 0 still logged its own client's watch
    ``UNAVAILABLE: Cancelling all calls`` as its service stopped. On two H100s (2026-11-27) it logged
    ``UNAVAILABLE: failed to connect to all addresses`` instead, after a capture of the stop alone had
    ended: hence a filter to the process's end (``training.watch_filter``). On CPU (jax 0.10.2 here)
    neither order printed anything, before or after.

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


def _stop_service(service: Any, process_id: int) -> None:
    """Stop the coordination service, this process's stderr filtered from then on (``watch_filter``).

    On a GPU host this process's own GPU client keeps a watch call open on the service; the stop ends it,
    and XLA's C++ logging writes its warning straight to fd 2 (no Python logger or warnings filter sees it),
    during the stop or, when the client calls again, after it. ``watch_filter.install`` drops those records
    of this process's task until the process ends and passes everything else on.
    """
    install_watch_filter(process_id)
    service.shutdown()
