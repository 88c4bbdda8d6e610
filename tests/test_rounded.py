"""Rounded shapes (spheres, circles, capsules, rounded polytopes) and half-spaces against
independent oracles.

A rounded shape is the set of points within r of its core. The references: closed forms where
both cores are points or segments (`oracle.segment_distance`), and otherwise the Minkowski
difference oracle of the cores (full-dimensional as soon as one core is), minus the radii;
for half-spaces, the lowest world vertex's height above the world plane, in NumPy.
"""

from __future__ import annotations

import dataclasses
import functools

import harness
import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from scipy.spatial.transform import Rotation

import jaxsat

COUNT = 2 * harness.BATCH


POOL_KINDS = {
    "box-class": ("sphere", "capsule", "rounded_box", "box"),
    "hull-class": ("sphere", "capsule", "rounded_hull"),
    "polygon-class": ("circle", "capsule2", "rounded_polygon", "polygon"),
    "segment-class": ("sphere", "capsule"),
}
"""Mixed pools, each stacked into one size class: the box class keeps the parallelepiped SAT
(edge pairs by projection), the hull class the Gauss map (a segment core by its four quarter
arcs), the segment class (spheres and capsules alone: cores of at most 2 vertices) the closed
form of `_closest.closest_pair_of_segments`; every query compiles once per pool pair and
dtype."""


@dataclasses.dataclass
class RoundedPool:
    """Shapes of mixed kinds padded to one size class: stacked, with their kinds, their cores'
    raw points and their radii (rounded to the dtype; 0 for sharp shapes)."""

    kinds: list[str]
    pool: harness.Pool
    radii: np.ndarray


DEGENERATE_DIMS = {"sphere": 3, "capsule": 3, "circle": 2, "capsule2": 2}
"""Kinds whose core is a point or a segment, and their dimension."""


def _kind_shape(kind: str, rng: np.random.Generator, dtype):
    """(shape, core points) of one random shape of `kind`."""
    radius = float(rng.uniform(0.05, 0.6))
    if kind in DEGENERATE_DIMS:
        core, factory = harness.point_or_segment_core(rng, 1.0, DEGENERATE_DIMS[kind], radius,
                                                      segment=kind.startswith("capsule"))
        return factory(dtype), core
    base = {"rounded_box": "box", "box": "box", "rounded_hull": "hull8",
            "rounded_polygon": "poly8", "polygon": "poly8"}[kind]
    raw, factory = harness.GENERATORS[base][1](rng, 1.0)
    sharp = factory(dtype)
    return (sharp if kind in ("box", "polygon") else
            jaxsat.rounded(sharp, np.asarray(radius, dtype))), raw


@functools.cache
def rounded_pool(name: str, dtype, per_kind: int = 3) -> RoundedPool:
    rng = np.random.default_rng([7, len(name)])
    kinds = [kind for kind in POOL_KINDS[name] for _ in range(per_kind)]
    shapes, points = zip(*(_kind_shape(kind, rng, dtype) for kind in kinds), strict=True)
    stacked = jaxsat.stack(list(shapes))
    points = [np.asarray(p, np.float64).astype(dtype).astype(np.float64) for p in points]
    return RoundedPool(kinds, harness.Pool(stacked.dim, points, stacked),
                       np.asarray(stacked.radius, np.float64))


POOL_CASES = [pytest.param(names, dtype, id=f"{names[0]}-{names[1]}-{dtype.__name__}",
                           marks=() if (names[0], dtype) == ("polygon-class", np.float64)
                           else pytest.mark.slow)
              for names in [("box-class", "box-class"), ("hull-class", "box-class"),
                            ("polygon-class", "polygon-class"),
                            ("segment-class", "segment-class")]
              for dtype in harness.DTYPES]


@dataclasses.dataclass
class RoundedPairs:
    pool_a: RoundedPool
    pool_b: RoundedPool
    pairs: harness.Pairs
    expected: np.ndarray
    """(N,) the oracle signed distance of each pair."""
    size: np.ndarray
    """(N,) the larger of the two shapes' bounding radii (rounded) about their centroids."""


@functools.cache
def rounded_pairs(name_a: str, name_b: str, dtype) -> RoundedPairs:
    pool_a, pool_b = rounded_pool(name_a, dtype), rounded_pool(name_b, dtype)
    rng = np.random.default_rng([3, len(name_a), len(name_b)])
    # Spheres and capsules alone are thinner: closer poses keep a quarter of them in contact.
    spread = 1.5 if "segment-class" in (name_a, name_b) else 3.0
    pairs = harness.random_pairs(pool_a.pool, pool_b.pool, COUNT, rng, dtype,
                                 distance=(0.0, spread))
    world_a, world_b = harness.world_points(pairs)
    expected, size = [], []
    for i, (index_a, index_b) in enumerate(zip(pairs.index_a, pairs.index_b, strict=True)):
        ra, rb = pool_a.radii[index_a], pool_b.radii[index_b]
        core = harness.core_signed_distance(world_a[i], world_b[i])
        expected.append(core - ra - rb)
        size.append(max(oracle.bounding_radius(world_a[i]) + ra,
                        oracle.bounding_radius(world_b[i]) + rb))
    return RoundedPairs(pool_a, pool_b, pairs, np.array(expected), np.array(size))


SMOOTHING = 0.02


def _query(a, params_a, b, params_b):
    """closest_points, the exact and smooth signed distance with their gradients in b's
    translation and radius, and in 2D penetration and intersects: one kernel per pool pair
    and dtype. (Rounded penetration and intersects read the same exact distance as
    closest_points; 3D kernels leave them out to halve the compile, and the degenerate
    catalogue checks them in 3D.)"""
    pose_a, pose_b = harness.make_pose(params_a), harness.make_pose(params_b)

    def of(translation_b, radius_b, smoothing):
        moved = dataclasses.replace(b, radius=radius_b)
        params = (translation_b[0], translation_b[1], params_b[2]) if a.dim == 2 else (
            translation_b, params_b[1])
        return jaxsat.signed_distance(a, pose_a, moved, harness.make_pose(params),
                                      smoothing=smoothing)

    translation = jnp.stack([params_b[0], params_b[1]]) if a.dim == 2 else params_b[0]
    signed = tuple(jax.value_and_grad(of, argnums=(0, 1))(translation, b.radius, smoothing)
                   for smoothing in (None, SMOOTHING))
    found = jaxsat.closest_points(a, pose_a, b, pose_b)
    if a.dim == 3:
        return found, None, signed
    penetration = jaxsat.penetration(a, pose_a, b, pose_b)
    overlap = jaxsat.intersects(a, pose_a, b, pose_b)
    return found, (penetration.depth, penetration.normal, overlap), signed


# FAST_COMPILE about halves the compile time (see harness.FAST_COMPILE for its caveat).
_batched_query = jax.jit(jax.vmap(_query), compiler_options=harness.FAST_COMPILE)


@pytest.mark.parametrize(("names", "dtype"), POOL_CASES)
def test_rounded_queries_match_the_cores_oracle_minus_the_radii(names, dtype):
    """Every query on rounded pairs (spheres, capsules, rounded and sharp polytopes, one size
    class per pool), against the cores' oracle signed distance minus r_a + r_b:

    * closest_points and signed_distance give that value; the points are on the rounded
      surfaces (at r from the cores when apart) and q - p = distance * normal;
    * (2D) penetration is minus the signed distance along the same normal, and intersects
      is signed distance <= 0 wherever the value is clear of 0 by the tolerance;
    * exact and smooth signed distance have finite gradients, unit-bounded in b's
      translation and -1 in b's radius, and exact - c tau <= smooth <= exact with
      c = smoothing_error_bound (a point core counts one vertex)."""
    case = rounded_pairs(*names, dtype)
    pairs, pool_a, pool_b = case.pairs, case.pool_a, case.pool_b
    found, overlap_queries, signed = harness.run_batched(_batched_query, len(pairs),
                                                         *pairs.inputs())
    world_a, world_b = harness.world_points(pairs)
    checked_apart = 0
    for i in range(len(pairs)):
        index_a, index_b = pairs.index_a[i], pairs.index_b[i]
        ra, rb = pool_a.radii[index_a], pool_b.radii[index_b]
        tolerance = 10 * harness.RELATIVE_TOLERANCE[dtype] * case.size[i]
        expected = case.expected[i]
        label = f"{pool_a.kinds[index_a]}-{pool_b.kinds[index_b]} pair {i}"
        assert abs(found.signed_distance[i] - expected) <= tolerance, label
        if overlap_queries is not None:
            depth, normal, overlap = (x[i] for x in overlap_queries)
            # Up to rounding (signed_distance's straight-through gradient term).
            assert abs(depth + found.signed_distance[i]) <= tolerance, label
            np.testing.assert_array_equal(normal, found.normal[i], err_msg=label)
            if abs(expected) > tolerance:
                assert overlap == (expected < 0), label
        assert abs(np.linalg.norm(found.normal[i]) - 1) <= harness.UNIT_TOLERANCE[dtype], label
        np.testing.assert_allclose(found.point_b[i] - found.point_a[i],
                                   found.signed_distance[i] * found.normal[i], atol=tolerance,
                                   err_msg=label)
        if expected > tolerance:
            checked_apart += 1
            on_a = harness.distance_to_core(found.point_a[i], world_a[i])
            on_b = harness.distance_to_core(found.point_b[i], world_b[i])
            assert abs(on_a - ra) <= tolerance and abs(on_b - rb) <= tolerance, label
    assert checked_apart >= len(pairs) // 8

    (exact, (exact_move, exact_radius)), (smooth, (smooth_move, smooth_radius)) = signed
    tolerance = 10 * harness.RELATIVE_TOLERANCE[dtype] * case.size
    assert np.all(np.abs(exact - case.expected) <= tolerance)
    a, _, b, _ = pairs.inputs()
    bound = np.asarray(jax.vmap(jaxsat.smoothing_error_bound)(a, b))
    for name, array in (("exact", exact), ("smooth", smooth), ("exact_move", exact_move),
                        ("smooth_move", smooth_move)):
        assert np.all(np.isfinite(array)), name
    for move in (exact_move, smooth_move):
        assert np.all(np.linalg.norm(move, axis=-1) <= 1 + 10 * harness.UNIT_TOLERANCE[dtype])
    np.testing.assert_array_equal(exact_radius, -1.0)
    np.testing.assert_array_equal(smooth_radius, -1.0)
    assert np.all(smooth <= exact + tolerance)
    assert np.all(smooth >= exact - bound * SMOOTHING - tolerance)


CONTACT_MARGIN = 0.1


def _contacts_query(a, params_a, b, params_b):
    return jaxsat.contacts(a, harness.make_pose(params_a), b, harness.make_pose(params_b),
                           margin=CONTACT_MARGIN)


_batched_contacts = jax.jit(jax.vmap(_contacts_query), compiler_options=harness.FAST_COMPILE)


@pytest.mark.parametrize(("names", "dtype"), POOL_CASES)
def test_rounded_contacts_follow_the_cores_oracle(names, dtype):
    """contacts on the mixed pools (margin 0.1), against the oracle signed distance sd of each
    pair: no valid point when -sd < -margin, at least one when overlapping; every depth in
    [-margin, -sd], the deepest equal to -sd (up to the documented 2e-3 x size for near-flat
    faces); a unit normal. Every point m is the midpoint of m + depth/2 n and m - depth/2 n,
    which lie on or inside the rounded shapes (at most r_a from a's core, r_b from b's), and
    on the surfaces (at r_a and r_b) at the deepest point."""
    case = rounded_pairs(*names, dtype)
    pairs, pool_a, pool_b = case.pairs, case.pool_a, case.pool_b
    result = harness.run_batched(_batched_contacts, len(pairs), *pairs.inputs())
    world_a, world_b = harness.world_points(pairs)
    failures, with_points = [], 0
    for i in range(len(pairs)):
        index_a, index_b = pairs.index_a[i], pairs.index_b[i]
        ra, rb = pool_a.radii[index_a], pool_b.radii[index_b]
        tol = 10 * harness.RELATIVE_TOLERANCE[dtype] * case.size[i]
        depth = -case.expected[i]
        valid = result.valid[i]
        points = result.points[i][valid].astype(np.float64)
        depths = result.depths[i][valid].astype(np.float64)
        normal = result.normal[i].astype(np.float64)
        problems = []
        if depth < -CONTACT_MARGIN - tol and valid.any():
            problems.append("valid points beyond the margin")
        if depth > tol and not valid.any():
            problems.append("overlapping without a point")
        if abs(np.linalg.norm(normal) - 1) > harness.UNIT_TOLERANCE[dtype]:
            problems.append(f"normal {normal}")
        if len(depths):
            with_points += 1
            if np.min(depths) < -CONTACT_MARGIN - tol or np.max(depths) > depth + tol:
                problems.append(f"depths {depths} outside [-margin, {depth}]")
            if np.max(depths) < depth - tol - 2e-3 * case.size[i]:
                problems.append(f"deepest {np.max(depths)} < {depth}")
        for point, point_depth in zip(points, depths, strict=True):
            on_a = harness.distance_to_core(point + point_depth / 2 * normal, world_a[i])
            on_b = harness.distance_to_core(point - point_depth / 2 * normal, world_b[i])
            if on_a > ra + tol or on_b > rb + tol:
                problems.append(f"surface points {on_a}, {on_b} from the cores (r {ra}, {rb})")
            if abs(point_depth - depth) <= tol and not (abs(on_a - ra) <= tol
                                                         and abs(on_b - rb) <= tol):
                problems.append(f"deepest point's surface points {on_a}, {on_b} from the cores "
                                f"(r {ra}, {rb})")
        if problems:
            failures.append(f"{pool_a.kinds[index_a]}-{pool_b.kinds[index_b]} pair {i}: "
                            + "; ".join(problems[:3]))
    assert not failures, f"{len(failures)} of {len(pairs)}:\n" + "\n".join(failures[:8])
    assert with_points >= len(pairs) // 4


def _pose(dim, translation, quaternion=(1.0, 0.0, 0.0, 0.0), dtype=np.float64):
    """A 3D pose, or a 2D pose at angle 0 (the quaternion is then unused)."""
    translation = np.asarray(translation, dtype)
    if dim == 2:
        return jaxsat.pose2(translation[0], translation[1], np.zeros((), dtype))
    return jaxsat.pose3(translation, np.asarray(quaternion, dtype))


_TURN_X = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0)
"""A quarter turn about x: local z onto world -y."""
DEGENERATE_CASES = {
    # name: (shape a, translation a, shape b, translation b, quaternion b, exact signed distance)
    "coincident-spheres": (jaxsat.sphere(0.5), (0, 0, 0), jaxsat.sphere(0.25), (0, 0, 0),
                           (1, 0, 0, 0), -0.75),
    "coincident-circles": (jaxsat.circle(0.5), (0, 0), jaxsat.circle(0.25), (0, 0), (1,), -0.75),
    "sphere-at-box-centre": (jaxsat.box([1.0, 1.0, 1.0]), (0, 0, 0), jaxsat.sphere(0.5),
                             (0, 0, 0), (1, 0, 0, 0), -1.5),
    "point-sphere-on-box-corner": (jaxsat.box([1.0, 1.0, 1.0]), (0, 0, 0), jaxsat.sphere(0.0),
                                   (1, 1, 1), (1, 0, 0, 0), 0.0),
    "collinear-capsules": (jaxsat.capsule(1.0, 0.25), (0, 0, 0), jaxsat.capsule(1.0, 0.25),
                           (0, 0, 0.5), (1, 0, 0, 0), -0.5),
    "parallel-capsules": (jaxsat.capsule(1.0, 0.25), (0, 0, 0), jaxsat.capsule(1.0, 0.25),
                          (1, 0, 0.5), (1, 0, 0, 0), 0.5),
    "crossing-capsules": (jaxsat.capsule(1.0, 0.25), (0, 0, 0), jaxsat.capsule(1.0, 0.25),
                          (0, 0, 0), _TURN_X, -0.5),
    "end-to-end-capsules": (jaxsat.capsule(1.0, 0.25), (0, 0, 0), jaxsat.capsule(1.0, 0.25),
                            (0, 0, 2.5), (1, 0, 0, 0), 0.0),
    "zero-length-capsule-on-box-edge": (jaxsat.box([1.0, 1.0, 1.0]), (0, 0, 0),
                                        jaxsat.capsule(0.0, 0.1), (1, 1, 0), (1, 0, 0, 0), -0.1),
    "capsule-along-box-face": (jaxsat.box([1.0, 1.0, 1.0]), (0, 0, 0), jaxsat.capsule(0.5, 0.1),
                               (1.1, 0, 0), (1, 0, 0, 0), 0.0),
    "collinear-2d-capsules": (jaxsat.capsule(1.0, 0.25, dim=2), (0, 0),
                              jaxsat.capsule(1.0, 0.25, dim=2), (0.5, 0), (1,), -0.5),
    "circle-at-square-centre": (jaxsat.box([1.0, 1.0]), (0, 0), jaxsat.circle(0.5), (0, 0), (1,),
                                -1.5),
}


def _degenerate_query(a, pose_a, b, pose_b):
    found = jaxsat.closest_points(a, pose_a, b, pose_b)
    depth = (jaxsat.penetration(a, pose_a, b, pose_b).depth,
             jaxsat.intersects(a, pose_a, b, pose_b))
    gradients = [jax.grad(lambda *args, smoothing=smoothing: jaxsat.signed_distance(
        *args, smoothing=smoothing), argnums=(0, 1, 2, 3), allow_int=True)(a, pose_a, b, pose_b)
        for smoothing in (None, 0.05)]
    manifold = jaxsat.contacts(a, pose_a, b, pose_b, margin=0.1)
    depth_gradient = jax.grad(lambda pose: jaxsat.contacts(a, pose_a, b, pose, margin=0.1)
                              .depths[0])(pose_b)
    return found, depth, gradients, (manifold, depth_gradient)


_batched_degenerate_query = jax.jit(jax.vmap(_degenerate_query),
                                    compiler_options=harness.FAST_COMPILE)


EXACT_TOUCHES = ("point-sphere-on-box-corner", "end-to-end-capsules")


@pytest.mark.slow
@pytest.mark.parametrize(("dim", "segments_only"), [(2, False), (3, False), (3, True)],
                         ids=["2", "3", "3-spheres-and-capsules"])
@pytest.mark.parametrize("dtype", harness.DTYPES, ids=harness.DTYPE_IDS)
def test_degenerate_rounded_pairs_are_finite_and_exact(dim, segments_only, dtype):
    """Coincident cores, cores inside a box at a many-way tie, collinear, parallel, crossing
    and end-to-end segments, zero radius and zero length (all cases of one dimension in one
    batch): the value by hand, a unit normal, penetration = minus the value, finite exact and
    smooth gradients in every input, unit-bounded in b's translation; intersects by the
    sign; contacts finite, with closest_points' normal and the deepest depth minus the value,
    and a finite gradient of the first depth. `segments_only`: the 3D cases between spheres
    and capsules alone, batched without a box, so that their cores keep at most 2 vertices
    and take the closed form (`_closest.closest_pair_of_segments`)."""
    names = [name for name, case in DEGENERATE_CASES.items() if case[0].dim == dim and not (
        segments_only and max(case[0].vertices.shape[0], case[2].vertices.shape[0]) > 2)]
    cast = lambda shape: jax.tree.map(  # noqa: E731
        lambda leaf: leaf.astype(dtype) if jnp.issubdtype(leaf.dtype, jnp.floating) else leaf,
        shape)
    cases = [DEGENERATE_CASES[name] for name in names]
    a = jaxsat.stack([cast(case[0]) for case in cases])
    b = jaxsat.stack([cast(case[2]) for case in cases])
    poses_a = [_pose(dim, case[1], dtype=dtype) for case in cases]
    poses_b = [_pose(dim, case[3], case[4], dtype=dtype) for case in cases]
    stack_poses = lambda poses: jax.tree.map(lambda *leaves: jnp.stack(leaves), *poses)  # noqa: E731
    found, depth, gradients, (manifold, depth_gradient) = _batched_degenerate_query(
        a, stack_poses(poses_a), b, stack_poses(poses_b))
    for leaf in jax.tree.leaves((manifold, depth_gradient)):
        assert np.all(np.isfinite(np.asarray(leaf))), "contacts"
    tolerance = 10 * harness.RELATIVE_TOLERANCE[dtype] * 3
    for i, name in enumerate(names):
        assert abs(float(found.signed_distance[i]) - cases[i][5]) <= tolerance, name
        assert abs(np.linalg.norm(found.normal[i]) - 1) <= harness.UNIT_TOLERANCE[dtype], name
        assert abs(float(depth[0][i]) + float(found.signed_distance[i])) <= tolerance, name
        # Touching cases count as overlapping where the touch is exact in binary (a corner,
        # segment ends); the others by their sign.
        if cases[i][5] != 0 or name in EXACT_TOUCHES:
            assert bool(depth[1][i]) == (cases[i][5] <= 0), name
        valid = np.asarray(manifold.valid[i])
        assert valid.any() == (cases[i][5] <= 0.1), name  # within the margin
        if not valid.any():
            continue
        deepest = float(np.max(np.asarray(manifold.depths[i])[valid]))
        assert abs(deepest + cases[i][5]) <= tolerance, (name, deepest)
        np.testing.assert_allclose(manifold.normal[i], found.normal[i], atol=tolerance,
                                   err_msg=name)
    for smoothing, gradient in zip((None, 0.05), gradients, strict=True):
        for leaf in jax.tree.leaves(gradient):
            if jnp.issubdtype(leaf.dtype, jnp.floating):
                bad = ~np.all(np.isfinite(np.asarray(leaf)).reshape(len(names), -1), axis=1)
                failing = [n for n, x in zip(names, bad, strict=True) if x]
                assert not failing, (smoothing, failing)
        move = np.linalg.norm(np.asarray(gradient[3].translation), axis=-1)
        assert np.all(move <= 1 + 10 * harness.UNIT_TOLERANCE[dtype]), (smoothing, move)


def test_unpadded_point_and_segment_cores_in_both_dtypes():
    """A sphere and a capsule as built (one and two core vertices, no padding): the closed-form
    value, in the input dtype."""
    for dtype in harness.DTYPES:
        ball = jaxsat.sphere(np.asarray(0.5, dtype))
        rod = jaxsat.capsule(np.asarray(1.0, dtype), np.asarray(0.2, dtype))
        assert ball.size_class.vertices == 1 and rod.size_class.vertices == 2
        for shape in (ball, rod):
            assert shape.radius.dtype == dtype and shape.vertices.dtype == dtype
        value = jaxsat.signed_distance(ball, _pose(3, (0, 0, 0), dtype=dtype), rod,
                                       _pose(3, (3, 0, 4), dtype=dtype))
        assert value.dtype == dtype
        assert abs(float(value) - (np.hypot(3.0, 3.0) - 0.7)) <= 1e-6


def _quaternion_from_z(direction) -> np.ndarray:
    """(w, x, y, z) of the shortest rotation taking local z onto a unit `direction` (not -z)."""
    quaternion = np.concatenate([[1.0 + direction[2]], np.cross([0.0, 0.0, 1.0], direction)])
    return quaternion / np.linalg.norm(quaternion)


@pytest.mark.parametrize("dtype", harness.DTYPES, ids=harness.DTYPE_IDS)
def test_nearly_parallel_capsules_match_the_closed_form(dtype):
    """Capsules whose cores are 1e-6 to 1e-2 radians from parallel, side by side, crossing, or
    at distances up to their length: the closed-form oracle's value within 1e-5 of the size in
    float32 and 1e-9 in float64. Before, float32 values were up to 5e-4 too large here: a rule
    that clamped the cores' stationary point and then walked to an edge, and a stationary
    point from aa bb - ab^2, which cancels for nearly parallel cores."""
    rng = np.random.default_rng(11)
    rod = jaxsat.capsule(np.asarray(0.5, dtype), np.asarray(0.05, dtype))
    # Cores side by side 0.1 apart, overlapping over half their length, or crossing, turned
    # by angle in the plane they span (both senses); then random nearly parallel pairs.
    cases = [(np.array([np.sin(sense * angle), 0.0, np.cos(angle)]),
              np.array([apart, 0.0, shift]))
             for angle in 10.0 ** np.arange(-6.0, -1.0) for sense in (1, -1)
             for shift in (0.5, -0.5) for apart in (0.1, 0.0)]
    for _ in range(64):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        tilt = np.cross(direction, rng.normal(size=3))
        tilt *= 10.0 ** rng.uniform(-6, -2) / np.linalg.norm(tilt)
        cases.append(((direction + tilt) / np.linalg.norm(direction + tilt),
                      rng.normal(size=3) * 0.3 + direction * rng.uniform(-1.0, 1.0)))
    translations, quaternions, expected = [], [], []
    for turned, centre in cases:
        quaternion = harness.f32(_quaternion_from_z(turned))
        translations.append(harness.f32(centre))
        quaternions.append(quaternion)
        rotation = Rotation.from_quat(np.roll(quaternion, -1)).as_matrix()
        ends = oracle.to_world(np.asarray(rod.vertices[:2], np.float64), rotation,
                               translations[-1])
        expected.append(oracle.segment_distance([0, 0, -0.5], [0, 0, 0.5], *ends) - 0.1)
    pose_a = _pose(3, (0, 0, 0), dtype=dtype)
    pose_b = jax.vmap(jaxsat.pose3)(np.asarray(translations, dtype),
                                    np.asarray(quaternions, dtype))
    values = jax.jit(jax.vmap(jaxsat.signed_distance, in_axes=(None, None, None, 0)),
                     compiler_options=harness.FAST_COMPILE)(rod, pose_a, rod, pose_b)
    tolerance = 1e-9 if dtype == np.float64 else 1e-5
    size = 2.0
    np.testing.assert_allclose(np.asarray(values, np.float64), expected, atol=tolerance * size)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_poses_of_spheres_and_capsules_give_nan(bad):
    """The closed form of point and segment cores: a NaN or inf in a pose gives NaN values,
    points, normals and gradients (not the plausible 0 of touching cores), and intersects
    False."""
    upright = np.array([1.0, 0.0, 0.0, 0.0])
    origin = jaxsat.pose3(np.zeros(3), upright)
    broken = jaxsat.pose3(np.array([bad, 0.0, 0.0]), upright)
    for a, b in ((jaxsat.capsule(1.0, 0.2), jaxsat.sphere(0.3)),
                 (jaxsat.sphere(0.3), jaxsat.capsule(1.0, 0.2))):
        found = jaxsat.closest_points(a, origin, b, broken)
        for leaf in jax.tree.leaves((found, jaxsat.penetration(a, origin, b, broken))):
            assert np.all(np.isnan(np.asarray(leaf)))
        gradient = jax.jit(jax.grad(lambda pose, a=a, b=b: jaxsat.signed_distance(
            a, origin, b, pose)), compiler_options=harness.FAST_COMPILE)(broken)
        assert np.all(np.isnan(np.asarray(gradient.translation)))
        assert not bool(jaxsat.intersects(a, origin, b, broken))


def test_a_stack_of_circles_capsules_and_polygons_batches_like_single_calls():
    """Mixed kinds in one stack (padded to one size class; sharp entries get radius 0): the
    batched answers equal the single calls on the unpadded shapes."""
    shapes = [jaxsat.circle(0.3), jaxsat.capsule(0.7, 0.2, dim=2), jaxsat.box([0.5, 0.4]),
              jaxsat.rounded(jaxsat.regular_polygon(5, 0.5), 0.1)]
    stacked = jaxsat.stack(shapes)
    np.testing.assert_array_equal(stacked.radius, [0.3, 0.2, 0.0, 0.1])
    other, other_pose = jaxsat.capsule(0.5, 0.1, dim=2), jaxsat.pose2(0.0, 0.0, 0.0)
    rng = np.random.default_rng(4)
    params = rng.uniform(-1.2, 1.2, (len(shapes), 3))
    batched = jax.jit(jax.vmap(lambda shape, p: jaxsat.signed_distance(
        shape, jaxsat.pose2(p[0], p[1], p[2]), other, other_pose)))(stacked, params)
    for i, shape in enumerate(shapes):
        single = jaxsat.signed_distance(shape, jaxsat.pose2(*params[i]), other, other_pose)
        np.testing.assert_allclose(batched[i], single, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(("call", "error", "match"), [
    (lambda: jaxsat.sphere(-1.0), ValueError, "radius must be finite and >= 0"),
    (lambda: jaxsat.sphere(np.nan), ValueError, "radius must be finite"),
    (lambda: jaxsat.sphere("1"), TypeError, "radius must be a number"),
    (lambda: jaxsat.sphere(True), TypeError, "radius must be a number"),
    (lambda: jaxsat.circle(np.array([1.0, 2.0])), TypeError, "scalar"),
    (lambda: jaxsat.capsule(-0.5, 0.1), ValueError, "half_length must be finite and >= 0"),
    (lambda: jaxsat.capsule(0.5, 0.1, dim=4), ValueError, "dim must be 2 or 3"),
    (lambda: jaxsat.rounded(np.eye(3), 0.1), TypeError, "must be a jaxsat.Polytope"),
    (lambda: jaxsat.rounded(jaxsat.stack([jaxsat.box([1.0, 1.0])] * 2), 0.1), TypeError,
     "unbatched"),
    (lambda: jaxsat.rounded(jaxsat.box([1.0, 1.0]), np.inf), ValueError, "finite"),
])
def test_rounded_constructors_reject_bad_input(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_rounded_adds_radii():
    shape = jaxsat.rounded(jaxsat.rounded(jaxsat.box([1.0, 1.0]), 0.25), 0.5)
    assert float(shape.radius) == 0.75


def test_world_aabbs_grow_by_the_radius():
    shapes = jaxsat.stack([jaxsat.sphere(0.5), jaxsat.capsule(1.0, 0.25), jaxsat.box([1.0] * 3)])
    poses = jax.vmap(jaxsat.pose3)(jnp.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [5.0, 0, 0]]),
                                   jnp.array([[1.0, 0, 0, 0]] * 3))
    low, high = jaxsat.world_aabbs(shapes, poses)
    np.testing.assert_allclose(low, [[0.5, 1.5, 2.5], [-0.25, -0.25, -1.25], [4.0, -1, -1]])
    np.testing.assert_allclose(high, [[1.5, 2.5, 3.5], [0.25, 0.25, 1.25], [6.0, 1, 1]])


@pytest.mark.slow
def test_collide_finds_every_overlapping_rounded_pair():
    """A 2D scene of circles, capsules and squares: collide's pairs (every level) are exactly
    the pairs with signed distance <= 0, with depth = minus it and, at level contacts, the
    pair's own contacts."""
    rng = np.random.default_rng(11)
    makers = [lambda: jaxsat.circle(rng.uniform(0.1, 0.4)),
              lambda: jaxsat.capsule(rng.uniform(0.0, 0.5), rng.uniform(0.05, 0.2), dim=2),
              lambda: jaxsat.box(rng.uniform(0.1, 0.3, 2))]
    count = 30
    shapes = jaxsat.stack([makers[i % 3]() for i in range(count)])
    poses = jax.vmap(jaxsat.pose2)(*(jnp.asarray(x) for x in (
        rng.uniform(0, 4, count), rng.uniform(0, 4, count), rng.uniform(-np.pi, np.pi, count))))
    rows, cols = np.triu_indices(count, 1)
    take_pair = lambda tree, index: jax.tree.map(lambda leaf: leaf[index], tree)  # noqa: E731
    brute = jax.jit(jax.vmap(jaxsat.signed_distance))(
        take_pair(shapes, rows), take_pair(poses, rows), take_pair(shapes, cols),
        take_pair(poses, cols))
    expected = {(int(i), int(j)): float(d) for i, j, d in zip(rows, cols, brute, strict=True)
                if d <= 0}
    assert len(expected) >= 5
    for level in ("intersects", "penetration", "contacts"):
        scene = jaxsat.collide(shapes, poses, capacity=256, level=level)
        assert int(scene.overflow) == 0
        hits = np.asarray(scene.colliding)
        found = {tuple(sorted(map(int, pair))): index
                 for index, pair in enumerate(np.asarray(scene.pairs)) if hits[index]}
        assert set(found) == set(expected), level
        if level != "intersects":
            for pair, index in found.items():
                assert abs(float(scene.depth[index]) + expected[pair]) <= 1e-5, pair
    for pair, index in found.items():
        own = jaxsat.contacts(*take_pair((shapes, poses), pair[0]),
                              *take_pair((shapes, poses), pair[1]))
        mine = take_pair(scene.contacts, index)
        for got, wanted in zip(jax.tree.leaves(mine), jax.tree.leaves(own), strict=True):
            np.testing.assert_allclose(got, wanted, atol=1e-5, err_msg=str(pair))
        assert np.asarray(mine.valid).any()


@pytest.mark.slow
def test_moved_shapes_answer_like_posed_shapes():
    """moved(shape, P) at the identity is shape at P: signed distance, penetration and contacts
    agree on a mixed batch (box, capsule, sphere, rounded box) against random boxes."""
    rng = np.random.default_rng(21)
    kinds = [jaxsat.box([0.5, 0.3, 0.2]), jaxsat.capsule(0.5, 0.1), jaxsat.sphere(0.4),
             jaxsat.rounded(jaxsat.box([0.3, 0.3, 0.3]), 0.1)] * 4
    params = [(rng.normal(size=3) * 0.5, rng.normal(size=4)) for _ in kinds]
    placed = jaxsat.stack([jaxsat.moved(shape, jaxsat.pose3(*p)) for shape, p in
                           zip(kinds, params, strict=True)])
    posed = jaxsat.stack(kinds)
    count = len(kinds)
    others = jaxsat.stack([jaxsat.box(rng.uniform(0.2, 0.6, 3)) for _ in kinds])
    def at(rows):
        translations, turns = (np.stack(column) for column in zip(*rows, strict=True))
        return jax.vmap(jaxsat.pose3)(jnp.asarray(translations), jnp.asarray(turns))

    other_poses = at([(rng.normal(size=3) * 0.6, rng.normal(size=4)) for _ in kinds])
    identity = at([(np.zeros(3), np.array([1.0, 0, 0, 0]))] * count)

    def queries(a, pose_a, b, pose_b):
        return (jaxsat.signed_distance(a, pose_a, b, pose_b),
                jaxsat.penetration(a, pose_a, b, pose_b),
                jaxsat.contacts(a, pose_a, b, pose_b, margin=0.1))

    batched = jax.jit(jax.vmap(queries))
    moved = batched(placed, identity, others, other_poses)
    original = batched(posed, at(params), others, other_poses)
    for got, wanted in zip(jax.tree.leaves(moved), jax.tree.leaves(original), strict=True):
        np.testing.assert_allclose(got, wanted, atol=1e-9)
    assert np.any(np.asarray(moved[0]) < 0) and np.any(np.asarray(moved[0]) > 0)
    with pytest.raises(TypeError, match="unbatched 3D jaxsat.Pose"):
        jaxsat.moved(jaxsat.sphere(1.0), jaxsat.pose2(0.0, 0.0, 0.0))
    with pytest.raises(TypeError, match="unbatched jaxsat.Polytope"):
        jaxsat.moved(posed, jaxsat.pose3(np.zeros(3), np.array([1.0, 0, 0, 0])))


def _dumbbell():
    """Two spheres joined by a capsule along x: (compound, [(kind, core points, radius)])."""
    lying = np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])  # local z onto x
    at = lambda x, turn=(1.0, 0.0, 0.0, 0.0): jaxsat.pose3(np.array([x, 0.0, 0.0]),  # noqa: E731
                                                           np.asarray(turn))
    pieces = [jaxsat.moved(jaxsat.sphere(0.35), at(-1.0)),
              jaxsat.moved(jaxsat.sphere(0.25), at(1.0)),
              jaxsat.moved(jaxsat.capsule(1.0, 0.1), at(0.0, lying))]
    cores = [np.array([[-1.0, 0, 0]]), np.array([[1.0, 0, 0]]),
             np.array([[-1.0, 0, 0], [1.0, 0, 0]])]
    return jaxsat.compound(pieces), list(zip(cores, (0.35, 0.25, 0.1), strict=True))


@pytest.mark.slow
def test_compounds_of_rounded_pieces_against_the_oracle():
    """A dumbbell (two spheres and a capsule, placed with `moved`) against random boxes:
    compound_penetration's depth is the deepest piece's minus signed distance (the cores'
    oracle minus the radius), with that piece; compound_intersects is depth >= 0."""
    rng = np.random.default_rng(22)
    dumbbell, pieces = _dumbbell()
    count = 48
    halves = rng.uniform(0.2, 0.6, (count, 3))
    boxes = jaxsat.stack([jaxsat.box(h) for h in halves])
    translations = rng.uniform(-1.5, 1.5, (count, 3)) * [1.0, 0.5, 0.5]
    turns = rng.normal(size=(count, 4))
    poses = jax.vmap(jaxsat.pose3)(jnp.asarray(translations), jnp.asarray(turns))
    origin = jaxsat.pose3(np.zeros(3), np.array([1.0, 0, 0, 0]))
    queries = jax.jit(jax.vmap(lambda box, pose: (
        jaxsat.compound_penetration(dumbbell, origin, box, pose),
        jaxsat.compound_intersects(dumbbell, origin, box, pose))))
    found, overlap = queries(boxes, poses)
    rotations = np.asarray(poses.rotation)
    overlapping = 0
    for i in range(count):
        world_box = harness.corners(halves[i]) @ rotations[i].T + translations[i]
        depths = [-(harness.core_signed_distance(core, world_box) - radius)
                  for core, radius in pieces]
        label = f"pair {i}: {depths}"
        assert abs(float(found.depth[i]) - max(depths)) <= 1e-9, label
        ranked = sorted(depths)
        if ranked[-1] - ranked[-2] > 1e-9:
            assert int(found.piece_a[i]) == int(np.argmax(depths)), label
        if abs(max(depths)) > 1e-9:
            assert bool(overlap[i]) == (max(depths) > 0), label
        overlapping += max(depths) > 0
    assert 0 < overlapping < count


def test_compounds_against_half_spaces():
    """A concave L against a line and the dumbbell against the ground, in both orders: the
    deepest world core point below the plane, plus its piece's radius."""
    rng = np.random.default_rng(23)
    l_shape = jaxsat.concave_polygon(np.array([[0, 0], [2, 0], [2, 0.5], [0.5, 0.5], [0.5, 2],
                                               [0, 2]], float))
    corners_l = np.array([[0, 0], [2, 0], [2, 0.5], [0.5, 0.5], [0.5, 2], [0, 2]], float)
    line = jaxsat.halfspace([0.3, 1.0], 0.2)
    normal_2d = np.array([0.3, 1.0]) / np.hypot(0.3, 1.0)
    offset_2d = 0.2 / np.hypot(0.3, 1.0)
    origin_2d = jaxsat.pose2(0.0, 0.0, 0.0)
    for _ in range(6):
        x, y, angle = rng.uniform(-1, 1), rng.uniform(-0.5, 1.5), rng.uniform(-np.pi, np.pi)
        world = corners_l @ oracle.rotation_2d(angle).T + [x, y]
        expected = np.max(offset_2d - world @ normal_2d)
        pose = jaxsat.pose2(x, y, angle)
        first = jaxsat.compound_penetration(line, origin_2d, l_shape, pose)
        second = jaxsat.compound_penetration(l_shape, pose, line, origin_2d)
        for found, sign in ((first, 1.0), (second, -1.0)):
            assert abs(float(found.depth) - expected) <= 1e-9
            np.testing.assert_allclose(found.normal, sign * normal_2d, atol=1e-12)
        assert bool(jaxsat.compound_intersects(l_shape, pose, line, origin_2d)) == (expected >= 0)
    dumbbell, pieces = _dumbbell()
    ground = jaxsat.halfspace([0.0, 0.0, 1.0])
    origin = jaxsat.pose3(np.zeros(3), np.array([1.0, 0, 0, 0]))
    for _ in range(4):
        translation, turn = rng.uniform(-0.2, 0.5, 3), rng.normal(size=4)
        rotation = oracle.rotation_3d(turn)
        expected = max(radius - np.min((core @ rotation.T + translation)[:, 2])
                       for core, radius in pieces)
        found = jaxsat.compound_penetration(dumbbell, jaxsat.pose3(translation, turn), ground,
                                            origin)
        assert abs(float(found.depth) - expected) <= 1e-9
    with pytest.raises(ValueError, match="both half-spaces"):
        jaxsat.compound_intersects(line, origin_2d, line, origin_2d)


# --------------------------------------------------------------------------------------------
# Half-spaces.
# --------------------------------------------------------------------------------------------


def _plane_query(plane, params_plane, shape, params_shape):
    """Both orders of every query on a half-space and a shape, and the exact and smooth
    gradients in the shape's translation."""
    pose_plane, pose_shape = harness.make_pose(params_plane), harness.make_pose(params_shape)

    def of(translation, smoothing):
        params = (translation[0], translation[1], params_shape[2]) if shape.dim == 2 else (
            translation, params_shape[1])
        return jaxsat.signed_distance(plane, pose_plane, shape, harness.make_pose(params),
                                      smoothing=smoothing)

    translation = (jnp.stack([params_shape[0], params_shape[1]]) if shape.dim == 2
                   else params_shape[0])
    return {"first": jaxsat.closest_points(plane, pose_plane, shape, pose_shape),
            "second": jaxsat.closest_points(shape, pose_shape, plane, pose_plane),
            "penetration": jaxsat.penetration(plane, pose_plane, shape, pose_shape),
            "intersects": jaxsat.intersects(shape, pose_shape, plane, pose_plane),
            "exact": jax.value_and_grad(of)(translation, None),
            "smooth": jax.value_and_grad(of)(translation, SMOOTHING),
            "bound": jaxsat.smoothing_error_bound(plane, shape)}


_batched_plane_query = jax.jit(jax.vmap(_plane_query), compiler_options=harness.FAST_COMPILE)


@pytest.mark.parametrize(("name", "dtype"), [(name, dtype) for name in ("box-class",
                                                                         "polygon-class")
                                             for dtype in harness.DTYPES])
def test_halfspace_queries_match_the_lowest_vertex(name, dtype):
    """A random half-space against spheres, capsules, rounded and sharp polytopes, in either
    order: the signed distance is the least height of the core's world vertices above the
    world plane minus the radius (NumPy); point_a and point_b lie on the plane and on the
    shape, q - p = distance * normal, the normal is the plane's (from a towards b); penetration
    is minus the distance, intersects its sign; gradients are finite with norm <= 1, and the
    smooth value obeys its bound with c = log(n)."""
    pool = rounded_pool(name, dtype)
    dim = pool.pool.dim
    rng = np.random.default_rng([9, dim])
    normals = rng.normal(size=(COUNT, dim))
    offsets = rng.uniform(-1.0, 1.0, COUNT)
    planes = jax.vmap(lambda n, o: jaxsat.HalfSpace(n / jnp.linalg.norm(n), o))(
        normals.astype(dtype), offsets.astype(dtype))
    params_plane = harness.random_params(dim, COUNT, rng, dtype)
    params_shape = harness.random_params(dim, COUNT, rng, dtype)
    index = rng.integers(len(pool.kinds), size=COUNT)
    found = harness.run_batched(_batched_plane_query, COUNT, planes, params_plane,
                                harness.take(pool.pool.shapes, index), params_shape)
    rotations_plane = harness.rotations(dim, params_plane)
    world_normals = np.einsum("nij,nj->ni", rotations_plane,
                              np.asarray(planes.normal, np.float64))
    world_offsets = (np.asarray(planes.offset, np.float64)
                     + np.sum(world_normals * harness.translations(dim, params_plane), axis=1))
    rotations_shape = harness.rotations(dim, params_shape)
    translations_shape = harness.translations(dim, params_shape)
    for i in range(COUNT):
        world = oracle.to_world(pool.pool.points[index[i]], rotations_shape[i],
                                translations_shape[i])
        radius = pool.radii[index[i]]
        heights = world @ world_normals[i] - world_offsets[i]
        expected = heights.min() - radius
        size = oracle.bounding_radius(world) + radius + abs(heights.min())
        tolerance = 10 * harness.RELATIVE_TOLERANCE[dtype] * size
        label = f"{pool.kinds[index[i]]} pair {i}"
        first, second = found["first"], found["second"]
        for result, sense in ((first, 1.0), (second, -1.0)):
            assert abs(result.signed_distance[i] - expected) <= tolerance, label
            np.testing.assert_allclose(result.normal[i], sense * world_normals[i],
                                       atol=10 * harness.UNIT_TOLERANCE[dtype], err_msg=label)
            np.testing.assert_allclose(result.point_b[i] - result.point_a[i],
                                       result.signed_distance[i] * result.normal[i],
                                       atol=tolerance, err_msg=label)
        on_plane = first.point_a[i] @ world_normals[i] - world_offsets[i]
        assert abs(on_plane) <= tolerance, label
        if expected > tolerance:
            on_shape = harness.distance_to_core(first.point_b[i], world)
            assert abs(on_shape - radius) <= tolerance, label
        assert abs(found["penetration"].depth[i] + expected) <= tolerance, label
        if abs(expected) > tolerance:
            assert found["intersects"][i] == (expected < 0), label
        exact, exact_move = (x[i] for x in found["exact"])
        smooth, smooth_move = (x[i] for x in found["smooth"])
        assert abs(exact - expected) <= tolerance, label
        for move in (exact_move, smooth_move):
            assert np.all(np.isfinite(move)), label
            assert np.linalg.norm(move) <= 1 + 10 * harness.UNIT_TOLERANCE[dtype], label
        count = np.sum(np.asarray(pool.pool.shapes.vertex_mask[index[i]]))
        assert abs(found["bound"][i] - np.log(count)) <= 1e-6, label
        assert exact - found["bound"][i] * SMOOTHING - tolerance <= smooth <= exact + tolerance


def test_halfspace_constructor_normalises_and_rejects_bad_input():
    plane = jaxsat.halfspace([0.0, 0.0, 2.0], 4.0)
    np.testing.assert_allclose(plane.normal, [0.0, 0.0, 1.0])
    assert float(plane.offset) == 2.0
    for args, error, match in [(([0.0, 0.0, 0.0],), ValueError, "non-zero"),
                               (([np.nan, 0.0],), ValueError, "finite"),
                               (([1.0, 0.0, 0.0, 0.0],), ValueError, "2 or 3 entries"),
                               (([1.0, 0.0], [1.0, 2.0]), ValueError, "offset"),
                               ((["x", 0.0],), TypeError, "numbers")]:
        with pytest.raises(error, match=match):
            jaxsat.halfspace(*args)
    ground = jaxsat.halfspace([0.0, 1.0])
    origin = jaxsat.pose2(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="both half-spaces"):
        jaxsat.signed_distance(ground, origin, ground, origin)
    with pytest.raises(ValueError, match="both half-spaces"):
        jaxsat.contacts(ground, origin, ground, origin)
    with pytest.raises(ValueError, match="both half-spaces"):
        jaxsat.compound_intersects(ground, origin, ground, origin)
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.compound_intersects(ground, origin, "box", origin)


@pytest.mark.slow
def test_a_face_resting_on_a_halfspace_has_finite_unit_gradients():
    """A box face flush with the ground (4 vertices tie) and a sphere touching it: value 0,
    finite exact and smooth gradients in every input, unit-bounded in the translation."""
    ground, upright = jaxsat.halfspace([0.0, 0.0, 1.0], dtype=np.float32), np.float32([1, 0, 0, 0])
    origin = jaxsat.pose3(np.zeros(3, np.float32), upright)
    for shape, height in ((jaxsat.box(np.float32([1.0, 1.0, 1.0])), 1.0),
                          (jaxsat.sphere(np.float32(0.5)), 0.5)):
        pose = jaxsat.pose3(np.float32([0.3, -0.2, height]), upright)
        assert float(jaxsat.signed_distance(ground, origin, shape, pose)) == 0.0
        for smoothing in (None, 0.05):
            gradients = jax.grad(lambda *args, smoothing=smoothing: jaxsat.signed_distance(
                *args, smoothing=smoothing), argnums=(0, 1, 2, 3), allow_int=True)(
                ground, origin, shape, pose)
            for leaf in jax.tree.leaves(gradients):
                if jnp.issubdtype(leaf.dtype, jnp.floating):
                    assert np.all(np.isfinite(leaf))
            np.testing.assert_allclose(gradients[3].translation, [0.0, 0.0, 1.0], atol=1e-6)
