"""The kernel layer's rules that XLA could silently undo (jaxsat/_kernels.py, its docstring):
`where` is jnp.where's select without a nested jit, and `materialize` stores a value once, in
an unbatched program (an eager call) as well as in a batched one."""

from __future__ import annotations

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxsat
from jaxsat._kernels import materialize, where

F32 = jnp.ones((3,), jnp.float32)
I32 = jnp.arange(3, dtype=jnp.int32)
MASK = jnp.array([True, False, True])


@pytest.mark.parametrize(("x", "y"), [
    (F32, 2.0 * F32),
    (F32, 0.0),
    (-jnp.inf, F32),
    (I32, 7),
    (F32[0], F32),
    (jnp.ones((2, 1), jnp.float64), jnp.zeros((3,), jnp.float64)),
    (1.0, -1.0),
], ids=["arrays", "scalar-right", "scalar-left", "ints", "broadcast-scalar", "broadcast-2d",
        "two-python-scalars"])
def test_where_equals_jnp_where_in_value_shape_and_dtype(x, y):
    expected = jnp.where(MASK, x, y)
    got = where(MASK, x, y)
    assert got.dtype == expected.dtype and got.shape == expected.shape
    assert got.weak_type == expected.weak_type
    np.testing.assert_array_equal(got, expected)


def test_where_rejects_mixed_float_dtypes_as_jnp_where_does():
    # conftest.py sets strict promotion: neither select may widen float32 to float64.
    with pytest.raises(jax.dtypes.TypePromotionError):
        jnp.where(MASK, F32, jnp.zeros(3, jnp.float64))
    with pytest.raises(jax.dtypes.TypePromotionError):
        where(MASK, F32, jnp.zeros(3, jnp.float64))


def _nested_jits(jaxpr) -> collections.Counter:
    """Names of the jits that the traced code calls (loop bodies and custom derivatives
    included; not the jits inside jnp's own jitted functions)."""
    names = collections.Counter()
    for eqn in jaxpr.eqns:
        if eqn.primitive.name in ("jit", "pjit"):
            names[eqn.params["name"]] += 1
            continue
        for param in eqn.params.values():
            for sub in param if isinstance(param, (tuple, list)) else (param,):
                inner = getattr(sub, "jaxpr", None)
                if inner is not None:
                    names += _nested_jits(getattr(inner, "jaxpr", inner))
    return names


def test_a_query_under_vmap_and_grad_traces_no_nested_selects_or_query_jits():
    """Each nested jit is traced again by vmap and by grad: jnp.where's (about 800 per distance
    query) and the query's own eager-call jit must not reach a user's trace."""
    a, b = jaxsat.box([1.0, 2.0, 3.0]), jaxsat.box([0.5, 0.5, 0.5])
    pose_a = jaxsat.pose3(jnp.zeros(3), jnp.array([1.0, 0.0, 0.0, 0.0]))

    def value(translation, smoothing):
        pose_b = jaxsat.pose3(translation, jnp.array([0.9, 0.1, 0.2, 0.3]))
        return jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=smoothing)

    for smoothing in (None, 0.01):
        closed = jax.make_jaxpr(jax.vmap(jax.value_and_grad(
            lambda t, s=smoothing: value(t, s))))(jnp.ones((4, 3)))
        names = _nested_jits(closed.jaxpr)
        assert "_where" not in names and "signed_distance" not in names, names


def _expensive_then_four_consumers(x, store):
    y = x
    for _ in range(12):
        y = jnp.sin(y) * 1.0001 + y * y * 0.5
    y = store(y)
    return y + 1, y * 2, y - 3, jnp.cos(y)


@pytest.mark.parametrize("batched", [False, True], ids=["unbatched", "batched"])
def test_materialize_computes_its_value_once(batched):
    """With `materialize`, the 12 sines before it are compiled once, not copied into each of
    the four consumers."""
    function = lambda x: _expensive_then_four_consumers(x, materialize)  # noqa: E731
    x = jnp.ones((), jnp.float32)
    if batched:
        function, x = jax.vmap(function), jnp.ones((64,), jnp.float32)
    sines = jax.jit(function).lower(x).compile().as_text().count(" sine(")
    assert sines == 12, sines


def test_without_materialize_the_producer_is_copied_into_each_consumer():
    """The copies `materialize` prevents, so that the test above can fail."""
    compiled = jax.jit(lambda x: _expensive_then_four_consumers(x, lambda y: y))
    assert compiled.lower(jnp.ones((), jnp.float32)).compile().as_text().count(" sine(") > 12


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_materialize_is_exact_for_every_float(dtype):
    values = np.array([-0.0, 0.0, 1.5, -np.inf, np.inf, np.nan,
                       np.finfo(dtype).tiny, -np.finfo(dtype).max], dtype)
    stored = np.asarray(jax.jit(materialize)(jnp.asarray(values)))
    np.testing.assert_array_equal(stored, values)  # NaN == NaN here
    np.testing.assert_array_equal(np.signbit(stored), np.signbit(values))


def test_materialize_keeps_integers_and_booleans():
    ints = jnp.array([np.iinfo(np.int32).min, -1, 0, 5], jnp.int32)
    flags = jnp.array([True, False])
    stored_ints, stored_flags = jax.jit(materialize)((ints, flags))
    assert stored_ints.dtype == jnp.int32 and stored_flags.dtype == jnp.bool_
    np.testing.assert_array_equal(stored_ints, ints)
    np.testing.assert_array_equal(stored_flags, flags)
