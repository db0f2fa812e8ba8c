"""A rollout and the update of other data as one loop (issue 19: can the update run beside the rollout?).

A trainer runs the rollout, then the update of the data it collected, as two programs, one after the
other. In a pipelined iteration the update works on the previous iteration's data while the rollout
collects the next (the collecting policy is then one update older than brax's). These two forms hold both
in one ``scan``, so that a GPU may run them side by side (``bench/stream_overlap.py``):

- ``overlapped``: each of the rollout's first control steps shares a loop body with one SGD pass, so that
  nothing orders the two inside a body (XLA's command buffers may then run them at once);
- ``streamed``: the same with each SGD pass on a GPU stream of its own (``training.gpu_stream``), its Adam
  steps written out (a stream's computation holds no loop).

Measured on an H200 (docs/benchmarks.md, sessions 44 and 53): neither pays at the reach default. With the
library Cholesky the streamed iteration took 220 ms against 125 ms for the two programs (the stream's
kernels are launched one by one while the host drives the physics' Newton loops); with
``cholesky=columns`` and graphed loops 106.8 against 111.7 ms, beside a 95.8 ms rollout alone, and its
program compiled in 88 s against 45 s. No trainer uses them.

Both return what ``Learner.rollout`` and ``Learner.update`` return for the same state and keys (tests:
test_learner_parts.py): ``(updated ts, env_state, the new data, stats, loss metrics)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.training import types

from bar_policy.training.brax.learner import Learner, TrainingState, segments
from bar_policy.training.gpu_stream import on_stream

__all__ = ["overlapped", "streamed"]

Result = tuple[TrainingState, Any, types.Transition, jax.Array, dict[str, jax.Array]]
"""``(updated ts, env_state, the new data, stats, loss metrics)``."""


def _one_loop(
    learner: Learner,
    ts: TrainingState,
    env_state: Any,
    key: jax.Array,
    env: Any,
    unrolls: int,
    data: Any,
    sgd_key: Any,
    sgd_pass: Callable[[tuple, Any, Any], tuple],
) -> Result:
    """The rollout's control steps and ``sgd_pass`` (``(carry, data, normaliser) -> (carry, metrics)``).

    The first ``min(control steps, passes)`` loop bodies hold one of each; the steps or passes left over
    (only one of the two) run alone after them, the passes as ``learner.sgd_passes``.
    """
    step = learner.collect_step(ts, env)
    normalizer, data = learner.prepare_update(ts, data)

    def body(c: tuple, _: None) -> tuple:
        env_c, out = step(c[0], None)
        sgd_c, metrics = sgd_pass(c[1], data, normalizer)
        return (env_c, sgd_c), (out, metrics)

    n_steps, n_passes = unrolls * learner.ppo.unroll_length, learner.ppo.num_updates_per_batch
    both = min(n_steps, n_passes)
    init = ((env_state, key), (ts.optimizer_state, ts.params, sgd_key))
    (env_c, sgd_c), (outs, metrics) = jax.lax.scan(body, init, None, length=both)
    if n_steps > both:
        env_c, rest = jax.lax.scan(step, env_c, None, length=n_steps - both)
        outs = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), outs, rest)
    if n_passes > both:
        sgd_c, rest = learner.sgd_passes(sgd_c, data, normalizer, n_passes - both)
        metrics = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), metrics, rest)
    trs, stats = jax.tree.map(lambda x: x.reshape((unrolls, learner.ppo.unroll_length, *x.shape[1:])), outs)
    ts = TrainingState(optimizer_state=sgd_c[0], params=sgd_c[1], normalizer_params=normalizer)
    return ts, env_c[0], segments(trs), stats.sum(axis=(0, 1)), jax.tree.map(jnp.mean, metrics)


def overlapped(
    learner: Learner,
    ts: TrainingState,
    env_state: Any,
    key: jax.Array,
    env: Any,
    unrolls: int,
    data: Any,
    sgd_key: Any,
) -> Result:
    """``rollout(ts, env_state, key, env, unrolls)`` and ``update(ts, data, sgd_key)`` as one loop.

    Each of the rollout's first control steps shares a loop body with one SGD pass over ``data`` (then the
    steps or passes left over run alone), so nothing orders the two inside a body.
    """
    return _one_loop(learner, ts, env_state, key, env, unrolls, data, sgd_key, learner.sgd_pass)


def streamed(
    learner: Learner,
    ts: TrainingState,
    env_state: Any,
    key: jax.Array,
    env: Any,
    unrolls: int,
    data: Any,
    sgd_key: Any,
    stream: int = 1,
) -> Result:
    """``overlapped`` with each SGD pass on GPU stream ``stream`` (``training.gpu_stream``).

    The first ``num_updates_per_batch`` control steps each share a loop body with one whole SGD pass (its
    Adam steps written out, ``sgd_pass(unrolled=True)``), which XLA runs on the other stream beside the
    step; the steps left over run alone.

    Raises:
        ValueError: fewer control steps per iteration than SGD passes.
    """
    n_steps, n_passes = unrolls * learner.ppo.unroll_length, learner.ppo.num_updates_per_batch
    if n_steps < n_passes:
        raise ValueError(
            f"streamed: {n_steps} control steps per iteration, fewer than the {n_passes} SGD passes "
            "(ppo.num_updates_per_batch) they would carry"
        )
    sgd = on_stream(lambda c, d, nz: learner.sgd_pass(c, d, nz, unrolled=True), stream)
    return _one_loop(learner, ts, env_state, key, env, unrolls, data, sgd_key, sgd)
