"""Host arrays onto the default device without compiling a program: the envs' constant tables.

``jnp.asarray(numpy_array)`` outside a trace compiles a small XLA program (``jit(stage)``, or
``jit(convert_element_type)`` when a dtype is given) once per shape and dtype, with jax 0.10: on the
start-up path of every training run, before anything is traced (about 20 ms each on the 2-core CPU,
a cache load or a GPU compile each on a GPU). ``jax.device_put`` of the same numpy array makes the
same array (same values, dtype, weak type, uncommitted on the default device) by a plain transfer.
The dtype cast is done by numpy on the host (IEEE round to nearest, as XLA's ``convert``).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

__all__ = ["to_device"]


def to_device(x: Any, dtype: Any = None) -> jax.Array:
    """``x`` (array-like) as a device array of ``dtype`` (default: its own, canonicalised as jax does).

    What ``jnp.asarray(x, dtype)`` returns, without its compile. The array is copied (``may_alias=False``):
    a later change to ``x`` never shows through, on CPU either.
    """
    return jax.device_put(np.asarray(x, dtype=dtype), may_alias=False)
