"""Cholesky factor and solves of small symmetric positive definite matrices, written out at trace time.

Two forms, both exact (tests against numpy in float64), both with no library call (``SOLVERS``):

``scalar`` (:func:`cholesky`, :func:`cho_solve`, :func:`spd_solve`): the same factorisation as LAPACK's
``potrf`` behind ``jax.scipy.linalg.cho_factor`` (``a = L L^T``, row by row) and the same two
substitutions as ``cho_solve``, unrolled at trace time: under ``vmap`` every scalar becomes one element-wise
op over the batch, which XLA fuses into a few kernels, where the library calls (a batched ``potrf`` and two
batched triangular solves on a GPU) each launch on their own. For n = 14 (the Lite's arms) a factor is about
n^3 / 6 = 460 multiply-adds and a solve about n^2 = 200. On a CPU the library calls are faster
(``libchol`` of ``bench/piano_variants.py`` at fdbaf1a). It is the largest program: some 1,500 scalar ops
per factor and solve for n = 14, which XLA's compile pays for.

``columns`` (:func:`cholesky_columns`, :func:`cho_solve_columns`): the same factor column by column and the
same substitutions entry by entry, each a masked vector op over the row (``n`` steps of a few ops rather
than ``n^3 / 6`` scalars): more arithmetic (n^3 rather than n^3 / 6 multiply-adds) in a smaller program
(the reach physics step's HLO text: 3,400 lines more than with the library calls, ``scalar`` 7,200). On this
2-core CPU the reach physics step (64 envs, float32) compiles in 20 s against 26 s
for ``scalar`` and 14 s for the library calls.

On a GPU XLA records none of the library calls into a command buffer (a CUDA graph), and it records both
forms; ``physics_step.plan(cholesky=...)`` opts in.

Shapes: ``a`` (n, n), of which only the lower triangle is read; ``low`` (n, n) lower triangular; ``y`` (n,).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

__all__ = ["SOLVERS", "cho_solve", "cho_solve_columns", "cholesky", "cholesky_columns", "spd_solve"]


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


def cholesky_columns(a: jax.Array) -> jax.Array:
    """:func:`cholesky` column by column (the ``columns`` form).

    Column ``j`` is ``a[:, j] - L L[j]^T`` (only the columns < j of ``L`` are filled yet), divided by the
    square root of its diagonal entry, kept on and below the diagonal.
    """
    n = a.shape[-1]
    below = jnp.arange(n)
    low = jnp.zeros_like(a)
    for j in range(n):
        v = a[:, j] - jnp.sum(low * low[j], axis=-1)
        low = low.at[:, j].set(jnp.where(below >= j, v / jnp.sqrt(v[j]), 0.0))
    return low


def cho_solve_columns(low: jax.Array, y: jax.Array) -> jax.Array:
    """:func:`cho_solve` entry by entry (the ``columns`` form); ``low``'s upper triangle must be zero.

    ``z_i = (y_i - L[i] z) / L_ii`` (the entries >= i of ``z`` are still 0), then
    ``x_i = (z_i - L[:, i] x) / L_ii`` from the last entry.
    """
    n = low.shape[-1]
    z = jnp.zeros_like(y)
    for i in range(n):
        z = z.at[i].set((y[i] - jnp.sum(low[i] * z)) / low[i, i])
    x = jnp.zeros_like(y)
    for i in reversed(range(n)):
        x = x.at[i].set((z[i] - jnp.sum(low[:, i] * x)) / low[i, i])
    return x


Factor = Callable[[jax.Array], jax.Array]
Solve = Callable[[jax.Array, jax.Array], jax.Array]

SOLVERS: dict[str, tuple[Factor, Solve]] = {
    "scalar": (cholesky, cho_solve),
    "columns": (cholesky_columns, cho_solve_columns),
}
"""Each form's ``(factor, solve)``: ``factor(a)`` the lower ``L`` (zeros above), ``solve(L, y)`` = a^-1 y."""
