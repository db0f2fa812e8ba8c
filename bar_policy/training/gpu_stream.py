"""A computation on a GPU stream of its own inside a jitted program (issue 19: the update beside the rollout).

XLA runs a ``call`` whose frontend attributes name a stream (``_xla_stream_annotation``, jax's
``compute_on(compute_type="gpu_stream:N")``) asynchronously on that stream, so the work after it in the
program, up to the first use of its results, runs beside it. Two limits of XLA's pass
(``ExplicitStreamAnnotationAsyncWrapper``) shape this module (measured on an H200, jax 0.11.2,
docs/performance.md "Session 53"):

- the annotated computation may sit in a loop's body, but it must hold no loop and no nested call itself:
  jax annotates every op traced under the annotation, so a nested ``jit`` (most ``jnp`` functions, optax,
  flax's layers) or a ``while`` becomes a second annotated call inside the first, which XLA refuses ("No
  ExecutionStreamId found for call-start ... only reachable through embedded calls");
- so ``on_stream`` traces the function once and evaluates its jaxpr with every nested call (``jit``,
  ``custom_jvp_call``, ``custom_vjp_call``, ``checkpoint``) written inline, and refuses one that still
  holds a loop or a conditional (``scan``, ``while``, ``cond``), naming it;
- jax's PRNG is the one part that hides its calls below the jaxpr: a key's ``random_split``,
  ``random_bits`` and ``random_fold_in`` lower to jitted functions of the key's implementation, and the
  Threefry hash (``threefry2x32``) to a function of its own. So those primitives are evaluated through
  the implementation's functions on the key's raw data (inlined in turn), and the hash through jax's own
  loop-free form of it (``_threefry2x32_lowering`` with ``use_rolled_loops=False``, what jax lowers it to
  on a GPU): the same bits (tests).

On a CPU the annotation is accepted and ignored: the values are those of ``fn`` itself (tests:
test_gpu_stream.py).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import Any

import jax
from jax.extend import core as jex_core

__all__ = ["LOOPS", "annotate", "inline_calls", "on_stream", "stream_api"]

_CALLS = {
    "jit": "jaxpr",
    "pjit": "jaxpr",
    "closed_call": "call_jaxpr",
    "core_call": "call_jaxpr",
    "custom_jvp_call": "call_jaxpr",
    "custom_vjp_call": "call_jaxpr",
    "custom_vjp_call_jaxpr": "fun_jaxpr",
    "checkpoint": "jaxpr",
    "remat": "jaxpr",
}
"""Primitives that call a sub-jaxpr, and the parameter holding it: written inline by ``inline_calls``."""

LOOPS = ("while", "scan", "cond", "fori_loop")
"""Primitives that hold their own computations: a stream's computation must not hold one."""


@functools.cache
def _threefry_hash() -> Callable[..., Any]:
    """The loop-free Threefry-2x32 of jax (``(k1, k2, x1, x2) -> (y1, y2)``, uint32 arrays)."""
    import importlib

    for module in ("jax._src.random.threefry2x32", "jax._src.prng"):  # jax 0.10-0.11; older
        try:
            lowering = importlib.import_module(module)._threefry2x32_lowering
        except (ImportError, AttributeError):
            continue
        return functools.partial(lowering, use_rolled_loops=False)
    raise NotImplementedError(f"on_stream: this jax ({jax.__version__}) has no _threefry2x32_lowering")


def _random(name: str, eqn: Any, invals: list) -> list:
    """A PRNG primitive through the key implementation's functions on raw key data (module docstring)."""
    from jax._src.random import prng

    if name == "threefry2x32":
        return list(inline_calls(_threefry_hash())(*invals))
    key = eqn.invars[0].aval
    impl, ndim = key.dtype._impl, len(key.shape)
    raw = prng.random_unwrap(invals[0])
    if name == "random_split":
        fn = lambda r: prng.random_split_impl_base(impl, r, ndim, **eqn.params)  # noqa: E731
        return [prng.random_wrap(inline_calls(fn)(raw), impl=impl)]
    if name == "random_bits":
        fn = lambda r: prng.random_bits_impl_base(impl, r, ndim, **eqn.params)  # noqa: E731
        return [inline_calls(fn)(raw)]
    fn = lambda r, msgs: prng.random_fold_in_impl_base(impl, r, msgs, key.shape)  # noqa: E731
    return [prng.random_wrap(inline_calls(fn)(raw, invals[1]), impl=impl)]


_RANDOM = ("random_split", "random_bits", "random_fold_in", "threefry2x32")
"""The PRNG primitives ``_random`` evaluates."""


def _evaluate(jaxpr: Any, consts: Any, args: Any) -> list:
    """``jaxpr`` on ``args`` in the current trace, every nested call's equations bound in its place."""
    env: dict = {}

    def read(v: Any) -> Any:
        return v.val if isinstance(v, jex_core.Literal) else env[v]

    env.update(zip(jaxpr.constvars, consts, strict=True))
    env.update(zip(jaxpr.invars, args, strict=True))
    for eqn in jaxpr.eqns:
        invals = [read(v) for v in eqn.invars]
        sub = eqn.params.get(_CALLS.get(eqn.primitive.name, ""))
        if eqn.primitive.name in _RANDOM:
            outs = _random(eqn.primitive.name, eqn, invals)
        elif sub is not None:
            closed = isinstance(sub, jex_core.ClosedJaxpr)
            outs = _evaluate(sub.jaxpr if closed else sub, sub.consts if closed else (), invals)
        else:
            if eqn.primitive.name in LOOPS:
                raise ValueError(
                    f"on_stream: the function holds a {eqn.primitive.name!r}; a computation on a GPU stream "
                    f"of its own must be loop-free (unroll it: a Python loop, or scan(..., unroll=True))"
                )
            params = eqn.primitive.get_bind_params(eqn.params)  # jax 0.10: params; older: (subfuns, params)
            subfuns, params = params if isinstance(params, tuple) else ((), params)
            # Not under ``eqn.ctx``: its compute type is the inner trace's (none), which would drop the
            # stream annotation of the trace this runs in.
            outs = eqn.primitive.bind(*subfuns, *invals, **params)
            if not eqn.primitive.multiple_results:
                outs = [outs]
        for v, x in zip(eqn.outvars, outs, strict=True):
            if not isinstance(v, jex_core.DropVar):
                env[v] = x
    return [read(v) for v in jaxpr.outvars]


def inline_calls(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with every nested call written inline (same values; pytrees in and out).

    Raises:
        ValueError: at trace time, if ``fn`` holds a loop or a conditional (``LOOPS``).
    """

    def inlined(*args: Any) -> Any:
        closed, shape = jax.make_jaxpr(fn, return_shape=True)(*args)
        outs = _evaluate(closed.jaxpr, closed.consts, jax.tree.leaves(args))
        return jax.tree.unflatten(jax.tree.structure(shape), outs)

    return inlined


def stream_api() -> str:
    """The jax function that annotates a stream, ``compute_on`` or ``compute_on2``.

    jax 0.11's ``compute_on`` takes the function; in 0.10 that is ``compute_on2`` (``compute_on`` is a
    context). Both take ``(fn, compute_type=, out_memory_spaces=)``. No public name yet.
    """
    import jax._src.compute_on as con

    takes_fn = "out_memory_spaces" in inspect.signature(con.compute_on).parameters
    return "compute_on" if takes_fn else "compute_on2"


def annotate(fn: Callable[..., Any], stream: int) -> Callable[..., Any]:
    """``fn`` as it is, annotated for GPU stream ``stream`` (outputs in device memory).

    No inlining and no check, so XLA sees what jax lowers (``bench/stream_overlap.py`` shows what it
    refuses).
    """
    import jax._src.compute_on as con

    space = jax._src.core.MemorySpace.Device
    return getattr(con, stream_api())(fn, compute_type=f"gpu_stream:{stream}", out_memory_spaces=space)


def on_stream(fn: Callable[..., Any], stream: int) -> Callable[..., Any]:
    """``fn`` (loop-free, see the module docstring) as a computation XLA runs on GPU stream ``stream``.

    ``annotate(inline_calls(fn), stream)``. Its outputs stay in device memory. Stream 0 is the program's
    own; use 1 or more.
    """
    return annotate(inline_calls(fn), stream)
