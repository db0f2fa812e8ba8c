"""Jax arrays <-> torch tensors through DLPack: the same device buffer on both sides, no host round trip.

``jax_to_torch(x)`` is ``torch.from_dlpack(x)`` and ``torch_to_jax(t)`` is ``jax.dlpack.from_dlpack(t)``:
a GPU array becomes a ``cuda`` tensor on the same GPU (and back), a CPU array a ``cpu`` tensor. Neither
waits for the device: on a GPU the consumer's stream waits on the producer's through an event (the
``stream`` argument of ``__dlpack__``), the host does not.

What may *not* be shared, and what happens then:

- jax -> torch never copies (torch's ``from_dlpack`` raises where it cannot share; jax arrays are dense
  and row-major). A jax array is immutable: the torch view must only be read. Writing into it in place
  changes the jax array under jax's feet (undefined behaviour); rsl-rl only reads the env's tensors (its
  storage copies them, and ``PPO.process_env_step`` clones the rewards before bootstrapping).
- torch -> jax copies in three cases, each **counted** in ``COPIES`` and logged (a warning on the first
  copy of each reason, the running count after): a dtype jax cannot hold without ``jax_enable_x64``
  (int64, float64; converted on the device by torch), a non-contiguous tensor (made contiguous on the
  device by torch), and a buffer jax would not alias (e.g. not aligned as XLA requires: jax copies it;
  detected by comparing the two buffer pointers). ``copy=False`` raises ``BufferError`` instead.
- The torch storage stays alive while the jax array lives (the DLPack capsule's deleter holds it), so the
  caller may drop its tensor. A torch tensor handed to jax must not be written in place afterwards: jax
  sees the change.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import dataclass, field

import jax
import torch

__all__ = ["COPIES", "BridgeCopies", "jax_to_torch", "torch_device_for_jax", "torch_to_jax"]

_log = logging.getLogger(__name__)

_NARROW = {torch.int64: torch.int32, torch.float64: torch.float32}
"""Dtypes a jax without ``jax_enable_x64`` holds only narrowed (jax would copy them silently)."""


@dataclass
class BridgeCopies:
    """Running count of the torch -> jax crossings that had to copy (by reason)."""

    count: int = 0
    """Copies since the start (or the last ``reset``)."""
    by_reason: collections.Counter[str] = field(default_factory=collections.Counter)
    """The same count split by reason (``dtype int64->int32``, ``non-contiguous``, ``not aliased``)."""

    def add(self, reason: str, t: torch.Tensor) -> None:
        """Count one copy of ``t`` for ``reason`` and log it (a warning the first time for a reason)."""
        self.count += 1
        self.by_reason[reason] += 1
        n = self.by_reason[reason]
        msg = "torch->jax copy (%s) of a %s %s tensor on %s: %d such copies so far"
        args = (reason, tuple(t.shape), t.dtype, t.device, n)
        if n == 1:
            _log.warning(msg, *args)
        else:
            _log.debug(msg, *args)

    def reset(self) -> None:
        """Zero the counts."""
        self.count = 0
        self.by_reason.clear()


COPIES = BridgeCopies()
"""The process-wide copy counter of ``torch_to_jax`` (read it, e.g. once per training iteration)."""


def torch_device_for_jax(device: jax.Device | None = None) -> str:
    """The torch device that shares memory with a jax device (default: jax's first): ``cuda:N`` or ``cpu``."""
    dev = device or jax.local_devices()[0]
    if dev.platform == "gpu":
        return f"cuda:{dev.local_hardware_id}"
    if dev.platform == "cpu":
        return "cpu"
    raise ValueError(f"jax device {dev} ({dev.platform}) has no torch counterpart; valid: gpu, cpu")


def jax_to_torch(x: jax.Array) -> torch.Tensor:
    """The torch view of a jax array (same buffer, same device, same dtype and shape; never a copy).

    Args:
        x: a jax array on one device (a sharded array raises ``BufferError``: cross per shard).

    Returns:
        A tensor whose ``data_ptr()`` is ``x.unsafe_buffer_pointer()``. Read it only (see the module
        docstring).
    """
    return torch.from_dlpack(x)


def torch_to_jax(t: torch.Tensor, *, copy: bool | None = None) -> jax.Array:
    """The jax view of a torch tensor (same buffer and device), or a counted copy where it cannot be one.

    Args:
        t: any tensor on the device jax uses (autograd history is dropped: ``detach`` shares the buffer).
        copy: ``None`` shares where it can and copies (counted in ``COPIES``, logged) where it cannot;
            ``False`` raises ``BufferError`` instead of copying.

    Returns:
        A jax array of ``t``'s shape; its dtype is ``t``'s, except int64 -> int32 and float64 -> float32
        while ``jax_enable_x64`` is off.
    """
    t = t.detach()
    reasons = []
    if t.dtype in _NARROW and not jax.config.jax_enable_x64:
        reasons.append(f"dtype {str(t.dtype)[6:]}->{str(_NARROW[t.dtype])[6:]}")
        if copy is not False:
            t = t.to(_NARROW[t.dtype])
    if not t.is_contiguous():
        reasons.append("non-contiguous")
        if copy is not False:
            t = t.contiguous()
    if reasons and copy is False:
        raise BufferError(
            f"torch_to_jax(copy=False): a {t.dtype} {tuple(t.shape)} tensor needs a copy: {reasons}"
        )
    for r in reasons:
        COPIES.add(r, t)
    x = jax.dlpack.from_dlpack(t)
    if t.numel() and x.unsafe_buffer_pointer() != t.data_ptr():
        if copy is False:
            raise BufferError(
                f"torch_to_jax(copy=False): jax copied a {t.dtype} {tuple(t.shape)} tensor at "
                f"{t.data_ptr():#x} (alignment {t.data_ptr() % 64} mod 64) instead of aliasing it"
            )
        COPIES.add("not aliased", t)
    return x
