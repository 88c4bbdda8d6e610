"""Generic properties of every public pair query, run once over every query x size class x
dtype (`harness.every_query_class_dtype`):

* values, and gradients with respect to both poses' parameters, are finite on random pairs and
  on the catalogue of degenerate configurations;
* every float output has the input dtype;
* a jitted vmap equals the query called eagerly, pair by pair (vmap = loop, jit = eager);
* swapping a and b keeps the depth or distance and flips the normal (where the oracle's
  normal is unique);
* moving both shapes by one rigid motion keeps depths and distances, rotates normals and moves
  points.

The size classes are the polytope ones, spheres and capsules stacked alone, spheres, capsules,
rounded and sharp boxes stacked together (in 2D circles, capsules, rounded and sharp
polygons), and half-spaces against boxes (`harness.PROPERTY_CLASSES`). Comparisons use
tolerances relative to the pair's size from the independent oracle (`oracle.py`: the cores'
Minkowski difference, or closest points for two points or segments, minus the radii; the
lowest vertex's height for a half-space). Each (query, size class, dtype) compiles one
jitted function, shared by every property: value and pose gradients of a batch of
`harness.BATCH` pairs, compiled with `harness.FAST_COMPILE`.
"""

from __future__ import annotations

import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from harness import (
    BATCH,
    FAST_COMPILE,
    NORMAL_TOLERANCE,
    QUERIES,
    RELATIVE_TOLERANCE,
    Pairs,
    catalogue_pairs,
    every_query_class_dtype,
    make_pose,
    pools,
    random_motion,
    random_pairs,
    references,
    rotation_matrices,
    run_batched,
    take,
)

import jaxsat

DIFFERENTIABLE = {name for name in QUERIES if name != "intersects"}
"""Queries with float outputs, whose pose gradients are checked."""

SMOOTH_TOLERANCE = {np.float64: 1e-7, np.float32: 2e-4}
"""The smooth distance stops its search at a relative tolerance above rounding: symmetric and
invariant within this (relative to the pair's size)."""


# --------------------------------------------------------------------------------------------
# One compiled function per (query, size class, dtype), and the parts properties compare.
# --------------------------------------------------------------------------------------------


def _float_sum(tree) -> jax.Array:
    return sum(jnp.sum(leaf) for leaf in jax.tree.leaves(tree)
               if jnp.issubdtype(leaf.dtype, jnp.floating))


@functools.cache
def batched(name: str):
    """jit(vmap(...)) of (output, pose-parameter gradients of its float leaves' sum)."""
    query = QUERIES[name]

    def one(a, params_a, b, params_b):
        def run(pa, pb):
            out = query(a, make_pose(pa), b, make_pose(pb))
            return _float_sum(out), out

        if name not in DIFFERENTIABLE:
            return run(params_a, params_b)[1], None
        (_, out), grads = jax.value_and_grad(run, argnums=(0, 1), has_aux=True)(params_a,
                                                                                  params_b)
        return out, grads

    return jax.jit(jax.vmap(one), compiler_options=FAST_COMPILE)


@pytest.fixture(autouse=True, scope="module")
def _release_a_finished_combinations_programs(query, size_class, dtype):
    """Drop the programs `batched` compiled for a (query, size class, dtype) combination once its
    tests are done: they run combination by combination (`every_query_class_dtype`, whose
    module-scoped parameters set this fixture up and tear it down once per combination), and no
    later test needs them. This file alone in one process peaked at 3.6 GiB with them all kept,
    1.9 GiB with this, in the same time (283 and 285 s); dropping every compiled program
    (`jax.clear_caches`) took it to 0.6 GiB but 310 s, by compiling the small eager programs
    again."""
    yield
    batched(query).clear_cache()


def evaluate(name: str, pairs: Pairs):
    return run_batched(batched(name), len(pairs), *pairs.inputs())


def scalar(name: str, out) -> np.ndarray:
    """The frame-free number of each output: overlap, depth or signed distance (contacts: the
    deepest valid contact's depth, -inf without contact)."""
    if name == "intersects":
        return np.asarray(out)
    if name == "penetration":
        return out.depth
    if name == "closest_points":
        return out.signed_distance
    if name == "contacts":
        return np.max(np.where(out.valid, out.depths, -np.inf), axis=-1)
    return out


def normal(name: str, out):
    return out.normal if name in ("penetration", "closest_points", "contacts") else None


def random_and_catalogue_pairs(size_class: str, dtype, seed: int) -> Pairs:
    """BATCH random pairs of the size class, then every catalogue configuration of it."""
    random = random_pairs(*pools(size_class, dtype), BATCH, np.random.default_rng(seed), dtype)
    return random.concatenate(catalogue_pairs(size_class, dtype))


def tolerance(name: str, dtype) -> float:
    return SMOOTH_TOLERANCE[dtype] if name == "smooth_signed_distance" else \
        RELATIVE_TOLERANCE[dtype]


# --------------------------------------------------------------------------------------------
# The properties.
# --------------------------------------------------------------------------------------------


@every_query_class_dtype
def test_finite_values_and_gradients_on_random_and_degenerate_pairs(query, size_class, dtype):
    pairs = random_and_catalogue_pairs(size_class, dtype, seed=1)
    out, grads = evaluate(query, pairs)
    chex.assert_tree_all_finite(jax.tree.map(
        lambda leaf: leaf if np.issubdtype(leaf.dtype, np.floating) else np.zeros(1), out))
    if query in DIFFERENTIABLE:
        chex.assert_tree_all_finite(grads)


@every_query_class_dtype
def test_float_outputs_follow_the_input_dtype(query, size_class, dtype):
    pairs = random_pairs(*pools(size_class, dtype), 4,
                         np.random.default_rng(2), dtype)
    out, grads = evaluate(query, pairs)
    floats = [leaf for leaf in jax.tree.leaves((out, grads))
              if np.issubdtype(leaf.dtype, np.floating)]
    assert floats or query == "intersects"
    assert all(leaf.dtype == dtype for leaf in floats), [leaf.dtype for leaf in floats]


@pytest.mark.slow  # each eager call compiles its query (0.2-4 s)
@every_query_class_dtype
def test_jitted_vmap_equals_eager_calls_pair_by_pair(query, size_class, dtype):
    pairs = random_pairs(*pools(size_class, dtype), 2,
                         np.random.default_rng(3), dtype)
    batched_out, _ = evaluate(query, pairs)
    sizes = np.array([r.size for r in references(pairs)])
    a, params_a, b, params_b = pairs.inputs()
    for i in range(len(pairs)):
        eager = QUERIES[query](take(a, i), make_pose(take(params_a, i)), take(b, i),
                               make_pose(take(params_b, i)))
        chex.assert_trees_all_equal_dtypes(eager, take(batched_out, i))
        chex.assert_trees_all_close(jax.tree.map(np.asarray, eager), take(batched_out, i),
                                    atol=tolerance(query, dtype) * sizes[i])


@every_query_class_dtype
def test_swapping_the_shapes_keeps_the_value_and_flips_the_normal(query, size_class, dtype):
    pairs = random_pairs(*pools(size_class, dtype), BATCH,
                         np.random.default_rng(4), dtype)
    refs = references(pairs)
    sizes = np.array([r.size for r in refs])
    out, _ = evaluate(query, pairs)
    swapped, _ = evaluate(query, pairs.swapped())
    value, value_swapped = scalar(query, out), scalar(query, swapped)
    decided = np.array([abs(r.value) > 10 * RELATIVE_TOLERANCE[dtype] * r.size for r in refs])
    assert decided.mean() > 0.9
    if query in ("intersects", "contacts"):  # overlap (or contact) or not
        np.testing.assert_array_equal(value_swapped[decided] > -np.inf if query == "contacts"
                                      else value_swapped[decided],
                                      value[decided] > -np.inf if query == "contacts"
                                      else value[decided])
    else:
        np.testing.assert_array_less(np.abs(value_swapped - value),
                                     tolerance(query, dtype) * sizes)
    if normal(query, out) is None:
        return
    overlapping = np.array([r.depth > 0 for r in refs])
    unique = (np.array([r.normal_is_unique for r in refs]) | ~overlapping) & decided
    if query == "contacts":  # contacts report a normal only for pairs in contact
        unique &= np.isfinite(value) & overlapping
    np.testing.assert_allclose(normal(query, swapped)[unique], -normal(query, out)[unique],
                               atol=NORMAL_TOLERANCE[dtype])


@every_query_class_dtype
def test_a_common_rigid_motion_moves_points_and_normals_and_keeps_values(query, size_class,
                                                                        dtype):
    rng = np.random.default_rng(5)
    pairs = random_pairs(*pools(size_class, dtype), BATCH, rng, dtype)
    refs = references(pairs)
    sizes = np.array([r.size for r in refs])
    motion = tuple(m[0] for m in random_motion(pairs.dim, 1, rng))
    rotation = rotation_matrices(pairs.dim, motion[0][None])[0]
    out, _ = evaluate(query, pairs)
    after, _ = evaluate(query, pairs.moved(motion))
    tol = tolerance(query, dtype) * sizes
    value, value_after = scalar(query, out), scalar(query, after)
    decided = np.array([abs(r.value) > 10 * RELATIVE_TOLERANCE[dtype] * r.size for r in refs])
    if value.dtype == bool:
        np.testing.assert_array_equal(value_after[decided], value[decided])
        return
    finite = np.isfinite(value) & decided
    np.testing.assert_array_equal(np.isfinite(value_after) & decided, finite)
    np.testing.assert_array_less(np.abs(value_after[finite] - value[finite]), tol[finite])
    if normal(query, out) is None:
        return
    unique = np.array([r.normal_is_unique or r.depth <= 0 for r in refs]) & finite
    np.testing.assert_allclose(normal(query, after)[unique],
                               normal(query, out)[unique] @ rotation.T,
                               atol=NORMAL_TOLERANCE[dtype])
    shift = motion[1]
    if query == "closest_points":
        # Where the closest features are parallel (an edge along a face, say) the witness
        # points are not unique even when the normal is, and the search may pick another
        # pair after the motion: each pair, moved back, must lie on the two shapes.
        moved_back = {"point_a": (after.point_a - shift) @ rotation,
                      "point_b": (after.point_b - shift) @ rotation}
        for i in np.nonzero(finite)[0]:
            for side, field in enumerate(("point_a", "point_b")):
                for name, points in (("before", getattr(out, field)), ("after", moved_back[field])):
                    gap = refs[i].surface_gap(side, points[i])
                    assert gap < 10 * tol[i], (name, i, field, gap)
    if query == "contacts":  # the same set of points (the order of ties may change)
        expected = out.points @ rotation.T + shift
        for i in np.nonzero(unique)[0]:
            assert after.valid[i].sum() == out.valid[i].sum(), i
            gaps = np.linalg.norm(after.points[i][after.valid[i]][:, None]
                                  - expected[i][out.valid[i]][None], axis=-1)
            np.testing.assert_array_less(np.min(gaps, axis=1), 10 * tol[i])
            np.testing.assert_array_less(np.min(gaps, axis=0), 10 * tol[i])


def _poison(shape, i: int, bad: float):
    """shape (batched) with entry i's plane offset (a half-space) or one vertex coordinate
    (which one varies with i) set to `bad`."""
    if isinstance(shape, jaxsat.HalfSpace):
        offset = np.array(shape.offset)
        offset[i] = bad
        return dataclasses.replace(shape, offset=offset)
    vertices = np.array(shape.vertices)
    vertices[i, i % vertices.shape[1], i % vertices.shape[2]] = bad
    return dataclasses.replace(shape, vertices=vertices)


NON_FINITE_SPOTS = ("translation of a", "rotation of b", "vertex or plane of a",
                    "vertex or plane of b", "radius of b", "rotation of a", "translation of b")


@every_query_class_dtype
def test_non_finite_inputs_give_nan_values_and_gradients(query, size_class, dtype):
    """A NaN, inf or -inf in one place of a pair's input (each of `NON_FINITE_SPOTS` in turn:
    either translation, either rotation parameter, a vertex or plane, a radius) makes every float
    output and every pose gradient of that pair NaN, and every boolean output False; the
    other pairs of the batch keep their finite answers."""
    pairs = random_pairs(*pools(size_class, dtype), BATCH, np.random.default_rng(6), dtype)
    a, params_a, b, params_b = jax.tree.map(np.array, pairs.inputs())
    poisoned = np.arange(BATCH) % 4 != 3  # every fourth pair stays finite
    for i in np.nonzero(poisoned)[0]:
        bad, spot = (np.nan, np.inf, -np.inf)[i % 3], NON_FINITE_SPOTS[i % len(NON_FINITE_SPOTS)]
        if spot == "translation of a":
            params_a[0][i, ...] = bad
        elif spot == "translation of b":
            params_b[0][i, ...] = bad
        elif spot == "rotation of a":
            params_a[-1][i, ...] = bad
        elif spot == "rotation of b":
            params_b[-1][i, ...] = bad
        elif spot == "vertex or plane of a":
            a = _poison(a, i, bad)
        elif b.radius is not None and spot == "radius of b":
            radius = np.array(b.radius)
            radius[i] = bad
            b = dataclasses.replace(b, radius=radius)
        else:
            b = _poison(b, i, bad)
    out, grads = run_batched(batched(query), BATCH, a, params_a, b, params_b)
    for leaf in jax.tree.leaves(out):
        if np.issubdtype(leaf.dtype, np.floating):
            assert np.all(np.isnan(leaf[poisoned])), leaf[poisoned]
            assert np.all(np.isfinite(leaf[~poisoned]))
        elif leaf.dtype == bool:
            assert not np.any(leaf[poisoned])
    if query in DIFFERENTIABLE:
        for leaf in jax.tree.leaves(grads):
            assert np.all(np.isnan(leaf[poisoned])), leaf[poisoned]
            assert np.all(np.isfinite(leaf[~poisoned]))
