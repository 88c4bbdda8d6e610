"""Oracle tests for compound shapes: jaxsat.compound, concave_polygon, stack_compounds,
compound_intersects and compound_penetration.

Two independent references, neither importing jaxsat:
* a brute-force oracle over the convex pieces: `oracle.evaluate` (Minkowski-difference hull
  by SciPy) on every pair of pieces' world points, reduced by max, as the compound queries
  define it;
* for 2D, an exact overlap test of the original concave polygons (edge crossings plus
  even-odd point-in-polygon), which knows nothing of any decomposition.

Compiling the SAT kernel dominates the run time (seconds per size class on a loaded machine),
so the tests share a few jitted functions and size classes: 2D compounds padded to 6 pieces of
6 vertices, 3D compounds to 5 pieces of 8 vertices, batches of 128 pairs. Shapes and poses
are kept as NumPy pytrees so that slicing them runs no JAX op.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import oracle
import pytest

import jaxsat

RELATIVE_TOLERANCE = {np.float64: 1e-9, np.float32: 1e-4}
"""Depth tolerance relative to the shapes' size."""

NORMAL_TOLERANCE = {np.float64: 1e-7, np.float32: 1e-3}

DTYPES = [np.float64, np.float32]
DTYPE_IDS = ["float64", "float32"]

BATCH = 128
"""Every batched call uses this many pairs, so nothing recompiles."""

# --------------------------------------------------------------------------------------------
# Shapes: raw float64 geometry (what the oracles see) and compounds built from it.
# --------------------------------------------------------------------------------------------

L_SHAPE = np.array([(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)], float) - 0.8
U_SHAPE = np.array([(0, 0), (3, 0), (3, 3), (2, 3), (2, 1), (1, 1), (1, 3), (0, 3)], float) - 1.5


def star(points: int, inner: float = 0.4) -> np.ndarray:
    angles = np.pi / 2 + np.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, 1.2, inner)
    return np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)


POLYGONS_2D = {"L": L_SHAPE, "U": U_SHAPE, "star": star(5)}
MAX_PIECES_2D, MAX_VERTICES_2D = 6, 6


def cuboid(low, high) -> np.ndarray:
    """The 8 corners of the axis-aligned box [low, high]."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    return np.array([[(low, high)[i][0], (low, high)[j][1], (low, high)[k][2]]
                     for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def table() -> list[np.ndarray]:
    """A top and four legs."""
    legs = [cuboid((x, y, -0.8), (x + 0.15, y + 0.15, 0.0))
            for x in (-0.9, 0.75) for y in (-0.5, 0.35)]
    return [cuboid((-1, -0.6, 0), (1, 0.6, 0.12)), *legs]


PIECES_3D = {
    "L": [cuboid((-1, -0.5, -0.5), (1, 0.5, 0.5)), cuboid((-1, 0.5, -0.5), (0, 1.5, 0.5))],
    "table": table(),
    "box": [cuboid((-0.4, -0.3, -0.2), (0.4, 0.3, 0.2))],
}
MAX_PIECES_3D, MAX_VERTICES_3D = 5, 8


def as_numpy(tree):
    return jax.tree.map(np.asarray, tree)


def take(tree, index):
    return jax.tree.map(lambda leaf: leaf[index], tree)


@dataclasses.dataclass
class Pool:
    """Compounds of one size class, stacked, with their raw pieces (rounded to the dtype)."""

    dim: int
    pieces: list[list[np.ndarray]]
    outlines: list[np.ndarray | None]
    """2D: each compound's original concave polygon; 3D: None."""
    compounds: jaxsat.Compound
    """Stacked, with NumPy leaves."""


def pool_2d(dtype) -> Pool:
    compounds, pieces, outlines = [], [], []
    for polygon in POLYGONS_2D.values():
        polygon = polygon.astype(dtype)
        compounds.append(jaxsat.concave_polygon(polygon, MAX_PIECES_2D, MAX_VERTICES_2D))
        # concave_polygon keeps decompose's piece order; the oracle sees the rounded pieces.
        pieces.append([p.astype(dtype).astype(np.float64) for p in jaxsat.decompose(polygon)])
        outlines.append(polygon.astype(np.float64))
    return Pool(2, pieces, outlines, as_numpy(jaxsat.stack_compounds(compounds)))


def pool_3d(dtype) -> Pool:
    compounds, pieces = [], []
    for corner_sets in PIECES_3D.values():
        rounded = [corners.astype(dtype) for corners in corner_sets]
        compounds.append(jaxsat.compound(rounded, MAX_PIECES_3D, MAX_VERTICES_3D))
        pieces.append([corners.astype(np.float64) for corners in rounded])
    return Pool(3, pieces, [None] * len(pieces), as_numpy(jaxsat.stack_compounds(compounds)))


POOLS = {}


def get_pool(dim: int, dtype) -> Pool:
    if (dim, dtype) not in POOLS:
        POOLS[dim, dtype] = pool_2d(dtype) if dim == 2 else pool_3d(dtype)
    return POOLS[dim, dtype]


def pool_box_2d(half_extents, dtype=np.float64) -> jaxsat.Compound:
    """A one-piece compound padded to the 2D pool's size class."""
    box = jaxsat.box(np.asarray(half_extents, dtype))
    return as_numpy(jaxsat.compound([box], MAX_PIECES_2D, MAX_VERTICES_2D))


# --------------------------------------------------------------------------------------------
# Poses and the shared jitted queries
# --------------------------------------------------------------------------------------------


def random_params(dim: int, count: int, rng: np.random.Generator, dtype, spread: float):
    if dim == 2:
        x, y = rng.uniform(-spread, spread, (2, count))
        return tuple(v.astype(dtype) for v in (x, y, rng.uniform(-np.pi, np.pi, count)))
    quaternions = rng.normal(size=(count, 4))
    return (rng.uniform(-spread, spread, (count, 3)).astype(dtype), quaternions.astype(dtype))


_make_poses = {2: jax.jit(jax.vmap(jaxsat.pose2)), 3: jax.jit(jax.vmap(jaxsat.pose3))}


def make_poses(dim: int, params) -> jaxsat.Pose:
    """Batched poses (NumPy leaves) through the public constructors."""
    return as_numpy(_make_poses[dim](*params))


def world_transforms(dim: int, params) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rotation, translation) per pose, by SciPy / NumPy (not jaxsat)."""
    if dim == 2:
        return [(oracle.rotation_2d(float(angle)), np.array([x, y], np.float64))
                for x, y, angle in zip(*params, strict=True)]
    return [(oracle.rotation_3d(q), np.asarray(t, np.float64))
            for t, q in zip(*params, strict=True)]


def to_world(pieces, transform):
    return [oracle.to_world(piece, *transform) for piece in pieces]


def _query(a, pose_a, b, pose_b):
    return (jaxsat.compound_penetration(a, pose_a, b, pose_b),
            jaxsat.compound_intersects(a, pose_a, b, pose_b))


batched_query = jax.jit(jax.vmap(_query))
single_query = jax.jit(_query)


# --------------------------------------------------------------------------------------------
# Oracles
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class PairOracle:
    """Brute force over real piece pairs: oracle.evaluate on each, reduced by max."""

    depth: float
    """max over pairs of the oracle depth: exact for the compound when > 0."""
    distance: float
    """min over pairs of the Euclidean distance (0 when some pair overlaps or touches)."""
    pair: tuple[int, int]
    normal: np.ndarray
    decided: bool
    """True when the winning pair wins by a margin and its oracle normal is unique."""
    size: float


def pair_oracle(world_a: list[np.ndarray], world_b: list[np.ndarray], tolerance: float):
    results = {(i, j): oracle.evaluate(a, b, tolerance)
               for i, a in enumerate(world_a) for j, b in enumerate(world_b)}
    ranked = sorted(results, key=lambda pair: -results[pair].depth)
    best = results[ranked[0]]
    runner_up = results[ranked[1]].depth if len(ranked) > 1 else -np.inf
    size = max(oracle.bounding_radius(np.concatenate(world_a)),
               oracle.bounding_radius(np.concatenate(world_b)))
    decided = best.normal_is_unique and best.depth - runner_up > tolerance
    distance = min(result.distance for result in results.values())
    return PairOracle(best.depth, distance, ranked[0], best.normal, decided, size)


def check_pair_result(depth, normal, pieces: tuple[int, int], truth: PairOracle, world_a,
                      world_b, tolerance: float, normal_tolerance: float) -> None:
    """Overlap: the depth, pair and normal are the oracle's. Separated: as for convex pairs
    (`jaxsat.penetration`), the depth is a gap certified by the normal on the reported pair,
    between minus the distance and the largest facet gap of the best pair."""
    assert abs(np.linalg.norm(normal) - 1) < normal_tolerance
    gap = oracle.support_gap(normal, world_a[pieces[0]], world_b[pieces[1]])
    assert depth == pytest.approx(gap, abs=tolerance)
    if truth.depth > tolerance:
        assert depth == pytest.approx(truth.depth, abs=tolerance)
        if truth.decided:
            assert pieces == truth.pair
            np.testing.assert_allclose(normal, truth.normal, atol=normal_tolerance)
    else:
        assert -truth.distance - tolerance <= depth <= truth.depth + tolerance


def _point_segment_distance(points, start, end):
    direction = end - start
    t = np.clip(np.sum((points[:, None] - start[None]) * direction[None], axis=-1)
                / np.sum(direction**2, axis=-1)[None], 0, 1)
    closest = start[None] + t[..., None] * direction[None]
    return np.linalg.norm(points[:, None] - closest, axis=-1)


def _boundaries_cross(first, second) -> bool:
    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    p, p_end = first[:, None], np.roll(first, -1, axis=0)[:, None]
    q, q_end = second[None], np.roll(second, -1, axis=0)[None]
    side_q = cross(p_end - p, q - p) * cross(p_end - p, q_end - p)
    side_p = cross(q_end - q, p - q) * cross(q_end - q, p_end - q)
    return bool(np.any((side_q < 0) & (side_p < 0)))


def polygons_overlap(first: np.ndarray, second: np.ndarray) -> tuple[bool, float]:
    """(whether two simple polygons share interior or boundary points, boundary gap).

    Boundaries that properly cross overlap; otherwise one contains the other or they are
    disjoint, which a vertex's point-in-polygon test tells. The gap is the distance between
    the two boundaries, so callers can skip near-touching cases."""
    gap = min(np.min(_point_segment_distance(first, second, np.roll(second, -1, axis=0))),
              np.min(_point_segment_distance(second, first, np.roll(first, -1, axis=0))))
    crossing = _boundaries_cross(first, second)
    inside = oracle.inside_polygon
    contained = inside(first[:1], second)[0] or inside(second[:1], first)[0]
    return bool(crossing or contained), 0.0 if crossing else float(gap)


def check_against_oracles(pool: Pool, rng, dtype, spread: float) -> None:
    dim = pool.dim
    index_a = rng.integers(len(pool.pieces), size=BATCH)
    index_b = rng.integers(len(pool.pieces), size=BATCH)
    params_a = random_params(dim, BATCH, rng, dtype, spread)
    params_b = random_params(dim, BATCH, rng, dtype, spread)
    result, hit = as_numpy(batched_query(take(pool.compounds, index_a), make_poses(dim, params_a),
                                         take(pool.compounds, index_b), make_poses(dim, params_b)))
    assert result.depth.dtype == dtype and result.normal.dtype == dtype
    assert result.piece_a.dtype == np.int32 and result.piece_b.dtype == np.int32
    assert np.all(np.isfinite(result.depth)) and np.all(np.isfinite(result.normal))
    transforms_a, transforms_b = world_transforms(dim, params_a), world_transforms(dim, params_b)
    decided = overlapping = 0
    for k in range(BATCH):
        world_a = to_world(pool.pieces[index_a[k]], transforms_a[k])
        world_b = to_world(pool.pieces[index_b[k]], transforms_b[k])
        tolerance = RELATIVE_TOLERANCE[dtype] * 10
        truth = pair_oracle(world_a, world_b, tolerance)
        tolerance *= truth.size
        pieces = (int(result.piece_a[k]), int(result.piece_b[k]))
        check_pair_result(result.depth[k], result.normal[k], pieces, truth, world_a, world_b,
                          tolerance, NORMAL_TOLERANCE[dtype])
        if abs(truth.depth) > tolerance:
            assert hit[k] == (truth.depth > 0), k
            overlapping += truth.depth > 0
            decided += truth.decided and truth.depth > 0
        if dim == 2:
            outline_a = oracle.to_world(pool.outlines[index_a[k]], *transforms_a[k])
            outline_b = oracle.to_world(pool.outlines[index_b[k]], *transforms_b[k])
            overlap, gap = polygons_overlap(outline_a, outline_b)
            if overlap or gap > tolerance:
                assert hit[k] == overlap, k
    # The random poses exercise both outcomes and mostly clear winners.
    assert 0.2 * BATCH < overlapping < 0.9 * BATCH
    assert decided > 0.5 * overlapping


# --------------------------------------------------------------------------------------------
# Oracle tests
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_2d_concave_polygons_against_oracles(dtype):
    check_against_oracles(get_pool(2, dtype), np.random.default_rng(0), dtype, spread=2.0)


@pytest.mark.slow
def test_3d_compounds_against_oracle():
    """float64 only here: 3D float32 runs in test_polytope_in_slot_a_3d_float32 (each 3D
    compile costs seconds)."""
    check_against_oracles(get_pool(3, np.float64), np.random.default_rng(1), np.float64,
                          spread=1.2)


def test_box_in_the_notch_of_a_u():
    """A box in the U's notch: the U's AABB and convex hull overlap it, the U does not."""
    u_shape = take(get_pool(2, np.float64).compounds, 1)
    small_box = pool_box_2d([0.3, 0.3])
    hull = U_SHAPE[[0, 1, 2, 7]]  # the U's convex hull: its outer square
    for angle in (0.0, 0.7, 2.0):
        # One rigid motion for both shapes; the box sits at (0, 0.5) or (0, -0.4) in U's frame.
        rotation = oracle.rotation_2d(angle)
        centres = np.array([[1.0, -2.0], rotation @ [0, 0.5] + [1, -2], rotation @ [0, -0.4]
                            + [1, -2]])
        poses = make_poses(2, (*centres.T, np.full(3, angle)))
        u_pose, in_notch, on_floor = (take(poses, i) for i in range(3))
        result, hit = single_query(u_shape, u_pose, small_box, in_notch)
        assert not hit
        assert float(result.depth) == pytest.approx(-0.2, abs=1e-12)  # the gap to either arm
        _, hit_swapped = single_query(small_box, in_notch, u_shape, u_pose)
        assert not hit_swapped
        world_u = oracle.to_world(U_SHAPE, rotation, centres[0])
        world_box = oracle.to_world([[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]],
                                    rotation, centres[1])
        assert np.all(world_u.min(0) <= world_box.max(0))
        assert np.all(world_box.min(0) <= world_u.max(0))
        assert polygons_overlap(oracle.to_world(hull, rotation, centres[0]), world_box)[0]
        assert not polygons_overlap(world_u, world_box)[0]
        # Lowered to y in [-0.7, -0.1] in U's frame, it overlaps the notch floor (y <= -0.5).
        result, hit = single_query(u_shape, u_pose, small_box, on_floor)
        assert hit and float(result.depth) == pytest.approx(0.2, abs=1e-12)


def _both_slots(plain, pose_plain, shape, pose_shape):
    return (_query(plain, pose_plain, shape, pose_shape),
            _query(shape, pose_shape, plain, pose_plain),
            jaxsat.compound_penetration(plain, pose_plain, plain, pose_shape),
            jaxsat.penetration(plain, pose_plain, plain, pose_shape))


both_slots = jax.jit(_both_slots)


@pytest.mark.slow
def test_polytope_in_either_slot_2d():
    """A plain Polytope acts as a one-piece compound, in slot a or b, against the oracle, and
    gives what the same box as a padded one-piece Compound gives."""
    rng = np.random.default_rng(2)
    pool = get_pool(2, np.float64)
    corners = np.array([[-0.5, -0.3], [0.5, -0.3], [0.5, 0.3], [-0.5, 0.3]])
    plain, wrapped = as_numpy(jaxsat.box([0.5, 0.3])), pool_box_2d([0.5, 0.3])
    params = random_params(2, 2 * 6, rng, np.float64, 1.0)
    poses, transforms = make_poses(2, params), world_transforms(2, params)
    for k in range(6):
        shape = take(pool.compounds, k % 3)
        pose_shape, pose_plain = take(poses, 2 * k), take(poses, 2 * k + 1)
        pieces = to_world(pool.pieces[k % 3], transforms[2 * k])
        box_world = [oracle.to_world(corners, *transforms[2 * k + 1])]
        (plain_a, hit_a), (plain_b, hit_b), both_plain, direct = both_slots(
            plain, pose_plain, shape, pose_shape)
        for result, hit, swap in ((plain_a, hit_a, True), (plain_b, hit_b, False)):
            world_a, world_b = (box_world, pieces) if swap else (pieces, box_world)
            truth = pair_oracle(world_a, world_b, 1e-8)
            check_pair_result(float(result.depth), np.asarray(result.normal),
                              (int(result.piece_a), int(result.piece_b)), truth, world_a,
                              world_b, 1e-8, 1e-7)
            if abs(truth.depth) > 1e-8:
                assert bool(hit) == (truth.depth > 0)
            assert int(result.piece_a if swap else result.piece_b) == 0
        again, hit_again = single_query(wrapped, pose_plain, shape, pose_shape)
        np.testing.assert_allclose(again.depth, plain_a.depth, atol=1e-12)
        np.testing.assert_allclose(again.normal, plain_a.normal, atol=1e-12)
        assert bool(hit_again) == bool(hit_a)
        np.testing.assert_allclose(both_plain.depth, direct.depth, atol=1e-12)
        np.testing.assert_allclose(both_plain.normal, direct.normal, atol=1e-12)


@pytest.mark.slow
def test_polytope_in_slot_a_3d_float32():
    """3D float32: a plain box against the 3D compounds, penetration against the oracle."""
    rng = np.random.default_rng(6)
    dtype = np.float32
    pool = get_pool(3, dtype)
    half = np.array([0.5, 0.3, 0.4], dtype)
    plain = as_numpy(jaxsat.box(half))
    query = jax.jit(jax.vmap(jaxsat.compound_penetration, in_axes=(None, 0, 0, 0)))
    count = 32
    index = rng.integers(3, size=count)
    params_a, params_b = (random_params(3, count, rng, dtype, 1.0) for _ in range(2))
    result = as_numpy(query(plain, make_poses(3, params_a), take(pool.compounds, index),
                            make_poses(3, params_b)))
    assert result.depth.dtype == dtype and result.normal.dtype == dtype
    transforms_a, transforms_b = world_transforms(3, params_a), world_transforms(3, params_b)
    corners = cuboid(-half, half)
    for k in range(count):
        world_a = [oracle.to_world(corners, *transforms_a[k])]
        world_b = to_world(pool.pieces[index[k]], transforms_b[k])
        truth = pair_oracle(world_a, world_b, 1e-3)
        check_pair_result(result.depth[k], result.normal[k],
                          (int(result.piece_a[k]), int(result.piece_b[k])), truth, world_a,
                          world_b, 1e-4 * truth.size * 10, NORMAL_TOLERANCE[dtype])
        assert result.piece_a[k] == 0


def test_padding_pieces_never_change_results():
    """Unpadded compounds, compounds padded by `concave_polygon` (the pool) and compounds
    padded by `stack_compounds` (to the pool's size class, so no new compile) agree exactly."""
    rng = np.random.default_rng(3)
    pool = get_pool(2, np.float64).compounds
    bare = [jaxsat.concave_polygon(U_SHAPE), jaxsat.concave_polygon(star(5))]
    assert bare[0].num_pieces == 3 and bare[1].num_pieces == 6
    assert bare[0].pieces.vertices.shape == (3, 4, 2)
    stacked = as_numpy(jaxsat.stack_compounds(
        [*bare, jaxsat.concave_polygon(L_SHAPE, MAX_PIECES_2D, MAX_VERTICES_2D)]))
    assert stacked.pieces.vertices.shape == pool.pieces.vertices.shape == (3, 6, 6, 2)
    np.testing.assert_array_equal(stacked.piece_mask.sum(axis=1), [3, 6, 2])
    assert pool.piece_mask[1].tolist() == [True] * 3 + [False] * 3
    params = random_params(2, 16, rng, np.float64, 1.5)
    poses = make_poses(2, params)
    for k in range(8):
        pose_a, pose_b = take(poses, 2 * k), take(poses, 2 * k + 1)
        reference = single_query(take(pool, 1), pose_a, take(pool, 2), pose_b)
        for a, b in ((bare[0], bare[1]), (take(stacked, 0), take(stacked, 1))):
            result = single_query(a, pose_a, b, pose_b)
            for got, want in zip(jax.tree.leaves(result), jax.tree.leaves(reference),
                                 strict=True):
                np.testing.assert_allclose(got, want, atol=1e-12)


@pytest.mark.parametrize("batch_shape", [(BATCH,), (2, BATCH // 2)])
def test_vmap_over_stacked_compounds_equals_loop(batch_shape):
    rng = np.random.default_rng(4)
    pool = get_pool(2, np.float64)
    index_a, index_b = rng.integers(3, size=BATCH), rng.integers(3, size=BATCH)
    params_a = random_params(2, BATCH, rng, np.float64, 1.5)
    params_b = random_params(2, BATCH, rng, np.float64, 1.5)
    a, b = take(pool.compounds, index_a), take(pool.compounds, index_b)
    poses_a, poses_b = make_poses(2, params_a), make_poses(2, params_b)
    if len(batch_shape) == 1:
        function = batched_query  # the oracle tests' executable
    else:
        function = jax.jit(jax.vmap(jax.vmap(_query)))
    reshape = lambda tree: jax.tree.map(  # noqa: E731
        lambda leaf: leaf.reshape(batch_shape + leaf.shape[1:]), tree)
    batched = as_numpy(function(reshape(a), reshape(poses_a), reshape(b), reshape(poses_b)))
    flat = jax.tree.map(lambda leaf: leaf.reshape((BATCH,) + leaf.shape[len(batch_shape):]),
                        batched)
    for k in range(0, BATCH, 3):
        one = single_query(take(a, k), take(poses_a, k), take(b, k), take(poses_b, k))
        for got, want in zip(jax.tree.leaves(flat), jax.tree.leaves(one), strict=True):
            np.testing.assert_allclose(got[k], want, atol=1e-12)


def test_output_dtypes_follow_the_inputs():
    """float32 shapes and poses give float32; a float64 pose promotes, as `penetration` does
    (traced with eval_shape: nothing compiles)."""
    shape32 = jaxsat.concave_polygon(L_SHAPE, dtype=np.float32)
    assert shape32.dtype == np.float32
    pose32 = jaxsat.Pose(np.zeros(2, np.float32), np.eye(2, dtype=np.float32))
    pose64 = jaxsat.Pose(np.zeros(2), np.eye(2))
    for query in (jaxsat.compound_penetration, jaxsat.compound_intersects):
        same = jax.eval_shape(query, shape32, pose32, shape32, pose32)
        mixed = jax.eval_shape(query, shape32, pose32, shape32, pose64)
        if query is jaxsat.compound_intersects:
            assert same.dtype == mixed.dtype == np.bool_ and same.shape == ()
        else:
            assert same.depth.dtype == same.normal.dtype == np.float32
            assert mixed.depth.dtype == np.float64 and same.piece_a.dtype == np.int32


# --------------------------------------------------------------------------------------------
# Gradients
# --------------------------------------------------------------------------------------------


def _depth_2d(shape_a, shape_b, params_a, params_b):
    return jaxsat.compound_penetration(shape_a, jaxsat.pose2(*params_a), shape_b,
                                       jaxsat.pose2(*params_b)).depth


depth_gradient = jax.jit(jax.value_and_grad(_depth_2d, argnums=(2, 3)))
"""d depth / d (x, y, angle) of both poses; one executable for the 2D pool's size class."""


def oracle_gradient(piece_a, piece_b, params_a, params_b, step: float = 1e-6):
    """Central differences of the oracle depth of one piece pair, (x, y, angle) of a then b."""
    def depth(values):
        (xa, ya, angle_a), (xb, yb, angle_b) = values[:3], values[3:]
        world_a = oracle.to_world(piece_a, oracle.rotation_2d(angle_a), [xa, ya])
        world_b = oracle.to_world(piece_b, oracle.rotation_2d(angle_b), [xb, yb])
        return oracle.evaluate(world_a, world_b).depth
    values = np.array([*params_a, *params_b], np.float64)
    steps = np.eye(6) * step
    return np.array([(depth(values + s) - depth(values - s)) / (2 * step) for s in steps])


@pytest.mark.slow
def test_gradients_are_the_winning_pairs():
    """d depth / d pose parameters is finite and equals the winning piece pair's gradient
    (the same compiled gradient on one-piece compounds holding just those two pieces), and
    matches central differences of the oracle where the winner is clear. Poses: overlapping,
    separated, and identical (deep overlap, many near-ties)."""
    rng = np.random.default_rng(5)
    pool = get_pool(2, np.float64)
    params = random_params(2, 2 * 10, rng, np.float64, 0.8)
    poses = make_poses(2, params)
    checked = 0
    for k in range(10):
        i, j = 2 * k, 2 * k + (1 if k else 0)
        which_a, which_b = k % 3, (k + 1) % 3
        shape_a, shape_b = take(pool.compounds, which_a), take(pool.compounds, which_b)
        params_a, params_b = take(params, i), take(params, j)
        result, _ = single_query(shape_a, take(poses, i), shape_b, take(poses, j))
        value, got = depth_gradient(shape_a, shape_b, params_a, params_b)
        piece_a, piece_b = int(result.piece_a), int(result.piece_b)
        alone_a, alone_b = (
            as_numpy(jaxsat.compound([take(shape.pieces, piece)], MAX_PIECES_2D, MAX_VERTICES_2D))
            for shape, piece in ((shape_a, piece_a), (shape_b, piece_b)))
        pair_value, want = depth_gradient(alone_a, alone_b, params_a, params_b)
        assert float(value) == pytest.approx(float(result.depth), abs=1e-12)
        assert float(pair_value) == pytest.approx(float(value), abs=1e-12)
        got = np.array([float(g) for g in jax.tree.leaves(got)])
        want = np.array([float(w) for w in jax.tree.leaves(want)])
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(got, want, atol=1e-12)
        transform_a, transform_b = world_transforms(2, params)[i], world_transforms(2, params)[j]
        truth = pair_oracle(to_world(pool.pieces[which_a], transform_a),
                            to_world(pool.pieces[which_b], transform_b), 1e-4)
        # Identical poses (k = 0) put parallel edges of the axis-aligned pieces in contact: a
        # kink of the depth in the angles, where central differences average the two sides.
        if k and truth.depth > 1e-3 and truth.decided:
            checked += 1
            numeric = oracle_gradient(pool.pieces[which_a][piece_a],
                                      pool.pieces[which_b][piece_b], params_a, params_b)
            np.testing.assert_allclose(got, numeric, atol=1e-5)
    assert checked >= 3


def test_gradients_finite_when_touching():
    shape, square = take(get_pool(2, np.float64).compounds, 0), pool_box_2d([0.5, 0.5])
    zero = np.float64(0.0)
    # x = 1.7: the square's left side lies exactly on the L's right side (x = 1.2).
    for x in (1.7, 1.6, 0.0):
        value, gradient = depth_gradient(shape, square, (zero, zero, zero),
                                         (np.float64(x), np.float64(-0.3), zero))
        assert np.isfinite(float(value))
        assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(gradient))
        if x == 1.7:
            assert float(value) == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------------------------
# Construction and errors
# --------------------------------------------------------------------------------------------


def test_compound_construction():
    pieces = PIECES_3D["table"]
    shape = jaxsat.compound(pieces)
    assert shape.dim == 3 and shape.num_pieces == 5 and shape.batch_shape == ()
    assert shape.pieces.vertices.shape == (5, 8, 3)
    assert np.asarray(shape.piece_mask).all()
    padded = jaxsat.compound([jaxsat.polyhedron(p) for p in pieces], max_pieces=7,
                             max_vertices=10)
    assert padded.pieces.vertices.shape == (7, 10, 3)
    assert padded.pieces.face_normals.shape == (7, 16, 3)
    assert np.asarray(padded.piece_mask).tolist() == [True] * 5 + [False] * 2
    np.testing.assert_array_equal(padded.pieces.vertices[5], padded.pieces.vertices[0])
    one = jaxsat.compound(jaxsat.box([1.0, 2.0]))
    assert one.num_pieces == 1 and one.dim == 2
    assert jaxsat.compound([L_SHAPE[:3].astype(np.float32)]).dtype == np.float32
    stacked = jaxsat.stack_compounds([shape, padded, jaxsat.box([1.0, 1.0, 1.0])])
    assert stacked.batch_shape == (3,) and stacked.num_pieces == 7
    assert np.asarray(stacked.piece_mask).sum(axis=1).tolist() == [5, 5, 1]
    convex = jaxsat.concave_polygon(np.array([[0, 0], [1, 0], [0, 1.0]]), max_pieces=2)
    assert np.asarray(convex.piece_mask).tolist() == [True, False]
    pieces_u = jaxsat.concave_polygon(U_SHAPE)
    assert pieces_u.num_pieces == 3 and pieces_u.pieces.vertices.shape == (3, 4, 2)


def _square(dtype=np.float64):
    return np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype)


BAD_COMPOUNDS = {
    "empty": (lambda: jaxsat.compound([]), "at least one piece"),
    "mixed dims": (lambda: jaxsat.compound([_square(), cuboid((0, 0, 0), (1, 1, 1))]),
                   "mix 2D and 3D"),
    "mixed dtypes": (lambda: jaxsat.compound([_square(), _square(np.float32)]), "mix dtypes"),
    "too many pieces": (lambda: jaxsat.compound([_square()] * 3, max_pieces=2),
                        "more than max_pieces"),
    "bad max_pieces": (lambda: jaxsat.compound([_square()], max_pieces=0), "positive integer"),
    "too many vertices": (lambda: jaxsat.compound([jaxsat.regular_polygon(9)], max_vertices=8),
                          "more than max_vertices"),
    "concave piece": (lambda: jaxsat.compound([L_SHAPE]), "not convex"),
    "batched piece": (lambda: jaxsat.compound([jaxsat.stack([jaxsat.box([1.0, 1.0])])]),
                      "batched"),
    "compound piece": (lambda: jaxsat.compound([jaxsat.compound([_square()])]), "Compound",
                       TypeError),
    "flat piece": (lambda: jaxsat.compound([np.zeros(4)]), "vertex array"),
    "bad polygon": (lambda: jaxsat.concave_polygon([[0, 0], [1, 1], [1, 0], [0, 1]]),
                    "self-intersecting"),
    "polygon pieces": (lambda: jaxsat.concave_polygon(star(5), max_pieces=3),
                       "more than max_pieces"),
    "polygon vertices": (lambda: jaxsat.concave_polygon(U_SHAPE, max_vertices=3),
                         "more than max_vertices"),
    "polygon dtype": (lambda: jaxsat.concave_polygon(U_SHAPE, dtype=np.int32), "floating"),
    "stack empty": (lambda: jaxsat.stack_compounds([]), "at least one"),
    "stack dims": (lambda: jaxsat.stack_compounds([jaxsat.compound([_square()]),
                                                   jaxsat.compound(PIECES_3D["box"])]),
                   "mix 2D and 3D"),
    "stack dtypes": (lambda: jaxsat.stack_compounds([jaxsat.compound([_square()]),
                                                     jaxsat.compound([_square(np.float32)])]),
                     "mix dtypes"),
    "stack batched": (lambda: jaxsat.stack_compounds([jaxsat.stack_compounds([
        jaxsat.compound([_square()])])]), "batched"),
    "stack other": (lambda: jaxsat.stack_compounds([np.zeros((4, 2))]),
                    "Compound or jaxsat.Polytope", TypeError),
}


@pytest.mark.parametrize("name", sorted(BAD_COMPOUNDS))
def test_bad_construction_raises(name):
    """TypeError for an argument of the wrong type, ValueError for a bad value."""
    build, message, *error = BAD_COMPOUNDS[name]
    with pytest.raises(error[0] if error else ValueError, match=message):
        build()


def test_bad_queries_raise():
    shape = jaxsat.concave_polygon(L_SHAPE)
    shape_3d = jaxsat.compound(PIECES_3D["L"])
    batch = jaxsat.stack_compounds([shape, shape])
    identity, identity_3d = (jaxsat.Pose(np.zeros(d), np.eye(d)) for d in (2, 3))
    batched_pose = jaxsat.Pose(np.zeros((2, 2)), np.stack([np.eye(2)] * 2))
    for query in (jaxsat.compound_penetration, jaxsat.compound_intersects):
        with pytest.raises(ValueError, match="one pair"):
            query(batch, identity, shape, identity)
        with pytest.raises(ValueError, match="one pair"):
            query(shape, identity, shape, batched_pose)
        with pytest.raises(ValueError, match="one pair"):
            query(jaxsat.stack([jaxsat.box([1.0, 1.0])] * 2), identity, shape, identity)
        with pytest.raises(TypeError, match="Compound or jaxsat.Polytope"):
            query(L_SHAPE, identity, shape, identity)
        with pytest.raises(TypeError, match="jaxsat.Pose"):
            query(shape, identity, shape, np.zeros(3))
        with pytest.raises(ValueError, match="one dimension"):
            query(shape, identity, shape_3d, identity_3d)
        with pytest.raises(ValueError, match="one dimension"):
            query(shape, identity_3d, shape, identity_3d)
