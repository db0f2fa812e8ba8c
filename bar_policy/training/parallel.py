"""Data parallelism on ``jax.sharding``: one ``Mesh`` axis over every device of every process.

The trainer's per-device code (rollout, loss, SGD) is written once, as if for one device, and mapped over
the mesh with ``jax.shard_map`` under ``jax.jit``:

- env state, rollouts and the per-slot model keys are sharded over the env axis (``P("data")``): each
  device holds ``num_envs / n_devices`` env slots;
- parameters, optimizer state and observation normaliser are replicated (``P()``);
- gradients are averaged with ``lax.pmean`` and normaliser statistics summed with ``lax.psum`` over the
  axis, so every replica applies the same update and stays identical.

Why ``shard_map`` rather than sharding-annotated ``jit`` (GSPMD): the per-device program is exactly what
runs on one GPU today (MJX's ``while_loop`` solvers, scatters and ``lax.cond`` auto-reset are left alone by
the partitioner), and the collectives are explicit, so their cost and placement are predictable. It is the
API JAX recommends in place of ``pmap`` (which jax >= 0.8 itself implements on top of ``shard_map``).

Under ``jax.distributed`` the mesh spans every process's devices (``jax.devices()``); each process feeds
and reads only its addressable shards. Host values enter through ``replicate`` (every process passes the
same value) and leave through ``jax.device_get``, which reads a fully replicated array from one local
replica on any process count (the trainer's parameters, metrics and evaluations are all replicated);
``to_host`` gives the first local shard of any array (the tests and benches inspect sharded ones).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = ["AXIS", "DataParallel", "barrier", "choose_partitioner", "make_data_parallel"]

AXIS = "data"
"""Name of the mesh axis the env batch is split over (the axis of ``pmean``/``psum`` in the learner)."""


@dataclass(frozen=True)
class DataParallel:
    """A 1-D device mesh and the helpers that place trees on it.

    Attributes:
        mesh: ``Mesh`` of shape ``(n_devices,)`` with axis ``AXIS``.
    """

    mesh: Mesh

    @property
    def n_devices(self) -> int:
        """Devices in the mesh (all processes)."""
        return int(self.mesh.devices.size)

    @property
    def n_local(self) -> int:
        """Devices of this process in the mesh."""
        return sum(d.process_index == jax.process_index() for d in self.mesh.devices.flat)

    @property
    def sharded(self) -> NamedSharding:
        """Leading axis split over the mesh (env slots)."""
        return NamedSharding(self.mesh, P(AXIS))

    @property
    def replicated(self) -> NamedSharding:
        """A full copy on every device."""
        return NamedSharding(self.mesh, P())

    def replicate(self, tree: Any) -> Any:
        """Host arrays (numpy or jax, the same value on every process) -> replicated global arrays."""

        def one(x: Any) -> jax.Array:
            x = np.asarray(x)
            return jax.make_array_from_callback(x.shape, self.replicated, lambda idx: x[idx])

        return jax.tree.map(one, tree)

    def to_host(self, tree: Any) -> Any:
        """Global arrays -> numpy: this process's first shard of each, no cross-process traffic.

        A replicated array's first shard is its whole value; the trainer reads those with ``jax.device_get``.
        """

        def one(x: Any) -> np.ndarray:
            if isinstance(x, jax.Array):
                return np.asarray(x.addressable_shards[0].data)
            return np.asarray(x)

        return jax.tree.map(one, tree)

    def abstract(self, tree: Any, *, sharded: bool) -> Any:
        """``ShapeDtypeStruct``s of ``tree`` placed like ``sharded``/``replicated`` (for AOT lowering).

        For ``sharded`` trees the shapes given are global (leading axis = all env slots).
        """
        sharding = self.sharded if sharded else self.replicated
        return jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding),
            tree,
            is_leaf=lambda x: hasattr(x, "shape") and hasattr(x, "dtype"),
        )

    def sharded_jit(
        self,
        fn: Callable[..., Any],
        in_specs: Sequence[Any],
        out_specs: Any,
        *,
        donate_argnums: tuple[int, ...] = (),
    ) -> Callable[..., Any]:
        """``jit(shard_map(fn))``: ``fn`` sees one device's shard; specs are ``P(AXIS)`` or ``P()`` prefixes.

        ``fn`` may use ``lax.pmean``/``psum``/``axis_index`` over ``AXIS``. Outputs declared ``P()`` must be
        the same on every device: here they come out of ``pmean``/``psum`` or from replicated inputs only.
        The varying-axes type check (``check_vma``) is off, as under ``pmap``: env code builds loop carries
        from constants (reset metrics are zeros) that become per-device values after a step, which the
        checker rejects unless every env casts them; no gradient flows through a collective here.
        """
        mapped = jax.shard_map(
            fn, mesh=self.mesh, in_specs=tuple(in_specs), out_specs=out_specs, check_vma=False
        )
        # The same placement, stated to jit: every output (zero-size arrays included, which XLA would
        # otherwise hand back replicated) comes out exactly as the next program expects it.
        return jax.jit(
            mapped,
            in_shardings=tuple(self._shardings(s) for s in in_specs),
            out_shardings=self._shardings(out_specs),
            donate_argnums=donate_argnums,
        )

    def _shardings(self, specs: Any) -> Any:
        """``P`` prefixes -> ``NamedSharding`` prefixes on this mesh."""
        return jax.tree.map(
            lambda spec: NamedSharding(self.mesh, spec), specs, is_leaf=lambda x: isinstance(x, P)
        )

    def check_divisible(self, **sizes: int) -> None:
        """Raise ``ValueError`` naming every size that does not split evenly over the devices."""
        bad = {k: v for k, v in sizes.items() if v % self.n_devices}
        if bad:
            listed = ", ".join(f"{k} = {v}" for k, v in bad.items())
            raise ValueError(
                f"{listed} must be a multiple of the device count {self.n_devices} "
                f"({self.n_local} local x {jax.process_count()} processes); valid: multiples of "
                f"{self.n_devices}, or --distributed.max-devices-per-host to use fewer devices"
            )


def barrier(name: str, timeout_s: float = 1800.0) -> None:
    """Wait until every process reaches ``name`` (no-op in a single process).

    Uses the ``jax.distributed`` coordination service (what jax's own multi-process tests use), not a
    device collective: gloo's CPU collectives give up on a peer after 30 s, far less than one process may
    spend compiling while another has finished.
    """
    if jax.process_count() == 1:
        return
    _client().wait_at_barrier(name, int(timeout_s * 1000))


_AGREE_CALLS: dict[str, int] = {}
"""How often this process called ``all_agree`` with each name (the n-th calls of the processes meet)."""


def all_agree(name: str, value: bool, timeout_s: float = 1800.0) -> bool:
    """Whether ``value`` is True on every process; ``value`` itself in a single process.

    Every process must make the same calls in the same order: the n-th call of a ``name`` on one process
    meets the n-th on the others (``startup.compiler.Compiler``: whether every process holds a program in
    its executable cache). Through the coordination service's key-value store, as ``barrier``: each process
    sets its answer under the call's key, then waits up to ``timeout_s`` for every other one.
    """
    if jax.process_count() == 1:
        return value
    client = _client()
    n = _AGREE_CALLS[name] = _AGREE_CALLS.get(name, 0) + 1
    prefix = f"bar_policy/agree/{name}/{n}"
    client.key_value_set(f"{prefix}/{jax.process_index()}", "1" if value else "0")
    wait_ms = int(timeout_s * 1000)
    answers = [client.blocking_key_value_get(f"{prefix}/{p}", wait_ms) for p in range(jax.process_count())]
    return all(a == "1" for a in answers)


def _client() -> Any:
    """This process's ``jax.distributed`` client (several processes imply one)."""
    from jax._src import distributed

    client = distributed.global_state.client
    if client is None:  # pragma: no cover - process_count > 1 implies an initialised client
        raise RuntimeError("several processes but no jax.distributed client")
    return client


def choose_partitioner() -> str:
    """Compile the data-parallel programs with GSPMD, not Shardy, unless the user chose.

    On 2 and 4 H200s (jax 0.11.2, CUDA 13) XLA segfaults while compiling any multi-device program that
    holds ``mjx.forward``/``mjx.step`` or returns an ``mjx.Data`` whole; one device compiles them, and the
    same programs compile on every device count once ``jax_use_shardy_partitioner`` is off
    (``docs/performance.md``; the bisect script is at ``git show dec95c9:bench/pmap_reset_bisect.py``).
    ``JAX_USE_SHARDY_PARTITIONER`` in the environment wins. Idempotent; returns the partitioner in use, for a
    run's header.
    """
    import os

    if "JAX_USE_SHARDY_PARTITIONER" not in os.environ:
        jax.config.update("jax_use_shardy_partitioner", False)
    return "shardy" if jax.config.jax_use_shardy_partitioner else "gspmd"


def make_data_parallel(max_devices_per_host: int | None = None) -> DataParallel:
    """The mesh over every device of every process (or the first ``max_devices_per_host`` local ones).

    Sets the partitioner first (``choose_partitioner``): every program mapped over this mesh compiles
    after it.

    Raises:
        ValueError: ``max_devices_per_host`` is not positive, or is combined with several processes
            (a mesh must hold every device the processes run on).
    """
    if max_devices_per_host is not None and max_devices_per_host <= 0:
        raise ValueError(
            f"distributed.max_devices_per_host must be positive or None, got {max_devices_per_host}"
        )
    if max_devices_per_host is not None and max_devices_per_host < jax.local_device_count():
        if jax.process_count() > 1:
            raise ValueError(
                "distributed.max_devices_per_host is supported in single-process runs only; with several "
                "processes limit the devices per process with CUDA_VISIBLE_DEVICES"
            )
        devices = jax.local_devices()[:max_devices_per_host]
    else:
        devices = jax.devices()
    choose_partitioner()
    return DataParallel(Mesh(np.asarray(devices), (AXIS,)))
