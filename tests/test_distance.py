"""Oracle and property tests for jaxsat.signed_distance (exact) and jaxsat.closest_points.

Exact references come from the independent NumPy/SciPy oracle in `oracle.py`: the signed
distance is the Euclidean distance between the hulls when they are apart and minus the
penetration depth when they overlap. Random pairs are evaluated in fixed-size batches through
one cached `jax.jit(jax.vmap(...))` per size class and dtype (compilation dominates the run
time); the hand-built cases reuse those size classes. Shapes, pairs and the hand-built
cases come from the shared harness (`harness.py`).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from harness import (
    BATCH,
    CUBE,
    DTYPE_IDS,
    DTYPES,
    IDENTITY,
    NORMAL_TOLERANCE,
    RELATIVE_TOLERANCE,
    UNIT_TOLERANCE,
    XY,
    Pairs,
    cases_3d,
    hand_built_pairs,
    hand_pool,
    make_pool,
    make_pose,
    pool,
    random_pairs,
    references,
    run_batched,
    take,
    world_points,
)
from scipy.spatial import ConvexHull

import jaxsat


def _exact_query(a, params_a, b, params_b):
    pose_a, pose_b = make_pose(params_a), make_pose(params_b)
    return (jaxsat.closest_points(a, pose_a, b, pose_b),
            jaxsat.signed_distance(a, pose_a, b, pose_b))


exact_batch = jax.jit(jax.vmap(_exact_query))
"""One jitted function for every batched test: one executable per size class and dtype."""


def evaluate(pairs: Pairs):
    """(ClosestPoints, signed_distance) for every pair, as NumPy arrays."""
    closest, distance = run_batched(exact_batch, len(pairs), *pairs.inputs())
    for leaf in (*jax.tree.leaves(closest), distance):
        assert leaf.dtype == pairs.dtype
    return closest, distance


def check_against_oracle(pairs: Pairs, outputs=None, refs=None):
    """Assert the documented properties of signed_distance and closest_points, pair by pair.

    With tol = relative tolerance * size:
      * signed_distance == closest_points(...).signed_distance == the oracle's exact value;
      * |normal| = 1 and the normal certifies the value: min_B n.b - max_A n.a = value;
      * point_a lies in hull A and point_b in hull B, and point_b = point_a + value * normal
        (apart: so they are a closest pair; overlapping: moving b by depth * normal makes
        them meet);
      * overlapping with a unique optimal facet: the normal is the oracle's facet normal.
    Returns (closest, distance, refs)."""
    closest, distance = evaluate(pairs) if outputs is None else outputs
    refs = references(pairs) if refs is None else refs
    rel = RELATIVE_TOLERANCE[pairs.dtype]
    for leaf in (*jax.tree.leaves(closest), distance):
        assert np.all(np.isfinite(leaf))
    np.testing.assert_allclose(np.linalg.norm(closest.normal, axis=1), 1.0,
                               atol=UNIT_TOLERANCE[pairs.dtype])
    failures = []
    for i, ref in enumerate(refs):
        tol = rel * ref.size
        value = float(distance[i])
        normal = closest.normal[i].astype(np.float64)
        point_a = closest.point_a[i].astype(np.float64)
        point_b = closest.point_b[i].astype(np.float64)
        problems = []
        if abs(value - ref.value) > tol:
            problems.append(f"value differs from the oracle's {ref.value!r}")
        if abs(float(closest.signed_distance[i]) - value) > tol:
            problems.append(f"closest_points value {float(closest.signed_distance[i])!r}")
        gap = -oracle.support_gap(normal, ref.world_a, ref.world_b)
        if abs(gap - value) > tol:
            problems.append(f"the normal's gap {gap!r} is not the value")
        outside_a = oracle.distance_to_hull(ConvexHull(ref.world_a), point_a)
        outside_b = oracle.distance_to_hull(ConvexHull(ref.world_b), point_b)
        if outside_a > tol or outside_b > tol:
            problems.append(f"witnesses outside their hulls by {outside_a!r}, {outside_b!r}")
        if np.max(np.abs(point_b - point_a - value * normal)) > tol:
            problems.append("point_b != point_a + value * normal")
        if ref.depth > 0 and ref.normal_is_unique and \
                np.max(np.abs(normal - ref.normal)) > NORMAL_TOLERANCE[pairs.dtype]:
            problems.append(f"normal differs from the oracle normal {ref.normal.tolist()}")
        if problems:
            failures.append(f"pair {i}: value {value!r} normal {normal.tolist()} points "
                            f"{point_a.tolist()} {point_b.tolist()} size {ref.size:.3g}: "
                            + "; ".join(problems))
    assert not failures, f"{len(failures)} of {len(refs)} pairs fail:\n" + "\n".join(failures[:8])
    return closest, distance, refs


# --------------------------------------------------------------------------------------------
# Random pairs against the oracle.
# --------------------------------------------------------------------------------------------

CLASS_CASES = [("poly8", np.float64), ("box", np.float64), ("hull", np.float64),
               ("hexagon", np.float32), ("box", np.float32), ("hull", np.float32)]
"""Each entry compiles once, and compilation dominates the run time: float32 takes unpadded
2D polygons (float64 the padded ones), boxes (edge axes by projection) and hulls of 8 and of
20 points (and boxes) padded to 20 vertices (edge axes on the Gauss map)."""


@pytest.mark.slow
@pytest.mark.parametrize(("name", "dtype"), CLASS_CASES,
                         ids=[f"{n}-{np.dtype(d).name}" for n, d in CLASS_CASES])
def test_random_pairs(name, dtype):
    """Pairs from deep overlap to clear separation, any rotations, against the oracle."""
    rng = np.random.default_rng([31, len(name), np.dtype(dtype).itemsize])
    pairs = random_pairs(pool(name, dtype), pool(name, dtype, seed=1), 2 * BATCH, rng, dtype)
    if name == "hexagon":
        assert np.all(pairs.pool_a.shapes.vertex_mask)  # no padding at all
    _, distance, refs = check_against_oracle(pairs)
    overlapping = np.array([r.depth > 0 for r in refs])
    assert 0.2 < overlapping.mean() < 0.9  # both regimes, deep overlaps included
    sizes = np.array([r.size for r in refs])
    assert np.max(-distance / sizes) > 0.3 and np.max(distance / sizes) > 0.3
    # Apart, the SAT gap often underestimates: the value really goes beyond it.
    gaps = np.array([-r.depth for r in refs])
    assert np.any(distance > gaps + 1e-3 * sizes)


SCALE_CASES = [(name, dtype) for name, dtype in CLASS_CASES if name in ("poly8", "hexagon",
                                                                         "hull")]


@pytest.mark.slow
@pytest.mark.parametrize("scale", [1e-3, 1e3])
@pytest.mark.parametrize(("name", "dtype"), SCALE_CASES,
                         ids=[f"{n}-{np.dtype(d).name}" for n, d in SCALE_CASES])
def test_scales_from_milli_to_kilo(name, dtype, scale):
    """Shapes and positions scaled together: the tolerances scale with the size."""
    rng = np.random.default_rng([33, int(np.log10(scale)) + 3])
    shapes = make_pool(name, dtype, rng, scale=scale, size=6)
    pairs = random_pairs(shapes, shapes, BATCH, rng, dtype, scale=scale)
    _, _, refs = check_against_oracle(pairs)
    assert all(0.1 * scale < r.size < 3.0 * scale for r in refs)
    assert 0 < np.mean([r.depth > 0 for r in refs]) < 1


@pytest.mark.slow
def test_nested_shapes():
    """A small hull inside a big one (both orders): minus the deepest escape distance."""
    rng = np.random.default_rng(34)
    big = pool("hull", np.float64, scale=4.0, seed=2)
    small = pool("hull", np.float64, scale=0.25, seed=3)
    pairs = random_pairs(big, small, BATCH, rng, np.float64)
    world_a, _ = world_points(pairs)
    centres = np.array([a.mean(axis=0) for a in world_a]) + rng.uniform(-0.1, 0.1, (BATCH, 3))
    pairs = dataclasses.replace(pairs, params_b=(centres, pairs.params_b[1]))
    _, distance, _ = check_against_oracle(pairs)
    assert np.all(distance < 0)
    check_against_oracle(pairs.swapped())


@pytest.mark.slow
def test_touching_and_barely_apart():
    """|value| <= 1e-3 size: move b along the oracle direction until the value is a target.

    Overlapping start (depth d, unique normal n): moving b by (d + target) n gives exactly
    `target` for target <= 0 and, for target > 0, exactly target too (translating by t n along
    the minimum-translation normal separates the shapes by t - d along n, and n stays optimal
    since the shapes were touching through n's facet). Both are re-checked with the oracle."""
    rng = np.random.default_rng(35)
    for name, dim in (("poly8", 2), ("hull", 3)):
        shapes = pool(name, np.float64)
        pairs = random_pairs(shapes, shapes, 3 * BATCH, rng, np.float64, distance=(0.0, 1.0))
        refs = references(pairs)
        deep = [i for i, r in enumerate(refs) if r.depth > 2e-3 * r.size and r.normal_is_unique]
        pairs = pairs.subset(deep[:BATCH])
        refs = [refs[i] for i in deep[:BATCH]]
        targets = rng.choice([-1e-3, -1e-6, 0.0, 1e-6, 1e-3], len(pairs)) * \
            np.array([r.size for r in refs])
        shift = np.array([(r.depth + t) * r.normal for r, t in zip(refs, targets, strict=True)])
        if dim == 2:
            params_b = (pairs.params_b[0] + shift[:, 0], pairs.params_b[1] + shift[:, 1],
                        pairs.params_b[2])
        else:
            params_b = (pairs.params_b[0] + shift, pairs.params_b[1])
        moved = dataclasses.replace(pairs, params_b=params_b)
        _, distance, new_refs = check_against_oracle(moved)
        sizes = np.array([r.size for r in new_refs])
        np.testing.assert_allclose([r.value for r in new_refs], targets, atol=1e-12 * sizes.max())
        np.testing.assert_allclose(distance, targets, atol=1e-9 * sizes.max())



@pytest.mark.slow
@pytest.mark.parametrize(("dim", "label"), [(2, "padded"), (3, "padded"), (3, "box")])
def test_hand_built_closest_features(dim, label):
    """Known closest features, each under four common rigid motions (the identity first),
    for gaps s from 1e-6 to 0.4, in the padded size classes and unpadded boxes.

    The analytic value is checked against the oracle too (so the construction is right), and
    so is whether a SAT axis attains it: where none does, the oracle's best facet gap (the
    SAT value) is strictly below the distance, which the result must nevertheless reach."""
    # 3D hulls padded to 20 vertices: the size class of the random hulls (one compilation).
    pairs, entries = hand_built_pairs(dim, label, (1e-6, 1e-3, 0.1, 0.4), max_vertices=20)
    closest, distance, refs = check_against_oracle(pairs)
    for i, (name, s, case, (turn, shift)) in enumerate(entries):
        where = f"{label} {name} s={s}"
        tol = RELATIVE_TOLERANCE[np.float64] * refs[i].size
        assert refs[i].value == pytest.approx(case.value, abs=1e-12), where
        assert distance[i] == pytest.approx(case.value, abs=tol), where
        assert (-refs[i].depth >= case.value - 1e-12) == case.sat_is_exact, where
        if case.point_a is None:
            continue
        rotation = oracle.rotation_2d(turn) if dim == 2 else oracle.rotation_3d(turn)
        np.testing.assert_allclose(closest.point_a[i], rotation @ case.point_a + shift,
                                   atol=tol, err_msg=where)
        np.testing.assert_allclose(closest.point_b[i], rotation @ case.point_b + shift,
                                   atol=tol, err_msg=where)
    _, swapped, _ = check_against_oracle(pairs.swapped())
    np.testing.assert_allclose(swapped, distance, atol=1e-9)


@pytest.mark.slow
def test_hand_built_overlaps_have_touching_witnesses():
    """Shallow overlaps (s < 0) through a vertex-face or an edge-edge contact: the value is
    s, and the witnesses are where the shapes touch after moving b out by |s| along the
    normal: point_a is the contact point on a, point_b = point_a + s * normal on b."""
    entries = []
    for s in (-1e-6, -1e-3, -0.05):
        cases = cases_3d(s)
        for name, normal in (("vertex-face", np.array([1.0, 0, 0])), ("edge-edge skew", XY)):
            entries.append((s, cases[name], normal))
    count = len(entries)
    pool_a = hand_pool(3, [(jaxsat.box([1.0, 1.0, 1.0], max_vertices=20), CUBE)])
    pool_b = hand_pool(3, [(jaxsat.polyhedron(c.points_b, max_vertices=20), c.points_b)
                           for _, c, _ in entries])
    pairs = Pairs(pool_a, pool_b, np.zeros(count, int), np.arange(count),
                  (np.zeros((count, 3)), np.tile(IDENTITY, (count, 1))),
                  (np.array([c.translation for _, c, _ in entries]),
                   np.tile(IDENTITY, (count, 1))), np.float64)
    closest, distance, refs = check_against_oracle(pairs)
    for i, (s, case, normal) in enumerate(entries):
        assert refs[i].depth == pytest.approx(-s, abs=1e-12)
        assert distance[i] == pytest.approx(s, abs=1e-12)
        np.testing.assert_allclose(closest.normal[i], normal, atol=1e-9)
        np.testing.assert_allclose(closest.point_a[i], case.point_a, atol=1e-9)
        np.testing.assert_allclose(closest.point_b[i], case.point_a + s * normal, atol=1e-9)


def _distance_in_angle(a, params_a, b, x, y, angle):
    return jaxsat.signed_distance(a, make_pose(params_a), b, jaxsat.pose2(x, y, angle))


_angle_derivative = jax.jit(jax.vmap(jax.value_and_grad(_distance_in_angle, argnums=5)))


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_angle_derivative_matches_finite_differences_on_many_polygon_pairs(dtype):
    """16,384 random 2D pairs, most of them overlapping: the exact derivative in b's angle
    equals central differences (in float64, on the same rounded inputs) wherever the value is
    smooth there (the one-sided differences agree). The witnesses must lie on the support
    faces of the winning axis: a touching pair found elsewhere on the shapes gives the right
    value and translation gradient but a wrong rotation gradient (GJK's did, in float32, on
    2 pairs in 10,000)."""
    rng = np.random.default_rng(5)
    shapes = pool("poly8", dtype)
    pairs = random_pairs(shapes, shapes, 16384, rng, dtype, distance=(0.0, 1.2))
    a, params_a, b, (x, y, angle) = pairs.inputs()
    derivative = _angle_derivative(a, params_a, b, x, y, angle)[1]
    # The reference: float64 shapes rebuilt from the rounded points (a float32 shape's stored
    # normals are rounded too, which would put noise into the differences).
    exact = jaxsat.stack([jaxsat.polygon(points, 8) for points in shapes.points])
    a, b = take(exact, pairs.index_a), take(exact, pairs.index_b)
    params_a, x, y, angle = jax.tree.map(lambda v: v.astype(np.float64), (params_a, x, y, angle))
    value = _angle_derivative(a, params_a, b, x, y, angle)[0]
    # Smooth: no kink within 1e-5 radians (float32 inputs are uncertain by about 1e-7).
    window = 1e-5
    ahead = _angle_derivative(a, params_a, b, x, y, angle + window)[0]
    behind = _angle_derivative(a, params_a, b, x, y, angle - window)[0]
    smooth = np.abs((ahead - value) / window - (value - behind) / window) < 1e-4
    assert np.mean(value < 0) > 0.6 and np.mean(smooth) > 0.95  # the pairs test overlaps
    step = 1e-6
    plus = _angle_derivative(a, params_a, b, x, y, angle + step)[0]
    minus = _angle_derivative(a, params_a, b, x, y, angle - step)[0]
    central = (plus - minus) / (2 * step)
    error = np.abs(np.asarray(derivative, np.float64) - np.asarray(central))[smooth]
    tolerance = 1e-6 if dtype == np.float64 else 1e-4
    assert np.max(error) < tolerance, (
        f"{np.sum(error >= tolerance)} pairs off, worst {np.max(error):.3g}")


# --------------------------------------------------------------------------------------------
# dtypes, vmap, jit.
# --------------------------------------------------------------------------------------------


def _distance_query(a, params_a, b, params_b):
    return jaxsat.signed_distance(a, make_pose(params_a), b, make_pose(params_b))


_single_query = jax.jit(_distance_query)
"""Unbatched and jitted: the pair-by-pair reference for the batched calls (signed_distance
only: each new function compiles anew, and closest_points costs several times more)."""


def _single_pairs(count: int, seed: int) -> Pairs:
    rng = np.random.default_rng(seed)
    return random_pairs(pool("poly8", np.float64), pool("poly8", np.float64), count, rng,
                        np.float64)


@pytest.mark.slow
@pytest.mark.parametrize("batch_shape", [(1,), (3, 4)], ids=str)
def test_vmap_matches_python_loop(batch_shape):
    """Nested vmaps over a batch of one and a 2D batch give the single jitted calls, pair by
    pair (the batches of 64 everywhere else cover plain 1D vmaps; the vmapped closest_points
    is compared pair by pair with the oracle there). Each batch shape compiles anew."""
    count = int(np.prod(batch_shape))
    pairs = _single_pairs(count, 37 + count)
    a, params_a, b, params_b = pairs.inputs()
    reshape = lambda tree: jax.tree.map(  # noqa: E731
        lambda leaf: np.reshape(leaf, batch_shape + np.shape(leaf)[1:]), tree)
    function = _distance_query
    for _ in batch_shape:
        function = jax.vmap(function)
    distance = jax.jit(function)(reshape(a), reshape(params_a), reshape(b), reshape(params_b))
    assert distance.shape == batch_shape and distance.dtype == np.float64
    for i, index in enumerate(np.ndindex(*batch_shape)):
        single = _single_query(*take((a, params_a, b, params_b), i))
        assert single.shape == () and single.dtype == np.float64
        assert float(distance[index]) == pytest.approx(float(single), abs=1e-12)


# --------------------------------------------------------------------------------------------
# Misuse.
# --------------------------------------------------------------------------------------------


def _unit_pair(dim: int):
    if dim == 2:
        return jaxsat.box([1.0, 1.0]), jaxsat.pose2(0.0, 0.0, 0.0)
    return jaxsat.box([1.0, 1.0, 1.0]), jaxsat.pose3(np.zeros(3), IDENTITY)


@pytest.mark.parametrize("smoothing", [0.0, -0.0, 0, -1.0, -1e-300, np.nan, np.inf, -np.inf,
                                       np.float64(-2.0), jnp.array(np.nan), jnp.array(0.0)],
                         ids=repr)
def test_bad_smoothing_raises(smoothing):
    """A concrete smoothing must be a finite length > 0: the exact distance is asked for with
    None, so a 0 cannot select it by accident."""
    square, pose = _unit_pair(2)
    with pytest.raises(ValueError, match="smoothing"):
        jaxsat.signed_distance(square, pose, square, pose, smoothing=smoothing)


@pytest.mark.parametrize("smoothing", [True, "0.1", [0.1], np.ones(2), jnp.ones(2),
                                       np.array("0.1")], ids=repr)
def test_smoothing_of_the_wrong_type_raises(smoothing):
    square, pose = _unit_pair(2)
    with pytest.raises(TypeError, match="smoothing"):
        jaxsat.signed_distance(square, pose, square, pose, smoothing=smoothing)


@pytest.mark.slow
def test_the_exact_path_is_chosen_by_none_alone():
    """None is exact; every number, Python or traced, takes the smooth path, whose value is
    below the exact one here (two squares apart diagonally: the soft extremes see more than
    one vertex)."""
    square, pose = _unit_pair(2)
    apart = jaxsat.pose2(3.0, 3.0, 0.0)
    exact = jaxsat.signed_distance(square, pose, square, apart)
    np.testing.assert_allclose(exact, np.sqrt(2.0), rtol=1e-6)
    assert jaxsat.signed_distance(square, pose, square, apart, smoothing=None) == exact
    tau = 0.3
    python_float = jaxsat.signed_distance(square, pose, square, apart, smoothing=tau)
    traced = jax.jit(lambda t: jaxsat.signed_distance(square, pose, square, apart,
                                                      smoothing=t))(tau)
    assert python_float < exact - 1e-3
    np.testing.assert_allclose(traced, python_float, rtol=1e-6)


def test_mismatched_dimensions_raise():
    square, pose_2d = _unit_pair(2)
    cube, pose_3d = _unit_pair(3)
    bad = [(square, pose_3d, square, pose_3d), (square, pose_2d, cube, pose_3d),
           (cube, pose_3d, cube, pose_2d), (square, pose_2d, cube, pose_2d)]
    for query in (jaxsat.signed_distance, jaxsat.closest_points,
                  functools.partial(jaxsat.signed_distance, smoothing=0.1),
                  jax.jit(jaxsat.signed_distance), jax.jit(jaxsat.closest_points)):
        for args in bad:
            with pytest.raises(ValueError, match="dimension"):
                query(*args)
    with pytest.raises(ValueError, match="dimension"):
        jaxsat.smoothing_error_bound(square, cube)


def test_batched_inputs_without_vmap_raise():
    cube, pose = _unit_pair(3)
    cubes = jaxsat.stack([cube, cube])
    poses = jax.vmap(jaxsat.pose3)(np.zeros((2, 3)), np.tile(IDENTITY, (2, 1)))
    for query in (jaxsat.signed_distance, jaxsat.closest_points,
                  functools.partial(jaxsat.signed_distance, smoothing=0.1)):
        for args in [(cubes, pose, cube, pose), (cube, pose, cubes, pose),
                     (cube, poses, cube, pose), (cube, pose, cube, poses)]:
            with pytest.raises(ValueError, match="vmap"):
                query(*args)


def test_wrong_argument_types_raise():
    cube, pose = _unit_pair(3)
    for query in (jaxsat.signed_distance, jaxsat.closest_points):
        with pytest.raises(TypeError, match="Polytope"):
            query(cube.vertices, pose, cube, pose)
        with pytest.raises(TypeError, match="Pose"):
            query(cube, pose, cube, (pose.translation, pose.rotation))
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.smoothing_error_bound(cube.vertices, cube)


FLAT_STOP_BOXES = (
    [0.5243715047836304, 0.823554515838623, 0.4051617383956909],
    [-0.8220275044441223, 0.14239975810050964, -0.04592170566320419,
     -1.8132514953613281, -0.3913702666759491, -0.3852023184299469, 0.9226381778717041],
    [0.8253276348114014, 0.6738374829292297, 0.7171571850776672],
    [-2.355544328689575, 0.6756882071495056, -1.9121971130371094,
     1.188921570777893, 1.2276322841644287, -0.2215195596218109, 1.0842119455337524],
)
"""Two boxes (half extents, translation + unnormalised quaternion) whose closest points are
a vertex of b and a point of a's edge 6.6e-5 of its length from a vertex: GJK's last step
from that vertex to the edge shortens |v| by a second-order amount only."""


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_eager_calls_agree_with_the_oracle_on_a_flat_gjk_stop(dtype):
    """An eager call gives the oracle's distance, within 1e-9 of the size in float64 and 1e-5
    in float32, with the cheaper CPU compile settings eager calls use (once the float64 eager
    build returned the SAT gap there, 1.3e-3 short); in float32 GJK stopped at the vertex (a's
    edge shortens |v|^2 by less than its rounding) and the gap along that vertex pair's axis
    was 1.4e-4 short."""
    half_a, params_a, half_b, params_b = (np.asarray(x, np.float64) for x in FLAT_STOP_BOXES)
    a, b = jaxsat.box(half_a, dtype=dtype), jaxsat.box(half_b, dtype=dtype)
    pose_a = make_pose((params_a[:3].astype(dtype), params_a[3:].astype(dtype)))
    pose_b = make_pose((params_b[:3].astype(dtype), params_b[3:].astype(dtype)))
    world_a, world_b = (oracle.to_world(shape.vertices, pose.rotation, pose.translation)
                        for shape, pose in ((a, pose_a), (b, pose_b)))
    expected = oracle.evaluate(world_a, world_b).distance
    size = max(oracle.bounding_radius(w) for w in (world_a, world_b))
    value = float(jaxsat.signed_distance(a, pose_a, b, pose_b))
    tolerance = 1e-9 if dtype == np.float64 else 1e-5
    assert abs(value - expected) <= tolerance * size, (value, expected)



def _value_and_gradient_memory(shape, pose, count: int):
    """XLA's memory analysis of jit(vmap(value_and_grad)) of the exact signed distance over
    `count` pairs of `shape` at `pose`, compiled as users compile it (shapes only, no data)."""
    spec = jax.tree.map(lambda leaf: jax.ShapeDtypeStruct((count, *leaf.shape), leaf.dtype),
                        (shape, pose, shape, pose))
    kernel = jax.jit(jax.vmap(jax.value_and_grad(jaxsat.signed_distance, argnums=(1, 3))))
    return kernel.lower(*spec).compile().memory_analysis()


@pytest.mark.slow
def test_a_vmap_of_1e5_hull_pairs_value_and_gradient_fits_in_2_gib():
    """XLA's own count (inputs, outputs, temporaries) for jit(vmap(value_and_grad)) of the exact
    signed distance over 1e5 pairs of 20-vertex hulls, float32, compiled as users compile it:
    at most 2 GiB (2.2 GiB while the SAT stored all K_a x K_b edge-pair depths)."""
    rng = np.random.default_rng(0)
    hull = jaxsat.polyhedron(rng.normal(size=(20, 3)), max_vertices=20, dtype=np.float32)
    pose = jaxsat.pose3(np.zeros(3, np.float32), np.array([1, 0, 0, 0], np.float32))
    memory = _value_and_gradient_memory(hull, pose, 100_000)
    total = (memory.argument_size_in_bytes + memory.output_size_in_bytes
             + memory.temp_size_in_bytes)
    assert total <= 2 * 2**30, total / 2**30


def test_1e5_polygon_pairs_value_and_gradient_temporaries_stay_under_32_mib():
    """XLA's temporaries for jit(vmap(value_and_grad)) of the exact signed distance over 1e5
    pairs of 8-gons, float32: under 32 MiB, glibc's largest mmap threshold, above which every
    call maps them afresh and faults them in (8,500 page faults a call, 5.5x `penetration`'s
    time instead of 3.9-4.2x, while the SAT stored its concatenated candidate axes: 34.8 MB)."""
    octagon = jaxsat.polygon(np.stack([np.cos(np.arange(8) * np.pi / 4),
                                       np.sin(np.arange(8) * np.pi / 4)], axis=1),
                             max_vertices=8, dtype=np.float32)
    pose = jaxsat.pose2(np.float32(0.0), np.float32(0.0), np.float32(0.0))
    temporaries = _value_and_gradient_memory(octagon, pose, 100_000).temp_size_in_bytes
    assert temporaries < 32 * 2**20, temporaries / 2**20


@pytest.mark.slow
@pytest.mark.parametrize("name", ["poly8", "hull8"])
def test_minus_signed_distance_has_the_penetration_depth_gradient_where_overlapping(name):
    """The README's advice for 2D polygons and hulls: where the shapes overlap,
    -signed_distance is the penetration depth and its pose gradient (the envelope theorem at
    the witness points) equals the gradient of `penetration(...).depth` (differentiated
    through the SAT's search), at a fraction of the cost. On 64 random pairs, float64, those
    that overlap by more than 1e-3 (at least a quarter): values and gradients agree to 1e-9."""
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 64, np.random.default_rng(81), np.float64)

    def both(a, params_a, b, params_b):
        def depth(pa, pb):
            return jaxsat.penetration(a, make_pose(pa), b, make_pose(pb)).depth

        def minus_distance(pa, pb):
            return -jaxsat.signed_distance(a, make_pose(pa), b, make_pose(pb))

        return (jax.value_and_grad(depth, argnums=(0, 1))(params_a, params_b),
                jax.value_and_grad(minus_distance, argnums=(0, 1))(params_a, params_b))

    by_sat, by_distance = jax.jit(jax.vmap(both))(*pairs.inputs())
    overlapping = np.asarray(by_sat[0]) > 1e-3
    assert np.sum(overlapping) >= 16
    for got, expected in zip(jax.tree.leaves(by_distance), jax.tree.leaves(by_sat), strict=True):
        np.testing.assert_allclose(np.asarray(got)[overlapping], np.asarray(expected)[overlapping],
                                   rtol=1e-9, atol=1e-9)
