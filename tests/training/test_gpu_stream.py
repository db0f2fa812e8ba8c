"""``training.gpu_stream``: a computation XLA can run on a GPU stream of its own.

XLA refuses a stream's computation that holds a nested call or a loop (session 53, H200: "No
ExecutionStreamId found for call-start ... only reachable through embedded calls", from a ``jit`` inside jax's
random split). On this CPU the annotation is accepted and ignored, so the tests check what XLA would see:
the lowered program's annotated function holds no ``call`` and no ``while``, and the values are those of
the function itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bar_policy.training.gpu_stream import inline_calls, on_stream


def _step(key: jax.Array, w: jax.Array, x: jax.Array) -> dict:
    """Nested jits (``jnp.clip``), custom JVPs (``relu``, ``softplus``), a gradient and jax's PRNG."""
    key, k_perm, k_noise = jax.random.split(key, 3)
    perm = jax.random.permutation(k_perm, x.shape[0])
    noise = jax.random.normal(k_noise, w.shape)

    def loss(w: jax.Array) -> jax.Array:
        y = x[perm] @ w
        return jnp.sum(jax.nn.relu(jnp.clip(y, -1.0, 1.0)) ** 2 + jax.nn.softplus(y))

    value, grad = jax.value_and_grad(loss)(w)
    folded = jax.random.uniform(jax.random.fold_in(key, 7), (2,))
    return {"key": key, "perm": perm, "value": value, "w": w - 0.1 * grad + 0.01 * noise, "u": folded}


KEY = jax.random.PRNGKey(3)
W = jnp.linspace(-1.0, 1.0, 12, dtype=jnp.float32).reshape(4, 3)
X = jnp.linspace(0.0, 1.0, 32, dtype=jnp.float32).reshape(8, 4)


def _names(jaxpr: jax.extend.core.Jaxpr) -> set[str]:
    """Every primitive in ``jaxpr``, sub-jaxprs included."""
    found = set()
    for eqn in jaxpr.eqns:
        found.add(eqn.primitive.name)
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            found |= _names(sub)
    return found


def _check_close(got: dict, want: dict) -> None:
    # The same operations on the same inputs; only the order XLA fuses them in may differ, so the floats
    # agree to a few float32 ulps (2**-23 = 1.2e-7 relative each): 1e-6 relative, 1e-7 absolute near 0.
    # Integers (the key, the permutation) are bits: exact.
    for name in want:
        if jnp.issubdtype(want[name].dtype, jnp.integer):
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)
        else:
            np.testing.assert_allclose(got[name], want[name], rtol=1e-6, atol=1e-7, err_msg=name)


@pytest.mark.numerics
def test_inlined_function_has_no_nested_call_and_the_same_values():
    plain = _names(jax.make_jaxpr(_step)(KEY, W, X).jaxpr)
    assert {"jit", "custom_jvp_call", "random_split", "random_bits"} <= plain  # what there is to inline
    inlined = _names(jax.make_jaxpr(inline_calls(_step))(KEY, W, X).jaxpr)
    assert not inlined & {"jit", "pjit", "custom_jvp_call", "custom_vjp_call", "random_split", "random_bits"}
    assert not inlined & {"threefry2x32", "random_fold_in", "while", "scan"}
    _check_close(jax.jit(inline_calls(_step))(KEY, W, X), jax.jit(_step)(KEY, W, X))


@pytest.mark.numerics
def test_stream_computation_in_a_loop_lowers_without_calls_and_keeps_values():
    def loop(stepper):
        def run(key, w, x):
            def body(_, c):
                out = stepper(c[0], c[1], x)
                return out["key"], out["w"]

            return jax.lax.fori_loop(0, 3, body, (key, w))

        return jax.jit(run)

    streamed = loop(on_stream(_step, 1))
    text = streamed.lower(KEY, W, X).as_text()
    functions = text.split("func.func ")
    on_streams = [f for f in functions if f.startswith("private @compute_on")]
    assert len(on_streams) == 1
    assert text.count('_xla_stream_annotation = "1"') >= 1
    assert on_streams[0].count("call @") == 0 and on_streams[0].count("stablehlo.while") == 0
    got, want = streamed(KEY, W, X), loop(_step)(KEY, W, X)
    _check_close({"key": got[0], "w": got[1]}, {"key": want[0], "w": want[1]})


def test_a_loop_in_the_stream_computation_is_refused_by_name():
    def with_loop(w: jax.Array) -> jax.Array:
        return jax.lax.fori_loop(0, 2, lambda _, c: c * 2.0, w)

    with pytest.raises(ValueError, match=r"holds a 'scan'.*must be loop-free"):
        jax.jit(on_stream(with_loop, 1))(W)


def test_inlined_products_keep_the_precision_they_were_traced_at():
    def product(w: jax.Array, x: jax.Array) -> jax.Array:
        return jnp.tanh(x @ w)

    with jax.default_matmul_precision("tensorfloat32"):
        jaxpr = jax.make_jaxpr(inline_calls(product))(W, X).jaxpr
    dots = [e for e in jaxpr.eqns if e.primitive.name == "dot_general"]
    assert len(dots) == 1
    precision = dots[0].params["precision"]
    assert (precision[0] if isinstance(precision, tuple) else precision).name == "HIGH"
