"""Oracle and property tests for jaxsat.signed_distance (exact) and jaxsat.closest_points.

Exact references come from the independent NumPy/SciPy oracle in `oracle.py`: the signed
distance is the Euclidean distance between the hulls when they are apart and minus the
penetration depth when they overlap. Random pairs are evaluated in fixed-size batches through
one cached `jax.jit(jax.vmap(...))` per size class and dtype (compilation dominates the run
time); the hand-built cases reuse those size classes. `test_smoothing.py` imports the shape and
pair helpers from here.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import oracle
import pytest
from scipy.spatial import ConvexHull

import jaxsat

BATCH = 64
"""Every batched call uses this many pairs (the last chunk is padded), so nothing recompiles."""

RELATIVE_TOLERANCE = {np.float64: 1e-9, np.float32: 1e-4}
"""Tolerance on distances and points, relative to the shapes' size (larger bounding radius)."""

UNIT_TOLERANCE = {np.float64: 1e-12, np.float32: 1e-5}
"""Tolerance on |normal| - 1."""

NORMAL_TOLERANCE = {np.float64: 1e-7, np.float32: 1e-3}
"""Tolerance on the normal, compared only where the oracle's optimal facet is unique."""

DTYPES = [np.float64, np.float32]
DTYPE_IDS = ["float64", "float32"]


# --------------------------------------------------------------------------------------------
# Random shapes: every generator returns (raw local points, factory(dtype)).
# --------------------------------------------------------------------------------------------


def _ellipse_polygon(rng: np.random.Generator, count: int, scale: float) -> np.ndarray:
    """`count` vertices on a random off-centre ellipse (strictly convex, no flat vertex)."""
    while True:
        angles = np.sort(rng.uniform(0, 2 * np.pi, count))
        if np.min(np.diff(np.append(angles, angles[0] + 2 * np.pi))) > 0.2:
            break
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    stretch = np.diag(rng.uniform(0.3, 1.0, 2)) @ oracle.rotation_2d(rng.uniform(0, 2 * np.pi))
    return (circle @ stretch.T + rng.uniform(-0.3, 0.3, 2)) * scale


def _polygon8(rng: np.random.Generator, scale: float):
    """3 to 8 vertices padded to 8: a box, a regular polygon or a random (either winding)."""
    kind = rng.integers(4)
    if kind == 0:
        half = rng.uniform(0.2, 1.0, 2) * scale
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return corners, lambda dtype: jaxsat.box(half.astype(dtype), max_vertices=8)
    if kind == 1:
        sides = int(rng.integers(3, 9))
        radius = float(rng.uniform(0.3, 1.0)) * scale
        angles = 2 * np.pi * np.arange(sides) / sides
        corners = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        return corners, lambda dtype: jaxsat.regular_polygon(sides, radius, 8, dtype=dtype)
    points = _ellipse_polygon(rng, int(rng.integers(3, 9)), scale)
    if kind == 3:
        points = points[::-1]
    return points, lambda dtype: jaxsat.polygon(points.astype(dtype), 8)


def _hexagon(rng: np.random.Generator, scale: float):
    """A random hexagon without padding (every vertex real)."""
    points = _ellipse_polygon(rng, 6, scale)
    return points, lambda dtype: jaxsat.polygon(points.astype(dtype))


def _box(rng: np.random.Generator, scale: float, max_vertices=None):
    half = rng.uniform(0.2, 1.0, 3) * scale
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return signs * half, lambda dtype: jaxsat.box(half.astype(dtype), max_vertices, dtype=dtype)


def _hull(rng: np.random.Generator, scale: float, count: int):
    """Hull of `count` points: on a stretched sphere, Gaussian (some interior), or a box."""
    if rng.integers(4) == 0:
        return _box(rng, scale, max_vertices=count)
    points = rng.normal(size=(count, 3))
    if rng.integers(2) == 0:
        points /= np.linalg.norm(points, axis=1, keepdims=True)
    else:
        points /= np.max(np.linalg.norm(points, axis=1))
    stretch = np.diag(rng.uniform(0.3, 1.0, 3)) @ oracle.rotation_3d(rng.normal(size=4))
    points = (points @ stretch.T + rng.uniform(-0.3, 0.3, 3)) * scale
    return points, lambda dtype: jaxsat.polyhedron(points.astype(dtype), count, dtype=dtype)


def _mixed_hull(rng: np.random.Generator, scale: float):
    """A hull of 8 or of 20 points (or a box), padded to the 20-vertex size class."""
    points, _ = _hull(rng, scale, int(rng.choice([8, 20])))
    return points, lambda dtype: jaxsat.polyhedron(points.astype(dtype), 20, dtype=dtype)


GENERATORS = {
    "poly8": (2, _polygon8),
    "hexagon": (2, _hexagon),
    "box": (3, _box),
    "hull8": (3, functools.partial(_hull, count=8)),
    "hull20": (3, functools.partial(_hull, count=20)),
    "hull": (3, _mixed_hull),
}


@dataclasses.dataclass
class Pool:
    """A few shapes of one size class, stacked, with their raw points (rounded to the dtype)."""

    dim: int
    points: list[np.ndarray]
    shapes: jaxsat.Polytope


def make_pool(name: str, dtype, rng: np.random.Generator, scale: float = 1.0,
              size: int = 12) -> Pool:
    dim, generate = GENERATORS[name]
    points, shapes = [], []
    for _ in range(size):
        raw, factory = generate(rng, scale)
        shape = factory(dtype)
        assert shape.dtype == dtype
        points.append(raw.astype(dtype).astype(np.float64))
        shapes.append(shape)
    return Pool(dim, points, jaxsat.stack(shapes))


@functools.cache
def pool(name: str, dtype, scale: float = 1.0, seed: int = 0) -> Pool:
    return make_pool(name, dtype, np.random.default_rng([seed, len(name)]), scale)


def hand_pool(dim: int, shapes_and_points) -> Pool:
    """A pool of hand-made (shape, raw points) entries."""
    shapes, points = zip(*shapes_and_points, strict=True)
    return Pool(dim, [np.asarray(p, np.float64) for p in points], jaxsat.stack(list(shapes)))


# --------------------------------------------------------------------------------------------
# Pairs of shapes and pose parameters, world points for the oracle, batched evaluation.
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Pairs:
    pool_a: Pool
    pool_b: Pool
    index_a: np.ndarray
    index_b: np.ndarray
    params_a: tuple[np.ndarray, ...]
    """2D: (x, y, angle) arrays; 3D: (translations (N, 3), quaternions (N, 4))."""
    params_b: tuple[np.ndarray, ...]
    dtype: type

    @property
    def dim(self) -> int:
        return self.pool_a.dim

    def __len__(self) -> int:
        return len(self.index_a)

    def subset(self, keep) -> Pairs:
        keep = np.asarray(keep)
        return Pairs(self.pool_a, self.pool_b, self.index_a[keep], self.index_b[keep],
                     tuple(p[keep] for p in self.params_a),
                     tuple(p[keep] for p in self.params_b), self.dtype)

    def swapped(self) -> Pairs:
        return Pairs(self.pool_b, self.pool_a, self.index_b, self.index_a, self.params_b,
                     self.params_a, self.dtype)

    def inputs(self):
        """(a, params_a, b, params_b) with a leading batch axis, for the batched functions."""
        return (take(self.pool_a.shapes, self.index_a), self.params_a,
                take(self.pool_b.shapes, self.index_b), self.params_b)


def random_params(dim: int, count: int, rng: np.random.Generator, dtype, spread: float = 2.0):
    """Random pose parameters: positions in [-spread, spread], any rotation."""
    if dim == 2:
        x, y = rng.uniform(-spread, spread, (2, count))
        return tuple(v.astype(dtype) for v in (x, y, rng.uniform(-np.pi, np.pi, count)))
    quaternions = rng.normal(size=(count, 4)) * rng.uniform(0.5, 2.0, (count, 1))
    return (rng.uniform(-spread, spread, (count, 3)).astype(dtype), quaternions.astype(dtype))


def random_pairs(pool_a: Pool, pool_b: Pool, count: int, rng: np.random.Generator, dtype,
                 distance=(0.0, 2.5), scale: float = 1.0) -> Pairs:
    """Random pairs whose origins are `distance` * scale apart (uniform), any rotations."""
    dim = pool_a.dim
    params_a = random_params(dim, count, rng, dtype, spread=2.0 * scale)
    directions = rng.normal(size=(count, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    offsets = directions * rng.uniform(*distance, (count, 1)) * scale
    fresh = random_params(dim, count, rng, dtype)
    if dim == 2:
        params_b = ((params_a[0] + offsets[:, 0]).astype(dtype),
                    (params_a[1] + offsets[:, 1]).astype(dtype), fresh[2])
    else:
        params_b = ((params_a[0] + offsets).astype(dtype), fresh[1])
    return Pairs(pool_a, pool_b, rng.integers(len(pool_a.points), size=count),
                 rng.integers(len(pool_b.points), size=count), params_a, params_b, dtype)


def make_pose(params) -> jaxsat.Pose:
    """One pose from its parameters: (x, y, angle) in 2D, (translation, quaternion) in 3D."""
    return jaxsat.pose2(*params) if len(params) == 3 else jaxsat.pose3(*params)


def take(tree, index):
    """Entries `index` of every leaf, in NumPy: eager JAX indexing would compile a gather for
    every new combination of shapes, which costs more than the queries themselves."""
    return jax.tree.map(lambda leaf: np.asarray(leaf)[index], tree)


def rotations(dim: int, params) -> np.ndarray:
    if dim == 2:
        return np.stack([oracle.rotation_2d(float(angle)) for angle in params[2]])
    return np.stack([oracle.rotation_3d(q) for q in params[1]])


def translations(dim: int, params) -> np.ndarray:
    if dim == 2:
        return np.stack([params[0], params[1]], axis=1).astype(np.float64)
    return np.asarray(params[0], np.float64)


def world_points(pairs: Pairs):
    """(world A, world B) float64 point lists, from raw points and SciPy rotations."""
    world = []
    for shapes, index, params in ((pairs.pool_a, pairs.index_a, pairs.params_a),
                                  (pairs.pool_b, pairs.index_b, pairs.params_b)):
        world.append([oracle.to_world(shapes.points[i], r, t) for i, r, t in
                      zip(index, rotations(pairs.dim, params), translations(pairs.dim, params),
                          strict=True)])
    return world[0], world[1]


@dataclasses.dataclass
class Reference:
    """Oracle values for one pair."""

    value: float
    """Exact signed distance: the distance when apart, minus the depth when overlapping."""
    depth: float
    normal: np.ndarray
    normal_is_unique: bool
    size: float
    world_a: np.ndarray
    world_b: np.ndarray


def references(pairs: Pairs, tie_factor: float = 10.0) -> list[Reference]:
    world_a, world_b = world_points(pairs)
    refs = []
    for a, b in zip(world_a, world_b, strict=True):
        size = max(oracle.bounding_radius(a), oracle.bounding_radius(b))
        o = oracle.evaluate(a, b, tie_factor * RELATIVE_TOLERANCE[pairs.dtype] * size)
        value = o.distance if o.depth < 0 else -o.depth
        refs.append(Reference(value, o.depth, o.normal, o.normal_is_unique, size, a, b))
    return refs


def run_batched(function, count: int, *args):
    """function(*args) over a leading axis of length `count`, in chunks of exactly BATCH
    (the last one padded by repetition), as NumPy arrays."""
    padded = np.resize(np.arange(count), -(-count // BATCH) * BATCH)
    chunks = [function(*take(args, padded[start:start + BATCH]))
              for start in range(0, len(padded), BATCH)]
    return jax.tree.map(lambda *leaves: np.concatenate(leaves)[:count], *chunks)


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


# --------------------------------------------------------------------------------------------
# Closest features built by hand, with analytic distances and witness points.
# --------------------------------------------------------------------------------------------


def quaternion(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def quaternion_product(p, q):
    w1, x1, y1, z1 = p
    w2, x2, y2, z2 = q
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_SQUARE = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
_DIAGONAL_2 = np.array([1.0, 1.0]) / np.sqrt(2)
_DIAGONAL_3 = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
_XY = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)


@dataclasses.dataclass
class Case:
    """b's raw points at its pose (translation, rotation) against the square or cube
    [-1, 1]^D at the identity; value, and the witness points where they are unique."""

    points_b: np.ndarray
    translation: np.ndarray
    rotation: float | np.ndarray
    """2D: angle; 3D: quaternion."""
    value: float
    point_a: np.ndarray | None
    point_b: np.ndarray | None
    sat_is_exact: bool
    """Whether some SAT axis (face normal, edge-edge cross product) attains the value."""


def _triangle_vertex_towards(corner_direction, distance_to_vertex, radius):
    """Regular triangle of `radius` turned so that vertex 0 points along -corner_direction,
    placed with that vertex `distance_to_vertex` beyond the square's corner (1, 1)."""
    corners = radius * np.stack([np.cos(2 * np.pi * np.arange(3) / 3),
                                 np.sin(2 * np.pi * np.arange(3) / 3)], axis=1)
    angle = np.arctan2(-corner_direction[1], -corner_direction[0])
    tip = np.array([1.0, 1.0]) + distance_to_vertex * corner_direction
    return corners, tip + radius * corner_direction, angle, tip


def cases_2d(s: float) -> dict[str, Case]:
    corners, centre, angle, tip = _triangle_vertex_towards(_DIAGONAL_2, s, 0.8)
    half = 0.5 * _SQUARE
    return {
        # Corner (1, 1) against corner (1 + s, 1 + s): SAT sees only s, the distance is s sqrt 2.
        "vertex-vertex squares": Case(half, np.array([1.5 + s, 1.5 + s]), 0.0, s * np.sqrt(2),
                                      np.array([1.0, 1.0]), np.array([1.0 + s, 1.0 + s]), False),
        # A triangle's tip s beyond the corner along the diagonal; its edges run at 15 and 75
        # degrees, inside the corner's normal cone, so the tip is the closest point.
        "vertex-vertex triangle": Case(corners, centre, angle, s, np.array([1.0, 1.0]), tip,
                                       False),
        # A triangle's tip s beyond the middle of the edge x = 1.
        "vertex-edge": Case(corners, np.array([1.0 + s + 0.8, 0.3]), np.pi, s,
                            np.array([1.0, 0.3]), np.array([1.0 + s, 0.3]), True),
        "edge-edge": Case(half, np.array([1.5 + s, 0.7]), 0.0, s, None, None, True),
    }


def _tetrahedron(tip, spokes):
    return np.vstack([np.zeros(3), spokes]), np.asarray(tip, float)


def cases_3d(s: float) -> dict[str, Case]:
    cases = {}
    # Corner against corner along the body diagonal.
    cases["vertex-vertex cubes"] = Case(0.5 * _CUBE, (1.5 + s) * np.ones(3), IDENTITY,
                                        s * np.sqrt(3), np.ones(3), (1 + s) * np.ones(3), False)
    # A tetrahedron's tip s beyond the corner (1, 1, 1); its other vertices lie further out in
    # every coordinate, so the whole tetrahedron sits in the corner's normal cone.
    points, tip = _tetrahedron(np.ones(3) + s * _DIAGONAL_3,
                               [[1.0, 0.3, 0.2], [0.2, 1.2, 0.4], [0.5, 0.6, 1.1]])
    cases["vertex-vertex tetrahedron"] = Case(points, tip, IDENTITY, s, np.ones(3), tip, False)
    # A tip s beyond the middle of the edge {x = y = 1}; the spokes move away in x and y, and no
    # edge of the tetrahedron is perpendicular to (1, 1, 0), so no SAT axis is (1, 1, 0).
    points, tip = _tetrahedron(np.array([1.0, 1.0, 0.25]) + s * _XY,
                               [[1.0, 0.3, 0.2], [0.2, 1.3, -0.4], [0.8, 0.9, 0.9]])
    cases["vertex-edge"] = Case(points, tip, IDENTITY, s, np.array([1.0, 1.0, 0.25]), tip,
                                False)
    # The same with the foot of the tip 1e-8 from the end of the edge: the vertex-vertex pair
    # to the cube's corner is then longer than the closest pair by a relative (1e-8 / s)^2 only.
    points, tip = _tetrahedron(np.array([1.0, 1.0, 1.0 - 1e-8]) + s * _XY,
                               [[1.0, 0.3, -0.2], [0.2, 1.3, -0.4], [0.8, 0.9, -0.9]])
    cases["vertex-edge near the end"] = Case(points, tip, IDENTITY, s,
                                             np.array([1.0, 1.0, 1.0 - 1e-8]), tip, False)
    # A tip s beyond the face x = 1.
    points, tip = _tetrahedron(np.array([1.0 + s, 0.2, 0.3]),
                               [[1.0, 0.3, 0.2], [0.6, -0.8, 0.5], [0.7, 0.4, -0.9]])
    cases["vertex-face"] = Case(points, tip, IDENTITY, s, np.array([1.0, 0.2, 0.3]), tip, True)
    # Skew edges: b's edge along (1, -1, 0) crosses the edge {x = y = 1} at z = 0.2 in
    # projection, s away along (1, 1, 0); the rest of b lies further along (1, 1, 0).
    across = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    middle = np.array([1.0, 1.0, 0.2]) + s * _XY
    points = np.array([0.7 * across, -0.7 * across, 0.9 * _XY + [0, 0, 0.6],
                       0.9 * _XY - [0, 0, 0.6]])
    cases["edge-edge skew"] = Case(points, middle, IDENTITY, s, np.array([1.0, 1.0, 0.2]),
                                   middle, True)
    # Parallel edges {x = y = 1} and {x = y = 1 + s}: distance s sqrt 2, any z in the overlap.
    cases["edge-edge parallel"] = Case(0.5 * _CUBE, np.array([1.5 + s, 1.5 + s, 0.2]),
                                       IDENTITY, s * np.sqrt(2), None, None, False)
    # Parallel faces x = 1 and x = 1 + s, offset sideways.
    cases["face-face offset"] = Case(0.5 * _CUBE, np.array([1.5 + s, 0.4, -0.3]),
                                     quaternion([1, 0, 0], 0.3), s, None, None, True)
    return cases


def moved_params(dim: int, case: Case, motion):
    """Pose parameters of a (identity) and b after the common rigid motion (turn, shift)."""
    turn, shift = motion
    if dim == 2:
        rotation = oracle.rotation_2d(turn)
        position = rotation @ case.translation + shift
        return (shift[0], shift[1], turn), (position[0], position[1], turn + case.rotation)
    rotation = oracle.rotation_3d(turn)
    return ((shift, turn),
            (rotation @ case.translation + shift, quaternion_product(turn, case.rotation)))


def _columns(params, side: int):
    """Per-pair parameter tuples to a tuple of batched arrays."""
    return tuple(np.array([p[side][k] for p in params], np.float64)
                 for k in range(len(params[0][side])))


def hand_built_pairs(dim: int, label: str, gaps, motions: int = 3, seed: int = 36,
                     max_vertices: int = 8):
    """Every hand-built case for every gap s, each under `motions` + 1 common rigid motions
    (the identity first), against the unit square or cube. `label` picks the size classes:
    "padded" (8-gons; in 3D hulls padded to `max_vertices`) or "box" (unpadded cuboids: the
    cube cases only). Returns (pairs, entries (name, s, case, motion))."""
    rng = np.random.default_rng(seed)
    if dim == 2:
        moves = [(0.0, np.zeros(2))] + [(rng.uniform(-np.pi, np.pi), rng.normal(size=2))
                                        for _ in range(motions)]
        unit = (jaxsat.box([1.0, 1.0], max_vertices=8), _SQUARE)
        make_b = lambda points: jaxsat.polygon(points, max_vertices=8)  # noqa: E731
    else:
        moves = [(IDENTITY, np.zeros(3))] + [(rng.normal(size=4), rng.normal(size=3))
                                             for _ in range(motions)]
        if label == "padded":
            unit = (jaxsat.box([1.0, 1.0, 1.0], max_vertices=max_vertices), _CUBE)
            make_b = lambda points: jaxsat.polyhedron(points, max_vertices)  # noqa: E731
        else:
            unit = (jaxsat.box([1.0, 1.0, 1.0]), _CUBE)
            make_b = None
    entries, shapes_b = [], []
    for s in gaps:
        for name, case in (cases_2d if dim == 2 else cases_3d)(s).items():
            is_cube = case.points_b.shape == (8, 3) and np.array_equal(case.points_b, 0.5 * _CUBE)
            if make_b is None and not is_cube:
                continue  # the unpadded box class holds cuboids only
            shape_b = jaxsat.box([0.5] * 3) if make_b is None else make_b(case.points_b)
            for motion in moves:
                entries.append((name, s, case, motion))
                shapes_b.append((shape_b, case.points_b))
    params = [moved_params(dim, case, motion) for _, _, case, motion in entries]
    count = len(entries)
    pairs = Pairs(hand_pool(dim, [unit]), hand_pool(dim, shapes_b), np.zeros(count, int),
                  np.arange(count), _columns(params, 0), _columns(params, 1), np.float64)
    return pairs, entries


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


def test_hand_built_overlaps_have_touching_witnesses():
    """Shallow overlaps (s < 0) through a vertex-face or an edge-edge contact: the value is
    s, and the witnesses are where the shapes touch after moving b out by |s| along the
    normal: point_a is the contact point on a, point_b = point_a + s * normal on b."""
    entries = []
    for s in (-1e-6, -1e-3, -0.05):
        cases = cases_3d(s)
        for name, normal in (("vertex-face", np.array([1.0, 0, 0])), ("edge-edge skew", _XY)):
            entries.append((s, cases[name], normal))
    count = len(entries)
    pool_a = hand_pool(3, [(jaxsat.box([1.0, 1.0, 1.0], max_vertices=20), _CUBE)])
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
    error = np.abs(derivative - central)[smooth]
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


@pytest.mark.slow
def test_jit_matches_eager_and_batched():
    """Eager and jitted single calls and the batched call agree (eager is slow: 2 pairs)."""
    pairs = _single_pairs(2, 40)
    _, batched, _ = check_against_oracle(pairs)
    for i in range(len(pairs)):
        inputs = take(pairs.inputs(), i)
        eager = float(_distance_query(*inputs))
        assert eager == pytest.approx(float(_single_query(*inputs)), abs=1e-12)
        assert eager == pytest.approx(float(batched[i]), abs=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=DTYPE_IDS)
def test_output_dtypes_follow_inputs(dtype):
    """float32 shapes and poses give float32 results everywhere, float64 give float64."""
    pairs = random_pairs(pool("box", dtype), pool("box", dtype), 4, np.random.default_rng(41),
                         dtype)
    assert pairs.pool_a.shapes.dtype == dtype
    assert all(p.dtype == dtype for p in (*pairs.params_a, *pairs.params_b))
    closest, distance = exact_batch(*take(pairs.inputs(), np.resize(np.arange(4), BATCH)))
    assert distance.dtype == dtype and distance.shape == (BATCH,)
    for leaf in jax.tree.leaves(closest):
        assert leaf.dtype == dtype


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
