"""The kernel layer's rules that XLA could silently undo (jaxsat/_kernels.py, its docstring):
`where` is jnp.where's select without a nested jit, and so are the component-form sums and
products, and `materialize` stores a value once, in an unbatched program (an eager call) as
well as in a batched one. And its segment helper against the oracle's closest points of two
segments."""

from __future__ import annotations

import collections
import re

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from harness import FAST_COMPILE, inner_jaxprs, make_pose, pool, random_pairs

import jaxsat
from jaxsat import _compound, _contacts, _queries
from jaxsat import _kernels as kernels
from jaxsat._contacts import _closest_midpoint
from jaxsat._kernels import materialize, segment_closest_parameters, where
from jaxsat._pair import EAGER_COMPILER_OPTIONS, eager_compiler_options

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
    # conftest.py sets strict promotion: neither select may widen float32 to float64. (JAX's
    # TypePromotionError, a ValueError, is public as jax.dtypes.TypePromotionError only from
    # jax 0.10.1; the floor check runs this test on older versions.)
    with pytest.raises(ValueError, match="implicit dtype promotion"):
        jnp.where(MASK, F32, jnp.zeros(3, jnp.float64))
    with pytest.raises(ValueError, match="implicit dtype promotion"):
        where(MASK, F32, jnp.zeros(3, jnp.float64))


ARITHMETIC_OPERANDS = [
    (F32, 2.0 * F32),
    (F32, 0.5),
    (3, F32),
    (I32, 7),
    (F32[0], F32),
    (F32[0], F32[1]),
    (jnp.asarray(2.0), jnp.asarray(3.0)),
    (jnp.asarray(2.0), jnp.ones((), jnp.float64)),
    (jnp.ones((2, 1), jnp.float64), jnp.zeros((3,), jnp.float64)),
    (1.0, -1.0),
]
ARITHMETIC_IDS = ["arrays", "scalar-right", "int-left", "ints", "broadcast-scalar", "scalars",
                  "weak-scalars", "weak-and-strong", "broadcast-2d", "two-python-scalars"]


@pytest.mark.parametrize(("x", "y"), ARITHMETIC_OPERANDS, ids=ARITHMETIC_IDS)
@pytest.mark.parametrize(("helper", "operator"), [
    (kernels.add, lambda x, y: x + y), (kernels.sub, lambda x, y: x - y),
    (kernels.mul, lambda x, y: x * y)], ids=["add", "sub", "mul"])
def test_arithmetic_helpers_equal_the_operators_in_value_shape_and_dtype(helper, operator, x,
                                                                          y):
    expected, got = operator(x, y), helper(x, y)
    assert jnp.shape(got) == jnp.shape(expected)
    assert jnp.result_type(got) == jnp.result_type(expected)
    assert getattr(got, "weak_type", True) == getattr(expected, "weak_type", True)
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize(("x", "y"), ARITHMETIC_OPERANDS, ids=ARITHMETIC_IDS)
def test_total_adds_left_to_right_as_the_operators_do(x, y):
    np.testing.assert_array_equal(kernels.total([x, y, x]), x + y + x)


def test_arithmetic_helpers_reject_mixed_float_dtypes_as_the_operators_do():
    for helper in (kernels.add, kernels.sub, kernels.mul):
        with pytest.raises(ValueError, match="implicit dtype promotion"):
            helper(F32, jnp.zeros(3, jnp.float64))
    with pytest.raises(ValueError, match="at least one term"):
        kernels.total([])


def test_component_form_helpers_trace_no_nested_jit(monkeypatch):
    """Each `+`, `-` or `*` on traced arrays is jnp's jitted ufunc, a nested jit traced again
    under `vmap` and `grad` (a smooth box distance's value and gradient made 7,429 of them,
    most in these helpers; the nested jits are inlined, so the jaxpr does not show them)."""
    from jax._src import pjit
    calls, counting = collections.Counter(), [False]
    infer_params = pjit._infer_params

    def counted(fun, *args, **kwargs):
        if counting[0]:
            calls[getattr(fun, "__name__", str(fun))] += 1
        return infer_params(fun, *args, **kwargs)

    def helpers(x, y, rotation):
        counting[0] = True
        u, v = kernels.as_vec(x), kernels.as_vec(y)
        rows = kernels.as_vecs(rotation)
        outputs = (kernels.vadd(u, v), kernels.vsub(u, v), kernels.vscale(u[0], v),
                   kernels.vdot(u, v), kernels.vcross(u, v), kernels.vcross2(u[:2], v[:2]),
                   kernels.vrotate(rows, u), kernels.vrotate_back(rows, u),
                   kernels.vsum([u, v, u]), kernels.total([u[0], v[1], u[2]]),
                   kernels.dot(x, y))
        counting[0] = False
        return sum(jnp.sum(leaf) for leaf in jax.tree.leaves(outputs))

    x, y = jnp.array([1.0, 2.0, 3.0]), jnp.array([0.5, -1.0, 2.0])
    rotation = jnp.eye(3)
    monkeypatch.setattr(pjit, "_infer_params", counted)
    jax.make_jaxpr(jax.vmap(jax.grad(helpers, argnums=(0, 1, 2))))(
        *(jnp.stack([value] * 2) for value in (x, y, rotation)))
    nested = {name: n for name, n in calls.items()
              if name in ("multiply", "add", "subtract", "true_divide")}
    assert not nested, nested


def _nested_jits(jaxpr) -> collections.Counter:
    """Names of the jits that the traced code calls (loop bodies and custom derivatives
    included; not the jits inside jnp's own jitted functions)."""
    names = collections.Counter()
    for eqn in jaxpr.eqns:
        if eqn.primitive.name in ("jit", "pjit"):
            names[eqn.params["name"]] += 1
            continue
        for inner in inner_jaxprs(eqn):
            names += _nested_jits(inner)
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


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the copies are XLA CPU's fusion "
                    "choice; XLA GPU computes the sines once without it (H100, jax 0.11.2)")
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


def test_materialize_has_the_identity_derivative_and_adds_no_operations_to_it():
    """Forward and reverse derivatives pass through unchanged, and the tangent takes no
    operation of its own (JAX differentiates the window maximum with a window pass,
    select_and_gather_add, per stored leaf in every linearised program)."""
    x = jnp.array([0.5, -2.0, 3.0], jnp.float32)
    tangent = jnp.array([1.0, 2.0, -1.0], jnp.float32)
    value, moved = jax.jvp(materialize, (x,), (tangent,))
    np.testing.assert_array_equal(value, x)
    np.testing.assert_array_equal(moved, tangent)
    gradient = jax.grad(lambda v: jnp.sum(materialize(v) * jnp.arange(3.0, dtype=v.dtype)))(x)
    np.testing.assert_array_equal(gradient, [0.0, 1.0, 2.0])
    linear = jax.linearize(materialize, x)[1]
    assert len(jax.make_jaxpr(linear)(tangent).eqns) <= 1


def _segment_cases(rng) -> list[tuple[str, np.ndarray]]:
    """(name, (4, 3) array a0, a1, b0, b1): random, crossing, nearly parallel (apart, and
    crossing at a small angle), parallel, point and segment, two points."""
    cases = [(f"random-{i}", rng.normal(size=(4, 3))) for i in range(200)]
    for i in range(200):
        a0, direction = rng.normal(size=3), rng.normal(size=3)
        tilt = rng.normal(size=3) * 10.0 ** rng.uniform(-7, -3)
        b0 = a0 + rng.normal(size=3) * 0.3
        cases.append((f"near-parallel-{i}", np.stack(
            [a0, a0 + direction, b0, b0 + rng.uniform(0.3, 2.0) * (direction + tilt)])))
    for i in range(200):  # crossing at one point, 1e-7 to 1e-1 radians apart
        angle = 10.0 ** rng.uniform(-7, -1)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        across = np.cross(direction, rng.normal(size=3))
        turned = np.cos(angle) * direction + np.sin(angle) * across / np.linalg.norm(across)
        crossing, (u, v) = rng.normal(size=3), rng.uniform(0.2, 0.8, 2)
        cases.append((f"nearly-parallel-crossing-{i}", np.stack(
            [crossing - u * direction, crossing + (1 - u) * direction, crossing - v * turned,
             crossing + (1 - v) * turned])))
    cases += [
        ("parallel-overlapping", np.array([[0, 0, 0], [2, 0, 0], [1, 1, 0], [3, 1, 0.0]])),
        ("crossing", np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 1], [0, 1, 1.0]])),
        ("segment-and-point", np.array([[0, 0, 0], [2, 0, 0], [1.5, 1, 0], [1.5, 1, 0.0]])),
        ("point-and-segment", np.array([[1.5, 1, 0], [1.5, 1, 0], [0, 0, 0], [2, 0, 0.0]])),
        ("two-points", np.array([[0, 0, 0], [0, 0, 0], [1, 2, 2], [1, 2, 2.0]])),
    ]
    return cases


@jax.jit
@jax.vmap
def _parameters(points):
    """segment_closest_parameters of (4, D) points a0, a1, b0, b1, batched."""
    a0, a1, b0, b1 = points
    return segment_closest_parameters(tuple(a0 - b0), tuple(a1 - a0), tuple(b1 - b0))


def test_segment_closest_parameters_minimise_the_distance():
    """The parameters' distance equals the enumerated minimum within 1e-12 of the segments'
    size in float64 and 1e-6 in float32, and a segment that is a point keeps parameter 0.
    Nearly parallel pairs are where a rule that clamps the stationary point and walks to an
    edge goes wrong, and where a stationary point from aa bb - ab^2 loses its digits."""
    names, cases = zip(*_segment_cases(np.random.default_rng(5)), strict=True)
    for dtype, tolerance in ((np.float64, 1e-12), (np.float32, 1e-6)):
        points = np.stack(cases).astype(dtype)
        s, t, crossing = (np.asarray(x, np.float64) for x in _parameters(jnp.asarray(points)))
        points = points.astype(np.float64)
        for i, name in enumerate(names):
            a0, a1, b0, b1 = points[i]
            assert 0.0 <= s[i] <= 1.0 and 0.0 <= t[i] <= 1.0, name
            got = np.linalg.norm(a0 + s[i] * (a1 - a0) - b0 - t[i] * (b1 - b0))
            size = np.abs(points[i]).max()
            assert got <= oracle.segment_distance(*points[i]) + tolerance * size, (name, dtype)
        point_case = names.index("segment-and-point")
        assert (s[point_case], t[point_case], crossing[point_case]) == (0.75, 0.0, 0.0)
    midpoint = _closest_midpoint(*(jnp.asarray(p, jnp.float64) for p in
                                   [[0, 0, 0], [2, 0, 0], [1.5, 1, 0], [1.5, 1, 0]]))
    np.testing.assert_allclose(midpoint, [1.5, 0.5, 0.0], atol=1e-15)


def test_segment_closest_parameters_have_finite_gradients_at_any_scale():
    """float32 segments of size 1e-6 and 1e3, crossing, parallel and degenerate: finite
    gradients of the closest points' midpoint (the products are scale-free before they are
    divided)."""
    gradient = jax.jit(jax.vmap(jax.grad(
        lambda p: jnp.sum(_closest_midpoint(p[0], p[1], p[2], p[3])))))
    cases = np.stack([points for _, points in _segment_cases(np.random.default_rng(6))[-5:]])
    for scale in (1e-6, 1.0, 1e3):
        found = np.asarray(gradient(jnp.asarray(cases * scale, jnp.float32)))
        assert np.all(np.isfinite(found)), scale


def test_eager_calls_take_the_cpu_options_only_on_the_cpu():
    """XLA's GPU compiler rejects the CPU option names (`No such compile option`), which made
    every eager query fail on an H100."""
    assert eager_compiler_options("cpu") == EAGER_COMPILER_OPTIONS
    assert eager_compiler_options("gpu") is None and eager_compiler_options("tpu") is None


def _compiled_queries() -> dict:
    """Every function `compiled_query` made, by name (signed_distance has two: exact, smooth)."""
    found = {}
    for module in (_queries, _contacts, _compound):
        for name, value in vars(module).items():
            if hasattr(value, "eager_function"):
                found[name] = value
    return found


def test_every_public_pair_query_is_a_compiled_query():
    """So that the test below covers them all."""
    names = set(_compiled_queries())
    assert {"intersects", "penetration", "closest_points", "contacts", "compound_intersects",
            "compound_penetration", "_exact_signed_distance", "_smooth_signed_distance"} <= names


@pytest.mark.parametrize("name", sorted(_compiled_queries()))
def test_an_eager_call_jits_a_program_without_effects(name):
    """A jitted program with an effect (checkify's `debug_check` leaves one) runs every call
    through jit's Python path: 0.3 ms a call for a box pair instead of 0.05. The checks that
    name a non-finite argument belong to traced calls only (`test_non_finite.py`)."""
    query = _compiled_queries()[name]
    a = jaxsat.box([1.0, 0.5, 0.25])
    if "compound" in name:
        a = jaxsat.compound([a, jaxsat.polyhedron(np.asarray(a.vertices) + 1.0)])
    identity = jnp.array([1.0, 0.0, 0.0, 0.0])
    arguments = (a, jaxsat.pose3(jnp.zeros(3), identity), a,
                 jaxsat.pose3(jnp.array([0.5, 0.2, 0.1]), identity))
    if "smooth" in name:
        arguments += (0.01,)
    eager = jax.make_jaxpr(query.eager_function)(*arguments)
    traced = jax.make_jaxpr(query)(*arguments)
    assert not eager.effects, eager.effects
    assert traced.effects  # the named checks are there when traced, so the test can fail


_BACKEND_COMPILES: list = []
"""Programs XLA compiled while `_backend_compiles` listens (one entry each)."""
_LISTENING: list = []


def _record_compile(name: str, seconds: float, **_) -> None:
    if _LISTENING and name == "/jax/core/compile/backend_compile_duration":
        _BACKEND_COMPILES.append(seconds)


jax.monitoring.register_event_duration_secs_listener(_record_compile)


def _backend_compiles(call) -> tuple[object, int]:
    """(call()'s result, blocked on, and how many programs XLA compiled meanwhile)."""
    _BACKEND_COMPILES.clear()
    _LISTENING.append(True)
    try:
        result = jax.block_until_ready(call())
    finally:
        _LISTENING.clear()
    return result, len(_BACKEND_COMPILES)


@pytest.mark.parametrize("smoothing", [None, 0.01], ids=["exact", "smooth"])
def test_an_eager_grad_or_vmap_of_a_query_runs_one_compiled_query(smoothing):
    """Outside any jit, grad and vmap run their primitives one at a time. A query traced into
    them that way compiled each primitive on its own (63 programs for an exact box distance's
    first gradient, 140 smooth) and the smooth one recompiled its search on every call (4.4 s
    a warm gradient on a 2-core AMD EPYC). Through the query's jit: a few programs once, none
    on a warm call. The results are checked against eager values, which compile the value
    once: the gradient against their central differences (float64), the vmap against them
    pair by pair."""
    a, b = jaxsat.box([1.0, 0.5, 0.3]), jaxsat.box([0.4, 0.6, 0.2])
    pose_a = jaxsat.pose3(jnp.zeros(3), jnp.array([1.0, 0.0, 0.0, 0.0]))
    turn = jaxsat.pose3(jnp.zeros(3), jnp.array([0.9, 0.1, 0.2, 0.3])).rotation

    def value(translation):  # nothing but the query runs primitives
        return jaxsat.signed_distance(a, pose_a, b, jaxsat.Pose(translation, turn),
                                      smoothing=smoothing)

    gradient = jax.grad(value)
    _, first = _backend_compiles(lambda: gradient(jnp.array([0.8, 0.2, 0.1])))
    found, warm = _backend_compiles(lambda: gradient(jnp.array([0.9, 0.2, 0.1])))
    assert first <= 4 and warm == 0, (first, warm)
    assert found.dtype == np.float64
    at, step = np.array([0.9, 0.2, 0.1]), 1e-6
    differences = [(float(value(jnp.asarray(at + step * e))) - float(value(jnp.asarray(
        at - step * e)))) / (2 * step) for e in np.eye(3)]
    np.testing.assert_allclose(found, differences, rtol=1e-6, atol=1e-8)
    assert abs(float(jnp.linalg.norm(found)) - 1.0) < 1e-6  # |d sd / d t_b| = 1
    translations = jnp.array([[0.9, 0.2, 0.1], [0.3, -0.4, 0.2], [1.5, 0.0, 0.0]])
    batched, compiles = _backend_compiles(lambda: jax.vmap(value)(translations))
    assert compiles <= 1, compiles
    np.testing.assert_allclose(batched, [value(t) for t in translations], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("smoothing", [None, 0.01], ids=["exact", "smooth"])
def test_a_query_of_closed_over_arguments_inside_a_jit_is_traced_into_it(smoothing):
    """Inside a user's jit a query whose arguments are all concrete (closed over, no tracer)
    is traced in too: it took the eager call's jit, whose compiler options JAX refuses on a
    nested jit (ValueError). The user's jit here has compiler options of its own
    (`FAST_COMPILE`, the cheaper build), which the query's would meet as it did the
    defaults."""
    a, b = jaxsat.box([1.0, 0.5, 0.3]), jaxsat.box([0.4, 0.6, 0.2])
    pose_a = jaxsat.pose3(jnp.zeros(3), jnp.array([1.0, 0.0, 0.0, 0.0]))
    pose_b = jaxsat.pose3(jnp.array([0.8, 0.2, 0.1]), jnp.array([0.9, 0.1, 0.2, 0.3]))
    eager = jaxsat.signed_distance(a, pose_a, b, pose_b, smoothing=smoothing)
    inside = jax.jit(lambda scale: scale * jaxsat.signed_distance(a, pose_a, b, pose_b,
                                                                  smoothing=smoothing),
                     compiler_options=FAST_COMPILE)
    np.testing.assert_allclose(inside(jnp.ones((), eager.dtype)), eager, rtol=1e-6)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_support_gap_and_largest_magnitude_equal_numpy_without_a_reduction(dtype):
    """Select chains over the vertices (rule 2): the values of NumPy's reductions, and no
    reduce op in their batched programs (a `jnp.min` over the vertex axis is a pass of its
    own, which cost an exact 2D distance about as much as its SAT)."""
    from jaxsat._closest import support_gap
    from jaxsat._kernels import largest_magnitude

    rng = np.random.default_rng(7)
    a, b = (rng.normal(size=(64, 8, 3)).astype(dtype) for _ in range(2))
    axis = rng.normal(size=(64, 3)).astype(dtype)
    gaps = np.einsum("nvd,nd->nv", b, axis).min(axis=1) - np.einsum(
        "nvd,nd->nv", a, axis).max(axis=1)
    np.testing.assert_allclose(jax.vmap(support_gap)(axis, a, b), gaps,
                               rtol=8 * np.finfo(dtype).eps, atol=8 * np.finfo(dtype).eps)
    assert "reduce" not in jax.jit(jax.vmap(support_gap)).lower(axis, a, b).as_text()
    np.testing.assert_array_equal(jax.vmap(largest_magnitude)(a), np.abs(a).max(axis=(1, 2)))
    assert "reduce" not in jax.jit(jax.vmap(largest_magnitude)).lower(a).as_text()


def test_gjk_loop_reads_the_vertices_as_columns():
    """Rule 8: every array a loop reads from outside is computed by a kernel of its own before
    it. GJK's loop takes each hull's D coordinate columns, not V x D coordinates (120 kernels
    for two 20-vertex hulls, 0.85 s of LLVM time in a hull distance's compile)."""
    from jaxsat._gjk import closest_point_gjk

    rng = np.random.default_rng(3)
    a, b = (jnp.asarray(rng.normal(size=(4, 20, 3)), jnp.float32) for _ in range(2))
    direction = jnp.ones((4, 3), jnp.float32)
    closed = jax.make_jaxpr(jax.vmap(
        lambda a, b, u: closest_point_gjk(a, b + 3.0, u, 1e-6, 8)))(a, b, direction)
    loops = [eqn for eqn in closed.jaxpr.eqns if eqn.primitive.name == "while"]
    assert len(loops) == 1
    captured = loops[0].invars[:loops[0].params["body_nconsts"]]
    assert len(captured) <= 2 * 3, [var.aval for var in captured]


@pytest.mark.slow
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="XLA CPU's fusion choice")
def test_exact_distance_gradient_compares_each_witness_index_in_one_pass():
    """The witness points p and q, in their shapes' frames, are stored once
    (`_closest.signed_distance_of_witnesses`): without it, XLA CPU gave each comparison of a
    stored witness index with a vertex number a pass of its own in the batched value and
    gradient (30 passes that output one bool a pair, for box pairs; 78 for 20-vertex hulls)."""
    shapes = pool("box", np.float32)
    pairs = random_pairs(shapes, shapes, 16, np.random.default_rng(8), np.float32)

    def value_and_gradients(a, params_a, b, params_b):
        def value(pa, pb):
            return jaxsat.signed_distance(a, make_pose(pa), b, make_pose(pb))
        return jax.value_and_grad(value, argnums=(0, 1))(params_a, params_b)

    text = jax.jit(jax.vmap(value_and_gradients)).lower(*pairs.inputs()).compile().as_text()
    bools_per_pair = re.findall(r"(?m)^\s*(?:ROOT )?%\S+ = pred\[16(?:,1)?\]\S* fusion\(", text)
    assert len(bools_per_pair) <= 4, len(bools_per_pair)


@pytest.mark.parametrize("dim", [2, 3])
def test_relative_pose_gradient_has_no_reduction(dim):
    """The pair frame's rotation R_a^T R_b is written entry by entry
    (`_kernels.transposed_product`): outer products would broadcast, and the gradient of every
    query would reduce each broadcast back in a pass of its own (a 2D exact distance's value
    and gradient took 1.1-1.2x as long)."""
    from jaxsat._pair import relative_pose

    rng = np.random.default_rng(5)
    draw = lambda *shape: jnp.asarray(rng.normal(size=(16, *shape)), jnp.float32)  # noqa: E731
    poses = [jax.vmap(jaxsat.pose2)(draw(), draw(), draw()) if dim == 2 else
             jax.vmap(jaxsat.pose3)(draw(3), draw(4)) for _ in range(2)]

    def total(pose_a, pose_b):
        rotation, translation = relative_pose(pose_a, pose_b)
        return jnp.sum(rotation * jnp.arange(dim * dim, dtype=jnp.float32).reshape(dim, dim)) \
            + jnp.sum(translation)

    gradient = jax.vmap(jax.grad(total, argnums=(0, 1)))
    # In the compiled program: jax 0.6.0 lowers the transpose of an unstack to reductions
    # over axes of length 1, which XLA removes (outer products leave 6 reductions).
    text = jax.jit(gradient).lower(*poses).compile().as_text()
    assert " reduce(" not in text
    # and the value is R_a^T R_b
    rotation = jax.vmap(relative_pose)(*poses)[0]
    expected = np.einsum("nki,nkj->nij", np.asarray(poses[0].rotation, np.float64),
                         np.asarray(poses[1].rotation, np.float64))
    np.testing.assert_allclose(rotation, expected, atol=1e-6)


@pytest.mark.slow
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="XLA CPU's fusion choice")
def test_box_penetration_gradient_builds_no_pass_from_the_whole_cotangent_graph():
    """`store_cotangent` in the box kernel: the gradient of box `penetration` reads the stored
    cotangents of the rotation's entries and of the axes. Without them XLA fused the whole
    cotangent graph into the two passes that write the poses' 3 x 3 rotation gradients (about
    600 lines of fused HLO each, evaluated once per entry: 101 ms against 1.6 ms on 1e4
    pairs); with them those passes hold 96 and 155 lines."""
    shapes = pool("box", np.float32)
    pairs = random_pairs(shapes, shapes, 16, np.random.default_rng(9), np.float32)
    a, params_a, b, params_b = pairs.inputs()
    poses = jax.vmap(make_pose)(params_a), jax.vmap(make_pose)(params_b)

    def depth(a, pose_a, b, pose_b):
        return jaxsat.penetration(a, pose_a, b, pose_b).depth

    text = jax.jit(jax.vmap(jax.grad(depth, argnums=(1, 3)))).lower(
        a, poses[0], b, poses[1]).compile().as_text()
    lines = {name: body.count("\n") for name, body in re.findall(
        r"\n%(fused_computation[\w.\-]*) [^\n]*\{(.*?)\n\}", text, re.S)}
    rotation_passes = [lines[called] for called in re.findall(
        r"(?m)^\s*(?:ROOT )?%\S+ = f32\[16,3,3\]\S* fusion\([^\n]*calls=%([\w.\-]+)", text)
        if called in lines]  # not the copies XLA wraps as fusions
    assert len(rotation_passes) == 2 and max(rotation_passes) < 300, rotation_passes
