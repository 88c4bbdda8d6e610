"""Tests for the shape constructors: polygon, polyhedron, box, regular_polygon and stack."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

import jaxsat

CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
SQUARE = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)


def real(field, mask):
    """The real (unpadded) rows of a documented Polytope field, as float64 NumPy."""
    return np.asarray(field, np.float64)[np.asarray(mask)]


def same_points(first, second, tolerance=1e-9) -> bool:
    """True when the two point sets are equal (each point of one is within tolerance of one of
    the other, and they have equally many points)."""
    first, second = np.asarray(first, np.float64), np.asarray(second, np.float64)
    if first.shape != second.shape:
        return False
    close = np.linalg.norm(first[:, None] - second[None], axis=-1) <= tolerance
    return bool(np.all(close.any(axis=0)) and np.all(close.any(axis=1)))


def same_lines(first, second, tolerance=1e-7, same_count=True) -> bool:
    """True when the two sets of directions are equal up to sign (and equally many, unless
    `same_count` is False)."""
    first, second = np.asarray(first, np.float64), np.asarray(second, np.float64)
    if same_count and first.shape != second.shape:
        return False
    first = first / np.linalg.norm(first, axis=1, keepdims=True)
    second = second / np.linalg.norm(second, axis=1, keepdims=True)
    parallel = np.abs(np.abs(first @ second.T) - 1.0) <= tolerance
    return bool(np.all(parallel.any(axis=0)) and np.all(parallel.any(axis=1)))


def assert_unique_up_to_sign(directions):
    """Unit rows, no two parallel or anti-parallel (sine of the angle between them > 1e-6)."""
    directions = np.asarray(directions, np.float64)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    for i in range(len(directions)):
        for j in range(i):
            first, second = directions[i], directions[j]
            if directions.shape[1] == 2:
                sine = abs(first[0] * second[1] - first[1] * second[0])
            else:
                sine = np.linalg.norm(np.cross(first, second))
            assert sine > 1e-6, f"directions {i} and {j} are parallel: {directions[[i, j]]}"


def signed_area(ring):
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


# --------------------------------------------------------------------------------------------
# Polygons.
# --------------------------------------------------------------------------------------------


def test_box_2d_has_four_vertices_and_two_normals():
    square = jaxsat.box([1.0, 2.0])
    assert square.dim == 2 and square.batch_shape == ()
    vertices = real(square.vertices, square.vertex_mask)
    assert same_points(vertices, SQUARE * [1.0, 2.0])
    normals = real(square.face_normals, square.face_mask)
    assert len(normals) == 2
    assert same_lines(normals, [[1, 0], [0, 1]])
    assert square.edge_directions.shape == (0, 2) and square.edge_mask.shape == (0,)


@pytest.mark.parametrize("radius", [1.0, 2.5])
@pytest.mark.parametrize("sides", range(3, 13))
def test_regular_polygon(sides, radius):
    shape = jaxsat.regular_polygon(sides, radius)
    vertices = real(shape.vertices, shape.vertex_mask)
    assert len(vertices) == sides
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), radius, rtol=1e-12)
    assert signed_area(vertices) > 0  # counter-clockwise
    normals = real(shape.face_normals, shape.face_mask)
    edges = np.roll(vertices, -1, axis=0) - vertices
    # Each normal is perpendicular to an edge, and each edge has its normal.
    assert same_lines(normals, edges[:, ::-1] * [1, -1], same_count=False)


def _rotated(points, rotvec):
    rotation = Rotation.from_rotvec(rotvec).as_matrix()[:points.shape[1], :points.shape[1]]
    return points @ rotation.T


UNIQUENESS_CASES = {
    # name: (shape factory, number of face normals, number of edge directions (3D))
    "box-2d": (lambda: jaxsat.box([1.0, 2.0]), 2, 0),
    "square-turned-0.3": (lambda: jaxsat.polygon(_rotated(SQUARE, [0, 0, 0.3])), 2, 0),
    "square-turned-45deg": (lambda: jaxsat.polygon(_rotated(SQUARE, [0, 0, np.pi / 4])), 2, 0),
    "square-turned-2.0": (lambda: jaxsat.polygon(_rotated(SQUARE, [0, 0, 2.0])), 2, 0),
    **{f"regular-{n}-radius-{r}": (functools.partial(jaxsat.regular_polygon, n, r),
                                   n // 2 if n % 2 == 0 else n, 0)
       for n in (4, 5, 6, 8, 10, 12) for r in (1.0, 2.5)},
    "box-3d": (lambda: jaxsat.box([1.0, 2.0, 3.0]), 3, 3),
    **{f"cube-turned-{i}": (lambda v=v: jaxsat.polyhedron(_rotated(CUBE, v)), 3, 3)
       for i, v in enumerate([[0.3, 0.5, 0.7], [0.0, 0.0, np.pi / 4], [1.0, -2.0, 0.5]])},
}


@pytest.mark.parametrize("case", list(UNIQUENESS_CASES))
def test_face_normals_and_edge_directions_are_unique_up_to_sign(case):
    """Documented: face normals and edge directions are unique up to sign, so a box has D face
    normals (and 3 edge directions in 3D) however it is turned, and an even-sided regular
    polygon has one normal per pair of opposite (parallel) edges."""
    factory, num_normals, num_edges = UNIQUENESS_CASES[case]
    shape = factory()
    normals = real(shape.face_normals, shape.face_mask)
    edges = real(shape.edge_directions, shape.edge_mask)
    assert_unique_up_to_sign(normals)
    assert len(normals) == num_normals
    if shape.dim == 3:
        assert_unique_up_to_sign(edges)
        assert len(edges) == num_edges


def test_polygon_either_winding_gives_the_same_polygon():
    points = np.array([[0.0, 0.0], [2.0, -0.5], [3.0, 1.0], [1.5, 2.5], [-0.5, 1.5]])
    ccw, cw = jaxsat.polygon(points), jaxsat.polygon(points[::-1])
    for shape in (ccw, cw):
        assert signed_area(real(shape.vertices, shape.vertex_mask)) > 0
    assert same_points(real(ccw.vertices, ccw.vertex_mask), points)
    assert same_points(real(cw.vertices, cw.vertex_mask), points)
    assert same_lines(real(ccw.face_normals, ccw.face_mask), real(cw.face_normals, cw.face_mask))
    pose_a, pose_b = jaxsat.pose2(0.0, 0.0, 0.0), jaxsat.pose2(1.0, 0.5, 0.7)
    for other in (ccw, cw):
        first = jaxsat.penetration(ccw, pose_a, other, pose_b)
        second = jaxsat.penetration(cw, pose_a, other, pose_b)
        np.testing.assert_allclose(first.depth, second.depth, atol=1e-12)
        np.testing.assert_allclose(first.normal, second.normal, atol=1e-12)


def test_polygon_drops_closing_duplicate_and_straight_vertices():
    points = [[0, 0], [1, 0], [2, 0], [2, 2], [2, 2], [0, 2], [0, 0]]
    shape = jaxsat.polygon(points)
    assert same_points(real(shape.vertices, shape.vertex_mask), [[0, 0], [2, 0], [2, 2], [0, 2]])
    assert len(real(shape.face_normals, shape.face_mask)) == 2


@settings(max_examples=30)
@given(count=st.integers(3, 12), seed=st.integers(0, 2**31 - 1),
       scale=st.sampled_from([1e-3, 1.0, 1e3]))
def test_polygon_matches_scipy_hull(count, seed, scale):
    """Vertices and edge normals of random convex polygons, against scipy's convex hull."""
    rng = np.random.default_rng(seed)
    while True:
        angles = np.sort(rng.uniform(0, 2 * np.pi, count))
        if np.min(np.diff(np.append(angles, angles[0] + 2 * np.pi))) > 0.05:
            break
    points = scale * np.stack([np.cos(angles), 0.5 * np.sin(angles)], axis=1) + scale
    shape = jaxsat.polygon(points, max_vertices=12)
    hull = ConvexHull(points)
    vertices = real(shape.vertices, shape.vertex_mask)
    assert len(vertices) == count == len(hull.vertices)
    assert signed_area(vertices) > 0
    assert same_points(vertices / scale, points[hull.vertices] / scale)
    normals = real(shape.face_normals, shape.face_mask)
    assert_unique_up_to_sign(normals)
    assert same_lines(normals, hull.equations[:, :2])


def test_polygon_dtypes():
    assert jaxsat.polygon(SQUARE).dtype == jnp.float64
    assert jaxsat.polygon(SQUARE.astype(np.float32)).dtype == jnp.float32
    assert jaxsat.polygon(SQUARE, dtype=np.float32).dtype == jnp.float32
    assert jaxsat.polygon(SQUARE.astype(int)).dtype == jnp.float64
    assert jaxsat.box(np.ones(3, np.float32)).dtype == jnp.float32
    assert jaxsat.regular_polygon(5, 1.0, dtype=jnp.float32).dtype == jnp.float32
    shape = jaxsat.polyhedron(CUBE, dtype=np.float32)
    for field in (shape.vertices, shape.face_normals, shape.edge_directions):
        assert field.dtype == jnp.float32
    for mask in (shape.vertex_mask, shape.face_mask, shape.edge_mask):
        assert mask.dtype == jnp.bool_


# --------------------------------------------------------------------------------------------
# Polyhedra.
# --------------------------------------------------------------------------------------------


def test_box_3d_has_three_normals_and_three_edge_directions():
    cube = jaxsat.box([1.0, 2.0, 3.0])
    assert cube.dim == 3
    assert same_points(real(cube.vertices, cube.vertex_mask), CUBE * [1, 2, 3])
    normals = real(cube.face_normals, cube.face_mask)
    edges = real(cube.edge_directions, cube.edge_mask)
    assert len(normals) == 3 and len(edges) == 3
    assert same_lines(normals, np.eye(3)) and same_lines(edges, np.eye(3))


@pytest.mark.parametrize("extra_first", [False, True], ids=["corners-first", "extras-first"])
def test_cube_with_interior_and_boundary_points(extra_first):
    """Interior points, face centres and edge midpoints are not hull vertices."""
    face_centres = np.vstack([np.eye(3), -np.eye(3)])
    edge_midpoints = np.array([[0, 1, 1], [1, 0, -1], [-1, -1, 0]], float)
    interior = np.array([[0, 0, 0], [0.5, -0.2, 0.3]])
    extras = np.vstack([face_centres, edge_midpoints, interior])
    points = np.vstack([extras, CUBE] if extra_first else [CUBE, extras])
    shape = jaxsat.polyhedron(points)
    vertices = real(shape.vertices, shape.vertex_mask)
    assert len(vertices) == 8
    assert same_points(vertices, CUBE)
    normals = real(shape.face_normals, shape.face_mask)
    assert len(normals) == 3 and same_lines(normals, np.eye(3))
    assert same_lines(real(shape.edge_directions, shape.edge_mask), np.eye(3))
    # So a cube fits its own size class.
    assert jaxsat.polyhedron(points, max_vertices=8).vertices.shape == (8, 3)


def _hull_edges(hull: ConvexHull) -> set[tuple[int, int]]:
    """Edges between non-coplanar scipy facets (scipy triangulates faces)."""
    edges = {}
    for simplex, equation in zip(hull.simplices, hull.equations, strict=True):
        for k in range(3):
            key = tuple(sorted((int(simplex[k]), int(simplex[(k + 1) % 3]))))
            edges.setdefault(key, []).append(equation[:3])
    return {key for key, normals in edges.items() if normals[0] @ normals[1] < 1 - 1e-9}


@settings(max_examples=30)
@given(count=st.integers(4, 30), seed=st.integers(0, 2**31 - 1),
       scale=st.sampled_from([1e-3, 1.0, 1e3]))
def test_polyhedron_matches_scipy_hull(count, seed, scale):
    """Vertices, face normals and edge directions of random hulls, against scipy's."""
    rng = np.random.default_rng(seed)
    points = scale * (rng.normal(size=(count, 3)) + rng.normal(size=3))
    hull = ConvexHull(points)
    shape = jaxsat.polyhedron(points, max_vertices=30)
    vertices = real(shape.vertices, shape.vertex_mask)
    assert same_points(vertices / scale, points[hull.vertices] / scale)
    normals = real(shape.face_normals, shape.face_mask)
    assert_unique_up_to_sign(normals)
    assert same_lines(normals, hull.equations[:, :3])
    segments = np.array([points[j] - points[i] for i, j in _hull_edges(hull)])
    segments /= np.linalg.norm(segments, axis=1, keepdims=True)
    edges = real(shape.edge_directions, shape.edge_mask)
    assert_unique_up_to_sign(edges)
    assert same_lines(edges, segments)


# --------------------------------------------------------------------------------------------
# Padding and stacking.
# --------------------------------------------------------------------------------------------


def test_max_vertices_pads_with_masks():
    square = jaxsat.polygon(SQUARE, max_vertices=7)
    assert square.vertices.shape == (7, 2) and square.vertex_mask.shape == (7,)
    assert int(square.vertex_mask.sum()) == 4 and bool(square.vertex_mask[:4].all())
    assert square.face_normals.shape[0] >= 2 and int(square.face_mask.sum()) == 2
    cube = jaxsat.polyhedron(CUBE, max_vertices=10)
    assert cube.vertices.shape == (10, 3) and int(cube.vertex_mask.sum()) == 8
    assert int(cube.face_mask.sum()) == 3 and int(cube.edge_mask.sum()) == 3
    # Padding repeats real entries, so it can never change a minimum or a maximum.
    padded = np.asarray(cube.vertices)
    assert np.all(np.min(np.linalg.norm(padded[:, None] - CUBE[None], axis=-1), axis=1) == 0)
    # Every hull in the size class has the same padded sizes.
    other = jaxsat.polyhedron(np.random.default_rng(0).normal(size=(10, 3)), max_vertices=10)
    for field in ("vertices", "vertex_mask", "face_normals", "face_mask", "edge_directions",
                  "edge_mask"):
        assert getattr(cube, field).shape == getattr(other, field).shape


def test_stack_adds_a_leading_batch_axis_and_pads():
    shapes = [jaxsat.box([1.0, 2.0]), jaxsat.regular_polygon(7, 1.0), jaxsat.polygon(SQUARE, 5)]
    stacked = jaxsat.stack(shapes)
    assert stacked.batch_shape == (3,) and stacked.dim == 2
    assert stacked.vertices.shape == (3, 7, 2) and stacked.vertex_mask.shape == (3, 7)
    assert stacked.face_normals.shape[:1] == (3,) and stacked.face_mask.shape[0] == 3
    np.testing.assert_array_equal(np.asarray(stacked.vertex_mask).sum(axis=1), [4, 7, 4])
    for index, shape in enumerate(shapes):
        entry = jax.tree.map(lambda leaf, i=index: leaf[i], stacked)
        assert same_points(real(entry.vertices, entry.vertex_mask),
                           real(shape.vertices, shape.vertex_mask))
        assert same_lines(real(entry.face_normals, entry.face_mask),
                          real(shape.face_normals, shape.face_mask))
    cubes = jaxsat.stack([jaxsat.box([1.0, 1.0, 1.0]), jaxsat.polyhedron(CUBE * 2, 12)])
    assert cubes.batch_shape == (2,) and cubes.vertices.shape == (2, 12, 3)


def test_stack_pads_every_field_by_repeating_row_zero():
    """The padding rule every kernel relies on (see `Polytope`): padding rows repeat row 0 and
    masks pad with False, field by field, and the stack takes the largest size class."""
    shapes = [jaxsat.box([1.0, 2.0, 3.0]), jaxsat.polyhedron(CUBE * 2),
              jaxsat.polyhedron(np.random.default_rng(3).normal(size=(9, 3)))]
    stacked = jaxsat.stack(shapes)
    assert stacked.size_class == tuple(max(sizes) for sizes in
                                       zip(*(shape.size_class for shape in shapes), strict=True))
    for index, shape in enumerate(shapes):
        for name, value in vars(shape).items():
            if name == "radius":  # sharp shapes: no radius, and none in their stack
                assert value is None and stacked.radius is None
                continue
            padded, own = np.asarray(getattr(stacked, name)[index]), np.asarray(value)
            rows = len(own)
            np.testing.assert_array_equal(padded[:rows], own, err_msg=name)
            expected = False if own.dtype == bool else own[:1]
            assert np.all(padded[rows:] == expected), name


def test_size_classes_and_parallelepipeds():
    """`polyhedron(..., max_vertices=V)` pads to 2V - 4 faces and 3V - 6 edges, as
    `size_class_for` says; only shapes with at most 3 edge directions are parallelepipeds."""
    rng = np.random.default_rng(4)
    for count in (4, 8, 20):
        hull = jaxsat.polyhedron(rng.normal(size=(count, 3)), max_vertices=count)
        assert hull.size_class == (count, 2 * count - 4, 3 * count - 6, 3 * count - 6)
        assert not hull.is_parallelepiped
    assert jaxsat.polygon(SQUARE, max_vertices=6).size_class == (6, 6, 0, 0)
    assert jaxsat.box([1.0, 2.0, 3.0]).is_parallelepiped
    sheared = jaxsat.polyhedron(CUBE @ np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.3], [0, 0, 1]]))
    assert sheared.is_parallelepiped
    assert not jaxsat.box([1.0, 2.0, 3.0], max_vertices=8).is_parallelepiped
    assert not jaxsat.box([1.0, 2.0]).is_parallelepiped  # 2D


@pytest.mark.parametrize("count", [3, 5, 8])
def test_polygon_ring_neighbours_close_at_the_last_real_vertex(count):
    """Edge i of a padded polygon joins vertex i and its ring successor, which is the rolled
    padded array for every real vertex (padding repeats vertex 0)."""
    from jaxsat._shapes import ring_neighbours

    shape = jaxsat.regular_polygon(count, 1.0, max_vertices=8)
    assert int(shape.num_real_vertices) == count
    index = jnp.arange(count)
    previous, following = ring_neighbours(index, shape.num_real_vertices)
    np.testing.assert_array_equal(following, (np.arange(count) + 1) % count)
    np.testing.assert_array_equal(previous, (np.arange(count) - 1) % count)
    rolled = np.roll(np.asarray(shape.vertices), -1, axis=0)[:count]
    np.testing.assert_array_equal(rolled, np.asarray(shape.vertices)[np.asarray(following)])


def _both(a, pose_a, b, pose_b):
    return jaxsat.penetration(a, pose_a, b, pose_b), jaxsat.intersects(a, pose_a, b, pose_b)


_query_many_poses = jax.jit(jax.vmap(_both, in_axes=(None, 0, None, 0)))


def _random_poses(dim, count, seed):
    rng = np.random.default_rng(seed)
    if dim == 2:
        x, y = rng.uniform(-2, 2, (2, count))
        return jax.vmap(jaxsat.pose2)(x, y, rng.uniform(-np.pi, np.pi, count))
    return jax.vmap(jaxsat.pose3)(rng.uniform(-2, 2, (count, 3)), rng.normal(size=(count, 4)))


@functools.cache
def _padding_variants(dim):
    """Penetration and intersects for the same 64 pairs, unpadded, padded with max_vertices and
    padded by stacking with a larger shape."""
    rng = np.random.default_rng(3)
    if dim == 2:
        angles = np.sort(rng.uniform(0, 2 * np.pi, 6))
        points_a = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        points_b = SQUARE * [0.7, 0.4]
        build = jaxsat.polygon
        big = jaxsat.regular_polygon(16, 1.0)
    else:
        points_a = rng.normal(size=(9, 3))
        points_b = CUBE * [0.7, 0.4, 0.5]
        build = jaxsat.polyhedron
        big = jaxsat.polyhedron(rng.normal(size=(24, 3)))
    plain_a, plain_b = build(points_a), build(points_b)
    variants = {
        "plain": (plain_a, plain_b),
        "max_vertices": (build(points_a, 12), build(points_b, 12)),
        "stacked": tuple(jax.tree.map(lambda leaf: leaf[0], jaxsat.stack([shape, big]))
                         for shape in (plain_a, plain_b)),
    }
    sizes = {name: (a.vertices.shape[0], b.vertices.shape[0]) for name, (a, b) in variants.items()}
    assert len(set(sizes.values())) == 3  # three genuinely different paddings
    poses_a, poses_b = _random_poses(dim, 64, 1), _random_poses(dim, 64, 2)
    results = {}
    for name, (a, b) in variants.items():
        result, hit = _query_many_poses(a, poses_a, b, poses_b)
        results[name] = (np.asarray(result.depth), np.asarray(result.normal), np.asarray(hit))
    return results


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_padding_never_changes_overlap_results(dim):
    """Overlap depth, normal and intersects are the same however the shapes are padded."""
    results = _padding_variants(dim)
    depth, normal, hits = results["plain"]
    assert np.all(np.isfinite(depth)) and np.all(np.isfinite(normal))
    overlapping = depth > 1e-9
    assert 0.2 < np.mean(overlapping) < 0.8  # both overlapping and separated pairs
    decided = np.abs(depth) > 1e-9
    for name, (other_depth, other_normal, other_hits) in results.items():
        np.testing.assert_allclose(other_depth[overlapping], depth[overlapping], atol=1e-12,
                                   err_msg=name)
        np.testing.assert_allclose(other_normal[overlapping], normal[overlapping], atol=1e-9,
                                   err_msg=name)
        np.testing.assert_array_equal(other_hits[decided], hits[decided], err_msg=name)
        np.testing.assert_array_equal(other_hits[decided], depth[decided] > 0, err_msg=name)


@pytest.mark.slow
def test_box_padding_never_changes_results():
    """Unpadded boxes take the projection edge method, padded ones the Gauss map; both must
    give the same depths and normals, overlapping or separated."""
    a_half, b_half = np.array([0.7, 0.4, 0.5]), np.array([0.3, 0.9, 0.6])
    poses_a, poses_b = _random_poses(3, 64, 5), _random_poses(3, 64, 6)
    plain, _ = _query_many_poses(jaxsat.box(a_half), poses_a, jaxsat.box(b_half), poses_b)
    padded, _ = _query_many_poses(jaxsat.box(a_half, max_vertices=10), poses_a,
                                  jaxsat.box(b_half, max_vertices=10), poses_b)
    depth = np.asarray(plain.depth)
    assert 0 < np.sum(depth > 0) < len(depth)  # both overlapping and separated pairs
    np.testing.assert_allclose(np.asarray(padded.depth), depth, atol=1e-12)
    np.testing.assert_allclose(np.asarray(padded.normal), np.asarray(plain.normal), atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("dim", [2, 3])
def test_padding_never_changes_separated_depth(dim):
    """The separation gap (depth <= 0) does not depend on the padding either."""
    results = _padding_variants(dim)
    depth = results["plain"][0]
    separated = depth < -1e-9
    for name, (other_depth, _, _) in results.items():
        np.testing.assert_allclose(other_depth[separated], depth[separated], atol=1e-12,
                                   err_msg=name)


# --------------------------------------------------------------------------------------------
# Validation: every bad input raises ValueError.
# --------------------------------------------------------------------------------------------


PENTAGRAM = [[np.cos(t), np.sin(t)] for t in np.pi / 2 + 4 * np.pi / 5 * np.arange(5)]

BAD_POLYGONS = {
    "nan": ([[0, 0], [1, 0], [np.nan, 1]], "NaN or inf"),
    "inf": ([[0, 0], [1, 0], [1, np.inf]], "NaN or inf"),
    "four-columns": (np.zeros((4, 4)), "shape"),
    "three-columns": (CUBE, "shape"),
    "one-dimensional": (np.arange(6.0), "shape"),
    "three-dimensional": (np.zeros((2, 3, 2)), "shape"),
    "empty": (np.zeros((0, 2)), "at least 3"),
    "two-points": ([[0, 0], [1, 1]], "at least 3"),
    "two-distinct": ([[0, 0], [1, 1], [0, 0], [1, 1]], "at least 3"),
    "collinear": ([[0, 0], [1, 1], [3, 3]], "collinear"),
    "collinear-many": ([[0, 0], [1, 2], [2, 4], [0.5, 1]], "collinear"),
    "non-convex": ([[0, 0], [2, 0], [1, 0.3], [2, 2], [0, 2]], "not convex"),
    "non-convex-arrow": ([[0, 0], [2, 1], [0, 2], [0.5, 1]], "not convex"),
    "pentagram": (PENTAGRAM, "self-intersecting"),
    "square-twice": (SQUARE.tolist() * 2, "self-intersecting"),
    "bow-tie": ([[0, 0], [2, 2], [2, 0], [0, 1]], "not convex|self-intersecting"),
    "symmetric-bow-tie": ([[0, 0], [1, 1], [1, 0], [0, 1]],
                          "not convex|self-intersecting|zero area"),
}


def test_non_numeric_vertices_raise_type_error():
    with pytest.raises(TypeError, match="numeric"):
        jaxsat.polygon("abc")
    with pytest.raises(TypeError, match="numeric"):
        jaxsat.polyhedron([["a", "b", "c"]] * 4)


@pytest.mark.parametrize("name", list(BAD_POLYGONS))
def test_bad_polygons_raise(name):
    points, message = BAD_POLYGONS[name]
    with pytest.raises(ValueError, match=message):
        jaxsat.polygon(points)


BAD_POLYHEDRA = {
    "nan": (np.vstack([CUBE, [[np.nan, 0, 0]]]), "NaN or inf"),
    "inf": (np.vstack([CUBE, [[0, -np.inf, 0]]]), "NaN or inf"),
    "two-columns": (SQUARE, "shape"),
    "four-columns": (np.zeros((5, 4)), "shape"),
    "one-dimensional": (np.arange(12.0), "shape"),
    "three-points": (CUBE[:3], "at least 4"),
    "three-distinct": (np.vstack([CUBE[:3], CUBE[:3]]), "at least 4"),
    "collinear": (np.outer(np.arange(6.0), [1, 2, 3]), "collinear"),
    "coplanar": (np.hstack([np.random.default_rng(0).normal(size=(10, 2)), np.ones((10, 1))]),
                 "coplanar"),
    "tilted-coplanar": (np.random.default_rng(1).normal(size=(10, 2)) @ [[1, 0, 1], [0, 1, 2]],
                        "coplanar"),
}


@pytest.mark.parametrize("name", list(BAD_POLYHEDRA))
def test_bad_polyhedra_raise(name):
    points, message = BAD_POLYHEDRA[name]
    with pytest.raises(ValueError, match=message):
        jaxsat.polyhedron(points)


def test_too_many_vertices_for_max_vertices_raise():
    with pytest.raises(ValueError, match="max_vertices"):
        jaxsat.polygon(jaxsat.regular_polygon(6, 1.0).vertices, max_vertices=5)
    with pytest.raises(ValueError, match="max_vertices"):
        jaxsat.polyhedron(CUBE, max_vertices=7)
    with pytest.raises(ValueError, match="max_vertices"):
        jaxsat.box([1.0, 1.0, 1.0], max_vertices=4)
    with pytest.raises(ValueError, match="max_vertices"):
        jaxsat.regular_polygon(9, 1.0, max_vertices=8)
    for bad in (0, -3, 4.5):
        with pytest.raises(ValueError, match="max_vertices"):
            jaxsat.polygon(SQUARE, max_vertices=bad)


@pytest.mark.parametrize("half_extents", [[1.0, 0.0], [1.0, -1.0, 1.0], [np.nan, 1.0],
                                          [1.0, np.inf, 1.0], [1.0], [1.0, 1.0, 1.0, 1.0],
                                          [[1.0, 1.0], [1.0, 1.0]], []])
def test_bad_box_raises(half_extents):
    with pytest.raises(ValueError, match="half_extents"):
        jaxsat.box(half_extents)


@pytest.mark.parametrize(("sides", "radius", "message"), [
    (2, 1.0, "num_sides"), (0, 1.0, "num_sides"), (-4, 1.0, "num_sides"), (3.5, 1.0, "num_sides"),
    (5, 0.0, "radius"), (5, -1.0, "radius"), (5, np.nan, "radius"), (5, np.inf, "radius"),
])
def test_bad_regular_polygon_raises(sides, radius, message):
    with pytest.raises(ValueError, match=message):
        jaxsat.regular_polygon(sides, radius)


def test_bad_dtype_raises():
    for constructor, points in ((jaxsat.polygon, SQUARE), (jaxsat.polyhedron, CUBE)):
        with pytest.raises(ValueError, match="floating"):
            constructor(points, dtype=np.int32)


def test_bad_stack_raises():
    square, cube = jaxsat.box([1.0, 1.0]), jaxsat.box([1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="at least one"):
        jaxsat.stack([])
    with pytest.raises(ValueError, match="2D and 3D"):
        jaxsat.stack([square, cube])
    with pytest.raises(ValueError, match="2D and 3D"):
        jaxsat.stack([cube, jaxsat.regular_polygon(5, 1.0)])
    with pytest.raises(ValueError, match="dtypes"):
        jaxsat.stack([square, jaxsat.box([1.0, 1.0], dtype=np.float32)])
    with pytest.raises(ValueError, match="batched"):
        jaxsat.stack([jaxsat.stack([square])])
    with pytest.raises(TypeError, match="not a jaxsat.Polytope"):
        jaxsat.stack([square, SQUARE])


# --------------------------------------------------------------------------------------------
# unique_axes=False: one face normal per face and one edge direction per edge, as a textbook
# SAT keeps them (the comparison of benchmarks/scene.py).
# --------------------------------------------------------------------------------------------


def _extents_match(shape):
    """face_extents is [min, max] of the shape's vertices on each real face normal."""
    normals = real(shape.face_normals, shape.face_mask)
    projections = real(shape.vertices, shape.vertex_mask) @ normals.T
    np.testing.assert_allclose(real(shape.face_extents, shape.face_mask),
                               np.stack([projections.min(0), projections.max(0)], axis=1),
                               atol=1e-12)


def test_unique_axes_false_keeps_every_face_and_edge():
    cube = jaxsat.box([1.0, 2.0, 3.0], unique_axes=False)
    normals = real(cube.face_normals, cube.face_mask)
    assert normals.shape == (6, 3) and same_points(normals, np.concatenate([np.eye(3),
                                                                            -np.eye(3)]))
    edges = real(cube.edge_directions, cube.edge_mask)
    assert edges.shape == (12, 3) and same_lines(edges, np.eye(3), same_count=False)
    for axis in range(3):  # 4 edges along each axis
        assert np.sum(np.abs(np.abs(edges[:, axis]) - 1) < 1e-12) == 4
    unique = jaxsat.box([1.0, 2.0, 3.0])
    for name in ("vertices", "edge_endpoints", "edge_face_normals"):  # hull edges unchanged
        np.testing.assert_array_equal(getattr(cube, name), getattr(unique, name))
    _extents_match(cube)
    rectangle = jaxsat.box([1.0, 2.0], unique_axes=False)
    normals = real(rectangle.face_normals, rectangle.face_mask)
    assert normals.shape == (4, 2) and same_points(normals, [[1, 0], [-1, 0], [0, 1], [0, -1]])
    assert rectangle.edge_directions.shape == (0, 2)
    _extents_match(rectangle)


def test_unique_axes_false_on_a_hull_keeps_one_normal_per_merged_face():
    points = np.random.default_rng(8).normal(size=(30, 3))
    every, unique = jaxsat.polyhedron(points, unique_axes=False), jaxsat.polyhedron(points)
    hull = ConvexHull(points)
    faces = {tuple(np.round(equation, 9)) for equation in hull.equations}  # merged facets
    normals = real(every.face_normals, every.face_mask)
    assert len(normals) == len(faces) >= len(real(unique.face_normals, unique.face_mask))
    assert same_lines(normals, real(unique.face_normals, unique.face_mask), same_count=False)
    assert len(real(every.edge_directions, every.edge_mask)) == int(every.hull_edge_mask.sum())
    _extents_match(every)


_penetration_pairs = jax.jit(jax.vmap(jaxsat.penetration))


def _world(shapes, poses):
    """float64 world vertices (N, V, D) of batched shapes and poses."""
    rotation, vertices = np.asarray(poses.rotation), np.asarray(shapes.vertices)
    return np.einsum("nrk,nvk->nvr", rotation, vertices) + np.asarray(poses.translation)[:, None]


def _assert_same_penetration(build, raw_a, raw_b, dim, seed, reach=2.0):
    """Penetration depth and normal of 64 random pairs (shapes drawn from raw_a x raw_b, b's
    origin within `reach` of a's) are the same with unique and with every axis; normals may
    differ only at ties, where both normals give the same depth."""
    rng = np.random.default_rng(seed)
    pick_a, pick_b = rng.integers(len(raw_a), size=64), rng.integers(len(raw_b), size=64)
    poses_a = _random_poses(dim, 64, seed + 1)
    offsets = rng.normal(size=(64, dim))
    offsets *= rng.uniform(0.0, reach, (64, 1)) / np.linalg.norm(offsets, axis=1, keepdims=True)
    poses_b = _random_poses(dim, 64, seed + 2)
    poses_b = jaxsat.Pose(poses_a.translation + offsets, poses_b.rotation)  # b near a
    results = []
    for unique in (True, False):
        a = jaxsat.stack([build(raw, unique_axes=unique) for raw in raw_a])
        b = jaxsat.stack([build(raw, unique_axes=unique) for raw in raw_b])
        a, b = (jax.tree.map(lambda leaf, p=pick: leaf[p], s) for s, pick in ((a, pick_a),
                                                                               (b, pick_b)))
        result = _penetration_pairs(a, poses_a, b, poses_b)
        results.append((np.asarray(result.depth), np.asarray(result.normal)))
    (depth, normal), (other_depth, other_normal) = results
    assert 0.2 < np.mean(depth > 0) < 0.8
    np.testing.assert_allclose(other_depth, depth, rtol=0, atol=1e-12)
    differ = np.max(np.abs(other_normal - normal), axis=1) > 1e-9
    world_a, world_b = _world(a, poses_a)[differ], _world(b, poses_b)[differ]
    for n in (normal[differ], other_normal[differ]):  # a tie: each normal certifies the depth
        gaps = (np.einsum("nvk,nk->nv", world_a, n).max(1)
                - np.einsum("nvk,nk->nv", world_b, n).min(1))
        np.testing.assert_allclose(gaps, depth[differ], atol=1e-9)


def _symmetric_octagon(rng):
    angles = rng.uniform(0, np.pi) + np.pi * np.array([0.0, 0.2, 0.45, 0.7])
    ring = np.stack([np.cos(angles), 0.6 * np.sin(angles)], axis=1)
    return np.concatenate([ring, -ring])


def test_unique_axes_false_gives_the_same_penetration_2d():
    rng = np.random.default_rng(10)
    hexagon = np.stack([np.cos(np.arange(6)), np.sin(np.arange(6) * 1.1)], axis=1)
    raw = [SQUARE * [0.8, 0.3], _symmetric_octagon(rng), _symmetric_octagon(rng),
           ConvexHull(hexagon).points[ConvexHull(hexagon).vertices]]
    assert len(real(jaxsat.polygon(raw[1]).face_normals,
                    jaxsat.polygon(raw[1]).face_mask)) == 4  # parallel edges do merge
    _assert_same_penetration(jaxsat.polygon, raw, raw, 2, 11)


@pytest.mark.slow
def test_unique_axes_false_gives_the_same_penetration_boxes():
    """Unique box axes take the projection edge method (3 x 3), every axis the Gauss map
    (12 x 12 hull edges): the same results, overlapping or separated."""
    rng = np.random.default_rng(12)
    raw = [rng.uniform(0.3, 1.0, 3) for _ in range(3)]
    _assert_same_penetration(jaxsat.box, raw, raw, 3, 13, reach=2.8)


@pytest.mark.slow
def test_unique_axes_false_gives_the_same_penetration_hulls():
    rng = np.random.default_rng(14)
    raw = [rng.normal(size=(10, 3)) * 0.6 for _ in range(2)] + [CUBE * [0.5, 0.3, 0.7]]
    build = functools.partial(jaxsat.polyhedron, max_vertices=10)
    _assert_same_penetration(build, raw, raw, 3, 15)


@pytest.mark.parametrize("unique_axes", [1, 0, None, "no"])
def test_non_bool_unique_axes_raises(unique_axes):
    for constructor, points in ((jaxsat.polygon, SQUARE), (jaxsat.polyhedron, CUBE),
                                (jaxsat.box, [1.0, 2.0]), (jaxsat.box, [1.0, 2.0, 3.0])):
        with pytest.raises(TypeError, match="unique_axes"):
            constructor(points, unique_axes=unique_axes)
