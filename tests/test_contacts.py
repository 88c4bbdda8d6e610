"""Oracle and property tests for jaxsat.contacts.

Random pairs are checked against independent NumPy/SciPy geometry built from the raw points
the shapes were made of, moved to the world frame with SciPy rotations (`oracle.py`): the
convex hull of each world shape, its halfspaces and the exact point-to-hull distance. Every
query runs through one cached `jax.jit(jax.vmap(...))` per size class and dtype, on batches of
exactly BATCH pairs (the margin is a batched argument), so that each class compiles once.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from harness import FAST_COMPILE
from scipy.spatial import ConvexHull

import jaxsat
from jaxsat._contacts import _manifold

BATCH = 64
"""Every batched call uses this many pairs (the last chunk is padded), so nothing recompiles."""

RELATIVE_TOLERANCE = {np.float64: 1e-9, np.float32: 2e-4}
"""Length tolerance relative to the shapes' size (largest world coordinate)."""

DTYPES = [np.float64, np.float32]
DTYPE_IDS = ["float64", "float32"]


# --------------------------------------------------------------------------------------------
# Shapes, poses and batched evaluation.
# --------------------------------------------------------------------------------------------


def _random_polygon(rng):
    """A box, or 3 to 8 vertices on a random off-centre ellipse (padded to 8)."""
    if rng.integers(3) == 0:
        half = rng.uniform(0.2, 1.0, 2)
        points = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    else:
        count = int(rng.integers(3, 9))
        while True:
            angles = np.sort(rng.uniform(0, 2 * np.pi, count))
            if np.min(np.diff(np.append(angles, angles[0] + 2 * np.pi))) > 0.2:
                break
        circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        points = circle * rng.uniform(0.3, 1.0, 2) + rng.uniform(-0.3, 0.3, 2)
    return points, lambda dtype: jaxsat.polygon(points.astype(dtype), 8, dtype=dtype)


def _cuboid_corners(half):
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * np.asarray(half, float)


def _random_box(rng):
    half = rng.uniform(0.2, 1.0, 3)
    return _cuboid_corners(half), lambda dtype: jaxsat.box(half.astype(dtype), dtype=dtype)


def _random_hull(rng):
    """The hull of 20 points on (or inside) a stretched, off-centre sphere; a quarter are boxes
    padded to 20 vertices (parallelepipeds through the general-hull path)."""
    if rng.integers(4) == 0:
        half = rng.uniform(0.2, 1.0, 3)
        return _cuboid_corners(half), lambda dtype: jaxsat.box(half.astype(dtype), 20,
                                                                dtype=dtype)
    points = rng.normal(size=(20, 3))
    if rng.integers(2):
        points /= np.linalg.norm(points, axis=1, keepdims=True)
    else:
        points /= np.max(np.linalg.norm(points, axis=1))
    points = points * rng.uniform(0.3, 1.0, 3) + rng.uniform(-0.3, 0.3, 3)
    return points, lambda dtype: jaxsat.polyhedron(points.astype(dtype), 20, dtype=dtype)


GENERATORS = {"poly8": (2, _random_polygon), "box": (3, _random_box),
              "hull20": (3, _random_hull)}


@dataclasses.dataclass
class Pairs:
    """A batch of pairs: stacked shapes and poses (NumPy rotations), with their raw points."""

    a: jaxsat.Polytope
    b: jaxsat.Polytope
    rotation_a: np.ndarray
    translation_a: np.ndarray
    rotation_b: np.ndarray
    translation_b: np.ndarray
    points_a: list[np.ndarray]
    points_b: list[np.ndarray]
    margin: np.ndarray
    dtype: type

    def __len__(self) -> int:
        return len(self.points_a)

    def world(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        return (oracle.to_world(self.points_a[index], self.rotation_a[index],
                                self.translation_a[index]),
                oracle.to_world(self.points_b[index], self.rotation_b[index],
                                self.translation_b[index]))


def _rotations(dim: int, rng, count: int) -> np.ndarray:
    if dim == 2:
        return np.stack([oracle.rotation_2d(angle) for angle in rng.uniform(-np.pi, np.pi, count)])
    return np.stack([oracle.rotation_3d(q) for q in rng.normal(size=(count, 4))])


def make_pairs(shapes_a, shapes_b, rotation_a, translation_a, rotation_b, translation_b, dtype,
               points_a, points_b, margin=0.0) -> Pairs:
    """Pairs from lists of shapes and arrays of poses (rotations and translations rounded to
    `dtype`, so that the oracle sees exactly the poses the library gets)."""
    as_dtype = lambda x: np.asarray(x).astype(dtype).astype(np.float64)  # noqa: E731
    return Pairs(jaxsat.stack(shapes_a), jaxsat.stack(shapes_b), as_dtype(rotation_a),
                 as_dtype(translation_a), as_dtype(rotation_b), as_dtype(translation_b),
                 [as_dtype(p) for p in points_a], [as_dtype(p) for p in points_b],
                 np.broadcast_to(np.asarray(margin, np.float64), (len(points_a),)), dtype)


@functools.cache
def pool(name: str, dtype, size: int = 12):
    """A few shapes of one size class: (raw points, shapes)."""
    rng = np.random.default_rng([3, len(name)])
    generated = [GENERATORS[name][1](rng) for _ in range(size)]
    return [points for points, _ in generated], [factory(dtype) for _, factory in generated]


def random_pairs(name: str, dtype, count: int, seed: int, distance=(0.0, 1.6)) -> Pairs:
    """Random pairs of one class whose origins are `distance` apart, any rotations."""
    dim = GENERATORS[name][0]
    rng = np.random.default_rng([seed, len(name)])
    points, shapes = pool(name, dtype)
    index_a, index_b = rng.integers(len(shapes), size=(2, count))
    translation_a = rng.uniform(-2, 2, (count, dim))
    direction = rng.normal(size=(count, dim))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    translation_b = translation_a + direction * rng.uniform(*distance, (count, 1))
    return make_pairs([shapes[i] for i in index_a], [shapes[i] for i in index_b],
                      _rotations(dim, rng, count), translation_a, _rotations(dim, rng, count),
                      translation_b, dtype, [points[i] for i in index_a],
                      [points[i] for i in index_b])


def _query(a, pose_a, b, pose_b, margin):
    result, details = _manifold(a, pose_a, b, pose_b, margin)
    # _manifold's own penetration result (tracing penetration again would cost a second);
    # test_default_build_agrees checks the normal against a separate penetration call.
    return result, details, jaxsat.Penetration(depth=details.depth, normal=result.normal)


# FAST_COMPILE halves the compile time of each size class (results agree with the default
# build up to rounding; test_default_build_agrees checks that).
batched_query = jax.jit(jax.vmap(_query), compiler_options=FAST_COMPILE)
"""One jitted function for every test: jit caches one executable per size class and dtype."""


def _stacked_poses(pairs: Pairs):
    return (jaxsat.Pose(pairs.translation_a.astype(pairs.dtype),
                        pairs.rotation_a.astype(pairs.dtype)),
            jaxsat.Pose(pairs.translation_b.astype(pairs.dtype),
                        pairs.rotation_b.astype(pairs.dtype)))


def take(tree, index):
    return jax.tree.map(lambda leaf: leaf[index], tree)


def evaluate(pairs: Pairs):
    """(Contacts, details, Penetration) as NumPy trees, evaluated in chunks of exactly BATCH."""
    count = len(pairs)
    padded = np.resize(np.arange(count), -(-count // BATCH) * BATCH)
    dtype = pairs.dtype
    poses_a, poses_b = _stacked_poses(pairs)
    margin = np.asarray(pairs.margin, dtype)
    # NumPy indexing: indexing JAX arrays eagerly compiles a gather per shape.
    arguments = jax.tree.map(np.asarray, (pairs.a, poses_a, pairs.b, poses_b))
    chunks = []
    for start in range(0, len(padded), BATCH):
        chunk = padded[start:start + BATCH]
        chunks.append(batched_query(*take(arguments, chunk), margin[chunk]))
    joined = jax.tree.map(lambda *leaves: np.concatenate(leaves)[:count], *chunks)
    for leaf in jax.tree.leaves(joined):
        assert leaf.dtype in (dtype, np.bool_)
        if leaf.dtype != np.bool_:
            assert np.all(np.isfinite(leaf))
    return joined


def identity_pairs(shape_a, points_a, shape_b, points_b, poses_b, dtype, pose_a=None, margin=0.0):
    """Pairs of one fixed a (identity pose unless given) and one b at each of `poses_b`
    ((rotation, translation) pairs)."""
    dim = points_a.shape[1]
    count = len(poses_b)
    rotation_a, translation_a = pose_a or (np.eye(dim), np.zeros(dim))
    return make_pairs([shape_a] * count, [shape_b] * count, [rotation_a] * count,
                      [translation_a] * count, [r for r, _ in poses_b], [t for _, t in poses_b],
                      dtype, [points_a] * count, [points_b] * count, margin)


def rotation_z(angle: float) -> np.ndarray:
    return oracle.rotation_3d([np.cos(angle / 2), 0, 0, np.sin(angle / 2)])


def rotation_axis(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return oracle.rotation_3d([np.cos(angle / 2), *(np.sin(angle / 2) * axis)])


def valid_points(result, index):
    valid = result.valid[index]
    return result.points[index][valid].astype(np.float64), result.depths[index][valid]


def assert_same_point_set(points, expected, tol):
    """Equal as sets (any order), each point matched within tol."""
    points, expected = np.asarray(points, float), np.asarray(expected, float)
    assert points.shape == expected.shape, (points, expected)
    distances = np.linalg.norm(points[:, None] - expected[None], axis=-1)
    assert np.all(np.min(distances, axis=1) <= tol), (points, expected)
    assert np.all(np.min(distances, axis=0) <= tol), (points, expected)


# --------------------------------------------------------------------------------------------
# Random pairs against the independent geometry.
# --------------------------------------------------------------------------------------------


def _surface_gap(hull: ConvexHull, point) -> tuple[float, float]:
    """(distance from the hull, largest halfspace value): a point on the surface has both ~0."""
    dim = hull.points.shape[1]
    return (oracle.distance_to_hull(hull, point),
            float(np.max(hull.equations[:, :dim] @ point + hull.equations[:, dim])))


def check_random_pairs(pairs: Pairs):
    """Assert the documented properties of every pair (tol = relative tolerance * size):

    * slots are valid-first and invalid ones copy slot 0;
    * penetration depth < -margin: no valid point; overlap: at least one;
    * every valid depth >= -margin - tol and <= penetration depth + tol, and the deepest equals
      the exact depth (the oracle's minimum over the Minkowski difference's facets), within tol
      for at least 90% of the pairs and within the documented 2e-3 * size for all;
    * every valid point m is the midpoint of a point on a's surface, m + depth/2 n, and one on
      b's surface, m - depth/2 n (so it lies within depth/2 of each shape);
    * for face contacts, each depth is the incident point's distance below the reference face
      plane (the supporting plane of the world points along the reported face normal),
      measured along the normal.
    Returns the evaluated trees."""
    result, details, reference = evaluate(pairs)
    rel = RELATIVE_TOLERANCE[pairs.dtype]
    valid = result.valid
    assert np.all(valid[:, 1:] <= valid[:, :-1])
    invalid = ~valid
    assert np.all((result.points == result.points[:, :1])[invalid])
    assert np.all((result.depths == result.depths[:, :1])[invalid])
    failures, deepest_exact = [], []
    for i in range(len(pairs)):
        world_a, world_b = pairs.world(i)
        size = max(np.max(np.abs(world_a)), np.max(np.abs(world_b)))
        tol, margin, depth = rel * size, pairs.margin[i], float(reference.depth[i])
        problems = []
        if depth < -margin - tol and valid[i].any():
            problems.append("separated beyond the margin but has valid points")
        if depth > tol and not valid[i].any():
            problems.append("overlapping but no valid point")
        points, depths = valid_points(result, i)
        normal = result.normal[i].astype(np.float64)
        if len(depths):
            if np.any(depths < -margin - tol) or np.any(depths > depth + tol):
                problems.append(f"depths {depths} outside [-margin, {depth}]")
            exact = oracle.evaluate(world_a, world_b).depth
            # Near-flat contacts may keep stable corners up to 2e-3 * (the shapes' largest local
            # coordinate) shallower (documented).
            local = max(np.max(np.abs(pairs.points_a[i])), np.max(np.abs(pairs.points_b[i])))
            if depth > 0 and abs(np.max(depths) - exact) > tol + 2e-3 * local:
                problems.append(f"deepest {np.max(depths)} != exact depth {exact}")
            deepest_exact.append(depth <= 0 or abs(np.max(depths) - exact) <= tol)
        hull_a, hull_b = ConvexHull(world_a), ConvexHull(world_b)
        for point, point_depth in zip(points, depths.astype(np.float64), strict=True):
            on_a, on_b = point + point_depth / 2 * normal, point - point_depth / 2 * normal
            for name, hull, surface_point in (("a", hull_a, on_a), ("b", hull_b, on_b)):
                distance, height = _surface_gap(hull, surface_point)
                if distance > tol or height < -tol:
                    problems.append(f"{name}'s point {surface_point} is {distance:.3g} outside, "
                                    f"{-height:.3g} inside")
            if details.single_point[i]:
                continue
            if details.reference_is_b[i]:
                face, world, incident, direction = details.face_normal_b[i], world_b, on_a, -normal
            else:
                face, world, incident, direction = details.face_normal_a[i], world_a, on_b, normal
            face = face.astype(np.float64)
            below = (np.max(world @ face) - incident @ face) / (face @ direction)
            if abs(below - point_depth) > tol:
                problems.append(f"depth {point_depth} != distance below the reference {below}")
        if problems:
            failures.append(f"pair {i}: depth {depth!r}: " + "; ".join(problems[:3]))
    assert not failures, f"{len(failures)} of {len(pairs)} pairs fail:\n" + "\n".join(failures[:8])
    if deepest_exact:
        assert np.mean(deepest_exact) >= 0.9
    return result, details, reference


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
@pytest.mark.parametrize("name", list(GENERATORS))
def test_random_pairs(name, dtype):
    """Random pairs from deep overlap to separation; face-face, edge-face, vertex-face and (3D)
    edge-edge contacts all occur."""
    pairs = random_pairs(name, dtype, 2 * BATCH, seed=1)
    result, details, reference = check_random_pairs(pairs)
    overlapping = reference.depth > 0
    assert 0.3 < overlapping.mean() < 0.95
    counts = np.bincount(result.valid[overlapping].sum(axis=1), minlength=5)
    assert counts[1] > 0 and counts[2] > 0  # single points and segments
    if GENERATORS[name][0] == 3:
        assert counts[4] > 0 and np.any(details.single_point[overlapping])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(GENERATORS))
def test_random_pairs_with_margin(name):
    """Pairs moved along their normal to depths from 0.02 (overlap) to -0.08 (a gap), with a
    margin of 0.05 that makes near points valid."""
    pairs = random_pairs(name, np.float64, BATCH, seed=2)
    _, _, reference = evaluate(pairs)
    targets = np.linspace(0.02, -0.08, len(pairs))
    shift = (reference.depth - targets)[:, None] * reference.normal
    pairs = dataclasses.replace(pairs, translation_b=pairs.translation_b + shift,
                                margin=np.full(len(pairs), 0.05))
    result, _, reference = check_random_pairs(pairs)
    near = (reference.depth < 0) & (reference.depth > -0.05)
    assert np.sum(near) > 5 and np.all(result.valid[near].any(axis=1))
    assert np.any(result.depths[result.valid] < 0)


# --------------------------------------------------------------------------------------------
# Configurations with known manifolds.
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [pytest.param(dtype, id=name, marks=(pytest.mark.slow,) if
                                               name == "float64" else ())
                                  for dtype, name in zip(DTYPES, DTYPE_IDS, strict=True)])
def test_box_resting_on_larger_box(dtype):
    """4 points at the resting box's bottom corners, halfway into the overlap, with its depth;
    also with the roles swapped (the normal flips, the points stay)."""
    big, small = np.array([2.0, 1.5, 0.5]), np.array([0.4, 0.3, 0.2])
    depth, angle, offset = 0.01, 0.4, np.array([0.3, -0.2, 0.0])
    rotation = rotation_z(angle)
    centre = offset + [0, 0, big[2] + small[2] - depth]
    corners = oracle.to_world(_cuboid_corners(small), rotation, centre)
    expected = corners[corners[:, 2] < centre[2]] + [0, 0, depth / 2]
    tol = 1e3 * np.finfo(dtype).eps
    pairs = identity_pairs(jaxsat.box(big, dtype=dtype), _cuboid_corners(big),
                           jaxsat.box(small, dtype=dtype), _cuboid_corners(small),
                           [(rotation, centre)], dtype)
    swapped = make_pairs([jaxsat.box(small, dtype=dtype)], [jaxsat.box(big, dtype=dtype)],
                         [rotation], [centre], [np.eye(3)], [np.zeros(3)], dtype,
                         [_cuboid_corners(small)], [_cuboid_corners(big)])
    for batch, normal in ((pairs, [0, 0, 1]), (swapped, [0, 0, -1])):
        result, details, _ = check_random_pairs(batch)
        assert result.valid[0].all()
        np.testing.assert_allclose(result.normal[0], normal, atol=tol)
        np.testing.assert_allclose(result.depths[0], depth, atol=tol)
        assert_same_point_set(result.points[0], expected, tol)
        assert not details.single_point[0]
        # Boxes leave no wedge: each point lies inside both shapes.
        world_a, world_b = batch.world(0)
        for point in result.points[0].astype(np.float64):
            assert oracle.distance_to_hull(ConvexHull(world_a), point) <= tol
            assert oracle.distance_to_hull(ConvexHull(world_b), point) <= tol


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_box_resting_on_equal_box(dtype):
    """Equal boxes, a's and b's faces tie: 4 points at the corners of the overlap rectangle,
    a's face is the reference."""
    half = np.array([1.0, 0.5, 0.25])
    depth, shift = 0.01, np.array([0.3, 0.1])
    centre = np.array([*shift, 2 * half[2] - depth])
    box = jaxsat.box(half, dtype=dtype)
    pairs = identity_pairs(box, _cuboid_corners(half), box, _cuboid_corners(half),
                           [(np.eye(3), centre)], dtype)
    result, details, _ = check_random_pairs(pairs)
    low, high = np.maximum(-half[:2], shift - half[:2]), np.minimum(half[:2], shift + half[:2])
    expected = [[x, y, half[2] - depth / 2] for x in (low[0], high[0]) for y in (low[1], high[1])]
    tol = 1e3 * np.finfo(dtype).eps
    assert result.valid[0].all() and not details.reference_is_b[0]
    np.testing.assert_allclose(result.depths[0], depth, atol=tol)
    assert_same_point_set(result.points[0], expected, tol)


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_square_resting_on_rectangle(dtype):
    """2D: two points at the resting square's bottom corners; tilted, one point at the lower
    corner."""
    big, small = np.array([2.0, 0.5]), np.array([0.3, 0.3])
    corners = lambda half: np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half  # noqa: E731
    depth = 0.02
    flat = (np.eye(2), np.array([0.5, big[1] + small[1] - depth]))
    tilted_rotation = oracle.rotation_2d(0.3)
    lowest = np.min((corners(small) @ tilted_rotation.T)[:, 1])
    tilted = (tilted_rotation, np.array([-0.4, big[1] - lowest - depth]))
    pairs = identity_pairs(jaxsat.box(big, 8, dtype=dtype), corners(big),
                           jaxsat.box(small, 8, dtype=dtype), corners(small), [flat, tilted], dtype)
    result, _, _ = check_random_pairs(pairs)
    tol = 1e3 * np.finfo(dtype).eps
    assert result.valid[0].all() and result.valid[1].tolist() == [True, False]
    y = big[1] - depth / 2
    assert_same_point_set(result.points[0], [[0.2, y], [0.8, y]], tol)
    np.testing.assert_allclose(result.depths[:, 0], depth, atol=tol)
    bottom = oracle.to_world(corners(small), *tilted)
    expected = bottom[np.argmin(bottom[:, 1])] + [0, depth / 2]
    np.testing.assert_allclose(result.points[1, 0], expected, atol=tol)


def test_crossed_edges_give_one_point():
    """Edge-edge: a's top edge (box turned 45 degrees about x) crosses b's bottom edge (turned
    about y): one point, the midpoint of the two edges' closest points, with the exact depth."""
    half, depth = np.ones(3), 0.1
    reach = np.sqrt(2.0)  # the turned boxes' half height
    rotation_a = rotation_axis([1, 0, 0], np.pi / 4)
    rotation_b = rotation_axis([0, 1, 0], np.pi / 4)
    offset = np.array([0.1, 0.2, 2 * reach - depth])
    box = jaxsat.box(half)
    pairs = identity_pairs(box, _cuboid_corners(half), box, _cuboid_corners(half),
                           [(rotation_b, offset), (rotation_b, offset + [0.3, -0.4, 0])],
                           np.float64, pose_a=(rotation_a, np.zeros(3)))
    result, details, _ = check_random_pairs(pairs)
    assert np.all(details.single_point)
    assert result.valid.sum(axis=1).tolist() == [1, 1]
    for i, (x, y) in enumerate([(0.1, 0.0), (0.4, 0.0)]):
        # a's edge runs along x at (y, z) = (0, reach); b's along y at x = offset x.
        np.testing.assert_allclose(result.points[i, 0], [x, y, reach - depth / 2], atol=1e-12)
        np.testing.assert_allclose(result.depths[i, 0], depth, atol=1e-12)
        np.testing.assert_allclose(result.normal[i], [0, 0, 1], atol=1e-12)


def test_cube_corner_on_face_gives_one_point():
    """Vertex-face: a cube standing on its corner gives that corner (halfway into the overlap)."""
    half, depth = np.ones(3), 0.05
    # Turn the diagonal (1, 1, 1) onto -z, so that the corner (1, 1, 1) points down.
    axis = np.cross([1, 1, 1], [0, 0, -1])
    rotation = rotation_axis(axis, np.arccos(-1 / np.sqrt(3)))
    corner = rotation @ half
    centre = np.array([0.2, 0.1, half[2] - corner[2] - depth])
    box = jaxsat.box(half)
    pairs = identity_pairs(box, _cuboid_corners(half), box, _cuboid_corners(half),
                           [(rotation, centre)], np.float64)
    result, details, _ = check_random_pairs(pairs)
    assert result.valid[0].tolist() == [True, False, False, False]
    assert not details.single_point[0] and details.reference_is_b[0] == np.False_
    np.testing.assert_allclose(result.points[0, 0], corner + centre + [0, 0, depth / 2],
                               atol=1e-12)
    np.testing.assert_allclose(result.depths[0, 0], depth, atol=1e-12)


# --------------------------------------------------------------------------------------------
# No jitter: slow motions and noise keep the reference face and move points continuously.
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_sliding_rotating_box_moves_points_continuously(dtype):
    """A box sliding and slowly turning on a larger box for 200 frames: the reference face,
    the faces and the normal never change, and the 4 points follow the box's bottom corners."""
    big, small, depth = np.array([2.0, 2.0, 0.5]), np.array([0.5, 0.3, 0.2]), 0.01
    frames = np.arange(200)
    poses = [(rotation_z(0.004 * k), np.array([-0.8 + 0.008 * k, 0.2 - 0.002 * k,
                                               big[2] + small[2] - depth])) for k in frames]
    pairs = identity_pairs(jaxsat.box(big, dtype=dtype), _cuboid_corners(big),
                           jaxsat.box(small, dtype=dtype), _cuboid_corners(small), poses, dtype)
    result, details, _ = evaluate(pairs)
    tol = 1e3 * np.finfo(dtype).eps
    assert result.valid.all() and not details.reference_is_b.any()
    assert not details.single_point.any()
    np.testing.assert_allclose(details.face_normal_a, [[0, 0, 1]] * len(frames), atol=tol)
    np.testing.assert_allclose(details.face_normal_b, [[0, 0, -1]] * len(frames), atol=tol)
    np.testing.assert_allclose(result.normal, [[0, 0, 1]] * len(frames), atol=tol)
    for k, (rotation, centre) in enumerate(poses):
        corners = oracle.to_world(_cuboid_corners(small), rotation, centre)
        expected = corners[corners[:, 2] < centre[2]] + [0, 0, depth / 2]
        assert_same_point_set(result.points[k], expected, tol)
    # Consecutive frames: each point moves by at most the corners' motion (here < 0.01).
    steps = np.linalg.norm(result.points[1:, :, None] - result.points[:-1, None], axis=-1)
    assert np.max(np.min(steps, axis=2)) < 0.012


@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_resting_equal_boxes_with_noise_do_not_jitter(dtype):
    """Equal boxes resting on each other (a's and b's faces tie, so the penetration axis comes
    out of either) under pose noise of 1e-4 (radians and lengths, as from a solver): the
    reference stays a's face, the normal stays up and the 4 points stay at the 4 corners,
    though near-parallel edges cross at sliver corners that can be a hair deeper."""
    half, depth, noise = np.array([0.5, 0.5, 0.5]), 0.01, 1e-4
    rng = np.random.default_rng(5)
    poses = [(rotation_axis(rng.normal(size=3), noise * rng.normal()),
              np.array([0.0, 0.0, 1.0 - depth]) + noise * rng.normal(size=3))
             for _ in range(200)]
    box = jaxsat.box(half, dtype=dtype)
    pairs = identity_pairs(box, _cuboid_corners(half), box, _cuboid_corners(half), poses, dtype)
    result, details, reference = evaluate(pairs)
    assert result.valid.all() and not details.reference_is_b.any()
    assert not details.single_point.any()
    assert np.all(result.normal[:, 2] > 1 - noise)
    on_b = np.any(result.normal != [0, 0, 1], axis=1)  # b's tilted face gave the normal
    assert 0 < on_b.sum() < len(poses)
    expected = [[x, y, 0.5 - depth / 2] for x in (-0.5, 0.5) for y in (-0.5, 0.5)]
    for k in range(len(poses)):
        assert_same_point_set(result.points[k], expected, 20 * noise)
    deepest = np.max(result.depths, axis=1)
    np.testing.assert_allclose(deepest, reference.depth, atol=1e3 * np.finfo(dtype).eps)


def test_sliding_equal_boxes_keep_reference_and_normal():
    """Equal boxes, b sliding and turning on a for 200 frames (an up to 8-sided overlap
    reduced to 4 points): the reference and normal never flip, every frame has 4 points on
    the boundary of the overlap, at the full depth."""
    half, depth = np.array([0.5, 0.5, 0.5]), 0.02
    poses = [(rotation_z(0.005 * k), np.array([0.002 * k, -0.001 * k, 1.0 - depth]))
             for k in range(200)]
    box = jaxsat.box(half)
    pairs = identity_pairs(box, _cuboid_corners(half), box, _cuboid_corners(half), poses,
                           np.float64)
    result, details, _ = evaluate(pairs)
    assert result.valid.all() and not details.reference_is_b.any()
    np.testing.assert_allclose(result.normal, [[0, 0, 1]] * 200, atol=1e-12)
    np.testing.assert_allclose(result.depths, depth, atol=1e-12)
    for k, (rotation, centre) in enumerate(poses):
        local = (result.points[k] - centre) @ rotation  # in b's frame
        inside_a = np.all(np.abs(result.points[k][:, :2]) <= half[:2] + 1e-12, axis=1)
        inside_b = np.all(np.abs(local[:, :2]) <= half[:2] + 1e-12, axis=1)
        on_edge = (np.any(np.abs(np.abs(result.points[k][:, :2]) - half[:2]) < 1e-12, axis=1)
                   | np.any(np.abs(np.abs(local[:, :2]) - half[:2]) < 1e-12, axis=1))
        assert inside_a.all() and inside_b.all() and on_edge.all()


# --------------------------------------------------------------------------------------------
# Separation and margin.
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_separated_and_margin(dim):
    """A box a gap of 0.05 above another: no point without a margin or with margin 0.04; with
    margin 0.1 the full face manifold, at depth -0.05."""
    half = np.array([1.0, 0.5, 0.25][:dim])
    corners = (_cuboid_corners(half) if dim == 3
               else np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half)
    box = jaxsat.box(half, 8 if dim == 2 else None)
    centre = np.zeros(dim)
    centre[-1] = 2 * half[-1] + 0.05
    results = []
    for margin in (0.0, 0.04, 0.1):
        pairs = identity_pairs(box, corners, box, corners, [(np.eye(dim), centre)], np.float64,
                               margin=margin)
        results.append(check_random_pairs(pairs)[0])
    assert not results[0].valid.any() and not results[1].valid.any()
    assert results[2].valid.sum() == 2 ** (dim - 1)
    np.testing.assert_allclose(results[2].depths, -0.05, atol=1e-12)


def test_far_apart_pairs_have_no_points():
    pairs = random_pairs("box", np.float64, BATCH, seed=3, distance=(4.0, 6.0))
    result, _, reference = evaluate(pairs)
    assert np.all(reference.depth < 0) and not result.valid.any()


# --------------------------------------------------------------------------------------------
# Batching, jit, dtypes, errors and degenerate inputs.
# --------------------------------------------------------------------------------------------


def _select(pairs: Pairs, index) -> Pairs:
    return dataclasses.replace(
        pairs, a=take(pairs.a, index), b=take(pairs.b, index),
        rotation_a=pairs.rotation_a[index], translation_a=pairs.translation_a[index],
        rotation_b=pairs.rotation_b[index], translation_b=pairs.translation_b[index],
        points_a=[pairs.points_a[i] for i in index], points_b=[pairs.points_b[i] for i in index],
        margin=pairs.margin[index])


@pytest.mark.slow
def test_vmap_batch_shapes_and_single_pairs_agree():
    """Nested vmap over a (4, 16) batch, and a loop over single pairs (each alone in a batch
    of copies of itself), give the flat (64,) batch's results. (Eager calls are left out: the
    first eager call compiles every primitive separately, 12 s for a 2D pair; a single jitted
    call is one more compile, 3 s.)"""
    pairs = random_pairs("poly8", np.float64, BATCH, seed=4)
    flat, _, _ = evaluate(pairs)
    poses_a, poses_b = _stacked_poses(pairs)
    grid = lambda tree: jax.tree.map(lambda x: x.reshape(4, 16, *x.shape[1:]), tree)  # noqa: E731
    nested = jax.jit(jax.vmap(jax.vmap(jaxsat.contacts)), compiler_options=FAST_COMPILE)(
        grid(pairs.a), grid(poses_a), grid(pairs.b), grid(poses_b))
    for got, want in zip(jax.tree.leaves(nested), jax.tree.leaves(flat), strict=True):
        np.testing.assert_allclose(np.asarray(got).reshape(want.shape), want, atol=1e-12)
    for i in range(0, BATCH, 16):
        copies = evaluate(_select(pairs, np.full(BATCH, i)))[0]
        for got, want in zip(jax.tree.leaves(copies), jax.tree.leaves(flat), strict=True):
            np.testing.assert_array_equal(got, np.broadcast_to(want[i], got.shape))


@pytest.mark.slow
def test_default_build_agrees():
    """The default XLA build (what users get) gives the fast-compiled build's manifolds up to
    rounding, and exactly penetration's normal, compiled separately."""
    pairs = random_pairs("poly8", np.float32, BATCH, seed=6)
    fast, _, _ = evaluate(pairs)
    poses_a, poses_b = _stacked_poses(pairs)
    default = jax.jit(jax.vmap(jaxsat.contacts))(pairs.a, poses_a, pairs.b, poses_b)
    default = jax.tree.map(np.asarray, default)
    alone = jax.jit(jax.vmap(jaxsat.penetration))(pairs.a, poses_a, pairs.b, poses_b)
    assert np.array_equal(np.asarray(alone.normal), default.normal)
    np.testing.assert_array_equal(default.valid, fast.valid)
    np.testing.assert_allclose(default.points, fast.points, atol=1e-5)
    np.testing.assert_allclose(default.depths, fast.depths, atol=1e-5)


@pytest.mark.parametrize("dim", [2, 3])
def test_output_dtypes_follow_inputs(dim):
    cases = [(np.float32, np.float32, np.float32), (np.float32, np.float64, np.float64)]
    for shape_dtype, pose_dtype, expected in cases:
        box = jaxsat.box(np.ones(dim), dtype=shape_dtype)
        pose = jaxsat.Pose.identity(dim, pose_dtype)
        out = jax.eval_shape(functools.partial(jaxsat.contacts, margin=0.1), box, pose, box, pose)
        points = 2 if dim == 2 else 4
        assert out.points.shape == (points, dim) and out.points.dtype == expected
        assert out.depths.shape == (points,) and out.depths.dtype == expected
        assert out.normal.shape == (dim,) and out.normal.dtype == expected
        assert out.valid.shape == (points,) and out.valid.dtype == np.bool_


@pytest.mark.parametrize(("margin", "error"), [
    (-0.1, ValueError), (np.nan, ValueError), (np.inf, ValueError), ([0.1, 0.2], ValueError),
    ("wide", TypeError), (None, TypeError)])
def test_bad_margin_raises(margin, error):
    box = jaxsat.box([1.0, 1.0, 1.0])
    pose = jaxsat.Pose.identity(3)
    with pytest.raises(error, match="margin"):
        jaxsat.contacts(box, pose, box, pose, margin=margin)


def test_traced_margin_is_accepted():
    box = jaxsat.box([1.0, 1.0])
    pose = jaxsat.Pose.identity(2)
    out = jax.eval_shape(lambda m: jaxsat.contacts(box, pose, box, pose, margin=m), 0.5)
    assert out.valid.shape == (2,)


def test_bad_inputs_raise():
    box2, box3 = jaxsat.box([1.0, 1.0]), jaxsat.box([1.0, 1.0, 1.0])
    pose2, pose3 = jaxsat.Pose.identity(2), jaxsat.Pose.identity(3)
    with pytest.raises(ValueError, match="dimension"):
        jaxsat.contacts(box2, pose2, box3, pose3)
    with pytest.raises(TypeError, match="Polytope"):
        jaxsat.contacts(box3.vertices, pose3, box3, pose3)
    with pytest.raises(TypeError, match="Pose"):
        jaxsat.contacts(box3, None, box3, pose3)
    stacked = jaxsat.stack([box3, box3])
    with pytest.raises(ValueError, match="vmap"):
        jaxsat.contacts(stacked, pose3, box3, pose3)


@pytest.mark.slow
def test_degenerate_inputs_give_finite_results():
    """Coincident identical shapes, exact touching, padded shapes and scales from 1e-3 to 1e3
    (through check_random_pairs: finite values and every documented property)."""
    rng = np.random.default_rng(8)
    for name, dtype in (("poly8", np.float64), ("box", np.float64), ("hull20", np.float32)):
        dim = GENERATORS[name][0]
        points, shapes = pool(name, dtype)
        cases = []
        for i in range(4):
            rotation = _rotations(dim, rng, 1)[0]
            translation = rng.uniform(-1, 1, dim)
            cases.append((i, (rotation, translation), (rotation, translation)))  # coincident
            # Touching: b translated so that its lowest point meets a's highest along an axis.
            world = oracle.to_world(points[i], rotation, translation)
            axis = np.eye(dim)[-1]
            lift = np.max(world @ axis) - np.min(world @ axis)
            cases.append((i, (rotation, translation), (rotation, translation + lift * axis)))
        pairs = make_pairs([shapes[i] for i, _, _ in cases], [shapes[i] for i, _, _ in cases],
                           [p[0] for _, p, _ in cases], [p[1] for _, p, _ in cases],
                           [q[0] for _, _, q in cases], [q[1] for _, _, q in cases], dtype,
                           [points[i] for i, _, _ in cases], [points[i] for i, _, _ in cases])
        result, _, _ = check_random_pairs(pairs)
        assert np.all(result.valid[::2].any(axis=1))  # coincident shapes overlap
    for scale in (1e-3, 1e3):
        pairs = random_pairs("box", np.float64, BATCH, seed=9)
        scaled_points = [p * scale for p in pairs.points_a], [p * scale for p in pairs.points_b]
        shapes_a = [jaxsat.box(np.max(p, axis=0)) for p in scaled_points[0]]
        shapes_b = [jaxsat.box(np.max(p, axis=0)) for p in scaled_points[1]]
        scaled = make_pairs(shapes_a, shapes_b, pairs.rotation_a, pairs.translation_a * scale,
                            pairs.rotation_b, pairs.translation_b * scale, np.float64,
                            *scaled_points)
        check_random_pairs(scaled)


@pytest.mark.slow
def test_gradients_are_finite():
    """Gradients of the valid depths and points with respect to b's pose, including at
    coincident and exactly touching shapes, are finite (2D: the 3D gradient takes 11 s to
    compile)."""

    def objective(translation_b, rotation_b, a, b):
        result = jaxsat.contacts(a, jaxsat.Pose.identity(a.dim), b,
                                 jaxsat.Pose(translation_b, rotation_b))
        return jnp.sum(jnp.where(result.valid, result.depths, 0.0)) + jnp.sum(result.points)

    gradient = jax.jit(jax.grad(objective, argnums=(0, 1)), compiler_options=FAST_COMPILE)
    box = jaxsat.box([1.0, 0.5], 8)
    tilted = oracle.rotation_2d(0.3)
    for translation, rotation in (((0.0, 0.0), np.eye(2)), ((0.0, 1.0), np.eye(2)),
                                  ((2.0, 0.0), np.eye(2)), ((0.3, 0.9), tilted),
                                  ((0.3, 0.9), oracle.rotation_2d(np.pi / 2))):
        grads = gradient(jnp.asarray(translation), jnp.asarray(rotation), box, box)
        for leaf in jax.tree.leaves(grads):
            assert np.all(np.isfinite(np.asarray(leaf)))


@pytest.mark.slow
def test_gradients_are_finite_for_tiny_hulls_in_float32():
    """Two tetrahedra of size 2^-20 (about 1e-6) touching edge to edge, in float32: the
    segment closest-point step once divided by a fourth power of their size, whose square
    underflows in the gradient (inf * 0 = NaN in every pose derivative)."""
    scale = 2.0**-20
    disphenoid = np.array([[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, -1.0, 0.0],
                           [0.0, 1.0, 0.0]]) * scale
    hull = jaxsat.polyhedron(disphenoid, 8, dtype=np.float32)

    def objective(translation_b, rotation_b):
        result = jaxsat.contacts(hull, jaxsat.Pose.identity(3, np.float32), hull,
                                 jaxsat.Pose(translation_b, rotation_b))
        return jnp.sum(result.depths) + jnp.sum(result.points)

    gradient = jax.jit(jax.grad(objective, argnums=(0, 1)), compiler_options=FAST_COMPILE)
    grads = gradient(jnp.asarray([0.0, 0.0, scale], jnp.float32), jnp.eye(3, dtype=jnp.float32))
    for leaf in jax.tree.leaves(grads):
        assert np.all(np.isfinite(np.asarray(leaf)))
