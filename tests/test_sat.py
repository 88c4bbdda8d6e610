"""Oracle and property tests for jaxsat.penetration and jaxsat.intersects.

Every random pair is checked against the independent NumPy/SciPy oracle in `oracle.py`, which
sees only the raw points the shapes were built from and rotations computed by SciPy. Pairs are
evaluated in fixed-size batches with one cached `jax.jit(jax.vmap(...))` so that each size class
(2D polygons padded to 8 vertices, 3D boxes, 3D hulls padded to 8 and to 20 vertices) compiles
once per dtype.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from harness import (
    DTYPE_IDS,
    DTYPES,
    GENERATORS,
    IDENTITY,
    NORMAL_TOLERANCE,
    RELATIVE_TOLERANCE,
    UNIT_TOLERANCE,
    Pairs,
    Pool,
    make_pool,
    make_pose,
    quaternion,
    quaternion_product,
    random_pairs,
    random_params,
    take,
    world_points,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

import jaxsat
from jaxsat._shapes import parallelepiped_frame

BATCH = 128
"""Every batched call uses this many pairs (the last chunk is padded), so nothing recompiles."""

# --------------------------------------------------------------------------------------------
# Pairs: the harness's pools and pairs, evaluated in fixed-size jitted batches.
# --------------------------------------------------------------------------------------------


def offset_params(dim: int, params, offsets: np.ndarray, dtype, rng: np.random.Generator):
    """Pose parameters at params' positions plus `offsets` (N, dim), with fresh rotations."""
    fresh = random_params(dim, len(offsets), rng, dtype)
    if dim == 2:
        return (params[0] + offsets[:, 0].astype(dtype), params[1] + offsets[:, 1].astype(dtype),
                fresh[2])
    return ((params[0] + offsets).astype(dtype), fresh[1])


def make_poses(dim: int, params) -> jaxsat.Pose:
    """Batched poses from batched parameters (through the public constructors, vmapped)."""
    params = tuple(jnp.asarray(p) for p in params)
    return jax.vmap(jaxsat.pose2 if dim == 2 else jaxsat.pose3)(*params)


def _query(a, pose_a, b, pose_b):
    return jaxsat.penetration(a, pose_a, b, pose_b), jaxsat.intersects(a, pose_a, b, pose_b)


batched_query = jax.jit(jax.vmap(_query))
"""One jitted function for every test: jit caches one executable per size class and dtype."""


def evaluate(pairs: Pairs, function=batched_query):
    """(depth, normal, intersects) as NumPy arrays, evaluated in chunks of exactly BATCH."""
    count = len(pairs)
    padded = np.resize(np.arange(count), -(-count // BATCH) * BATCH)
    poses_a = make_poses(pairs.dim, pairs.params_a)
    poses_b = make_poses(pairs.dim, pairs.params_b)
    depths, normals, hits = [], [], []
    for start in range(0, len(padded), BATCH):
        chunk = padded[start:start + BATCH]
        result, hit = function(take(pairs.pool_a.shapes, pairs.index_a[chunk]),
                               take(poses_a, chunk),
                               take(pairs.pool_b.shapes, pairs.index_b[chunk]),
                               take(poses_b, chunk))
        depths.append(np.asarray(result.depth))
        normals.append(np.asarray(result.normal))
        hits.append(np.asarray(hit))
        assert result.depth.dtype == pairs.dtype and result.normal.dtype == pairs.dtype
        assert hit.dtype == jnp.bool_
    return (np.concatenate(depths)[:count], np.concatenate(normals)[:count],
            np.concatenate(hits)[:count])


def oracles(pairs: Pairs, tie_factor: float = 10.0):
    world_a, world_b = world_points(pairs)
    results = []
    for a, b in zip(world_a, world_b, strict=True):
        size = max(oracle.bounding_radius(a), oracle.bounding_radius(b))
        results.append(oracle.evaluate(a, b, tie_factor * RELATIVE_TOLERANCE[pairs.dtype] * size))
    return results, world_a, world_b


def check_against_oracle(pairs: Pairs, outputs=None, references=None):
    """Assert every documented property of (depth, normal, intersects) against the oracle.

    For every pair, with tol = relative tolerance * size:
      * depth and normal are finite and the normal has unit length;
      * the normal certifies the depth: support_gap(normal) == depth;
      * depth <= oracle facet depth (a minimum over a superset of the facet normals);
      * overlap (oracle depth >= 0): depth == oracle depth (exact minimum translation distance);
      * separation: -depth <= Euclidean distance (a gap on an axis is a lower bound);
      * where the optimal facet is unique by a margin, the normal is the oracle's facet normal;
      * intersects == (depth >= 0) and == (oracle depth >= 0) away from |depth| < tol.
    Returns (depth, normal, hits, oracles) for further checks.
    """
    depth, normal, hits = evaluate(pairs) if outputs is None else outputs
    if references is None:
        references = oracles(pairs)
    refs, world_a, world_b = references
    rel = RELATIVE_TOLERANCE[pairs.dtype]
    assert np.all(np.isfinite(depth)) and np.all(np.isfinite(normal))
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0,
                               atol=UNIT_TOLERANCE[pairs.dtype])
    failures = []
    for i, ref in enumerate(refs):
        tol = rel * ref.size
        d, n = float(depth[i]), normal[i].astype(np.float64)
        gap = oracle.support_gap(n, world_a[i], world_b[i])
        problems = []
        if abs(gap - d) > tol:
            problems.append(f"support gap of normal {gap!r} != depth")
        if d > ref.depth + tol:
            problems.append("depth above the oracle facet depth")
        if ref.depth >= 0 and abs(d - ref.depth) > tol:
            problems.append("overlap depth differs from the oracle")
        if ref.depth < 0 and -d > ref.distance + tol:
            problems.append(f"gap larger than the distance {ref.distance!r}")
        if ref.depth > 0 and ref.normal_is_unique and np.max(np.abs(n - ref.normal)) > \
                NORMAL_TOLERANCE[pairs.dtype]:
            problems.append(f"normal differs from the oracle normal {ref.normal.tolist()}")
        if abs(d) > tol and bool(hits[i]) != (d >= 0):
            problems.append(f"intersects {bool(hits[i])} disagrees with depth")
        if abs(ref.depth) > tol and bool(hits[i]) != (ref.depth >= 0):
            problems.append(f"intersects {bool(hits[i])} disagrees with the oracle")
        if problems:
            failures.append(f"pair {i}: depth {d!r} normal {n.tolist()} oracle depth "
                            f"{ref.depth!r} size {ref.size:.3g}: " + "; ".join(problems))
    assert not failures, f"{len(failures)} of {len(refs)} pairs fail:\n" + "\n".join(failures[:10])
    return depth, normal, hits, refs


# --------------------------------------------------------------------------------------------
# Fixtures: one pool per (size class, dtype), built once per module.
# --------------------------------------------------------------------------------------------


@functools.cache
def pool(name: str, dtype, scale: float = 1.0, seed: int = 0) -> Pool:
    """This module's pools (its own seeds)."""
    return make_pool(name, dtype, np.random.default_rng([seed, 1 + len(name)]), scale)


CLASS_PAIRS = [("poly8", "poly8"), ("box", "box"), ("hull8", "hull8"), ("hull20", "hull20")]
CLASS_IDS = [f"{a}-{b}" for a, b in CLASS_PAIRS]


@pytest.fixture(params=DTYPES, ids=DTYPE_IDS)
def dtype(request):
    return request.param


@pytest.fixture(params=CLASS_PAIRS, ids=CLASS_IDS)
def classes(request):
    return request.param


# --------------------------------------------------------------------------------------------
# The oracle itself, on cases with known answers.
# --------------------------------------------------------------------------------------------


def test_oracle_on_known_cases():
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    overlap = oracle.evaluate(square, square + [1.5, 0.2])
    assert overlap.depth == pytest.approx(0.5) and np.allclose(overlap.normal, [1, 0])
    diagonal = oracle.evaluate(square, square + [3, 3])
    assert diagonal.depth == pytest.approx(-1.0) and diagonal.distance == pytest.approx(2**0.5)
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    corner = oracle.evaluate(cube, cube + [3, 3, 3])
    assert corner.depth == pytest.approx(-1.0) and corner.distance == pytest.approx(3**0.5)
    assert not corner.normal_is_unique
    inside = oracle.evaluate(cube, 0.1 * cube + [0.5, 0.2, 0.0])
    assert inside.depth == pytest.approx(0.6) and np.allclose(inside.normal, [1, 0, 0])
    assert oracle.support_gap([1, 0, 0], cube, cube + [1.5, 0, 0]) == pytest.approx(0.5)


def test_oracle_distance_matches_quadratic_programme():
    """The exact point-to-hull distance agrees with a generic QP over convex combinations."""
    rng = np.random.default_rng(7)
    for dim in (2, 3):
        for _ in range(5):
            direction = rng.normal(size=dim)
            points = rng.normal(size=(30, dim)) + 6 * direction / np.linalg.norm(direction)
            hull = ConvexHull(points)

            def squared(weights, points=points):
                return float(np.sum((weights @ points) ** 2))

            start = np.full(len(points), 1 / len(points))
            solution = minimize(squared, start, method="SLSQP", bounds=[(0, 1)] * len(points),
                                constraints=[{"type": "eq", "fun": lambda w: np.sum(w) - 1}],
                                options={"ftol": 1e-14, "maxiter": 500})
            distance = oracle.distance_to_hull(hull)
            assert distance > 1.0  # the origin is outside
            assert distance == pytest.approx(np.sqrt(solution.fun), rel=1e-5)


# --------------------------------------------------------------------------------------------
# Random pairs against the oracle.
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_random_pairs(classes, dtype):
    """Generic pairs from deep overlap to clear separation, any rotations."""
    rng = np.random.default_rng([11, len(classes[0]), len(classes[1])])
    pairs = random_pairs(pool(classes[0], dtype), pool(classes[1], dtype), 3 * BATCH, rng, dtype)
    depth, _, _, refs = check_against_oracle(pairs)
    overlapping = np.array([r.depth > 0 for r in refs])
    # The generator really covers both regimes, including deep overlaps.
    assert 0.2 < overlapping.mean() < 0.9
    assert np.max(depth) > 0.5 * max(r.size for r in refs)


@pytest.mark.slow
def test_mixed_size_classes():
    """a and b from different size classes (box vs padded hulls), in both orders."""
    rng = np.random.default_rng(12)
    pairs = random_pairs(pool("box", np.float64), pool("hull8", np.float64), 2 * BATCH, rng,
                         np.float64)
    check_against_oracle(pairs)
    check_against_oracle(pairs.swapped())


def _shallow(pairs: Pairs, refs, targets: np.ndarray) -> Pairs:
    """Move each b along its oracle normal so that its oracle depth becomes `targets`."""
    shift = np.array([(r.depth - t) * r.normal for r, t in zip(refs, targets, strict=True)])
    if pairs.dim == 2:
        x, y, angle = pairs.params_b
        params_b = ((x + shift[:, 0]).astype(pairs.dtype), (y + shift[:, 1]).astype(pairs.dtype),
                    angle)
    else:
        translation, quaternion = pairs.params_b
        params_b = ((translation + shift).astype(pairs.dtype), quaternion)
    return pairs.replace(params_b=params_b)


@pytest.mark.slow
def test_shallow_contacts(classes, dtype):
    """|depth| < 1e-3: touching, barely overlapping and barely separated pairs.

    Start from overlapping pairs (oracle depth d0 > 2e-3 size) and move b out along the oracle
    normal n by d0 - target: every facet's support drops by at most that much, so the new depth
    is exactly `target` (re-checked with the oracle)."""
    rng = np.random.default_rng([13, len(classes[0])])
    pairs = random_pairs(pool(classes[0], dtype), pool(classes[1], dtype), 3 * BATCH, rng, dtype,
                         distance=(0.0, 1.0))
    refs, _, _ = oracles(pairs)
    deep = np.flatnonzero([r.depth > 2e-3 * r.size for r in refs])[:BATCH]
    assert len(deep) == BATCH
    pairs = pairs.replace(index_a=pairs.index_a[deep], index_b=pairs.index_b[deep],
                          params_a=tuple(p[deep] for p in pairs.params_a),
                          params_b=tuple(p[deep] for p in pairs.params_b))
    refs = [refs[i] for i in deep]
    targets = rng.choice([-1e-3, -1e-5, -1e-7, 0.0, 1e-7, 1e-5, 1e-3], len(pairs))
    targets *= np.array([r.size for r in refs])
    shallow = _shallow(pairs, refs, targets)
    depth, _, _, new_refs = check_against_oracle(shallow)
    sizes = np.array([r.size for r in new_refs])
    new_depths = np.array([r.depth for r in new_refs])
    # The construction worked: the oracle depths are the chosen small values (up to the
    # rounding of the new translations to the dtype).
    rounding = 1e-12 if dtype == np.float64 else 1e-6
    np.testing.assert_allclose(new_depths, targets, atol=rounding * sizes.max())
    assert np.all(np.abs(depth) <= (1e-3 + RELATIVE_TOLERANCE[dtype]) * sizes)


@pytest.mark.slow
def test_nested_shapes(dtype):
    """One shape entirely inside the other (both orders): depth is the deepest escape."""
    rng = np.random.default_rng(14)
    big = pool("hull8", dtype, scale=4.0, seed=1)
    small = pool("hull8", dtype, scale=0.25, seed=2)
    pairs = random_pairs(big, small, BATCH, rng, dtype)
    world_a, _ = world_points(pairs)
    # Put b's origin near the centroid of a.
    centres = np.array([a.mean(axis=0) for a in world_a]) + rng.uniform(-0.1, 0.1, (BATCH, 3))
    pairs = pairs.replace(params_b=(centres.astype(dtype), pairs.params_b[1]))
    depth, _, _, refs = check_against_oracle(pairs)
    world_a, world_b = world_points(pairs)
    contained = []
    for a, b in zip(world_a, world_b, strict=True):
        equations = ConvexHull(a).equations
        contained.append(np.all(b @ equations[:, :3].T + equations[:, 3] < 0))
    assert np.mean(contained) > 0.8  # the construction really nests most pairs
    assert np.all(depth > 0)
    check_against_oracle(pairs.swapped())


@pytest.mark.slow
@settings(max_examples=12)
@given(exponent=st.floats(-3.0, 3.0), seed=st.integers(0, 2**31 - 1))
@example(exponent=-3.0, seed=0)
@example(exponent=-3.0, seed=1)
@example(exponent=-3.0, seed=2)
@example(exponent=-3.0, seed=3)
@example(exponent=3.0, seed=0)
@example(exponent=3.0, seed=1)
@example(exponent=3.0, seed=2)
@example(exponent=3.0, seed=3)
def test_scales_from_milli_to_kilo(exponent, seed):
    """Shapes and translations scaled together by 1e-3 .. 1e3: tolerances scale with size."""
    scale = 10.0**exponent
    rng = np.random.default_rng(seed)
    dtype = DTYPES[seed % 2]
    name = ("poly8", "box", "hull8", "hull20")[seed % 4]
    shapes = make_pool(name, dtype, rng, scale=scale, size=4)
    pairs = random_pairs(shapes, shapes, BATCH // 2, rng, dtype, scale=scale)
    _, _, _, refs = check_against_oracle(pairs)
    assert all(0.1 * scale < r.size < 3.0 * scale for r in refs)


# --------------------------------------------------------------------------------------------
# Contact types with analytic answers: two cubes (or squares) meeting along the x axis.
# --------------------------------------------------------------------------------------------


# Rotating by atan(sqrt(2)) about (0, 1, -1)/sqrt(2) takes the corner (-1, -1, -1) to -sqrt(3) x.
_CORNER_TO_MINUS_X = quaternion([0, 1, -1], np.arctan(np.sqrt(2)))
CONTACTS = {
    # name: (quaternion a, quaternion b, reach of a along +x, reach of b along -x)
    "face-face": (IDENTITY, quaternion([1, 0, 0], 0.3), 1.0, 1.0),
    "edge-edge": (quaternion([0, 0, 1], np.pi / 4), quaternion([0, 1, 0], np.pi / 4),
                  np.sqrt(2), np.sqrt(2)),
    "vertex-face": (IDENTITY, _CORNER_TO_MINUS_X, 1.0, np.sqrt(3)),
    # The same rotation takes the corner (1, 1, 1) to +sqrt(3) x.
    "face-vertex": (_CORNER_TO_MINUS_X, IDENTITY, np.sqrt(3), 1.0),
}


@pytest.mark.parametrize("contact", list(CONTACTS))
@pytest.mark.parametrize("padded", [False, True], ids=["box", "box-as-hull8"])
def test_cube_contacts(contact, padded):
    """Unit cubes touching face-face, edge-edge or vertex-face: depth d, normal +x, exactly.

    Unpadded boxes use the few unique edge directions; boxes padded to the hull8 size class go
    through the per-hull-edge path, so both edge-edge methods are checked."""
    quaternion_a, quaternion_b, reach_a, reach_b = CONTACTS[contact]
    assert np.allclose(oracle.rotation_3d(_CORNER_TO_MINUS_X) @ [-1, -1, -1], [-3**0.5, 0, 0])
    depths = np.array([0.5, 0.1, 1e-3, 1e-6, 0.0, -1e-6, -1e-3, -0.5])
    cube = jaxsat.box([1.0, 1.0, 1.0], 8 if padded else None)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    count = len(depths)
    cubes = Pool(3, [corners], jaxsat.stack([cube]))
    pairs = Pairs(cubes, cubes, np.zeros(count, int), np.zeros(count, int),
                  (np.zeros((count, 3)), np.tile(quaternion_a, (count, 1))),
                  (np.array([[reach_a + reach_b - d, 0, 0] for d in depths]),
                   np.tile(quaternion_b, (count, 1))), np.float64)
    depth, normal, hits, _ = check_against_oracle(pairs)
    np.testing.assert_allclose(depth, depths, atol=1e-12)
    np.testing.assert_allclose(normal, np.tile([1.0, 0.0, 0.0], (count, 1)), atol=1e-9)
    decided = depths != 0  # exact touching is at the mercy of rounding
    np.testing.assert_array_equal(hits[decided], depths[decided] > 0)


@pytest.mark.parametrize("padded", [False, True], ids=["box", "box-as-hull8"])
def test_sat_search_names_the_feature_of_its_axis(padded):
    """`sat_search` says which kind of candidate gave the axis: an edge pair for the crossed
    cubes, a's or b's face normal when only that shape's face is aligned with the contact."""
    from jaxsat._pair import pair_frame
    from jaxsat._sat import EDGE_PAIR, FACE_OF_A, FACE_OF_B, sat_search

    cube = jaxsat.box([1.0, 1.0, 1.0], 8 if padded else None, dtype=np.float64)
    search = jax.jit(lambda *pair: sat_search(pair_frame(*pair)))
    expected = {"edge-edge": EDGE_PAIR, "vertex-face": FACE_OF_A, "face-vertex": FACE_OF_B}
    for contact, feature in expected.items():
        quaternion_a, quaternion_b, reach_a, reach_b = CONTACTS[contact]
        for depth in (0.1, -0.1):
            found = search(cube, jaxsat.pose3([0.0, 0.0, 0.0], quaternion_a), cube,
                           jaxsat.pose3([reach_a + reach_b - depth, 0, 0], quaternion_b))
            assert int(found.feature) == feature, (contact, depth)
            np.testing.assert_allclose(found.depth, depth, atol=1e-12)


@pytest.mark.parametrize("contact", ["edge-edge", "vertex-face"])
def test_cube_contacts_perturbed(contact):
    """The same contacts with small random rotations: still exact against the oracle."""
    rng = np.random.default_rng(15)
    quaternion_a, quaternion_b, reach_a, reach_b = CONTACTS[contact]
    count = BATCH
    wobble = lambda: quaternion(rng.normal(size=3), rng.uniform(0, 0.05))  # noqa: E731
    q_a = np.array([quaternion_product(wobble(), quaternion_a) for _ in range(count)])
    q_b = np.array([quaternion_product(wobble(), quaternion_b) for _ in range(count)])
    offsets = np.zeros((count, 3))
    offsets[:, 0] = reach_a + reach_b - rng.uniform(-0.1, 0.2, count)
    offsets[:, 1:] = rng.uniform(-0.1, 0.1, (count, 2))
    for padded in (None, 8):
        cube = jaxsat.stack([jaxsat.box([1.0, 1.0, 1.0], padded)])
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        pairs = Pairs(Pool(3, [corners], cube), Pool(3, [corners], cube), np.zeros(count, int),
                      np.zeros(count, int), (np.zeros((count, 3)), q_a), (offsets, q_b),
                      np.float64)
        _, normal, _, _ = check_against_oracle(pairs)
        assert np.all(normal[:, 0] > 0.9)  # still the contact along +x


@pytest.mark.parametrize("rotated", [False, True], ids=["face-face", "vertex-face"])
def test_square_contacts(rotated):
    """2D: squares meeting edge to edge, or corner (square turned 45 degrees) to edge."""
    depths = np.array([0.5, 1e-3, 1e-8, 0.0, -1e-8, -1e-3, -0.5])
    count = len(depths)
    angle = np.pi / 4 if rotated else 0.0
    reach_b = np.sqrt(2) if rotated else 1.0
    square = jaxsat.box([1.0, 1.0], max_vertices=8)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    pool_ = Pool(2, [corners], jaxsat.stack([square]))
    pairs = Pairs(pool_, pool_, np.zeros(count, int), np.zeros(count, int),
                  (np.zeros(count), np.zeros(count), np.zeros(count)),
                  (1.0 + reach_b - depths, np.zeros(count), np.full(count, angle)), np.float64)
    depth, normal, hits, _ = check_against_oracle(pairs)
    np.testing.assert_allclose(depth, depths, atol=1e-12)
    np.testing.assert_allclose(normal, np.tile([1.0, 0.0], (count, 1)), atol=1e-9)
    decided = depths != 0
    np.testing.assert_array_equal(hits[decided], depths[decided] > 0)


# --------------------------------------------------------------------------------------------
# Invariances.
# --------------------------------------------------------------------------------------------


single_query = jax.jit(_query)
"""Unbatched jitted query, shared by the tests that call pairs one at a time."""


@pytest.mark.slow
def test_same_padded_sizes_do_not_recompile():
    """New shapes and poses with the same padded sizes reuse the compiled kernel."""
    traces = []

    @jax.jit
    def counted(a, pose_a, b, pose_b):
        traces.append(1)
        return jax.vmap(jaxsat.penetration)(a, pose_a, b, pose_b)

    def call(shapes, seed):
        rng = np.random.default_rng(seed)
        pairs = random_pairs(shapes, shapes, 16, rng, np.float64)
        result = counted(take(shapes.shapes, pairs.index_a), make_poses(2, pairs.params_a),
                         take(shapes.shapes, pairs.index_b), make_poses(2, pairs.params_b))
        check_against_oracle(pairs, (np.asarray(result.depth), np.asarray(result.normal),
                                     np.asarray(result.depth) >= 0))

    for seed in range(3):  # different polygons (3 to 8 vertices, padded to 8) and poses
        call(make_pool("poly8", np.float64, np.random.default_rng(seed), size=4), seed)
    assert len(traces) == 1
    assert counted._cache_size() == 1
    # A different padded size does trace again (so the counter does count).
    bigger = jaxsat.stack([jaxsat.regular_polygon(12, 1.0)])
    call(Pool(2, [np.asarray(bigger.vertices[0], np.float64)], bigger), 3)
    assert len(traces) == 2


@pytest.mark.parametrize("name", ["poly8", "box", "hull8",
                                  pytest.param("hull20", marks=pytest.mark.slow)])
def test_identical_shapes_at_identical_poses(name):
    """Each shape against itself at the same (random) pose: finite positive depth, unit normal."""
    rng = np.random.default_rng(20)
    shapes = pool(name, np.float64)
    params = random_params(shapes.dim, BATCH, rng, np.float64)
    index = rng.integers(len(shapes.points), size=BATCH)
    pairs = Pairs(shapes, shapes, index, index, params, params, np.float64)
    depth, normal, hits, refs = check_against_oracle(pairs)
    assert np.all(depth > 0) and np.all(hits)


@pytest.mark.parametrize("name", ["box", "hull8",
                                  pytest.param("hull20", marks=pytest.mark.slow)])
def test_translated_copies(name):
    """Each 3D shape against a translated copy of itself, both unrotated.

    Every edge of a is then exactly parallel to an edge of b: a common situation (instanced
    shapes on a grid) and a degenerate one for edge-edge axes, which must be skipped."""
    rng = np.random.default_rng(21)
    shapes = pool(name, np.float64)
    index = rng.integers(len(shapes.points), size=BATCH)
    identity = np.tile(IDENTITY, (BATCH, 1))
    offsets = rng.normal(size=(BATCH, 3)) * 0.4
    pairs = Pairs(shapes, shapes, index, index, (np.zeros((BATCH, 3)), identity),
                  (offsets, identity), np.float64)
    check_against_oracle(pairs)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["poly8", "box"])
def test_depth_gradient_is_minus_normal(name):
    """d depth / d translation_b = -normal and d depth / d translation_a = +normal.

    depth = min over axes u of max(u.A) - min(u.B); translations do not move the axes, so
    where the minimum is unique its derivative in b's translation is -u (envelope theorem).
    The rotation parameters get finite, non-zero gradients."""
    rng = np.random.default_rng(22)
    shapes = pool(name, np.float64)
    pairs = random_pairs(shapes, shapes, 32, rng, np.float64)
    depth, normal, _, refs = check_against_oracle(pairs)
    make_pose = jaxsat.pose2 if shapes.dim == 2 else jaxsat.pose3
    count = len(pairs)

    def depth_of(a, b, params_a, params_b):
        return jaxsat.penetration(a, make_pose(*params_a), b, make_pose(*params_b)).depth

    grads = jax.jit(jax.vmap(jax.grad(depth_of, argnums=(2, 3))))
    grad_a, grad_b = grads(take(shapes.shapes, pairs.index_a), take(shapes.shapes, pairs.index_b),
                           pairs.params_a, pairs.params_b)
    for g in jax.tree.leaves((grad_a, grad_b)):
        assert np.all(np.isfinite(g))
    if shapes.dim == 2:
        translation_a = np.stack(grad_a[:2], axis=1)
        translation_b = np.stack(grad_b[:2], axis=1)
        rotation_b = np.asarray(grad_b[2])[:, None]
    else:
        translation_a, translation_b = np.asarray(grad_a[0]), np.asarray(grad_b[0])
        rotation_b = np.asarray(grad_b[1])
    assert translation_a.shape == (count, shapes.dim)
    unique = np.array([r.normal_is_unique for r in refs])
    assert unique.mean() > 0.5
    np.testing.assert_allclose(translation_b[unique], -normal[unique], atol=1e-9)
    np.testing.assert_allclose(translation_a[unique], normal[unique], atol=1e-9)
    assert np.all(np.linalg.norm(rotation_b[unique], axis=1) > 0)


# --------------------------------------------------------------------------------------------
# Misuse.
# --------------------------------------------------------------------------------------------


def _single_2d():
    return jaxsat.box([1.0, 1.0]), jaxsat.pose2(0.0, 0.0, 0.0)


def _single_3d():
    return jaxsat.box([1.0, 1.0, 1.0]), jaxsat.pose3(np.zeros(3), np.array([1.0, 0, 0, 0]))


@pytest.mark.parametrize("query", [jaxsat.penetration, jaxsat.intersects])
def test_mismatched_dimensions_raise(query):
    square, pose_2d = _single_2d()
    cube, pose_3d = _single_3d()
    for call, args in [(query, (square, pose_3d, square, pose_3d)),
                       (query, (square, pose_2d, cube, pose_3d)),
                       (query, (cube, pose_3d, cube, pose_2d)),
                       (jax.jit(query), (square, pose_2d, cube, pose_2d))]:
        with pytest.raises(ValueError, match="dimension"):
            call(*args)


@pytest.mark.parametrize("query", [jaxsat.penetration, jaxsat.intersects])
def test_batched_inputs_without_vmap_raise(query):
    cube, pose = _single_3d()
    cubes = jaxsat.stack([cube, cube])
    poses = jax.vmap(jaxsat.pose3)(np.zeros((2, 3)), np.tile([1.0, 0, 0, 0], (2, 1)))
    for args in [(cubes, pose, cube, pose), (cube, pose, cubes, pose),
                 (cube, poses, cube, pose), (cube, pose, cube, poses)]:
        with pytest.raises(ValueError, match="vmap"):
            query(*args)
    with pytest.raises(ValueError, match="vmap"):
        jax.vmap(query, in_axes=(0, 0, None, None))(cubes, poses, cubes, pose)
    # Correct use of the same batched inputs works.
    result = jax.jit(jax.vmap(query, in_axes=(0, 0, None, None)))(cubes, poses, cube, pose)
    assert jax.tree.leaves(result)[0].shape[0] == 2


@pytest.mark.parametrize("query", [jaxsat.penetration, jaxsat.intersects])
def test_wrong_argument_types_raise(query):
    cube, pose = _single_3d()
    with pytest.raises(TypeError, match="Polytope"):
        query(cube.vertices, pose, cube, pose)
    with pytest.raises(TypeError, match="Pose"):
        query(cube, pose, cube, (pose.translation, pose.rotation))


@pytest.mark.slow
def test_intersects_single_calls_batches_and_gradients_agree():
    """intersects has two code paths (a single call checks AABBs first, a vmapped one goes
    straight to SAT); both must agree with the depth sign, nested vmaps with shared arguments
    must work, and a function that calls intersects must stay differentiable."""
    square = jaxsat.box([0.5, 0.5])
    hexagon = jaxsat.regular_polygon(6, 0.7, max_vertices=8)
    offsets = np.linspace(-2.5, 2.5, 11)  # overlapping, touching-free and AABB-disjoint pairs
    at = lambda x, y: jaxsat.pose2(x, y, 0.3)  # noqa: E731
    origin = jaxsat.pose2(0.0, 0.0, 0.0)
    grid = jax.jit(jax.vmap(jax.vmap(
        lambda x, y: jaxsat.intersects(square, origin, hexagon, at(x, y)),
        in_axes=(0, None)), in_axes=(None, 0)))(offsets, offsets)
    depths = jax.vmap(jax.vmap(
        lambda x, y: jaxsat.penetration(square, origin, hexagon, at(x, y)).depth,
        in_axes=(0, None)), in_axes=(None, 0))(offsets, offsets)
    single = jax.jit(lambda x, y: jaxsat.intersects(square, origin, hexagon, at(x, y)))
    singles = np.array([[bool(single(x, y)) for x in offsets] for y in offsets])
    decided = np.abs(np.asarray(depths)) > 1e-6
    assert 0 < np.sum(np.asarray(depths) > 0) < depths.size
    np.testing.assert_array_equal(np.asarray(grid)[decided], np.asarray(depths)[decided] >= 0)
    np.testing.assert_array_equal(singles, np.asarray(grid))

    def cost(x):
        hit = jaxsat.intersects(square, origin, hexagon, at(x, 0.0))
        return jnp.where(hit, x**2, 3.0 * x)

    assert float(jax.grad(cost)(0.5)) == pytest.approx(1.0)  # overlapping: d(x^2)/dx
    assert float(jax.grad(cost)(2.5)) == pytest.approx(3.0)  # separated: d(3x)/dx
    np.testing.assert_allclose(jax.vmap(jax.grad(cost))(jnp.array([0.5, 2.5])), [1.0, 3.0])


def test_jitted_hull_pair_regression_picks_a_true_axis():
    """Regression: a jitted query on this separated pair of 8-point hulls once returned depth
    +0.35 because the argmin over Gauss-map edge pairs found no entry equal to the minimum
    (XLA had recomputed the depths with different rounding). Inputs found by a random sweep."""
    points_a = np.array([
        [2.0023573450508905, -1.587164001458463, -0.7671333729974577],
        [-0.1002567493530576, 0.892654254964764, 0.38992295549373895],
        [0.8483110857317361, -0.5289712565347323, 0.7346209638673363],
        [-0.27123402994105134, 0.9687589406662617, 0.9900425699056145],
        [-0.3933076974087195, 0.24059198614868602, 0.8457175170950988],
        [-0.01751846963796733, -0.1234253081006076, 0.1785610549254531],
        [0.713488048756262, 0.9008130557184157, -1.0601837823036484],
        [0.5798861665235018, 0.4211377349334494, -0.39461205432117624]])
    points_b = np.array([
        [-1.1176696951212617, 0.9319622921692319, -0.18723315887819536],
        [1.040359492411596, 0.9304172928924245, -0.3969081946970987],
        [-0.6829162742724009, 1.3624981903209645, -0.8041389201313714],
        [0.3060035053116264, 0.06894860751459406, 0.3847623708328469],
        [0.998698247667529, 1.0451892794230175, -0.03892180531790738],
        [1.3578872608493435, -1.1412332252220556, 0.8159002488740417],
        [-1.207904299389802, -1.1719667500280957, 0.02964502902058478],
        [0.1627809043501228, -1.770985856440146, 0.6898852845290933]])
    translation_a = np.array([0.9337030401133525, 0.6693894595860311, -0.4617510830043323])
    quaternion_a = np.array([-1.1140884510901978, -1.733741180849187, -0.5605240277654393,
                             -1.3302977918457302])
    translation_b = np.array([2.5710732912577745, -1.948006217559075, 1.7968215274768635])
    quaternion_b = np.array([0.47488523655217424, 0.9809361879010339, -0.061569023524906,
                             -0.22332408189801645])
    a = jaxsat.polyhedron(points_a, max_vertices=8)
    b = jaxsat.polyhedron(points_b, max_vertices=8)
    pose_a = jaxsat.pose3(translation_a, quaternion_a)
    pose_b = jaxsat.pose3(translation_b, quaternion_b)
    result = jax.jit(jaxsat.penetration)(a, pose_a, b, pose_b)
    world_a = oracle.to_world(points_a, oracle.rotation_3d(quaternion_a), translation_a)
    world_b = oracle.to_world(points_b, oracle.rotation_3d(quaternion_b), translation_b)
    reference = oracle.evaluate(world_a, world_b)
    depth = float(result.depth)
    assert reference.depth < 0 and depth < 0
    assert reference.depth - 1e-9 >= depth >= -reference.distance - 1e-9
    gap = oracle.support_gap(np.asarray(result.normal), world_a, world_b)
    assert gap == pytest.approx(depth, abs=1e-9)  # the normal really has this gap
    assert not bool(jax.jit(jaxsat.intersects)(a, pose_a, b, pose_b))


# --------------------------------------------------------------------------------------------
# prune=False: every pair of edge directions by projection, as a textbook SAT does (the
# comparison of benchmarks/scene.py).
# --------------------------------------------------------------------------------------------


def _unpruned_query(a, pose_a, b, pose_b):
    return (jaxsat.penetration(a, pose_a, b, pose_b, prune=False),
            jaxsat.intersects(a, pose_a, b, pose_b))


unpruned_query = jax.jit(jax.vmap(_unpruned_query))


def _is_parallelepiped(pool_: Pool, index: np.ndarray) -> np.ndarray:
    """True for shapes with 3 edge directions (boxes, padded or not)."""
    return np.asarray(pool_.shapes.edge_mask)[index].sum(axis=1) == 3


@functools.cache
def _padded_box_pool(dtype) -> Pool:
    """Boxes padded to 8 vertices, the size class of "hull8" (one compile serves both): they
    take the Gauss map, and every pair of their edge directions forms a Minkowski face."""
    rng = np.random.default_rng(43)
    raw = [GENERATORS["box"][1](rng, 1.0, max_vertices=8) for _ in range(12)]
    return Pool(3, [points.astype(dtype).astype(np.float64) for points, _ in raw],
                jaxsat.stack([factory(dtype) for _, factory in raw]))


@pytest.mark.slow
@pytest.mark.parametrize(("name", "dtype"), [("hull8", np.float64), ("box8", np.float64),
                                             ("hull8", np.float32)],
                         ids=["hull8-float64", "box8-float64", "hull8-float32"])
def test_prune_false_changes_no_overlap_result(name, dtype):
    """prune=False tests every edge-direction pair by projection, a superset of the Gauss-map
    pairs. Overlapping pairs: the same depth and normal. Separated pairs: the extra axes may
    find a larger gap (closer to the distance), never a smaller one; for two boxes every
    edge-direction pair is a Minkowski face, so there the gap is the same. Both stay within
    the oracle's bounds. (Unpadded boxes take the projection path either way; test_shapes.py
    covers boxes built with unique_axes=False.)"""
    shapes = _padded_box_pool(dtype) if name == "box8" else pool(name, dtype)
    pairs = random_pairs(shapes, shapes, BATCH, np.random.default_rng([41, len(name)]), dtype)
    depth, normal, hits = evaluate(pairs)
    full_depth, full_normal, full_hits = evaluate(pairs, unpruned_query)
    references = oracles(pairs)
    sizes = np.array([ref.size for ref in references[0]])
    tol = {np.float64: 1e-12, np.float32: RELATIVE_TOLERANCE[np.float32]}[dtype] * sizes
    overlap, separated = depth > tol, depth < -tol
    assert 0.2 < overlap.mean() < 0.8
    np.testing.assert_array_equal(full_hits, hits)
    np.testing.assert_array_less(np.abs(full_depth - depth)[overlap], tol[overlap])
    unique = overlap & np.array([ref.normal_is_unique for ref in references[0]])
    np.testing.assert_allclose(full_normal[unique], normal[unique],
                               atol=NORMAL_TOLERANCE[dtype])
    np.testing.assert_array_less(full_depth[separated], depth[separated] + tol[separated])
    boxes = (separated & _is_parallelepiped(pairs.pool_a, pairs.index_a)
             & _is_parallelepiped(pairs.pool_b, pairs.index_b))
    assert name != "box8" or boxes.sum() > 20
    np.testing.assert_array_less(np.abs(full_depth - depth)[boxes], tol[boxes])
    if name != "box8":  # hulls: some separated pair finds a larger gap (else this tests little)
        assert np.any(full_depth[separated] < depth[separated] - tol[separated])
    check_against_oracle(pairs, (full_depth, full_normal, full_hits), references)


@pytest.mark.parametrize("prune", [1, 0, None, "no", 1.0])
def test_non_bool_prune_raises(prune):
    cube, pose = jaxsat.box([1.0, 1.0, 1.0]), jaxsat.pose3(np.zeros(3), [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(TypeError, match="prune"):
        jaxsat.penetration(cube, pose, cube, pose, prune=prune)


def _random_rotations(dim: int, count: int, rng: np.random.Generator, seed: int) -> jax.Array:
    """(count, dim, dim) rotation matrices: uniform angles drawn from `rng` in 2D, SciPy's
    uniform rotations with random_state `seed` in 3D (no draw from `rng`)."""
    if dim == 3:
        return jnp.asarray(Rotation.random(count, random_state=seed).as_matrix())
    angles = rng.uniform(-np.pi, np.pi, count)
    return jnp.asarray(np.stack([[np.cos(angles), -np.sin(angles)],
                                 [np.sin(angles), np.cos(angles)]]).transpose(2, 0, 1))


def _depth(a, pose_a, b, rotation_b, translation_b):
    """penetration's depth, with b's pose as two arguments (to differentiate the last)."""
    return jaxsat.penetration(a, pose_a, b, jaxsat.Pose(translation_b, rotation_b)).depth


def _penetrations(a, pose_a, b, rotation_b, translation_b):
    """Batched penetration of `_depth`'s arguments."""
    return jax.vmap(lambda *x: jaxsat.penetration(*x[:3], jaxsat.Pose(x[4], x[3])))(
        a, pose_a, b, rotation_b, translation_b)


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_jitted_batched_depth_gradient_is_minus_normal_at_face_ties(dim):
    """Regression: under jit(vmap(grad)), a chain of jnp.minimum over the tied vertices of a
    face let XLA recompute the ties differently in the backward pass; the gradient of the
    depth with respect to b's translation had norm up to 1.4 instead of being -normal."""
    rng = np.random.default_rng(27)
    count = 64
    shapes = jaxsat.stack([jaxsat.box(rng.uniform(0.15, 0.6, dim)) for _ in range(count)])
    rotations = _random_rotations(dim, 2 * count, rng, seed=3)
    translations = jnp.asarray(rng.uniform(-0.5, 0.5, (2 * count, dim)))
    pose_a = jaxsat.Pose(translations[:count], rotations[:count])
    args = (shapes, pose_a, shapes, rotations[count:], translations[count:])
    gradients = jax.jit(jax.vmap(jax.grad(_depth, argnums=4)))(*args)
    np.testing.assert_allclose(gradients, -_penetrations(*args).normal, atol=1e-9)


@pytest.mark.parametrize("dim", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_depth_gradient_follows_the_normal_where_both_senses_of_the_axis_tie(dim):
    """Concentric boxes: along every axis, pushing b out along +n or -n takes the same depth.
    The depth's gradient with respect to b's translation is then -normal (norm 1), the
    derivative along the sense `penetration` returns; a minimum of the two senses split it
    into halves that cancelled (gradient 0)."""
    rng = np.random.default_rng(31)
    count = 16
    shapes_a = jaxsat.stack([jaxsat.box(rng.uniform(0.15, 0.6, dim)) for _ in range(count)])
    shapes_b = jaxsat.stack([jaxsat.box(rng.uniform(0.15, 0.6, dim)) for _ in range(count)])
    rotations = _random_rotations(dim, 2 * count, rng, seed=5)
    centres = jnp.asarray(rng.uniform(-0.5, 0.5, (count, dim)))
    args = (shapes_a, jaxsat.Pose(centres, rotations[:count]), shapes_b, rotations[count:],
            centres)
    hits = _penetrations(*args)
    assert np.all(np.asarray(hits.depth) > 0.1)
    gradients = jax.jit(jax.vmap(jax.grad(_depth, argnums=4)))(*args)
    np.testing.assert_allclose(gradients, -hits.normal, atol=1e-9)
    one = jax.tree.map(lambda x: x[0], args)
    np.testing.assert_allclose(jax.grad(_depth, argnums=4)(*one), -hits.normal[0], atol=1e-9)


@pytest.mark.slow
def test_large_batch_keeps_gauss_map_axis_sense_at_vertex_vertex_contact():
    """Regression: two octahedra 5e-8 apart tip to tip, in float64. For batches of more than
    about 1,400 pairs XLA rounded the sign of the Gauss-map winner's orientation (a dot
    product that vanishes there) differently than in its depth, and `penetration` returned
    the axis turned round with depth 2.31 (width + gap) instead of -5e-8."""
    octahedron = np.concatenate([np.eye(3), -np.eye(3)])
    shape = jaxsat.polyhedron(octahedron, max_vertices=8)
    params_a = np.float32([1.61529267, 0.92735612, -0.95081633,
                           0.76852161, 0.56748998, 0.27642649, -0.10448954]).astype(np.float64)
    params_b = np.float32([3.26597381, 1.23362327, -2.0377624,
                           0.76852161, 0.56748998, 0.27642649, -0.10448954]).astype(np.float64)
    truth = oracle.evaluate(*(oracle.to_world(octahedron, oracle.rotation_3d(p[3:]), p[:3])
                              for p in (params_a, params_b)))
    assert -1e-7 < truth.depth < 0
    count = 2048
    batch = jax.tree.map(lambda leaf: jnp.repeat(leaf[None], count, axis=0), shape)
    pose_a, pose_b = (jax.vmap(jaxsat.pose3)(jnp.repeat(jnp.asarray(p[None, :3]), count, 0),
                                             jnp.repeat(jnp.asarray(p[None, 3:]), count, 0))
                      for p in (params_a, params_b))
    found = jax.jit(jax.vmap(jaxsat.penetration))(batch, pose_a, batch, pose_b)
    np.testing.assert_allclose(found.depth, truth.depth, rtol=0, atol=1e-12)
    assert np.all(np.asarray(found.normal) @ truth.normal > 1 - 1e-9)


_CORNER_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
"""The 8 corners of [-1, 1]^3."""


def _parallelepiped_points(rng: np.random.Generator) -> np.ndarray:
    """The 8 corners of a parallelepiped: a box, or a sheared one off the origin."""
    edges = np.diag(rng.uniform(0.2, 1.0, 3))
    if rng.integers(2):
        edges = edges @ (np.eye(3) + rng.uniform(-0.5, 0.5, (3, 3))) @ oracle.rotation_3d(
            rng.normal(size=4))
        return _CORNER_SIGNS @ edges + rng.uniform(-0.3, 0.3, 3)
    return _CORNER_SIGNS @ edges


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_parallelepiped_frame_spans_the_corners(dtype):
    """The box kernel's frame of a parallelepiped (centre and three half-edge vectors, from
    its face and edge data) gives back its corners: centre + sum_m s_m e_m over the eight
    sign choices is the corner set, for boxes and sheared parallelepipeds off the origin."""
    @jax.jit
    def stacked_frame(shape):
        centre, half_edges = parallelepiped_frame(shape)
        return jnp.stack([jnp.stack(vector) for vector in (centre, *half_edges)])

    rng = np.random.default_rng(62)
    for _ in range(12):
        corners = _parallelepiped_points(rng)
        shape = jaxsat.polyhedron(corners, dtype=dtype)
        assert shape.has_parallelepiped_frame
        frame = np.asarray(stacked_frame(shape), np.float64)
        centre, half_edges = frame[0], frame[1:]
        spanned = centre + _CORNER_SIGNS @ half_edges
        size = np.max(np.abs(corners))
        tolerance = {np.float64: 1e-12, np.float32: 1e-5}[dtype] * size
        # Each spanned point is a corner, and each corner is spanned.
        distances = np.linalg.norm(spanned[:, None] - corners[None], axis=-1)
        assert np.max(np.min(distances, axis=1)) <= tolerance
        assert np.max(np.min(distances, axis=0)) <= tolerance


@pytest.mark.slow  # 20-35 s a dtype on a 2-core VM: the fast subset keeps the oracle tests of boxes
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_box_kernel_equals_the_general_path(dtype):
    """Two parallelepipeds (boxes, and sheared ones off their origin) take the box kernel
    (the winning axis chosen in closed form); the same shapes padded to the hull8 size class
    take the general path (vertices projected on face normals, edge pairs by the Gauss map).
    Same depth and intersects on every pair, same normal and pose gradients where the
    oracle's normal is unique; the box kernel's answers also pass every oracle check."""
    rng = np.random.default_rng(61)
    exact = [_parallelepiped_points(rng) for _ in range(12)]
    # Hulls of the float64 corners (float32-rounded sheared corners are not coplanar enough
    # for polyhedron to merge their faces), stored in dtype.
    raw = [p.astype(dtype).astype(np.float64) for p in exact]
    closed = Pool(3, raw, jaxsat.stack([jaxsat.polyhedron(p, dtype=dtype) for p in exact]))
    general = Pool(3, raw, jaxsat.stack([jaxsat.polyhedron(p, max_vertices=8, dtype=dtype)
                                         for p in exact]))
    assert closed.shapes.has_parallelepiped_frame
    assert not general.shapes.has_parallelepiped_frame
    pairs = random_pairs(closed, closed, 2 * BATCH, rng, dtype)
    general_pairs = pairs.replace(pool_a=general, pool_b=general)
    depth, normal, hits, refs = check_against_oracle(pairs)
    general_depth, general_normal, general_hits = evaluate(general_pairs)
    sizes = np.array([ref.size for ref in refs])
    tol = {np.float64: 1e-12, np.float32: RELATIVE_TOLERANCE[np.float32]}[dtype] * sizes
    assert 0.2 < np.mean(depth > tol) < 0.8
    np.testing.assert_array_less(np.abs(depth - general_depth), tol)
    decided = np.abs(depth) > tol
    np.testing.assert_array_equal(hits[decided], general_hits[decided])
    unique = np.array([ref.normal_is_unique for ref in refs])
    np.testing.assert_allclose(normal[unique], general_normal[unique],
                               atol=NORMAL_TOLERANCE[dtype])

    def depth_of(a, b, params_a, params_b):
        return jaxsat.penetration(a, make_pose(params_a), b, make_pose(params_b)).depth

    gradients = jax.jit(jax.vmap(jax.grad(depth_of, argnums=(2, 3))))
    found, expected = (
        jax.tree.leaves(gradients(*(take(p.pool_a.shapes, p.index_a),
                                    take(p.pool_b.shapes, p.index_b), p.params_a, p.params_b)))
        for p in (pairs, general_pairs))
    atol = {np.float64: 1e-9, np.float32: 1e-4}[dtype]
    for leaf, reference in zip(found, expected, strict=True):
        np.testing.assert_allclose(np.asarray(leaf)[unique], np.asarray(reference)[unique],
                                   atol=atol)
