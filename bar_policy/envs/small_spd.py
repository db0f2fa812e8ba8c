"""Cholesky factor and solves of small symmetric positive definite matrices, written out in scalars.

The same factorisation as LAPACK's ``potrf`` behind ``jax.scipy.linalg.cho_factor`` (``a = L L^T``, row by
row) and the same two substitutions as ``cho_solve``, unrolled at trace time: under ``vmap`` every scalar
becomes one element-wise op over the batch, which XLA fuses into a few kernels, where the library calls (a
batched ``potrf`` and two batched triangular solves on a GPU) each launch on their own. For n = 14 (the
Lite's arms) a factor is about n^3 / 6 = 460 multiply-adds and a solve about n^2 = 200. On a CPU the library
calls are faster (``bench/piano_variants.py``'s ``libchol``), so ``physics_step.plan`` uses these on GPUs.

Shapes: ``a`` (n, n), of which only the lower triangle is read; ``low`` (n, n) lower triangular; ``y`` (n,).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["cho_solve", "cholesky", "spd_solve"]


def _rows(a: jax.Array) -> list[list[jax.Array]]:
    """``L``'s lower triangle as rows of scalars (row i holds ``L[i, 0..i]``)."""
    n = a.shape[-1]
    low: list[list[jax.Array]] = [[] for _ in range(n)]
    for i in range(n):
        for j in range(i + 1):
            acc = a[i, j]
            for k in range(j):
                acc = acc - low[i][k] * low[j][k]
            low[i].append(jnp.sqrt(acc) if i == j else acc / low[j][j])
    return low


def _solve_rows(low: list[list[jax.Array]], y: jax.Array) -> jax.Array:
    """``(L L^T)^-1 y`` from ``L``'s rows of scalars: ``L z = y``, then ``L^T x = z``."""
    n = len(low)
    z: list[jax.Array] = []
    for i in range(n):
        acc = y[i]
        for k in range(i):
            acc = acc - low[i][k] * z[k]
        z.append(acc / low[i][i])
    x: list[jax.Array] = [jnp.zeros((), y.dtype)] * n
    for i in reversed(range(n)):
        acc = z[i]
        for k in range(i + 1, n):
            acc = acc - low[k][i] * x[k]
        x[i] = acc / low[i][i]
    return jnp.stack(x)


def cholesky(a: jax.Array) -> jax.Array:
    """The lower triangular ``L`` (n, n) with ``a = L L^T`` (zeros above the diagonal)."""
    low = _rows(a)
    n = len(low)
    zero = jnp.zeros((), a.dtype)
    return jnp.stack([jnp.stack(row + [zero] * (n - len(row))) for row in low])


def cho_solve(low: jax.Array, y: jax.Array) -> jax.Array:
    """``a^-1 y`` (n,) given ``a``'s factor ``low`` from :func:`cholesky` (its lower triangle is read)."""
    n = low.shape[-1]
    return _solve_rows([[low[i, k] for k in range(i + 1)] for i in range(n)], y)


def spd_solve(a: jax.Array, y: jax.Array) -> jax.Array:
    """``a^-1 y`` (n,): :func:`cholesky` then :func:`cho_solve`, without building ``L`` as an array."""
    return _solve_rows(_rows(a), y)
