"""Array-namespace helper so one function body runs on numpy (deploy) and jax (training)."""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

Array = Any
"""numpy.ndarray or jax.Array (or a float); kept loose so numpy-only code never imports jax."""


def array_namespace(*arrays: Array) -> ModuleType:
    """numpy, or jax.numpy when any argument is a jax array or tracer (jax is imported lazily)."""
    for a in arrays:
        if type(a).__module__.split(".")[0] in ("jax", "jaxlib"):
            import jax.numpy as jnp

            return jnp
    return np
